#include "routing/router.h"

#include <algorithm>

#include "core/log.h"
#include "mavlink/frame_parser.h"
#include "mavlink/radio_status.h"

namespace mavbond {

Router::Router(EventLoop& loop, Duration route_timeout) : loop_(loop), route_timeout_(route_timeout) {}

// --- what endpoints call -------------------------------------------------------------------

void Router::attach(Link& link) {
    auto free_slot = std::find_if(slots_.begin(), slots_.end(), [](const Slot& s) { return !s.link; });
    if (free_slot == slots_.end())
        free_slot = slots_.emplace(slots_.end());
    link.id_ = static_cast<LinkId>(free_slot - slots_.begin());
    free_slot->link = &link;
    free_slot->routes.clear();
    free_slot->positions.clear();
    place_links();
    if (link.records_everything())
        recorders_.push_back(&link);
    if (filter_)
        filter_->on_link(link, true);
}

void Router::detach(Link& link) {
    LinkId id = link.id();
    if (id >= slots_.size() || slots_[id].link != &link)
        return;
    if (filter_)
        filter_->on_link(link, false);
    Slot& s = slots_[id];
    if (s.bond != kNoBond) {
        Bond& bond = bonds_[s.bond];
        bond.forget_link(id);
        // Its frames still waiting go with it (a link gone within a round of a stall).
        // Lent frames of a socket that goes are no longer valid, copied ones no longer wanted.
        auto& waiting = bond.waiting;
        size_t before = waiting.size();
        waiting.erase(std::remove_if(waiting.begin(), waiting.end(),
                                     [&](const Bond::WaitingFrame& w) { return w.received.from == &link; }),
                      waiting.end());
        if (waiting.size() != before)
            log_warning("[%s] removed with %zu received frames not yet handled: dropped",
                        link.name().c_str(), before - waiting.size());
    }
    s = Slot{};
    dirty_.erase(std::remove(dirty_.begin(), dirty_.end(), &link), dirty_.end());
    recorders_.erase(std::remove(recorders_.begin(), recorders_.end(), &link), recorders_.end());
    link.id_ = kNoLink;
}

void Router::attach(Input& input) {
    inputs_.push_back(&input);
    place_links();
}

void Router::detach(Input& input) {
    inputs_.erase(std::remove(inputs_.begin(), inputs_.end(), &input), inputs_.end());
    place_links();
}

void Router::ingress(ReceivedBatch& batch) {
    Input* input = batch.input();
    if (input) {
        // A socket epoll reported readable held its first datagram when epoll looked.
        polled_no_earlier_than(input->first_reported());
        if (input->bond_index_ != kNoBond) {
            // A datagram socket's buffer lasts the round: its bond's frames wait there, lent,
            // for the merge of everything the round read (its links are the bond's).
            Bond& bond = bonds_[input->bond_index_];
            for (size_t i = 0; i < batch.size(); i++) {
                const ReceivedFrame& r = batch[i];
                bond.heard(slot(*r.from).member, r.arrival);
                bond.wait(r, wait_order_++, false);
            }
            return;
        }
    }
    ready_.clear();
    for (size_t i = 0; i < batch.size(); i++) {
        ReceivedFrame& r = batch[i];
        const Slot& from = slot(*r.from);
        if (from.bond == kNoBond) {
            ready_.push_back(&r);
            continue;
        }
        Bond& bond = bonds_[from.bond];
        bond.heard(from.member, r.arrival);
        if (bond.must_wait(r.arrival, polled(), loop_.all_reported())) {
            // A byte stream reuses its buffer at its next read: the frame is copied aside.
            bond.wait(r, wait_order_++, true);
            frames_held_back_++;
        } else {
            ready_.push_back(&r);
        }
    }
    handle(ready_.data(), ready_.size());
}

void Router::end_batch() {
    // flush() may call back into detach() (a connection closing on a write error), which
    // edits dirty_: take from the back until it is empty.
    while (!dirty_.empty()) {
        Link* link = dirty_.back();
        dirty_.pop_back();
        link->flush();
    }
}

// --- bonds and links -----------------------------------------------------------------------

void Router::replace_bonds(const Config& config) {
    // Frames waiting in a bond that is replaced are handled first, in the order they came.
    merge_round(true);
    std::vector<Bond> old = std::move(bonds_);
    bonds_.clear();
    for (const auto& b : config.bonds) {
        Bond& bond = bonds_.emplace_back(b, config.endpoints, config.tx_classes, loop_.now());
        auto was = std::find_if(old.begin(), old.end(),
                                [&](const Bond& o) { return o.name() == bond.name(); });
        if (was != old.end() && bond.continue_from(*was))
            log_info("bond %s: standby continues %s", bond.name().c_str(),
                     bond.standby()->active() ? "active" : "in standby");
    }
    place_links();
}

void Router::place_links() {
    for (Slot& s : slots_) {
        if (!s.link)
            continue;
        s.bond = bond_index(s.link->bond());
        s.member = s.bond == kNoBond ? Bond::kNoMember
                                     : bonds_[s.bond].member_index(s.link->endpoint_name());
    }
    for (Bond& b : bonds_)
        b.inputs.clear();
    for (Input* in : inputs_) {
        in->bond_index_ = bond_index(in->bond());
        if (in->bond_index_ != kNoBond)
            bonds_[in->bond_index_].inputs.push_back(in);
    }
}

uint32_t Router::bond_index(const std::string& name) const {
    for (size_t i = 0; i < bonds_.size(); i++) {
        if (bonds_[i].name() == name)
            return static_cast<uint32_t>(i);
    }
    return kNoBond;
}

void Router::set_filter(FrameFilter* filter) {
    filter_ = filter;
    if (!filter_)
        return;
    for (const Slot& s : slots_) {
        if (s.link)
            filter_->on_link(*s.link, true);
    }
}

bool Router::set_active_link(uint32_t bond, LinkId link) {
    if (bond >= bonds_.size() || link >= slots_.size() || !slots_[link].link ||
        slots_[link].bond != bond)
        return false;
    bonds_[bond].set_active_link(link);
    return true;
}

// --- routes --------------------------------------------------------------------------------

void Router::learn(Slot& from, uint8_t sysid, uint8_t compid, TimePoint now) {
    for (auto& r : from.routes) {
        if (r.sysid == sysid && r.compid == compid) {
            r.last_heard = now;
            return;
        }
    }
    from.routes.push_back(Route{sysid, compid, now});
}

bool Router::knows(const Link& link, uint8_t sysid, uint8_t compid) const {
    if (link.id() >= slots_.size())
        return false;
    for (const auto& r : slot(link).routes) {
        if (r.sysid == sysid && (compid == 0 || r.compid == compid))
            return true;
    }
    return false;
}

bool Router::target_knows(const Slot& to, uint8_t sysid, uint8_t compid) const {
    if (to.bond == kNoBond)
        return knows(*to.link, sysid, compid);
    for (const Slot& s : slots_) {
        if (s.link && s.bond == to.bond && knows(*s.link, sysid, compid))
            return true;
    }
    return false;
}

void Router::expire_routes(TimePoint now) {
    for (Slot& s : slots_) {
        s.routes.erase(std::remove_if(s.routes.begin(), s.routes.end(),
                                      [&](const Route& r) { return now - r.last_heard > route_timeout_; }),
                       s.routes.end());
    }
}

// --- the data path -------------------------------------------------------------------------

TimePoint Router::polled() const {
    return polled_round_ == loop_.round() ? polled_ : loop_.polled_after();
}

void Router::polled_no_earlier_than(TimePoint t) {
    if (t == TimePoint{})
        return;
    polled_ = std::max(polled(), t);
    polled_round_ = loop_.round();
}

void Router::merge_round(bool all) {
    // Each bond's frames of the round in arrival order, as far as every socket of the bond is
    // read: filtered and routed as one batch.
    std::vector<size_t>& released = released_;
    released.assign(bonds_.size(), 0);
    bool any = false;
    for (size_t b = 0; b < bonds_.size(); b++) {
        Bond& bond = bonds_[b];
        if (bond.waiting.empty())
            continue;
        any = true;
        released[b] = bond.release(polled(), loop_.all_reported(), all);
        ready_.clear();
        for (size_t i = 0; i < released[b]; i++)
            ready_.push_back(&bond.released(i));
        handle(ready_.data(), ready_.size());
    }
    if (!any)
        return;
    // The frames just routed are lent to the links' queues: sent before their bytes move.
    end_batch();
    bool held = false;
    for (size_t b = 0; b < bonds_.size(); b++) {
        Bond& bond = bonds_[b];
        if (bond.waiting.empty())
            continue;
        // What waits past this round needed a copy: it is held back for arrival order.
        frames_held_back_ += bond.keep_unreleased(released[b]);
        held = held || !bond.waiting.empty();
    }
    if (held)
        loop_.request_prompt_round();
}

TimePoint Router::arrival_clock(TimePoint now) const {
    TimePoint t = now;
    for (const Bond& b : bonds_) {
        if (!b.waiting.empty())
            t = std::min(t, b.held_until);
    }
    return t;
}

void Router::handle(ReceivedFrame* const* frames, size_t count) {
    if (count == 0)
        return;
    verdicts_.assign(count, FrameFilter::Ingress{});
    // Each frame's place in its source's stream on its link, once, for the filters and standby.
    for (size_t i = 0; i < count; i++) {
        ReceivedFrame& r = *frames[i];
        if (r.routed)
            r.step = slots_[r.from->id()].positions.track(r.frame.sysid, r.frame.compid, r.frame.seq);
    }
    if (filter_)
        filter_->on_ingress(frames, count, verdicts_.data());
    for (size_t i = 0; i < count; i++) {
        ReceivedFrame& r = *frames[i];
        Slot& from = slots_[r.from->id()];
        // Only a frame whose CRC was checked may teach a route: noise never creates one.
        if (r.frame.crc_checked)
            learn(from, r.frame.sysid, r.frame.compid, r.arrival);
        if (!r.routed)
            continue;
        if (from.bond != kNoBond && standby_sees(from, r))
            continue;
        const FrameFilter::Ingress& v = verdicts_[i];
        bool pass = v.pass;
        if (pass && from.bond != kNoBond && is_radio_status(r.frame.msgid) &&
            bonds_[from.bond].reports_radio_status) {
            bonds_[from.bond].foreign_radio_status++;
            pass = false;
        }
        if (from.bond != kNoBond && bonds_[from.bond].renumbers())
            bonds_[from.bond].renumber(r.frame, pass, v.bond_pos, r.arrival);
        if (pass)
            route(r);
    }
}

bool Router::standby_sees(const Slot& from, const ReceivedFrame& r) {
    Standby* standby = bonds_[from.bond].standby();
    if (!standby)
        return false;
    standby->received(from.member, r.step, r.arrival);
    if (!standby->take_report(r.frame, r.arrival))
        return false;
    // A report may say the free links are failing: act on it at once, not at the next tick.
    judge_standby(from.bond, r.arrival);
    return true;
}

void Router::judge_standby(uint32_t bond, TimePoint now) {
    Standby& standby = *bonds_[bond].standby();
    const uint64_t to_standby = standby.counters().to_standby;
    if (standby.judge(now)) {
        uint64_t resent = resend_held(bond, now);
        log_notice("bond %s: metered links active (the free links are failing); %llu frames "
                   "standby held back resent",
                   bonds_[bond].name().c_str(), static_cast<unsigned long long>(resent));
    } else if (standby.counters().to_standby != to_standby) {
        log_notice("bond %s: metered links back in standby (the free links are healthy)",
                   bonds_[bond].name().c_str());
    }
}

void Router::deliver(const Frame& frame, Slot& to) {
    if (filter_ && !filter_->on_egress(frame, *to.link))
        return;
    if (to.link->send(frame))
        dirty_.push_back(to.link);
}

void Router::deliver_to_recorders(const Slot& from, const Frame& frame) {
    for (Link* to : recorders_) {
        Slot& s = slots_[to->id()];
        if (may_send(from, s, frame))
            deliver(frame, s);
    }
}

void Router::route(const ReceivedFrame& received) {
    const Frame& frame = received.frame;
    const Slot& from = slots_[received.from->id()];
    frames_routed_++;

    if (!frame.is_broadcast()) {
        auto ts = static_cast<uint8_t>(frame.target_system);
        auto tc = static_cast<uint8_t>(frame.target_component > 0 ? frame.target_component : 0);
        // Prefer where the exact component was heard, then where the system was heard;
        // a target heard nowhere is sent everywhere, as a broadcast is.
        for (uint8_t want_comp : {tc, uint8_t{0}}) {
            bool found = false;
            for (Slot& to : slots_) {
                if (!to.link || same_target(from, to))
                    continue;
                if (!target_knows(to, ts, want_comp))
                    continue;
                found = true;
                if (bond_lets_send(to, frame))
                    deliver(frame, to);
            }
            if (found) {
                deliver_to_recorders(from, frame);
                return;
            }
            if (want_comp == 0)
                break;
        }
    }
    bool any = false;
    for (Slot& to : slots_) {
        if (to.link && may_send(from, to, frame)) {
            deliver(frame, to);
            any = true;
        }
    }
    if (!any)
        frames_without_destination_++;
}

void Router::inject(const Frame& frame, Reach reach) {
    for (Slot& to : slots_) {
        if (!to.link)
            continue;
        bool sends = false;
        switch (reach.kind) {
        case Reach::Everywhere:
            sends = bond_lets_send(to, frame);
            break;
        case Reach::OutsideBonds:
            sends = to.bond == kNoBond;
            break;
        case Reach::OneBond:
            sends = to.bond == reach.bond;
            break;
        }
        if (sends)
            deliver(frame, to);
    }
    end_batch();
}

void Router::mark_radio_status_bonds(const Config& config) {
    for (Bond& b : bonds_) {
        b.reports_radio_status = std::any_of(
            config.endpoints.begin(), config.endpoints.end(), [&](const EndpointConfig& ep) {
                return ep.bond == b.name() &&
                       ep.tx_budget.radio_status != RadioStatusSource::None;
            });
    }
}

uint64_t Router::resend_held(uint32_t bond, TimePoint now) {
    Standby* standby = bond < bonds_.size() ? bonds_[bond].standby() : nullptr;
    if (!standby)
        return 0;
    uint64_t sent = 0;
    standby->take_held(now, [&](uint32_t member, std::span<const uint8_t> bytes) {
        // Parsed back as it came (it was a routed frame): the links take a Frame.
        ParserCounters counters;
        DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
        Frame frame;
        if (!parser.next(frame))
            return;
        for (Slot& to : slots_) {
            if (to.link && to.bond == bond && to.member == member) {
                deliver(frame, to);
                sent++;
            }
        }
        // Each frame's bytes live in the ring only until the next: sent before it is reused.
        end_batch();
    });
    standby->counters().resent += sent;
    return sent;
}

}  // namespace mavbond
