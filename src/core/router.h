// mavlink-router semantics: learn which (sysid, compid) was heard on which endpoint (only from
// frames whose CRC was checked), forget it after route_timeout; a targeted frame goes where its
// target was heard, a broadcast (or an unknown target) to every endpoint but its source.
//
// Bonds: the links of a bond act as one endpoint. What is learned on any member is reachable
// through the bond, and a frame never goes back into the bond it came from (no reflection from
// link A to link B). A bond sends on every member (`tx: broadcast`) or only on its active one
// (`tx: active`, chosen by the link-switch filter).
//
// Recorders (a flight log) get every routed frame, targeted ones included.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "mavlink/frame.h"

namespace mavbond {

class Endpoint;

/// A stage of the data path (the filter chain plugs in here). Ingress runs once per frame
/// before routing; egress once per (frame, destination) before the frame is queued.
class FrameFilter {
public:
    enum class Verdict { Pass, Drop };
    virtual ~FrameFilter() = default;
    virtual Verdict on_ingress(const Frame& frame, Endpoint& from, TimePoint now) = 0;
    virtual Verdict on_egress(const Frame& frame, Endpoint& to, TimePoint now) = 0;
    /// An endpoint was registered (added) or is about to go away (!added).
    virtual void on_endpoint(Endpoint& endpoint, bool added) = 0;
};

class Router {
public:
    static constexpr uint32_t kNoBond = UINT32_MAX;
    static constexpr uint32_t kNoLink = UINT32_MAX;

    struct Bond {
        std::string name;
        bool tx_active = false;
        uint32_t active_link = kNoLink;  // endpoint id; kNoLink: none chosen yet
        uint64_t switches = 0;
    };

    Router(Duration route_timeout, const std::vector<BondConfig>& bonds = {});

    /// Registers a route target and gives it an id (and its bond, from its config). The
    /// endpoint must call remove() before it is destroyed.
    void add(Endpoint& endpoint);
    void remove(Endpoint& endpoint);

    /// Handles one received frame: learn, filter, route, queue. The frame's bytes must stay
    /// valid until end_batch().
    void handle_frame(Endpoint& from, const Frame& frame, TimePoint now);
    /// Sends a frame mavbond made itself (its own HEARTBEAT, STATUSTEXT) as a local source:
    /// to every endpoint the bonds' tx policy lets send, through the egress filters; nothing
    /// is learned and no ingress filter sees it. Flushes before returning, so the bytes need
    /// only live for the call (call it from a timer, not from inside a receive batch).
    void inject(const Frame& frame, TimePoint now);
    /// Flushes every endpoint that got frames since the last call. Receivers call it after
    /// each batch, before reusing their buffers.
    void end_batch();

    /// Forgets routes not heard for route_timeout.
    void expire_routes(TimePoint now);
    /// Puts `filter` on the data path (nullptr: none); it hears of every endpoint registered.
    void set_filter(FrameFilter* filter);
    void set_route_timeout(Duration timeout) { route_timeout_ = timeout; }
    /// Replaces the bonds (a reload) and re-reads each endpoint's bond from its config. Active
    /// links and switch counts start afresh.
    void replace_bonds(const std::vector<BondConfig>& bonds);

    const std::vector<Endpoint*>& endpoints() const { return endpoints_; }
    const std::vector<Bond>& bonds() const { return bonds_; }
    /// The bond index of an endpoint, or kNoBond.
    uint32_t bond_of(const Endpoint& endpoint) const;
    uint32_t bond_index(const std::string& name) const;
    /// Makes `link` the active member of `bond`; false if it is not a member.
    bool set_active_link(uint32_t bond, uint32_t link);
    /// Whether (sysid, compid) was heard on `endpoint` (compid 0: any component).
    bool knows(const Endpoint& endpoint, uint8_t sysid, uint8_t compid) const;
    uint64_t frames_routed() const { return frames_routed_; }
    uint64_t frames_without_destination() const { return frames_without_destination_; }

private:
    struct Route {
        uint8_t sysid;
        uint8_t compid;
        TimePoint last_heard;
    };
    void learn(Endpoint& from, uint8_t sysid, uint8_t compid, TimePoint now);
    /// Whether the route target `to` belongs to (itself, or its whole bond) knows the target.
    bool target_knows(const Endpoint& to, uint8_t sysid, uint8_t compid) const;
    /// Whether a and b are one route target: the same endpoint, or links of the same bond.
    bool same_target(const Endpoint& a, const Endpoint& b) const;
    /// Whether `to` may carry a frame from `from`: not the same endpoint or bond, and the
    /// bond's tx policy lets this member send.
    bool may_send(const Endpoint& from, const Endpoint& to) const;
    /// Whether `to` may send under its bond's tx policy (always, outside a bond).
    bool bond_lets_send(const Endpoint& to) const;
    void deliver(const Frame& frame, Endpoint& to, TimePoint now);
    /// A targeted frame that found its target also goes to endpoints that record everything
    /// (they never learn routes, so the targeted path passes them by).
    void deliver_to_recorders(const Endpoint& from, const Frame& frame, TimePoint now);

    Duration route_timeout_;
    std::vector<Bond> bonds_;
    std::vector<Endpoint*> endpoints_;            // index = endpoint id; nullptr = free slot
    std::vector<uint32_t> bond_of_;               // index = endpoint id
    std::vector<std::vector<Route>> routes_;      // index = endpoint id
    std::vector<Endpoint*> dirty_;
    std::vector<Endpoint*> recorders_;            // endpoints that receive everything (tlog)
    FrameFilter* filter_ = nullptr;
    uint64_t frames_routed_ = 0;
    uint64_t frames_without_destination_ = 0;
};

}  // namespace mavbond
