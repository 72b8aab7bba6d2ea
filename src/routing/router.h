// mavlink-router semantics: learn which (sysid, compid) was heard on which link (only from
// frames whose CRC was checked), forget it after route_timeout (or, past kMaxRoutesPerLink
// on one link, the least recently heard first); a targeted frame goes where its
// target was heard, a broadcast (or an unknown target) to every link but its source.
//
// Bonds (bond.h): the links of a bond act as one route target. What is learned on any member
// is reachable through the bond, and a frame never goes back into the bond it came from (no
// reflection from link A to link B). A bond sends on every member (`tx: broadcast`) or only on
// its active one (`tx: active`, chosen by the link-switch filter).
//
// Recorders (a flight log) get every routed frame, targeted ones included.
//
// A bond numbers what it sends (routing/egress_numbering.h): each of its links gets the frame
// with the bond's BondCopy, and the first link that puts it on its line gives it its number;
// the numbered copy (made once per routing, in the arena below) is what every link that sends
// at once sends, and a link that holds the frame numbers its own copy when it goes.
//
// Signed bonds (mavlink/bond_signing.h): a frame going to a bond's signed links is signed once
// for that bond, the first time it goes to one of them, into an arena the links are lent from
// until the batch's end; its other signed links get the same bytes, its unsigned links the
// frame as it came. mavbond's own frames (inject) and standby's resends are signed the same
// way. The arena is chunks kept from batch to batch: it allocates only when a batch signs
// more than any before (a backlog after a stall), never per frame, and never makes the links
// write in the middle of a batch.
//
// Arrival order: the frames of a bond's links reach the filters in the order they arrived,
// however late the loop gets to them. A stalled daemon finds a backlog on every link at once;
// handed on link by link, the frames one link lost would come after newer ones another link
// carried (and be dropped as stale, or numbered out of order). So the frames a round reads
// from a bond's sockets wait, lent in the sockets' buffers (which last the round), until the
// round's reads are done; then they are merged in arrival order and go through the filters
// as one batch, up to the time every socket of the bond is known to be read to (a socket
// epoll did not report had nothing when epoll looked; one it reported is read to where its
// read got: the last datagram of a full batch, or the time of a read that emptied it). The
// rest is copied aside (held back) and waits for the next round, which then comes at once.
// A byte-stream link of such a bond (a UART) reuses its buffer at every read: its frame goes
// at once when nothing may have come before it, else it is copied aside to wait.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "core/event_loop.h"
#include "mavlink/frame.h"
#include "routing/bond.h"
#include "routing/frame_sink.h"
#include "routing/link.h"

namespace mavbond {

/// The filters on the data path (the filter chain plugs in here).
class FrameFilter {
public:
    /// What the ingress filters said of one frame.
    struct Ingress {
        bool pass = true;
        std::optional<int64_t> bond_pos;  // its place in its source's stream, as the bond numbers it
    };
    virtual ~FrameFilter() = default;
    /// Every received frame, once, before routing, in arrival order: out[i] for frames[i]
    /// (frames the endpoint refused, `routed` false, pass unseen).
    virtual void on_ingress(ReceivedFrame* const* frames, size_t count, Ingress* out) = 0;
    /// Every (frame, destination) before the frame is queued; false: not sent there.
    virtual bool on_egress(const Frame& frame, const Link& to) = 0;
    /// A link was attached (added) or is about to detach (!added).
    virtual void on_link(const Link& link, bool added) = 0;
};

class Router final : public FrameSink {
public:
    static constexpr uint32_t kNoBond = UINT32_MAX;
    /// Routes (sysid, compid) learned per link at most; past it the least recently heard is
    /// forgotten (Link::route_evicted). Room for a swarm behind one link, and a bound on what
    /// a sender cycling through ids can make the router keep and search per frame.
    static constexpr size_t kMaxRoutesPerLink = 128;

    Router(EventLoop& loop, Duration route_timeout);

    // FrameSink: what endpoints call.
    void attach(Link& link) override;
    void detach(Link& link) override;
    void attach(Input& input) override;
    void detach(Input& input) override;
    void ingress(ReceivedBatch& batch) override;
    void end_batch() override;
    std::shared_ptr<BondSigning> bond_signing(const std::string& bond) override;

    /// Handles the frames copied aside, in arrival order, as far as every socket of their bond
    /// is read (the event loop calls it after every round's reads); `all`: every one of them
    /// (the bonds are about to be replaced).
    void merge_round(bool all = false);
    /// The time up to which every frame that arrived has been handled: `now`, or earlier while
    /// a bond's frames wait for a socket still to be read.
    TimePoint arrival_clock(TimePoint now) const;
    /// Where a frame mavbond made itself goes.
    struct Reach {
        enum Kind {
            Everywhere,    // every link the bonds' tx policy lets send
            OutsideBonds,  // the local side only: every link in no bond (a bond's RADIO_STATUS)
            OneBond,       // every member of `bond`, whatever its tx policy or standby (a
                           // standby report must go over every link, the metered one too)
            BondRouted,    // the members of `bond` its tx policy lets send, as Everywhere
            LikeBond,      // where the frames `bond` delivers go: every link outside it, by
                           // the tx policies (a link event told as the bond's vehicle)
        };
        Reach(Kind k = Everywhere, uint32_t b = kNoBond) : kind(k), bond(b) {}
        static Reach to_bond(uint32_t bond) { return {OneBond, bond}; }
        static Reach like_bond(uint32_t bond) { return {LikeBond, bond}; }
        Kind kind;
        uint32_t bond;
    };
    /// Sends a frame mavbond made itself (its own HEARTBEAT, STATUSTEXT) as a local source:
    /// to the links `reach` names, through the egress filters; nothing is learned and no
    /// ingress filter sees it. Flushes before returning, so the bytes need only live for the
    /// call (call it from a timer, not from inside a receive batch).
    void inject(const Frame& frame, Reach reach = Reach());
    /// Marks the bonds whose members' radios report (`radio_status` on one of them): see
    /// Bond::reports_radio_status. Called whenever the endpoints or the bonds change.
    void mark_radio_status_bonds(const Config& config);
    /// Sends on the metered members of bond `bond` what standby held back from them (it just
    /// went active); returns how many frames that was.
    uint64_t resend_held(uint32_t bond, TimePoint now);
    /// Lets bond `bond`'s standby judge the peer's reports now: logs a change, and on going
    /// active resends what was held.
    void judge_standby(uint32_t bond, TimePoint now);
    /// The accounts of bond `bond`'s member `member`, its links' summed (routing/link_account.h);
    /// false when none of them has had a count marker.
    bool member_account(uint32_t bond, uint32_t member, Standby::Account& out) const;

    /// Forgets routes not heard for route_timeout.
    void expire_routes(TimePoint now);
    /// Puts `filter` on the data path (nullptr: none); it hears of every link attached.
    void set_filter(FrameFilter* filter);
    void set_route_timeout(Duration timeout) { route_timeout_ = timeout; }
    /// Replaces the bonds (a reload) with those of `config`, their members in its order.
    /// Active links and switch counts start afresh.
    void replace_bonds(const Config& config);

    const std::vector<Bond>& bonds() const { return bonds_; }
    Bond& bond(uint32_t index) { return bonds_[index]; }
    uint32_t bond_index(const std::string& name) const;
    /// The bond index of a link, or kNoBond.
    uint32_t bond_of(const Link& link) const { return slot(link).bond; }
    /// A link's place among its bond's members (Bond::kNoMember outside a bond).
    uint32_t member_of(const Link& link) const { return slot(link).member; }
    /// The attached link with id `id`, or nullptr.
    const Link* link(LinkId id) const { return id < slots_.size() ? slots_[id].link : nullptr; }
    /// One past the highest link id in use.
    size_t link_id_bound() const { return slots_.size(); }
    /// Makes `link` the active member of bond `bond`; false if it is not one.
    bool set_active_link(uint32_t bond, LinkId link);
    /// Whether (sysid, compid) was heard on `link` (compid 0: any component).
    bool knows(const Link& link, uint8_t sysid, uint8_t compid) const;
    /// Whether a vehicle's autopilot (a HEARTBEAT whose autopilot is not MAV_AUTOPILOT_INVALID,
    /// from no GCS) was heard on a link outside the bonds: this is the vehicle's side.
    bool local_autopilot() const { return local_autopilot_; }
    /// Frames that came in from mavbond's own (sysid, compid), which another sender must not
    /// use: when the first and the last came, how many, and the link of the first.
    struct OwnIdentityHeard {
        uint64_t count = 0;
        TimePoint first{}, last{};
        std::string link;
    };
    /// Watches for frames from (sysid, compid), mavbond's own identity now (forgets the last).
    void watch_own_identity(uint8_t sysid, uint8_t compid) {
        own_sysid_ = sysid;
        own_compid_ = compid;
        own_heard_ = OwnIdentityHeard{};
    }
    const OwnIdentityHeard& own_identity_heard() const { return own_heard_; }

    uint64_t frames_routed() const { return frames_routed_; }
    /// Standby reports (`mbl:`) not taken by a bond's standby: from outside every bond (a GCS
    /// port), or on a bond with no metered member. Never routed on.
    uint64_t standby_reports_dropped() const { return standby_reports_dropped_; }
    uint64_t frames_without_destination() const { return frames_without_destination_; }
    /// Frames that waited past the round that read them (copied aside) for frames that
    /// arrived before them on another link of their bond.
    uint64_t frames_held_back() const { return frames_held_back_; }

private:
    struct Route {
        uint8_t sysid;
        uint8_t compid;
        TimePoint last_heard;
    };
    /// An attached link and what routing keeps of it.
    struct Slot {
        Link* link = nullptr;  // nullptr: a free slot
        uint32_t bond = kNoBond;
        uint32_t member = Bond::kNoMember;
        bool signs = false;  // its bond signs what it sends on it
        std::vector<Route> routes;
        StreamPositions positions;  // of the sources heard on this link (ReceivedFrame::step)
    };

    const Slot& slot(const Link& link) const { return slots_[link.id()]; }
    /// Resolves every attached link's and input's bond by name (after replace_bonds()).
    void place_links();
    /// Tells each link of bond `bond` (every bond: kNoBond) whether standby holds it now.
    void mark_standby(uint32_t bond);
    /// Filters, renumbers and routes frames ready to go, in order.
    void handle(ReceivedFrame* const* frames, size_t count);
    void route(const ReceivedFrame& received);
    /// A time no later than when epoll looked at the fds in this round: its own bound, raised
    /// by the arrival of the first datagram read from each fd it reported (each was there when
    /// epoll looked).
    TimePoint polled() const;
    void polled_no_earlier_than(TimePoint t);
    void learn(Slot& from, uint8_t sysid, uint8_t compid, TimePoint now);
    /// A member heard its far side: any frame but a radio's own report (its radio says it
    /// whether or not the far side is there).
    static void heard(Bond& bond, uint32_t member, const ReceivedFrame& r) {
        if (!is_radio_own_report(r.frame))
            bond.heard(member, r.arrival);
    }
    /// Whether the route target `to` belongs to (itself, or its whole bond) knows the target.
    bool target_knows(const Slot& to, uint8_t sysid, uint8_t compid) const;
    /// Whether a and b are one route target: the same link, or links of the same bond.
    static bool same_target(const Slot& a, const Slot& b) {
        return &a == &b || (a.bond != kNoBond && a.bond == b.bond);
    }
    /// Whether `to` may send `frame` under its bond's tx policy and standby (always, outside
    /// a bond); a frame standby keeps off a metered member is held for a resend.
    bool bond_lets_send(const Slot& to, const Frame& frame) {
        if (to.bond == kNoBond)
            return true;
        Bond& bond = bonds_[to.bond];
        if (!bond.lets_send(to.link->id()))
            return false;
        Standby* standby = bond.standby();
        if (!standby || to.member == Bond::kNoMember)
            return true;
        if (standby->lets_send(to.member, frame.msgid)) {
            if (standby->metered(to.member))
                standby->sent(to.member, frame, frames_routed_);
            return true;
        }
        BondCopy* copy = egress_copy(frame, to);
        standby->hold(to.member, frame, frames_routed_, copy ? copy->ticket : 0, loop_.now());
        return false;
    }
    /// Whether `to` may carry `frame` from `from`: not the same link or bond, and the bond's
    /// tx policy lets this member send.
    bool may_send(const Slot& from, const Slot& to, const Frame& frame) {
        return !same_target(from, to) && bond_lets_send(to, frame);
    }
    void deliver(const Frame& frame, Slot& to, uint64_t ticket = 0);
    /// What bond member `to` is given of `frame`, the frame being routed (ticket: one of its
    /// bond's, given already: a resend); null when its bond leaves the frame as it is.
    BondCopy* egress_copy(const Frame& frame, const Slot& to, uint64_t ticket = 0);
    /// A new frame is about to be routed (or injected, or resent): the signed copies made for
    /// the one before are not its own.
    void begin_routing() { routing_++; }
    /// Room for a signed frame in the arena, lent until end_batch().
    uint8_t* sign_room();
    /// `frame` signed for bond `bond` (once per routing); null when it cannot be signed.
    const Frame* signed_for(const Frame& frame, uint32_t bond);
    /// A targeted frame that found its target also goes to links that record everything
    /// (they never learn routes, so the targeted path passes them by).
    void deliver_to_recorders(const Slot& from, const Frame& frame);
    /// Takes in what a bond's standby reads of a received frame; true: it was a standby
    /// report (Standby::is_report), consumed here (taken by the bond's standby, or dropped:
    /// it came from outside every bond, or its bond has no standby).
    bool standby_sees(const Slot& from, const ReceivedFrame& r);
    /// A HEARTBEAT: whose side an autopilot is on (local_autopilot, Bond::autopilot).
    void note_heartbeat(const Slot& from, const Frame& frame);

    /// A bond's BondCopy of the frame being routed: its ticket, its numbered copy once made.
    class Egress final : public BondCopy {
    public:
        const Frame* now(bool signed_link) override;

        Router* router = nullptr;
        uint32_t bond = kNoBond;
        uint64_t routing = UINT64_MAX;  // the routing it is for (begin_routing)
        Frame routed;                   // the frame as routed
        Frame numbered;                 // with its number, once made
        bool made = false;
    };

    EventLoop& loop_;
    Duration route_timeout_;
    std::vector<Bond> bonds_;
    std::vector<Egress> egress_;         // by bond
    std::vector<Slot> slots_;            // index = link id
    std::vector<Input*> inputs_;
    std::vector<Link*> dirty_;
    std::vector<Link*> recorders_;       // links that receive everything (tlog)
    FrameFilter* filter_ = nullptr;
    std::vector<ReceivedFrame*> ready_;  // the frames handle() is given, reused
    std::vector<FrameFilter::Ingress> verdicts_;
    std::vector<size_t> released_;       // per bond: how many frames merge_round() released
    uint64_t wait_order_ = 0;
    TimePoint polled_ = {};              // polled()'s bound for round polled_round_
    uint64_t polled_round_ = 0;
    uint64_t frames_held_back_ = 0;
    uint64_t frames_routed_ = 0;
    uint64_t frames_without_destination_ = 0;
    uint64_t standby_reports_dropped_ = 0;
    uint64_t routing_ = 0;                  // frames begun routing (begin_routing)
    /// Signed copies, lent to the links until end_batch: chunks in use up to sign_chunk_.
    static constexpr size_t kSignChunkBytes = 16384;
    std::vector<std::unique_ptr<std::array<uint8_t, kSignChunkBytes>>> sign_chunks_;
    size_t sign_chunk_ = 0, sign_used_ = 0;
    bool local_autopilot_ = false;
    uint8_t own_sysid_ = 0, own_compid_ = 0;  // 0/0: no identity watched
    OwnIdentityHeard own_heard_;
};

}  // namespace mavbond
