// Standby: a bond member marked `cost: metered` (LTE, satellite: paid by the byte) carries only
// the classes it is told to (`standby_carries`, by default control: commands and acks, the
// mission and parameter protocols, HEARTBEAT; the same classification as a transmit budget's,
// `tx_classes`), and everything else only while the free members are failing. A message no
// free member may carry (their block_out / allow_out keep it off, as an air side keeps file
// transfers off a slow radio) it carries always: standby would otherwise lose it on every link.
//
// Failing is known where it matters, on the receiving side. Each side measures what it
// receives on each member (its loss over kLossWindow, or silence as routing/link_silence.h
// judges it, within kMinSilence..kMaxSilence: its far side evidently wrote on it meanwhile, and
// nothing came) and tells the other side, for each free member, with a NAMED_VALUE_INT sent
// over every member of the bond (so it arrives over the metered link when the radio is dead;
// and because every member carries it, it is also what tells a link that stopped from one whose
// far side had nothing to send). The loss is of what the far side gave the link: its count markers
// (routing/link_account.h) say how many frames it wrote there, so a radio whose budget thins
// telemetry, or that carries less than is routed to it, fails only when it loses what it is
// given. (Until the first markers come, or from a far side that sends none, the loss is read
// from the gaps in the sources' sequence numbers.) The report:
//   name  "mbl:" + the first 6 characters of the member's endpoint name (identifies the link)
//   value its loss in per mille over the window (0 when under kMinExpected frames: too few to
//         judge); 1000 when silent
// A report goes every kReportEvery, and at once (checked every kTick) when a link falls silent,
// comes back or its loss moves by kReportStep: a second of reports is what the metered link
// carries in standby, and a radio cut is told within a fraction of a second.
// NAMED_VALUE_INT is common.xml, has no target (stock routers forward it as any broadcast),
// carries a name that says which link, and means nothing to an autopilot or a GCS: a report is
// consumed by the bond that receives it and never routed further; one that comes from outside
// every bond (a GCS port) is dropped (Router::standby_sees). Only a report naming one of this
// bond's free members counts (both sides name the bond's links alike), and a peer link not
// reported for kPeerExpiry is forgotten: names nobody uses take no room. On a signed bond
// only verified frames reach the router, so nobody without the key can make or move a report.
// (RADIO_STATUS would make an autopilot throttle its streams; LINK_NODE_STATUS has no field
// naming a link.)
//
// The sending side decides what the metered member carries (a state per bond):
//   standby -> active  as soon as every free link the peer reports is above failover_loss, or no
//                      report has come for kReportTimeout (the peer cannot be heard at all);
//   active -> standby  once no free link failed for failback_after and the best one's loss,
//                      averaged over the last failback_after, is below failback_loss.
// The gap between the two thresholds and the time to fail back are the hysteresis.
// On going active, the frames standby held back from the metered member over the last `resend`
// are sent on it first: they are the ones a failing radio lost while the failure was being
// detected, and the other side's dedup drops those the radio did deliver. It can only if it
// still remembers their first copies: each side announces its `resend` to the other (a
// NAMED_VALUE_INT "mbp:resend", milliseconds, with the first reports and every
// kAnnounceEvery), and the host tells its dedup (mavbond_bond_state.peer_resend_ns), which
// remembers long enough to cover it.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "core/event_loop.h"
#include "mavlink/frame.h"
#include "routing/link_silence.h"
#include "mavbond/source_table.hpp"
#include "routing/stream_positions.h"

namespace mavbond {

class Standby {
public:
    static constexpr Duration kTick = milliseconds(100);
    static constexpr Duration kReportEvery = seconds(1);
    static constexpr int32_t kReportStep = 50;      // per mille
    static constexpr Duration kLossWindow = seconds(2);
    static constexpr int64_t kMinExpected = 20;     // frames in the window to judge a loss
    // The bounds of silence (LinkSilence) standby judges by: a radio cut is reported soon.
    static constexpr Duration kMinSilence = milliseconds(250);
    static constexpr Duration kMaxSilence = seconds(3);
    static constexpr Duration kReportTimeout = LinkSilence::kEvidenceTimeout;
    static constexpr Duration kPeerExpiry = seconds(10);  // a peer link not reported: forgotten
    static constexpr uint32_t kMsgNamedValueInt = 252;
    static constexpr size_t kNameLen = 10;          // NAMED_VALUE_INT.name
    static constexpr const char* kNamePrefix = "mbl:";
    static constexpr const char* kResendName = "mbp:resend";  // this side's resend, in ms
    static constexpr Duration kAnnounceEvery = seconds(10);
    static constexpr size_t kHeldCapacity = 512;    // frames kept for a resend, at most
    static constexpr int kResendPerSource = 96;     // frames of one source resent, at most: within
                                                    // 127, with room for the control frames that
                                                    // went on the metered link among them
    static constexpr size_t kAccounts = 8;          // markers remembered per member (8 s)
    // How long a link is heard before its sequence gaps are taken for its loss, waiting for
    // the far side's first count markers (a mavbond's come within a second).
    static constexpr Duration kAwaitMarkers = seconds(3);

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
               (members_[member].carries >> static_cast<unsigned>(classes_.class_of(msgid)) & 1u) ||
               (free_filters_ && !a_free_member_carries(msgid));
    }
    /// Whether a free member's allow_out / block_out lets message `msgid` through.
    bool a_free_member_carries(uint32_t msgid) const;
    /// What metered member `member` carries in standby, for the log: "control", and the
    /// messages no free member may carry when there are such ("control; and
    /// FILE_TRANSFER_PROTOCOL, which no free member may carry (block_out, allow_out)").
    std::string carried_in_standby(uint32_t member) const;
    const std::string& member_name(uint32_t member) const { return members_[member].name; }
    size_t member_count() const { return members_.size(); }
    bool metered(uint32_t member) const { return members_[member].metered; }
    bool active() const { return active_; }
    /// Keeps a copy of a frame withheld from metered member `member` (`route`: which routing
    /// of a frame this is, so a member with several links keeps it once; `ticket`: its
    /// number's on the bond, routing/egress_numbering.h).
    void hold(uint32_t member, const Frame& frame, uint64_t route, uint64_t ticket, TimePoint now);
    /// A frame went on metered member `member` (`route`: its routing): the first of each
    /// source there bounds how far back a resend may reach (take_held).
    void sent(uint32_t member, const Frame& frame, uint64_t route) {
        if (FirstSent* f = members_[member].first_sent.find(frame.sysid, frame.compid);
            f && f->route == UINT64_MAX)
            f->route = route;
    }
    /// The frames held over the last `resend` (oldest first), each with its member; called
    /// with each as (member, bytes, ticket). Forgets them. A resend steps back in the numbering
    /// of each source the far side tracks on the metered link (routing/stream_positions.h): of
    /// a source it goes no further back than the link's first frame of it (before that, the
    /// far side takes the frames for repeats and then for a restarted counter), and holds at
    /// most kResendPerSource frames of it (a step back of more than 127 reads as one forward).
    template <typename F>
    void take_held(TimePoint now, F&& f);

    // --- what is received ----------------------------------------------------------------

    /// A frame received on member `member` (its step in its source's stream there).
    void received(uint32_t member, const StreamStep& step, TimePoint arrival);
    /// What the count markers of a member's links say (Router::member_account): the frames the
    /// far side wrote on them and how many of those arrived, as of the last marker, `at`.
    struct Account {
        uint64_t expected = 0;
        uint64_t received = 0;
        TimePoint at{};
    };
    /// A member's account now (every tick): its loss is measured from it once it has one.
    void accounted(uint32_t member, const Account& account);
    /// The name a report gives member endpoint `member` ("mbl:" left out): its first six
    /// characters.
    static std::string_view reported_name(std::string_view member) {
        return member.substr(0, kNameLen - std::char_traits<char>::length(kNamePrefix));
    }
    /// Whether `frame` is a standby report (a NAMED_VALUE_INT named "mbl:..."): mavbond's own,
    /// never routed on.
    static bool is_report(const Frame& frame);
    /// Takes in a peer's report (is_report) that came on member `member`: of one of this
    /// bond's free members, it is judged; naming anything else, it is counted
    /// (`reports_ignored`) and changes nothing. Either way its copies tell which members carry
    /// what the far side writes (LinkSilence).
    void take_report(uint32_t member, const Frame& frame, TimePoint arrival);

    // --- the timer -----------------------------------------------------------------------

    /// What this side reports of one free member.
    struct Report {
        std::array<char, kNameLen> name{};
        int32_t permille = 0;
    };
    /// When each member was last heard (epoch: never), as of `now` (every tick; reports()
    /// does it).
    void heard(const std::vector<TimePoint>& last_heard, TimePoint now);
    /// The reports due now: one per free member, or none (see the header).
    std::vector<Report> reports(TimePoint now, const std::vector<TimePoint>& last_heard);
    /// This side's `resend`, to tell the peer, when due (with the first reports, then every
    /// kAnnounceEvery: it changes only with a reload, and costs metered bytes).
    std::optional<Report> resend_announcement(TimePoint now);
    /// How far back the peer resends on its failover: what it announced, or this side's own
    /// until it has (the sides are usually set alike). `announced`: whether it has.
    Duration peer_resend(bool* announced = nullptr) const {
        if (announced)
            *announced = peer_resend_announced_;
        return peer_resend_announced_ ? peer_resend_ : resend_;
    }
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
        uint64_t resend_skipped = 0;  // held, not resent: beyond what the far side can place
        uint64_t reports_sent = 0;
        uint64_t reports_received = 0;
        uint64_t reports_ignored = 0;  // of them, naming no free member of this bond
    };
    const std::vector<PeerLink>& peer_links() const { return peer_; }
    /// Which members are silent (link events judge this bond's links by it too).
    const LinkSilence& silence() const { return silence_; }
    Counters& counters() { return counters_; }
    const Counters& counters() const { return counters_; }
    /// The loss of what this side receives on member `member` now, in per mille.
    int32_t measured_permille(uint32_t member, TimePoint now, TimePoint last_heard);

private:
    struct FirstSent {
        uint64_t route = UINT64_MAX;  // none yet
    };
    struct Member {
        std::string name;
        bool metered = false;
        uint8_t carries = 0;  // bit per TxClass
        MessageFilterConfig out;  // its allow_out / block_out
        // Received and lost frames in kBuckets buckets of kLossWindow / kBuckets.
        std::array<int64_t, 8> received{};
        std::array<int64_t, 8> lost{};
        int64_t epoch = 0;   // bucket of the newest count
        // The account at each of its last markers (a ring, newest at accounts_head - 1).
        std::array<Account, kAccounts> accounts{};
        size_t accounts_head = 0, accounts_count = 0;
        TimePoint first_arrival{};
        int32_t reported = -1;  // per mille last reported (-1: never)
        SourceTable<FirstSent, StreamPositions::kCapacity> first_sent;  // metered: see sent()
    };
    struct Held {
        TimePoint at;
        uint64_t route = 0;
        uint64_t ticket = 0;
        uint32_t member = 0;
        uint16_t len = 0;
        std::array<uint8_t, kMaxFrameLen> bytes{};
    };
    static std::pair<uint8_t, uint8_t> source_of(const Held& h) {
        return h.bytes[0] == kMagicV1 ? std::pair{h.bytes[3], h.bytes[4]}
                                      : std::pair{h.bytes[5], h.bytes[6]};
    }
    static constexpr int64_t kBuckets = 8;
    int64_t bucket_of(TimePoint t) const;
    /// The loss the markers tell over the last kLossWindow, per mille; -1 when they tell
    /// nothing recent (the sequence numbers' figure stands).
    static int32_t account_permille(const Member& m, TimePoint now);
    void roll(Member& m, int64_t epoch);

    const TxClassesConfig classes_;
    const double failover_loss_, failback_loss_;
    const Duration failback_after_, resend_;
    std::vector<Member> members_;
    bool free_filters_ = false;  // a free member has an allow_out or block_out
    std::vector<PeerLink> peer_;
    LinkSilence silence_;
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
    Duration peer_resend_{};
    bool peer_resend_announced_ = false;
    TimePoint last_announced_ = TimePoint::min();
    std::vector<Held> held_;  // a ring (empty when resend is 0)
    size_t held_head_ = 0, held_count_ = 0;
    Counters counters_;
};

template <typename F>
void Standby::take_held(TimePoint now, F&& f) {
    SourceTable<int, StreamPositions::kCapacity> left;  // per source: held frames to skip
    for (int pass = 0; pass < 2; pass++) {
        for (size_t i = 0; i < held_count_; i++) {
            const Held& h = held_[(held_head_ + i) % held_.size()];
            if (now - h.at > resend_)
                continue;
            const auto [sysid, compid] = source_of(h);
            FirstSent* first = members_[h.member].first_sent.find(sysid, compid);
            if (first && first->route != UINT64_MAX && h.route < first->route)
                continue;
            int* skip = left.find(sysid, compid);
            if (pass == 0) {
                if (skip)
                    ++*skip;  // counts the source's frames, then what is over the bound
                continue;
            }
            if (skip && *skip > kResendPerSource) {
                --*skip;
                counters_.resend_skipped++;
                continue;
            }
            f(h.member, std::span<const uint8_t>(h.bytes.data(), h.len), h.ticket);
        }
    }
    held_head_ = held_count_ = 0;
}

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
