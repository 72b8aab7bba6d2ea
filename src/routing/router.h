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
//
// Arrival order: the frames of a bond's links reach the filters in the order they arrived,
// however late the loop gets to them. A stalled daemon finds a backlog on every link at once;
// handed on link by link, the frames one link lost would come after newer ones another link
// carried (and be dropped as stale, or numbered out of order). So a frame from a bond's link
// is handled at once only when every socket of the bond is known to be read up to its arrival
// (a socket epoll did not report had nothing when epoll looked; one it reported is read to
// where its read got: the last datagram of a full batch, or the time of a read that emptied
// it); otherwise it is copied aside,
// and after the round's reads the copies are handled in arrival order, up to the time every
// socket of the bond is read to. The rest waits for the next round, which then comes at once.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "core/event_loop.h"
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

    /// A datagram socket that may feed a bond's links (a UDP server with its peers, a UDP
    /// client): what the arrival-order merge must know of it. Registered for its owner's life.
    class Input {
    public:
        /// `watch` is the socket's (its address must stay put while the input lives).
        Input(Router& router, const std::string& bond, const EventLoop::Watch& watch);
        ~Input();
        Input(const Input&) = delete;
        Input& operator=(const Input&) = delete;
        /// After each read: `until`, the time up to which everything that arrived for it has
        /// been read (the last datagram of a full batch; else the round's start, or the last
        /// datagram if later). `first`: when the first datagram it read arrived, from a socket
        /// epoll reported readable (else zero).
        void read(TimePoint until, TimePoint first) {
            last_ = until;
            if (first != TimePoint{} && watch_.ready_this_round())
                router_.polled_no_earlier_than(first);
        }

    private:
        friend class Router;
        /// The time up to which every datagram that arrived for it has been read, as far as
        /// this round shows: a socket epoll did not report had nothing new when epoll looked
        /// (`polled`, a time no later than that); one it did is read to where its read got.
        TimePoint read_to(TimePoint polled, bool all_reported) const {
            return watch_.ready_this_round() || !all_reported ? last_ : std::max(last_, polled);
        }
        Router& router_;
        std::string bond_name_;
        uint32_t bond_ = kNoBond;
        const EventLoop::Watch& watch_;
        TimePoint last_{};
    };

    Router(EventLoop& loop, Duration route_timeout, const std::vector<BondConfig>& bonds = {});

    /// Registers a route target and gives it an id (and its bond, from its config). The
    /// endpoint must call remove() before it is destroyed.
    void add(Endpoint& endpoint);
    void remove(Endpoint& endpoint);

    /// Handles one received frame that arrived at `arrival`: learn, filter, route, queue (or,
    /// for a bond's link, copy it aside until the frames that arrived before it are in; see
    /// above). The frame's bytes must stay valid until end_batch().
    void handle_frame(Endpoint& from, const Frame& frame, TimePoint arrival);
    /// Handles the frames copied aside, in arrival order, as far as every socket of their bond
    /// is read (the event loop calls it after every round's reads); `all`: every one of them
    /// (the bonds are about to be replaced).
    void merge_round(bool all = false);
    /// The time up to which every frame that arrived has been handled: `now`, or earlier while
    /// a bond's frames wait for a socket still to be read.
    TimePoint arrival_clock(TimePoint now) const;
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
    /// Frames that waited for frames that arrived before them on another link of their bond.
    uint64_t frames_held_back() const { return frames_held_back_; }

private:
    struct Route {
        uint8_t sysid;
        uint8_t compid;
        TimePoint last_heard;
    };
    /// A frame copied aside: its bytes at `offset` in the bond's arena.
    struct WaitingFrame {
        TimePoint arrival;
        uint64_t order;  // ties (the frames of one datagram) keep the order they came in
        Endpoint* from;
        Frame frame;     // spans rebuilt from the arena when handled
        uint32_t offset;
    };
    /// A bond's frames copied aside and the inputs that feed it.
    struct ArrivalQueue {
        std::vector<Input*> inputs;
        std::vector<WaitingFrame> frames;
        std::vector<uint8_t> arena;
        size_t handled = 0;  // frames routed by the merge under way
        TimePoint held_until = TimePoint::max();  // frames after it wait for the next round
        /// Whether a frame that arrived at `t` must wait for others that may have come before.
        bool must_wait(TimePoint t, TimePoint polled, bool all_reported) const;
    };
    /// Learn, filter, route, queue.
    void route(Endpoint& from, const Frame& frame, TimePoint arrival);
    void wait_aside(ArrivalQueue& queue, Endpoint& from, const Frame& frame, TimePoint arrival);
    /// Resolves every input's bond by name (after replace_bonds()).
    void place_inputs();
    /// A time no later than when epoll looked at the fds in this round: its own bound, raised
    /// by the arrival of the first datagram read from each fd it reported (each was there when
    /// epoll looked).
    TimePoint polled() const;
    void polled_no_earlier_than(TimePoint t);
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

    EventLoop& loop_;
    Duration route_timeout_;
    std::vector<Bond> bonds_;
    std::vector<ArrivalQueue> queues_;            // index = bond index
    std::vector<Input*> inputs_;
    uint64_t wait_order_ = 0;
    TimePoint polled_ = {};      // polled()'s bound for round polled_round_
    uint64_t polled_round_ = 0;
    uint64_t frames_held_back_ = 0;
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
