// When a bond member is silent: the one rule every judge of it goes by (link events on both
// sides, standby's reports), per bond.
//
// A gap in what a link brings is silence only when its far side evidently sent meanwhile. An
// autopilot pauses its stream now and then (ArduCopter SITL for up to 1.4 s): the far gateway
// then has nothing to write, and a gap rule alone took the radio for dead, told the GCS so and
// sent the metered link out of standby. What a far mavbond does write on every member, always:
// its standby reports (NAMED_VALUE_INT "mbl:"/"mbp:", routed to every member whatever its tx
// policy or standby and written at once whatever a transmit budget holds (Endpoint::send), one
// frame numbered alike on all of them, about once a second; a bond with a metered member,
// marked on both sides, has them). So a link is silent when
//   - it has brought nothing for kGapFactor of its usual gaps (the longest of its last 32 gaps
//     as the ticks see them, kAssumedGap until kMinSamples are seen; a gap longer than
//     kGapFactor of them is an outage's, no usual gap), within the judge's least and most: one
//     lost frame of a sparse link leaves no such gap, and a busy one is judged fast again
//     seconds after its far side paused; and
//   - a report of the far side came on another member after this link's last frame and has not
//     come here within this link's usual lag behind the first copy (the longest of its last 32,
//     plus kLagSlack; kMaxLag until kMinSamples are seen): its far side wrote on it, and it did
//     not arrive.
// With nothing to go by - a one-member bond, a far side that sends no reports, every link
// silent - the gaps alone decide: once no report has come on another member for
// kEvidenceTimeout during the link's silence, it is silent for the rest of it (a report that
// comes later does not make it heard). A member never heard is silent once the far side, heard
// on another member, has had `most` to use it too (counted from the start when it is heard on
// none).
//
// Fed on the judges' 100 ms timers (heard) and with each copy of a report (report): nothing on
// the per-frame path.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/clock.h"
#include "mavlink/frame_writer.h"

namespace mavbond {

/// The longest of the last kKept values seen (gaps, lags): what a link usually does now, for
/// as many values as make "usually" (a busy link forgets a pause within seconds, a sparse one
/// keeps its long gaps for as long as it takes to have kKept of them).
class RecentLongest {
public:
    static constexpr size_t kKept = 32;

    void add(Duration d) {
        kept_[count_ % kKept] = d;
        count_++;
    }
    Duration value() const {
        return *std::max_element(kept_.begin(), kept_.begin() + std::min<uint64_t>(count_, kKept));
    }
    uint64_t count() const { return count_; }

private:
    std::array<Duration, kKept> kept_{};
    uint64_t count_ = 0;
};

class LinkSilence {
public:
    static constexpr int kGapFactor = 3;
    static constexpr uint32_t kMinSamples = 3;
    static constexpr Duration kAssumedGap = seconds(1);  // a HEARTBEAT's: the least a link carries
    static constexpr Duration kLagSlack = milliseconds(250);
    static constexpr Duration kMaxLag = seconds(3);
    static constexpr Duration kEvidenceTimeout = milliseconds(2500);  // two reports missed, and more
    static constexpr size_t kReportsKept = 16;     // several seconds of reports, copies included
    static constexpr Duration kSameReport = seconds(10);  // its copies come this close at most
    static constexpr uint32_t kNone = UINT32_MAX;

    /// `members`: the bond's, in its member order (names for the log).
    LinkSilence(std::vector<std::string> members, TimePoint started);

    /// When member `member`'s last frame arrived (epoch: never), as of `now` (every tick).
    void heard(uint32_t member, TimePoint last_rx, TimePoint now);
    /// A copy of one of the far side's standby reports came in on `member` (`id`: its source
    /// and sequence number, the same on every member).
    void report(uint32_t member, const FrameSource& id, TimePoint arrival);

    struct Verdict {
        enum class By : uint8_t {
            Gaps,        // not silent for kGapFactor of its usual gaps (or `least`) yet
            Evidence,    // a report of the far side to go by: came elsewhere, not here (silent)
                         // or not yet overdue here (not silent)
            NoEvidence,  // nothing to go by: the gaps alone
            NeverHeard,
        };
        bool silent = false;
        By by = By::Gaps;
        Duration quiet{};      // since its last frame
        Duration usual_gap{};  // the gap rule's
        Duration allowed_lag{};
        uint32_t witness = kNone;  // By::Evidence, silent: the member the missed report came on
        Duration witness_age{};    // how long ago
    };
    /// Whether member `member` (its last frame at `last_rx`, as the caller knows it now) is
    /// silent at `now`; the gaps judged within [least, most].
    Verdict judge(uint32_t member, TimePoint last_rx, TimePoint now, Duration least,
                  Duration most) const;
    /// Why, for the log ("silent for 1200 ms: the far side's report on lte 600 ms ago is not
    /// here (its usual lag 40 ms)").
    std::string explain(const Verdict& v) const;

    /// A member's usual gap and lag behind the first copy of a report, as judged now.
    Duration usual_gap(uint32_t member) const;
    Duration allowed_lag(uint32_t member) const;

private:
    struct Member {
        std::string name;
        TimePoint last{};        // its last frame, as of the last tick
        RecentLongest gaps;
        RecentLongest lags;      // behind the first copy of each report
        TimePoint last_report{}; // its last copy of a report
        bool nothing_to_go_by = false;  // since `last`: no report elsewhere for kEvidenceTimeout
    };
    struct Report {
        FrameSource id{};
        TimePoint first{};
        uint32_t first_member = kNone;
        uint64_t on = 0;  // bit per member that brought a copy
    };
    /// The latest copy of a report on any member but `member` (epoch: none).
    TimePoint report_elsewhere(uint32_t member) const;

    std::vector<Member> members_;
    std::array<Report, kReportsKept> reports_{};  // a ring, the newest at next_ - 1
    size_t next_ = 0;
    TimePoint started_;
    TimePoint peer_since_{};  // the far side's first frame on any member
};

}  // namespace mavbond
