#include "routing/link_events.h"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "core/log.h"
#include "routing/router.h"

namespace mavbond {

namespace {
constexpr size_t kTextMax = 50;
}  // namespace

LinkEvents::LinkEvents(Duration silent_after, Duration min_interval)
    : silent_after_(silent_after), min_interval_(min_interval) {}

uint32_t LinkEvents::add_bond(std::string name) {
    bonds_.push_back(Bond{std::move(name), "", "", 0, {}});
    return static_cast<uint32_t>(bonds_.size() - 1);
}

uint32_t LinkEvents::add_link(uint32_t bond, std::string name) {
    Link l;
    l.name = std::move(name);
    l.bond = bond;
    links_.push_back(std::move(l));
    return static_cast<uint32_t>(links_.size() - 1);
}

unsigned LinkEvents::up_count(uint32_t bond, unsigned* members) const {
    unsigned up = 0, all = 0;
    for (const Link& l : links_) {
        if (l.bond != bond)
            continue;
        all++;
        up += l.state == State::Up ? 1 : 0;
    }
    if (members)
        *members = all;
    return up;
}

std::string LinkEvents::link_text(std::string_view link, bool up, std::string_view bond,
                                  unsigned up_count, unsigned members) {
    const char* what = up ? "back" : "lost";
    std::string l(link), b(bond);
    char text[256];
    snprintf(text, sizeof text, "mavbond: link %s %s (bond %s, %u of %u up)", l.c_str(), what,
             b.c_str(), up_count, members);
    if (strlen(text) > kTextMax)
        snprintf(text, sizeof text, "mavbond: %s %s (%s %u/%u up)", l.c_str(), what, b.c_str(),
                 up_count, members);
    return std::string(text).substr(0, kTextMax);
}

void LinkEvents::observe_link(uint32_t id, TimePoint last_rx, TimePoint now) {
    Link& l = links_[id];
    const bool was_due = l.state != l.reported;
    bool heard = last_rx > l.last_heard;
    const Bond& b = bonds_[l.bond];
    if (heard) {
        l.last_heard = last_rx;
        if (l.state == State::Up)
            return;
        State was = l.state;
        l.state = State::Up;
        unsigned members = 0;
        unsigned up = up_count(l.bond, &members);
        if (was == State::Never) {
            l.reported = State::Up;  // first heard: the normal start, not news for the GCS
            events_.push_back("link " + l.name + " up (bond " + b.name + ", " +
                              std::to_string(up) + " of " + std::to_string(members) + " up)");
            return;
        }
        events_.push_back("link " + l.name + " back (bond " + b.name + ", " + std::to_string(up) +
                          " of " + std::to_string(members) + " up)");
    } else if (l.state == State::Up && now - l.last_heard >= silent_after_) {
        l.state = State::Lost;
        unsigned members = 0;
        unsigned up = up_count(l.bond, &members);
        events_.push_back("link " + l.name + " lost (bond " + b.name + ", " + std::to_string(up) +
                          " of " + std::to_string(members) + " up; silent for " +
                          std::to_string(std::chrono::duration_cast<milliseconds>(now - l.last_heard).count()) +
                          " ms)");
    } else {
        return;
    }
    // Waiting since it came to differ from what the GCS was told (back to it: nothing is due).
    if (!was_due)
        l.subject.changed = now;
}

void LinkEvents::observe_bond(uint32_t id, std::string_view active, uint64_t switches,
                              TimePoint now) {
    Bond& b = bonds_[id];
    if (switches == b.switches && active == b.active)
        return;
    const bool was_due = b.active != b.reported;
    uint64_t count = switches - b.switches;
    b.switches = switches;
    b.active = std::string(active);
    if (b.reported.empty()) {
        b.reported = b.active;  // the first choice is the start, not a switch
        events_.push_back("bond " + b.name + ": active link " + b.active);
        return;
    }
    events_.push_back("bond " + b.name + ": active link now " +
                      (b.active.empty() ? std::string("none") : b.active) + " (" +
                      std::to_string(count) + (count == 1 ? " switch)" : " switches)"));
    if (!was_due)
        b.subject.changed = now;
}

bool LinkEvents::may_send(const Subject& s, TimePoint now) const {
    return !s.last_sent || now - *s.last_sent >= min_interval_;
}

void LinkEvents::sent(Subject& s, TimePoint now) {
    s.last_sent = now;
    recent_.push_back(now);
}

LinkEvents::Output LinkEvents::poll(TimePoint now) {
    Output out;
    out.events.swap(events_);
    while (!recent_.empty() && now - recent_.front() >= min_interval_)
        recent_.pop_front();

    // Subjects whose state differs from the one last reported, the longest-waiting first.
    struct Due {
        TimePoint since;
        bool is_link;
        uint32_t index;
    };
    std::vector<Due> due;
    for (uint32_t i = 0; i < links_.size(); i++) {
        if (links_[i].state != links_[i].reported)
            due.push_back(Due{links_[i].subject.changed, true, i});
    }
    for (uint32_t i = 0; i < bonds_.size(); i++) {
        if (!bonds_[i].active.empty() && bonds_[i].active != bonds_[i].reported)
            due.push_back(Due{bonds_[i].subject.changed, false, i});
    }
    std::stable_sort(due.begin(), due.end(),
                     [](const Due& a, const Due& b) { return a.since < b.since; });

    for (const Due& d : due) {
        if (recent_.size() >= kGlobalBurst)
            break;
        if (d.is_link) {
            Link& l = links_[d.index];
            if (!may_send(l.subject, now))
                continue;
            unsigned members = 0;
            unsigned up = up_count(l.bond, &members);
            bool is_up = l.state == State::Up;
            Severity sev = is_up ? Severity::Notice : up == 0 ? Severity::Critical : Severity::Warning;
            out.notices.push_back(
                Notice{sev, link_text(l.name, is_up, bonds_[l.bond].name, up, members)});
            l.reported = l.state;
            sent(l.subject, now);
        } else {
            Bond& b = bonds_[d.index];
            if (!may_send(b.subject, now))
                continue;
            std::string text = "mavbond: bond " + b.name + " switched to " + b.active;
            if (text.size() > kTextMax)
                text = "mavbond: " + b.name + " now on " + b.active;
            out.notices.push_back(Notice{Severity::Warning, text.substr(0, kTextMax)});
            b.reported = b.active;
            sent(b.subject, now);
        }
    }
    return out;
}

// --- LinkEventMonitor ------------------------------------------------------------------------

LinkEventMonitor::LinkEventMonitor(const LinkEventsConfig& config, const Router& router,
                                   EventLoop& loop, LocalSource& source)
    : config_(config), router_(router), source_(source),
      events_(config.silent_after, config.min_interval) {
    for (const Bond& b : router.bonds()) {
        uint32_t bond = events_.add_bond(b.name());
        auto& ids = links_.emplace_back();
        for (const std::string& member : b.members())
            ids.push_back(events_.add_link(bond, member));
    }
    timer_ = loop.schedule(kTick, [this, &loop] {
        tick(router_.arrival_clock(loop.now()));
        return kTick;
    });
}

void LinkEventMonitor::tick(TimePoint now) {
    const auto& bonds = router_.bonds();
    for (uint32_t i = 0; i < bonds.size(); i++) {
        for (uint32_t m = 0; m < links_[i].size(); m++)
            events_.observe_link(links_[i][m], bonds[i].last_heard(m), now);
        const Link* active = router_.link(bonds[i].active_link());
        events_.observe_bond(i, active ? active->endpoint_name() : "", bonds[i].switches(), now);
    }
    LinkEvents::Output out = events_.poll(now);
    for (const auto& e : out.events)
        log_notice("link event: %s", e.c_str());
    for (const auto& n : out.notices) {
        log_info("statustext severity=%d \"%s\"%s", static_cast<int>(n.severity), n.text.c_str(),
                 config_.statustext ? "" : " (not sent: statustext is off)");
        if (config_.statustext)
            source_.send_statustext(n.severity, n.text);
    }
}

}  // namespace mavbond
