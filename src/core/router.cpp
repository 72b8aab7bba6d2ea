#include "core/router.h"

#include <algorithm>

#include "endpoints/endpoint.h"

namespace mavbond {

Router::Router(Duration route_timeout, const std::vector<BondConfig>& bonds)
    : route_timeout_(route_timeout) {
    replace_bonds(bonds);
}

void Router::replace_bonds(const std::vector<BondConfig>& bonds) {
    bonds_.clear();
    for (const auto& b : bonds)
        bonds_.push_back(Bond{b.name, b.tx == BondConfig::Tx::Active});
    for (size_t id = 0; id < endpoints_.size(); id++) {
        if (endpoints_[id])
            bond_of_[id] = bond_index(endpoints_[id]->config().bond);
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

void Router::handle_frame(Endpoint& from, const Frame& frame, TimePoint now) {
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
