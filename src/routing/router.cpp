#include "routing/router.h"

#include <algorithm>

#include "endpoints/endpoint.h"

namespace mavbond {

// --- Input --------------------------------------------------------------------------------

Router::Input::Input(Router& router, const std::string& bond, const EventLoop::Watch& watch)
    : router_(router), bond_name_(bond), watch_(watch) {
    router_.inputs_.push_back(this);
    router_.place_inputs();
}

Router::Input::~Input() {
    auto& inputs = router_.inputs_;
    inputs.erase(std::remove(inputs.begin(), inputs.end(), this), inputs.end());
    router_.place_inputs();
}

// --- Router --------------------------------------------------------------------------------

Router::Router(EventLoop& loop, Duration route_timeout, const std::vector<BondConfig>& bonds)
    : loop_(loop), route_timeout_(route_timeout) {
    replace_bonds(bonds);
}

void Router::replace_bonds(const std::vector<BondConfig>& bonds) {
    // Frames waiting in a bond that is replaced are handled first, in the order they came.
    merge_round(true);
    bonds_.clear();
    for (const auto& b : bonds)
        bonds_.push_back(Bond{b.name, b.tx == BondConfig::Tx::Active});
    for (size_t id = 0; id < endpoints_.size(); id++) {
        if (endpoints_[id])
            bond_of_[id] = bond_index(endpoints_[id]->config().bond);
    }
    queues_.assign(bonds_.size(), ArrivalQueue{});
    place_inputs();
}

void Router::place_inputs() {
    for (ArrivalQueue& q : queues_)
        q.inputs.clear();
    for (Input* in : inputs_) {
        in->bond_ = bond_index(in->bond_name_);
        if (in->bond_ != kNoBond)
            queues_[in->bond_].inputs.push_back(in);
    }
}

void Router::set_filter(FrameFilter* filter) {
    filter_ = filter;
    if (!filter_)
        return;
    for (Endpoint* e : endpoints_) {
        if (e)
            filter_->on_endpoint(*e, true);
    }
}

uint32_t Router::bond_index(const std::string& name) const {
    for (size_t i = 0; i < bonds_.size(); i++) {
        if (bonds_[i].name == name)
            return static_cast<uint32_t>(i);
    }
    return kNoBond;
}

uint32_t Router::bond_of(const Endpoint& endpoint) const {
    return endpoint.id() < bond_of_.size() ? bond_of_[endpoint.id()] : kNoBond;
}

void Router::add(Endpoint& endpoint) {
    auto free_slot = std::find(endpoints_.begin(), endpoints_.end(), nullptr);
    auto id = static_cast<uint32_t>(free_slot - endpoints_.begin());
    if (free_slot == endpoints_.end()) {
        endpoints_.push_back(&endpoint);
        routes_.emplace_back();
        bond_of_.push_back(kNoBond);
    } else {
        *free_slot = &endpoint;
        routes_[id].clear();
    }
    bond_of_[id] = bond_index(endpoint.config().bond);
    if (endpoint.receives_everything())
        recorders_.push_back(&endpoint);
    endpoint.set_id(id);
    if (filter_)
        filter_->on_endpoint(endpoint, true);
}

void Router::remove(Endpoint& endpoint) {
    uint32_t id = endpoint.id();
    if (id >= endpoints_.size() || endpoints_[id] != &endpoint)
        return;
    if (filter_)
        filter_->on_endpoint(endpoint, false);
    endpoints_[id] = nullptr;
    routes_[id].clear();
    for (auto& bond : bonds_) {
        if (bond.active_link == id)
            bond.active_link = kNoLink;
    }
    if (uint32_t bond = bond_of_[id]; bond != kNoBond) {
        // Its frames still waiting go with it (a link gone within a round of a stall).
        auto& frames = queues_[bond].frames;
        size_t before = frames.size();
        frames.erase(std::remove_if(frames.begin(), frames.end(),
                                    [&](const WaitingFrame& w) { return w.from == &endpoint; }),
                     frames.end());
        if (frames.size() != before)
            log_warning("[%s] removed with %zu received frames not yet handled: dropped",
                        endpoint.name().c_str(), before - frames.size());
    }
    bond_of_[id] = kNoBond;
    dirty_.erase(std::remove(dirty_.begin(), dirty_.end(), &endpoint), dirty_.end());
    recorders_.erase(std::remove(recorders_.begin(), recorders_.end(), &endpoint),
                     recorders_.end());
    endpoint.set_id(Endpoint::kNoId);
}

bool Router::set_active_link(uint32_t bond, uint32_t link) {
    if (bond >= bonds_.size() || link >= endpoints_.size() || !endpoints_[link] ||
        bond_of_[link] != bond)
        return false;
    if (bonds_[bond].active_link != link) {
        bonds_[bond].active_link = link;
        bonds_[bond].switches++;
    }
    return true;
}

void Router::learn(Endpoint& from, uint8_t sysid, uint8_t compid, TimePoint now) {
    auto& routes = routes_[from.id()];
    for (auto& r : routes) {
        if (r.sysid == sysid && r.compid == compid) {
            r.last_heard = now;
            return;
        }
    }
    routes.push_back(Route{sysid, compid, now});
}

bool Router::knows(const Endpoint& endpoint, uint8_t sysid, uint8_t compid) const {
    if (endpoint.id() >= routes_.size())
        return false;
    for (const auto& r : routes_[endpoint.id()]) {
        if (r.sysid == sysid && (compid == 0 || r.compid == compid))
            return true;
    }
    return false;
}

bool Router::target_knows(const Endpoint& to, uint8_t sysid, uint8_t compid) const {
    uint32_t bond = bond_of_[to.id()];
    if (bond == kNoBond)
        return knows(to, sysid, compid);
    for (size_t id = 0; id < endpoints_.size(); id++) {
        if (endpoints_[id] && bond_of_[id] == bond && knows(*endpoints_[id], sysid, compid))
            return true;
    }
    return false;
}

bool Router::same_target(const Endpoint& a, const Endpoint& b) const {
    if (&a == &b)
        return true;
    uint32_t bond = bond_of_[a.id()];
    return bond != kNoBond && bond == bond_of_[b.id()];
}

bool Router::may_send(const Endpoint& from, const Endpoint& to) const {
    // Never back to the source, and never reflected from one link of a bond into another.
    if (same_target(from, to))
        return false;
    return bond_lets_send(to);
}

bool Router::bond_lets_send(const Endpoint& to) const {
    uint32_t bond = bond_of_[to.id()];
    if (bond == kNoBond)
        return true;
    const Bond& b = bonds_[bond];
    // Until the link-switch filter has chosen, an active-only bond sends on every member
    // rather than on none.
    return !b.tx_active || b.active_link == kNoLink || b.active_link == to.id();
}

void Router::expire_routes(TimePoint now) {
    for (auto& routes : routes_) {
        routes.erase(std::remove_if(routes.begin(), routes.end(),
                                    [&](const Route& r) { return now - r.last_heard > route_timeout_; }),
                     routes.end());
    }
}

void Router::deliver(const Frame& frame, Endpoint& to, TimePoint now) {
    if (filter_ && filter_->on_egress(frame, to, now) == FrameFilter::Verdict::Drop)
        return;
    if (to.send(frame))
        dirty_.push_back(&to);
}

void Router::deliver_to_recorders(const Endpoint& from, const Frame& frame, TimePoint now) {
    for (Endpoint* to : recorders_) {
        if (may_send(from, *to))
            deliver(frame, *to, now);
    }
}

bool Router::ArrivalQueue::must_wait(TimePoint t, TimePoint polled, bool all_reported) const {
    if (!frames.empty())
        return true;  // after the ones already waiting
    for (const Input* in : inputs) {
        if (in->read_to(polled, all_reported) < t)
            return true;
    }
    return false;
}

TimePoint Router::polled() const {
    return polled_round_ == loop_.round() ? polled_ : loop_.polled_after();
}

void Router::polled_no_earlier_than(TimePoint t) {
    polled_ = std::max(polled(), t);
    polled_round_ = loop_.round();
}

void Router::handle_frame(Endpoint& from, const Frame& frame, TimePoint arrival) {
    uint32_t bond = bond_of_[from.id()];
    if (bond != kNoBond && queues_[bond].must_wait(arrival, polled(), loop_.all_reported()))
        wait_aside(queues_[bond], from, frame, arrival);
    else
        route(from, frame, arrival);
}

void Router::wait_aside(ArrivalQueue& queue, Endpoint& from, const Frame& frame,
                        TimePoint arrival) {
    auto offset = static_cast<uint32_t>(queue.arena.size());
    queue.arena.insert(queue.arena.end(), frame.bytes.begin(), frame.bytes.end());
    queue.frames.push_back(WaitingFrame{arrival, wait_order_++, &from, frame, offset});
    frames_held_back_++;
}

void Router::merge_round(bool all) {
    bool any = false;
    for (ArrivalQueue& q : queues_) {
        if (q.frames.empty())
            continue;
        any = true;
        // Every frame up to the time each input is known to be read to.
        q.held_until = TimePoint::max();
        for (const Input* in : q.inputs) {
            if (!all)
                q.held_until = std::min(q.held_until, in->read_to(polled(), loop_.all_reported()));
        }
        std::sort(q.frames.begin(), q.frames.end(), [](const WaitingFrame& a, const WaitingFrame& b) {
            return a.arrival != b.arrival ? a.arrival < b.arrival : a.order < b.order;
        });
        for (q.handled = 0; q.handled < q.frames.size(); q.handled++) {
            WaitingFrame& w = q.frames[q.handled];
            if (w.arrival > q.held_until)
                break;
            const uint8_t* base = q.arena.data() + w.offset;
            auto payload_at = w.frame.payload.data() - w.frame.bytes.data();
            w.frame.payload = {base + payload_at, w.frame.payload.size()};
            w.frame.bytes = {base, w.frame.bytes.size()};
            route(*w.from, w.frame, w.arrival);
        }
    }
    if (!any)
        return;
    // The frames just routed are lent from the arenas: sent before the arenas change.
    end_batch();
    bool held = false;
    for (ArrivalQueue& q : queues_) {
        if (q.frames.empty())
            continue;
        q.frames.erase(q.frames.begin(), q.frames.begin() + static_cast<ptrdiff_t>(q.handled));
        q.handled = 0;
        if (q.frames.empty()) {
            q.arena.clear();
            continue;
        }
        // The rest waits for the next round; its bytes move to the front of the arena.
        held = true;
        size_t keep_from = q.frames.front().offset;  // not sorted by offset: find the lowest
        for (const WaitingFrame& w : q.frames)
            keep_from = std::min<size_t>(keep_from, w.offset);
        q.arena.erase(q.arena.begin(), q.arena.begin() + static_cast<ptrdiff_t>(keep_from));
        for (WaitingFrame& w : q.frames)
            w.offset -= static_cast<uint32_t>(keep_from);
    }
    if (held)
        loop_.request_prompt_round();
}

TimePoint Router::arrival_clock(TimePoint now) const {
    TimePoint t = now;
    for (const ArrivalQueue& q : queues_) {
        if (!q.frames.empty())
            t = std::min(t, q.held_until);
    }
    return t;
}

void Router::route(Endpoint& from, const Frame& frame, TimePoint now) {
    // A frame that fails the endpoint's signing check is nobody's: it may not even teach a route.
    if (!from.authentic(frame))
        return;
    // Only a frame whose CRC was checked may teach a route: noise never creates one.
    if (frame.crc_checked)
        learn(from, frame.sysid, frame.compid, now);
    if (!from.accept_in(frame))
        return;
    if (filter_ && filter_->on_ingress(frame, from, now) == FrameFilter::Verdict::Drop)
        return;
    frames_routed_++;

    if (!frame.is_broadcast()) {
        auto ts = static_cast<uint8_t>(frame.target_system);
        auto tc = static_cast<uint8_t>(frame.target_component > 0 ? frame.target_component : 0);
        // Prefer where the exact component was heard, then where the system was heard;
        // a target heard nowhere is sent everywhere, as a broadcast is.
        for (uint8_t want_comp : {tc, uint8_t{0}}) {
            bool found = false;
            for (Endpoint* to : endpoints_) {
                if (!to || same_target(from, *to))
                    continue;
                if (!target_knows(*to, ts, want_comp))
                    continue;
                found = true;
                if (may_send(from, *to))
                    deliver(frame, *to, now);
            }
            if (found) {
                deliver_to_recorders(from, frame, now);
                return;
            }
            if (want_comp == 0)
                break;
        }
    }
    bool any = false;
    for (Endpoint* to : endpoints_) {
        if (to && may_send(from, *to)) {
            deliver(frame, *to, now);
            any = true;
        }
    }
    if (!any)
        frames_without_destination_++;
}

void Router::inject(const Frame& frame, TimePoint now) {
    for (Endpoint* to : endpoints_) {
        if (to && bond_lets_send(*to))
            deliver(frame, *to, now);
    }
    end_batch();
}

void Router::end_batch() {
    // flush() may call back into remove() (a connection closing on a write error), which
    // edits dirty_: take from the back until it is empty.
    while (!dirty_.empty()) {
        Endpoint* e = dirty_.back();
        dirty_.pop_back();
        e->flush();
    }
}

}  // namespace mavbond
