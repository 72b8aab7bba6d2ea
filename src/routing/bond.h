// A bond: links to one peer that act as one route target (two radios, radio + LTE). Everything
// routing keeps of a bond lives here: its members in config order (a link's place among them
// is its priority for the filters; a UDP peer or TCP connection takes its server's place),
// when each member was last heard, the tx policy and the active link, the frames held back
// for arrival order and the sockets that feed them, and the renumbering of what it delivers.
#pragma once

#include <algorithm>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "mavlink/bond_signing.h"
#include "routing/egress_numbering.h"
#include "routing/frame_sink.h"
#include "routing/link.h"
#include "routing/renumber.h"
#include "routing/standby.h"

namespace mavbond {

class Bond {
public:
    static constexpr uint32_t kNoMember = UINT32_MAX;

    /// The bond `config` declares, with the endpoints of `endpoints` that name it as members;
    /// `classes`: what standby goes by when a member is metered; `now`: when it starts.
    Bond(const BondConfig& config, const std::vector<EndpointConfig>& endpoints,
         const TxClassesConfig& classes, TimePoint now);

    const std::string& name() const { return name_; }
    bool tx_active() const { return tx_active_; }

    /// The members' endpoint names, in config order.
    const std::vector<std::string>& members() const { return members_; }
    /// The place of configured endpoint `endpoint` among the members, or kNoMember.
    uint32_t member_index(const std::string& endpoint) const;
    /// When a frame last came in on member `member` (epoch: never).
    TimePoint last_heard(uint32_t member) const { return last_heard_[member]; }
    void heard(uint32_t member, TimePoint arrival) {
        if (member < last_heard_.size())
            last_heard_[member] = std::max(last_heard_[member], arrival);
    }

    /// The link `tx: active` sends on (kNoLink: none chosen yet, every member sends).
    LinkId active_link() const { return active_link_; }
    uint64_t switches() const { return switches_; }
    /// Makes `link` (a member's) the active one; counts a switch when it changes.
    void set_active_link(LinkId link);
    /// A member's link went away: if it was the active one, none is.
    void forget_link(LinkId link);
    /// Whether member link `to` may send under the tx policy.
    bool lets_send(LinkId to) const {
        // Until the link-switch filter has chosen, an active-only bond sends on every member
        // rather than on none.
        return !tx_active_ || active_link_ == kNoLink || active_link_ == to;
    }
    /// The standby of its metered members (routing/standby.h); nullptr when none is metered.
    Standby* standby() { return standby_.get(); }
    const Standby* standby() const { return standby_.get(); }
    /// A reload rebuilt this bond from `old`, its namesake: what outlives the config is
    /// taken over (its numbering of what it sends, so the far side sees one stream; the
    /// standby's measurements and state, Standby::continue_from; the signing with the same
    /// key: its replay window and clock, which the endpoints kept share). True when a standby
    /// was.
    bool continue_from(const Bond& old);

    /// Its signing (`signing:`, mavlink/bond_signing.h); null when it signs no link. Shared
    /// with its signed members' endpoints, which verify with it.
    const std::shared_ptr<BondSigning>& signing() const { return signing_; }
    /// The member endpoints it signs, in config order.
    const std::vector<std::string>& signed_links() const { return signed_links_; }
    /// Whether it signs what it sends on member endpoint `endpoint`.
    bool signs(const std::string& endpoint) const {
        return std::find(signed_links_.begin(), signed_links_.end(), endpoint) !=
               signed_links_.end();
    }
    /// The router's: the frame it is routing now (`routing`), signed for this bond once,
    /// whichever of the bond's links it goes to first; `refused`: it could not be signed.
    struct SignedCopy {
        uint64_t routing = UINT64_MAX;
        bool refused = false;
        Frame frame;
    };
    SignedCopy signed_copy;

    /// Whether a member's radio reports for the bond (`radio_status`): then mavbond speaks
    /// RADIO_STATUS for the bond, and any other RADIO_STATUS that comes in on a member (a far
    /// side's relayed, another system's) is dropped and counted: ArduPilot honours a
    /// RADIO_STATUS from any system and would slow for a report about some other link.
    bool reports_radio_status = false;
    /// RADIO_STATUS frames dropped so (not the radios' own, which their endpoints take).
    uint64_t foreign_radio_status = 0;

    /// How it numbers what it sends (routing/egress_numbering.h): shared with the member
    /// links, which number the copies their budgets held when they go.
    const std::shared_ptr<EgressNumbering>& numbering() const { return numbering_; }

    /// Whether the bond renumbers what it delivers (FilterChain::renumbers decides).
    bool renumbers() const { return renumberer_ != nullptr; }
    /// Starts renumbering afresh (`on`) or stops it.
    void set_renumbering(bool on);
    /// Gives a frame of a member that the filters let through (`delivered`) its output
    /// sequence number, in its bytes and in `frame.seq`. `bond_pos`: its place in its source's
    /// stream as dedup numbers it (the same for every link's copy), when dedup placed it.
    /// Signed frames are left alone, and counted whether delivered or not: the signature
    /// covers the sequence number.
    void renumber(Frame& frame, bool delivered, std::optional<int64_t> bond_pos, TimePoint arrival);
    /// The number for a frame mavbond adds to the stream of (sysid, compid) it delivers (a link
    /// event told as the vehicle), so a GCS counts no gap; nullopt when the bond does not
    /// renumber or has delivered nothing of that source yet.
    std::optional<uint8_t> number_added_frame(uint8_t sysid, uint8_t compid);

    /// A vehicle's autopilot (its HEARTBEAT's autopilot is not MAV_AUTOPILOT_INVALID, its type
    /// no GCS) as heard through the bond: this side faces the ground station.
    struct Autopilot {
        uint8_t sysid = 0, compid = 0;
    };
    const std::optional<Autopilot>& autopilot() const { return autopilot_; }
    void heard_autopilot(uint8_t sysid, uint8_t compid) { autopilot_ = Autopilot{sysid, compid}; }

    /// What renumbering did, as (name, count) pairs in a fixed order; empty when the bond
    /// does not renumber.
    std::vector<std::pair<const char*, uint64_t>> renumber_counters() const;

    // --- arrival order (the router's merge, see router.h) -----------------------------------

    /// A frame of a member waiting for the merge: lent (its bytes still in the receive buffer
    /// of a datagram socket, which is not reused before the round ends) or copied aside (its
    /// bytes at `offset` in the arena).
    struct WaitingFrame {
        ReceivedFrame received;  // owned: spans rebuilt from the arena when it is released
        uint64_t order;          // ties (the frames of one datagram) keep the order they came in
        uint32_t offset;
        bool owned;
    };
    /// The sockets that feed the members.
    std::vector<Input*> inputs;
    std::vector<WaitingFrame> waiting;
    std::vector<uint8_t> arena;
    TimePoint held_until = TimePoint::max();  // frames after it wait for the next round
    /// Whether a frame that arrived at `t` must wait for others that may have come before it.
    bool must_wait(TimePoint t, TimePoint polled, bool all_reported) const;
    /// Keeps a frame for the merge: lent, or with its bytes copied into the arena (`copy`).
    void wait(const ReceivedFrame& frame, uint64_t order, bool copy);
    /// Sorts what waits in arrival order and says how many may go: those that arrived no
    /// later than every input is read to (`all`: every one).
    size_t release(TimePoint polled, bool all_reported, bool all);
    /// The frame at `i` of the released ones, its spans pointing where its bytes are.
    ReceivedFrame& released(size_t i);
    /// Forgets the first `count` frames (routed); the rest wait for the next round, their
    /// bytes all in the arena now (a lent frame's buffer is reused then). Returns how many
    /// were lent until now.
    size_t keep_unreleased(size_t count);

private:
    std::string name_;
    bool tx_active_;
    std::vector<std::string> members_;
    std::vector<TimePoint> last_heard_;
    LinkId active_link_ = kNoLink;
    uint64_t switches_ = 0;
    std::shared_ptr<EgressNumbering> numbering_ = std::make_shared<EgressNumbering>();
    std::unique_ptr<SeqRenumberer> renumberer_;  // nullptr: the bond does not renumber
    std::unique_ptr<Standby> standby_;           // nullptr: no member is metered
    std::shared_ptr<BondSigning> signing_;       // nullptr: it signs no link
    std::vector<std::string> signed_links_;      // the endpoints it signs, in config order
    uint64_t signed_left_alone_ = 0;
    std::optional<Autopilot> autopilot_;
};

}  // namespace mavbond
