#include "routing/link_events.h"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "core/log.h"
#include "mavlink/frame_parser.h"
#include "routing/router.h"

namespace mavbond {

namespace {
constexpr size_t kTextMax = 50;
constexpr uint32_t kMsgStatustext = 253;
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

void LinkEvents::set_direction(std::string_view own) { direction_ = own; }

std::string_view LinkEvents::own_direction() const {
    return direction_.empty() ? std::string_view("inbound") : std::string_view(direction_);
}

std::string_view LinkEvents::far_direction() const {
    return direction_ == "downlink" ? "uplink" : direction_ == "uplink" ? "downlink" : "outbound";
}

LinkEvents::Whole LinkEvents::whole_of(const Link& l) {
    if (l.own == State::Never)
        return Whole::Never;
    const bool own_lost = l.own == State::Lost;
    // No report lately: where this side hears nothing either, the far side's reception goes
    // with it (both links cut: no report can come); else it is what the last report said.
    const State far = l.far != State::Never ? l.far : own_lost ? State::Lost : l.far_known;
    const bool far_lost = far == State::Lost;
    if (own_lost && far_lost)
        return Whole::Lost;
    if (own_lost || far_lost)
        return own_lost ? Whole::OwnLost : Whole::FarLost;
    return Whole::Up;
}

unsigned LinkEvents::up_count(uint32_t bond, unsigned* members) const {
    unsigned up = 0, all = 0;
    for (const Link& l : links_) {
        if (l.bond != bond)
            continue;
        all++;
        up += l.whole == Whole::Up ? 1 : 0;
    }
    if (members)
        *members = all;
    return up;
}

std::string LinkEvents::link_text(std::string_view link, std::string_view what,
                                  std::string_view bond, unsigned up_count, unsigned members) {
    std::string l(link), w(what), b(bond);
    char text[256];
    snprintf(text, sizeof text, "mavbond: link %s %s (bond %s, %u of %u up)", l.c_str(),
             w.c_str(), b.c_str(), up_count, members);
    if (strlen(text) > kTextMax)
        snprintf(text, sizeof text, "mavbond: %s %s (%s %u/%u up)", l.c_str(), w.c_str(),
                 b.c_str(), up_count, members);
    return std::string(text).substr(0, kTextMax);
}

std::string LinkEvents::what_of(const Link& l, bool* back) const {
    // One way only: from lost both ways, the other way came back; else this way was lost.
    const bool from_lost = l.reported == Whole::Lost;
    *back = l.whole == Whole::Up || (one_way(l.whole) && from_lost);
    switch (l.whole) {
    case Whole::Up:
        return "back";
    case Whole::Lost:
        return "lost";
    case Whole::OwnLost:
        return std::string(from_lost ? far_direction() : own_direction()) + (from_lost ? " back" : " lost");
    case Whole::FarLost:
        return std::string(from_lost ? own_direction() : far_direction()) + (from_lost ? " back" : " lost");
    case Whole::Never:
        break;
    }
    return "";
}

void LinkEvents::follow(Link& l, TimePoint now) {
    const Whole before = l.whole;
    l.whole = whole_of(l);
    if (l.whole == before)
        return;
    if (before == Whole::Never)
        l.reported = Whole::Up;  // first heard: the normal start, not news for the GCS
    else if (before == l.reported)
        l.subject.changed = now;  // came to differ from what the GCS was told
    l.since = now;
}

void LinkEvents::log_change(const Link& l, bool far, State was, State state,
                            const std::string& why) {
    unsigned members = 0;
    const unsigned up = up_count(l.bond, &members);
    const std::string dir(far ? far_direction() : direction_);
    const char* what = state == State::Lost ? "lost" : was == State::Never ? "up" : "back";
    events_.push_back("link " + l.name + (dir.empty() ? "" : " " + dir) + " " + what + " (bond " +
                      bonds_[l.bond].name + ", " + std::to_string(up) + " of " +
                      std::to_string(members) + " up" + (why.empty() ? "" : "; " + why) + ")");
}

void LinkEvents::observe_link(uint32_t id, TimePoint last_rx, bool silent, TimePoint now,
                              const std::string& why) {
    Link& l = links_[id];
    // Lost only once heard (a link never heard is not news).
    const State state = last_rx == TimePoint{} ? State::Never : silent && l.own != State::Never
                                                                    ? State::Lost
                                                                    : State::Up;
    if (state == l.own)
        return;
    const State was = l.own;
    l.own = state;
    follow(l, now);
    log_change(l, false, was, state, why);
}

void LinkEvents::observe_reported(uint32_t id, std::optional<bool> up, TimePoint now) {
    Link& l = links_[id];
    const State state = !up ? State::Never : *up ? State::Up : State::Lost;
    if (state == l.far)
        return;
    l.far = state;
    follow(l, now);
    // A report that stopped says nothing; one that comes again is news only if it differs.
    if (state == State::Never || state == l.far_known)
        return;
    const State was = l.far_known;
    l.far_known = state;
    log_change(l, true, was, state, "as the far side reports");
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
        const Link& l = links_[i];
        // One way only: the other way's finding may be on its way.
        if (l.whole != Whole::Never && l.whole != l.reported &&
            (!one_way(l.whole) || now - l.since >= kSettle))
            due.push_back(Due{l.subject.changed, true, i});
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
            const unsigned up = up_count(l.bond, &members);
            bool back = false;
            const std::string what = what_of(l, &back);
            const Severity sev = back ? Severity::Notice : up == 0 ? Severity::Critical : Severity::Warning;
            out.notices.push_back(Notice{sev, link_text(l.name, what, bonds_[l.bond].name, up, members),
                                         l.bond});
            l.reported = l.whole;
            sent(l.subject, now);
        } else {
            Bond& b = bonds_[d.index];
            if (!may_send(b.subject, now))
                continue;
            std::string text = "mavbond: bond " + b.name + " switched to " + b.active;
            if (text.size() > kTextMax)
                text = "mavbond: " + b.name + " now on " + b.active;
            out.notices.push_back(Notice{Severity::Warning, text.substr(0, kTextMax), d.index});
            b.reported = b.active;
            sent(b.subject, now);
        }
    }
    return out;
}

// --- LinkEventMonitor ------------------------------------------------------------------------

LinkEventMonitor::LinkEventMonitor(const LinkEventsConfig& config, Router& router,
                                   EventLoop& loop, LocalSource& source)
    : config_(config), router_(router), source_(source),
      events_(config.silent_after, config.min_interval) {
    for (const Bond& b : router.bonds()) {
        uint32_t bond = events_.add_bond(b.name());
        BondLinks& ids = links_.emplace_back();
        for (const std::string& member : b.members())
            ids.members.push_back(events_.add_link(bond, member));
        if (!b.standby())
            ids.silence = std::make_unique<LinkSilence>(b.members(), router.arrival_clock(loop.now()));
    }
    timer_ = loop.schedule(kTick, [this, &loop] {
        tick(router_.arrival_clock(loop.now()));
        return kTick;
    });
}

bool LinkEventMonitor::announces(const LinkEventsConfig& config, const Router& router) {
    return config.statustext.value_or(!router.local_autopilot());
}

void LinkEventMonitor::tick(TimePoint now) {
    // What this side receives goes from the vehicle when the vehicle is heard through a bond,
    // to it when its autopilot is heard here.
    bool vehicle_beyond = false;
    for (const Bond& b : router_.bonds())
        vehicle_beyond = vehicle_beyond || b.autopilot().has_value();
    events_.set_direction(vehicle_beyond ? "downlink" : router_.local_autopilot() ? "uplink" : "");
    const auto& bonds = router_.bonds();
    for (uint32_t i = 0; i < bonds.size(); i++) {
        BondLinks& ids = links_[i];
        const Standby* standby = bonds[i].standby();
        const LinkSilence& silence = standby ? standby->silence() : *ids.silence;
        for (uint32_t m = 0; m < ids.members.size(); m++) {
            const TimePoint last = bonds[i].last_heard(m);
            if (ids.silence)
                ids.silence->heard(m, last, now);
            const LinkSilence::Verdict v = silence.judge(m, last, now, events_.least_silence(),
                                                         events_.most_silence());
            events_.observe_link(ids.members[m], last, v.silent, now,
                                 v.silent ? silence.explain(v) : std::string());
            // The far side's reception of its free links, as its standby reports say (a report
            // that stopped says nothing: this side hears nothing then either).
            std::optional<bool> far;
            if (standby) {
                for (const Standby::PeerLink& p : standby->peer_links()) {
                    if (now - p.heard <= Standby::kReportTimeout &&
                        Standby::reported_name(bonds[i].members()[m]) == p.name)
                        far = p.permille < 1000;
                }
            }
            events_.observe_reported(ids.members[m], far, now);
        }
        const Link* active = router_.link(bonds[i].active_link());
        events_.observe_bond(i, active ? active->endpoint_name() : "", bonds[i].switches(), now);
    }
    LinkEvents::Output out = events_.poll(now);
    for (const auto& e : out.events)
        log_notice("link event: %s", e.c_str());
    const bool sends = announces(config_, router_);
    for (const auto& n : out.notices) {
        log_info("statustext severity=%d \"%s\"%s", static_cast<int>(n.severity), n.text.c_str(),
                 sends                             ? ""
                 : config_.statustext.has_value() ? " (not sent: statustext is off)"
                                                  : " (not sent: the ground side announces)");
        if (sends)
            announce(n.bond, n);
    }
}

void LinkEventMonitor::announce(uint32_t bond, const LinkEvents::Notice& notice) {
    const auto payload = statustext_payload(notice.severity, notice.text);
    Bond& b = router_.bond(bond);
    if (auto vehicle = b.autopilot()) {
        if (auto seq = b.number_added_frame(vehicle->sysid, vehicle->compid)) {
            inject_local_frame(router_, FrameSource{vehicle->sysid, vehicle->compid, *seq},
                               kMsgStatustext, payload, Router::Reach::like_bond(bond));
            return;
        }
    }
    source_.send_statustext(notice.severity, notice.text);
}

}  // namespace mavbond
