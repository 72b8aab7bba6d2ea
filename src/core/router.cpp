#include "core/router.h"

#include <algorithm>

#include "endpoints/endpoint.h"

namespace mavbond {

void Router::add(Endpoint& endpoint) {
    auto free_slot = std::find(endpoints_.begin(), endpoints_.end(), nullptr);
    auto id = static_cast<uint32_t>(free_slot - endpoints_.begin());
    if (free_slot == endpoints_.end()) {
        endpoints_.push_back(&endpoint);
        routes_.emplace_back();
    } else {
        *free_slot = &endpoint;
        routes_[id].clear();
    }
    endpoint.set_id(id);
}

void Router::remove(Endpoint& endpoint) {
    uint32_t id = endpoint.id();
    if (id >= endpoints_.size() || endpoints_[id] != &endpoint)
        return;
    endpoints_[id] = nullptr;
    routes_[id].clear();
    dirty_.erase(std::remove(dirty_.begin(), dirty_.end(), &endpoint), dirty_.end());
    endpoint.set_id(Endpoint::kNoId);
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

void Router::handle_frame(Endpoint& from, const Frame& frame, TimePoint now) {
    // Only a frame whose CRC was checked may teach a route: noise never creates one.
    if (frame.crc_checked)
        learn(from, frame.sysid, frame.compid, now);
    if (!from.accept_in(frame))
        return;
    if (filter_ && filter_->on_ingress(frame, from, now) == FrameFilter::Verdict::Drop)
        return;
    frames_routed_++;

    bool targeted = !frame.is_broadcast();
    if (targeted) {
        auto ts = static_cast<uint8_t>(frame.target_system);
        auto tc = static_cast<uint8_t>(frame.target_component > 0 ? frame.target_component : 0);
        // Prefer where the exact component was heard, then where the system was heard;
        // a target heard nowhere is sent everywhere, as a broadcast is.
        for (uint8_t want_comp : {tc, uint8_t{0}}) {
            bool sent = false;
            for (Endpoint* to : endpoints_) {
                if (to && to != &from && knows(*to, ts, want_comp)) {
                    deliver(frame, *to, now);
                    sent = true;
                }
            }
            if (sent)
                return;
            if (want_comp == 0)
                break;
        }
    }
    bool any = false;
    for (Endpoint* to : endpoints_) {
        if (to && to != &from) {
            deliver(frame, *to, now);
            any = true;
        }
    }
    if (!any)
        frames_without_destination_++;
}

void Router::end_batch() {
    // flush() may call back into remove() (a connection closing on a write error), which
    // edits dirty_: take the list first.
    while (!dirty_.empty()) {
        Endpoint* e = dirty_.back();
        dirty_.pop_back();
        e->flush();
    }
}

}  // namespace mavbond
