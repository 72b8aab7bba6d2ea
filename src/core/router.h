// mavlink-router semantics: learn which (sysid, compid) was heard on which endpoint (only from
// frames whose CRC was checked), forget it after route_timeout; a targeted frame goes where its
// target was heard, a broadcast (or an unknown target) to every endpoint but its source.
#pragma once

#include <cstdint>
#include <vector>

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
};

class Router {
public:
    explicit Router(Duration route_timeout) : route_timeout_(route_timeout) {}

    /// Registers a route target and gives it an id. The endpoint must call remove() before
    /// it is destroyed.
    void add(Endpoint& endpoint);
    void remove(Endpoint& endpoint);

    /// Handles one received frame: learn, filter, route, queue. The frame's bytes must stay
    /// valid until end_batch().
    void handle_frame(Endpoint& from, const Frame& frame, TimePoint now);
    /// Flushes every endpoint that got frames since the last call. Receivers call it after
    /// each batch, before reusing their buffers.
    void end_batch();

    /// Forgets routes not heard for route_timeout.
    void expire_routes(TimePoint now);
    void set_filter(FrameFilter* filter) { filter_ = filter; }

    const std::vector<Endpoint*>& endpoints() const { return endpoints_; }
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
    void deliver(const Frame& frame, Endpoint& to, TimePoint now);

    Duration route_timeout_;
    std::vector<Endpoint*> endpoints_;            // index = endpoint id; nullptr = free slot
    std::vector<std::vector<Route>> routes_;      // index = endpoint id
    std::vector<Endpoint*> dirty_;
    FrameFilter* filter_ = nullptr;
    uint64_t frames_routed_ = 0;
    uint64_t frames_without_destination_ = 0;
};

}  // namespace mavbond
