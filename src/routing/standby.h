// Standby: a bond member marked `cost: metered` (LTE, satellite: paid by the byte) carries only
// the classes it is told to (`standby_carries`, by default control: commands and acks, the
// mission and parameter protocols, HEARTBEAT; the same classification as a transmit budget's,
// `tx_classes`), and everything else only while the free members are failing.
//
// Failing is known where it matters, on the receiving side. Each side measures what it
// receives on each member (loss from the sequence numbers over kLossWindow, or silence: no
// frame for four of the link's usual gaps, within kMinSilence..kMaxSilence) and tells the other
// side, for each free member, with a NAMED_VALUE_INT sent over every member of the bond (so it
// arrives over the metered link when the radio is dead):
//   name  "mbl:" + the first 6 characters of the member's endpoint name (identifies the link)
//   value its loss in per mille over the window (0 when under kMinExpected frames: too few to
//         judge); 1000 when silent
// A report goes every kReportEvery, and at once (checked every kTick) when a link falls silent,
// comes back or its loss moves by kReportStep: a second of reports is what the metered link
// carries in standby, and a radio cut is told within a fraction of a second.
// NAMED_VALUE_INT is common.xml, has no target (stock routers forward it as any broadcast),
// carries a name that says which link, and means nothing to an autopilot or a GCS: a report is
// consumed by the bond that receives it and never routed further. (RADIO_STATUS would make an
// autopilot throttle its streams; LINK_NODE_STATUS has no field naming a link.)
//
// The sending side decides what the metered member carries (a state per bond):
//   standby -> active  as soon as every free link the peer reports is above failover_loss, or no
//                      report has come for kReportTimeout (the peer cannot be heard at all);
//   active -> standby  once no free link failed for failback_after and the best one's loss,
//                      averaged over the last failback_after, is below failback_loss.
// The gap between the two thresholds and the time to fail back are the hysteresis.
// On going active, the frames standby held back from the metered member over the last `resend`
// are sent on it first: they are the ones a failing radio lost while the failure was being
// detected, and the other side's dedup drops those the radio did deliver.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "core/event_loop.h"
#include "mavlink/frame.h"
#include "routing/stream_positions.h"

namespace mavbond {

class Standby {
public:
    static constexpr Duration kTick = milliseconds(100);
    static constexpr Duration kReportEvery = seconds(1);
    static constexpr int32_t kReportStep = 50;      // per mille
    static constexpr Duration kLossWindow = seconds(2);
    static constexpr int64_t kMinExpected = 20;     // frames in the window to judge a loss
    static constexpr Duration kMinSilence = milliseconds(250);
    static constexpr Duration kMaxSilence = seconds(3);
    static constexpr Duration kReportTimeout = milliseconds(2500);  // two reports missed, and more
    static constexpr uint32_t kMsgNamedValueInt = 252;
    static constexpr size_t kNameLen = 10;          // NAMED_VALUE_INT.name
    static constexpr const char* kNamePrefix = "mbl:";
    static constexpr size_t kHeldCapacity = 512;    // frames kept for a resend, at most

    /// `members`: the bond's endpoints, in its member order, with their cost and classes.
    Standby(const BondConfig& bond, const std::vector<const EndpointConfig*>& members,
            const TxClassesConfig& classes, TimePoint now);

    /// Takes over what `old`, this bond's standby before a reload, measured and decided, when
    /// its members are the same (names and costs, in order): a reload that changes a threshold
    /// neither forgets a failing radio nor drops what was held for a resend. The thresholds
    /// and classes are the new ones; with a new failback_after the free links prove themselves
    /// healthy again over it. False, and nothing taken, when the members differ.
    bool continue_from(const Standby& old);

    // --- what is sent --------------------------------------------------------------------

    /// Whether member `member` may carry a frame of message `msgid` now.
    bool lets_send(uint32_t member, uint32_t msgid) const {
        return !members_[member].metered || active_ ||
               (members_[member].carries >> static_cast<unsigned>(classes_.class_of(msgid)) & 1u);
    }
    bool metered(uint32_t member) const { return members_[member].metered; }
    bool active() const { return active_; }
    /// Keeps a copy of a frame withheld from metered member `member` (`route`: which routing
    /// of a frame this is, so a member with several links keeps it once).
    void hold(uint32_t member, const Frame& frame, uint64_t route, TimePoint now);
    /// The frames held over the last `resend` (oldest first), each with its member; called
    /// with each as (member, bytes). Forgets them.
    template <typename F>
    void take_held(TimePoint now, F&& f) {
        for (size_t i = 0; i < held_count_; i++) {
            const Held& h = held_[(held_head_ + i) % held_.size()];
            if (now - h.at <= resend_)
                f(h.member, std::span<const uint8_t>(h.bytes.data(), h.len));
        }
        held_head_ = held_count_ = 0;
    }

    // --- what is received ----------------------------------------------------------------

    /// A frame received on member `member` (its step in its source's stream there).
    void received(uint32_t member, const StreamStep& step, TimePoint arrival);
    /// Whether `frame` is a peer's report; if so it is taken in (and must not be routed).
    bool take_report(const Frame& frame, TimePoint arrival);

    // --- the timer -----------------------------------------------------------------------

    /// What this side reports of one free member.
    struct Report {
        std::array<char, kNameLen> name{};
        int32_t permille = 0;
    };
    /// The reports due now: one per free member, or none (see the header).
    std::vector<Report> reports(TimePoint now, const std::vector<TimePoint>& last_heard);
    /// Judges the peer's reports: true when the metered members just went active (the caller
    /// resends what was held).
    bool judge(TimePoint now);

    // --- what the status shows -----------------------------------------------------------

    struct PeerLink {
        std::string name;    // as the peer names it ("mbl:" left out)
        int32_t permille = 0;
        TimePoint heard{};
    };
    struct Counters {
        uint64_t to_active = 0;     // standby -> active
        uint64_t to_standby = 0;    // active -> standby
        uint64_t withheld = 0;      // frames kept off a metered member in standby
        uint64_t resent = 0;        // frames sent on it again on going active
        uint64_t reports_sent = 0;
        uint64_t reports_received = 0;
    };
    const std::vector<PeerLink>& peer_links() const { return peer_; }
    Counters& counters() { return counters_; }
    const Counters& counters() const { return counters_; }
    /// The loss of what this side receives on member `member` now, in per mille.
    int32_t measured_permille(uint32_t member, TimePoint now, TimePoint last_heard);

private:
    struct Member {
        std::string name;
        bool metered = false;
        uint8_t carries = 0;  // bit per TxClass
        // Received and lost frames in kBuckets buckets of kLossWindow / kBuckets.
        std::array<int64_t, 8> received{};
        std::array<int64_t, 8> lost{};
        int64_t epoch = 0;   // bucket of the newest count
        TimePoint last_arrival{};
        double gap_ns = 0;   // the usual gap between two frames (moving average)
        int32_t reported = -1;  // per mille last reported (-1: never)
    };
    struct Held {
        TimePoint at;
        uint64_t route = 0;
        uint32_t member = 0;
        uint16_t len = 0;
        std::array<uint8_t, kMaxFrameLen> bytes{};
    };
    static constexpr int64_t kBuckets = 8;
    int64_t bucket_of(TimePoint t) const;
    void roll(Member& m, int64_t epoch);

    const TxClassesConfig classes_;
    const double failover_loss_, failback_loss_;
    const Duration failback_after_, resend_;
    std::vector<Member> members_;
    std::vector<PeerLink> peer_;
    TimePoint started_;
    TimePoint last_report_{};
    bool active_ = false;
    TimePoint healthy_since_ = TimePoint::max();  // active: since when the free links are fine
    // The best free link's loss at each judgement while active and not failing, in buckets of
    // failback_after / kHealthyBuckets: its average over the last failback_after.
    struct HealthyBucket {
        int64_t epoch = -1;
        double sum = 0;
        uint64_t count = 0;
    };
    static constexpr int64_t kHealthyBuckets = 10;
    std::array<HealthyBucket, kHealthyBuckets> healthy_{};
    std::vector<Held> held_;  // a ring (empty when resend is 0)
    size_t held_head_ = 0, held_count_ = 0;
    Counters counters_;
};

class Router;
class LocalSource;

/// Sends each bond's standby reports every kReportPeriod and lets it judge the peer's (a
/// peer that stopped reporting is judged on this timer, not on a report).
class StandbyMonitor {
public:
    StandbyMonitor(Router& router, EventLoop& loop, LocalSource& source);

private:
    void tick(TimePoint now);

    Router& router_;
    LocalSource& source_;
    EventLoop::Timer timer_;
};

}  // namespace mavbond
