// Loss of a bond's delivered stream, per source (sysid, compid), for stats (each link's loss
// comes from the host's stream positions): by the bond's positions where dedup notes them,
// else from MAVLink sequence numbers.
//
// MAVLink has one 8-bit sequence counter per source, so loss is only measurable per source and
// only modulo 256: a forward step of g (1 <= g < 128) means g - 1 frames were lost; anything
// else is a late frame (reordering), a repeat, or a source that restarted. A late frame that
// fills a gap already counted as lost gives that loss back, so reordering never inflates loss.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>

#include "mavbond/source_table.hpp"
#include "mavbond/stream_holes.hpp"

namespace mavbond_plugins {

/// What one frame changes: `received` counts distinct sequence numbers (0 for a repeat),
/// `lost` may be -1 when a late frame fills a counted gap. Expected = received + lost.
struct SeqStep {
    int32_t received = 0;
    int32_t lost = 0;
};

/// The sequence state of one source on one stream.
class SeqTracker {
public:
    SeqStep step(uint8_t seq) {
        if (!started_) {
            restart(seq);
            return {1, 0};
        }
        auto ahead = static_cast<uint8_t>(seq - last_);
        if (ahead != 0 && ahead < kMaxGap) {
            seen_ = ahead >= kHistory ? 0 : seen_ << ahead;
            seen_ |= 1;
            last_ = seq;
            odd_run_ = 0;
            return {1, ahead - 1};
        }
        auto behind = static_cast<uint8_t>(last_ - seq);
        if (behind < kHistory && !((seen_ >> behind) & 1)) {
            seen_ |= uint64_t{1} << behind;
            odd_run_ = 0;
            return {1, -1};
        }
        // A repeat, or far behind: one such frame is noise, a run of them means the source
        // restarted its counter or came back after a long outage; follow it from here without
        // counting the jump as loss (it is meaningless modulo 256).
        if (++odd_run_ >= kResyncRun) {
            restart(seq);
            return {1, 0};
        }
        return {0, 0};
    }

    /// Follows the source from `seq` on, with nothing before it to fill.
    void restart(uint8_t seq) {
        started_ = true;
        last_ = seq;
        seen_ = ~uint64_t{0};  // before the first frame: nothing to fill
        odd_run_ = 0;
    }

private:
    static constexpr uint8_t kMaxGap = 128;   // forward steps at least this far are not gaps
    static constexpr uint8_t kHistory = 64;   // how far back a late frame can fill a gap
    static constexpr uint8_t kResyncRun = 3;  // odd frames in a row that mean "start over"

    uint64_t seen_ = 0;  // bit i: seq (last_ - i) arrived
    uint8_t last_ = 0;
    uint8_t odd_run_ = 0;
    bool started_ = false;
};

/// Sequence trackers for the sources seen on one stream, in a fixed table so a frame never
/// allocates. A stream rarely has more than a handful of sources (autopilot, gimbal, companion,
/// GCS); sources beyond the table are counted as received, never lost.
class StreamLoss {
public:
    SeqStep step(uint8_t sysid, uint8_t compid, uint8_t seq) {
        SeqTracker* t = trackers_.find(sysid, compid);
        return t ? t->step(seq) : SeqStep{1, 0};
    }

private:
    mavbond::SourceTable<SeqTracker, 64> trackers_;
};

/// The delivered stream of a bond: by position when the frame has one (a copy from a slower
/// link fills its hole however far behind a burst it comes), else by sequence number. Holes
/// become lost after StreamHoles' hold, at a frame or an expire() call.
///
/// A source that starts its numbering again (a GCS reconnecting, an autopilot rebooting) is
/// no loss: where the host saw its numbering restart (MAVBOND_STREAM_RESYNC), or the bond's
/// position leaps kMaxLeap or more (modulo 256 such a step says nothing: dedup placed the
/// first frames of a new numbering a turn away), the source is followed from there with no
/// hole for the leap. A position dedup placed one step on from the newest is read as such,
/// whatever the host saw of one link's numbering: after an outage on every link, a link whose
/// own step it could not read is flagged MAVBOND_STREAM_RESYNC though dedup placed its frames
/// right (a second of a 124 frames/s stream lost on both links read as 24 lost of 148). So
/// is a source that went quiet: unheard for kQuietNs
/// or more while every link that brought it was heard throughout, it stopped sending (its
/// links would have brought its frames, as they brought the others'); a new numbering then
/// steps forward as often as back (MAVProxy's 192 to 0 read as 63 lost). A source unheard
/// because its links were silent comes back with its loss counted.
class DeliveredLoss {
public:
    static constexpr int64_t kMaxLeap = 128;
    static constexpr int64_t kQuietNs = 5'000'000'000;  // a source's or a link's silence
    static constexpr uint32_t kMembers = 64;             // members followed (more: never quiet)

    /// A frame came in on the bond's member `member` at t_ns, delivered or a copy (after
    /// step() for it: a step judges what came before).
    void heard(uint32_t member, int64_t t_ns) {
        if (member >= kMembers)
            return;
        Hearing& h = members_[member];
        if (h.last == kNever || t_ns - h.last >= kQuietNs)
            h.back = t_ns;
        h.last = std::max(h.last, t_ns);
    }

    /// A delivered frame, that came on `member` (heard() next); `pos` its bond position,
    /// nullptr when dedup did not place it; `stream_flags` the host's MAVBOND_STREAM_* of the
    /// link it came on.
    SeqStep step(uint8_t sysid, uint8_t compid, const int64_t* pos, uint8_t seq, int64_t t_ns,
                 uint32_t stream_flags = 0, uint32_t member = kMembers) {
        Source* s = sources_.find(sysid, compid);
        if (!s)
            return SeqStep{1, 0};
        const bool quiet = s->last_ns != kNever && t_ns - s->last_ns >= kQuietNs &&
                           heard_throughout(s->members, s->last_ns, t_ns);
        s->last_ns = std::max(s->last_ns, t_ns);
        if (member < kMembers)
            s->members |= uint64_t{1} << member;
        if (!pos) {
            if (quiet) {
                s->seq.restart(seq);
                return SeqStep{1, 0};
            }
            return s->seq.step(seq);
        }
        if (s->holes && s->holes->started() &&
            (quiet || *pos - s->holes->newest() >= kMaxLeap ||
             ((stream_flags & MAVBOND_STREAM_RESYNC) && *pos <= s->holes->newest()))) {
            // The source goes on from here: holes still waiting for a late copy are forgotten,
            // and a frame from before this point is no late copy of one.
            s->holes.reset();
            s->restart_at = *pos;
        }
        if (!s->holes) {
            s->holes = std::make_unique<mavbond::StreamHoles>();
            if (s->restart_at == kNever)
                s->restart_at = *pos;
        }
        if (*pos < s->restart_at)
            return SeqStep{1, 0};
        uint64_t lost = s->holes->expire(t_ns);
        switch (s->holes->deliver(*pos, t_ns, lost)) {
        case mavbond::StreamHoles::Arrival::New:
        case mavbond::StreamHoles::Arrival::Filled:
            return SeqStep{1, static_cast<int32_t>(lost)};
        case mavbond::StreamHoles::Arrival::AfterLoss:
            break;
        }
        // Counted lost, then delivered after all.
        return SeqStep{1, static_cast<int32_t>(lost) - 1};
    }

    /// The holes that have waited long enough by t_ns, counted lost now.
    int64_t expire(int64_t t_ns) {
        int64_t lost = 0;
        sources_.for_each([&](Source& s) {
            if (s.holes)
                lost += static_cast<int64_t>(s.holes->expire(t_ns));
        });
        return lost;
    }

private:
    static constexpr int64_t kNever = INT64_MIN;
    struct Source {
        SeqTracker seq;
        std::unique_ptr<mavbond::StreamHoles> holes;  // from its first frame with a position
        int64_t restart_at = kNever;  // where the holes are counted from
        int64_t last_ns = kNever;     // its last delivered frame
        uint64_t members = 0;         // bit m: member m delivered it
    };
    struct Hearing {
        int64_t last = kNever;  // its last frame
        int64_t back = kNever;  // its first frame after its last silence of kQuietNs or more
    };

    /// Whether every member in `mask` (at least one) was heard from `from` to `to` with no
    /// silence of kQuietNs or more.
    bool heard_throughout(uint64_t mask, int64_t from, int64_t to) const {
        if (!mask)
            return false;
        for (uint32_t m = 0; m < kMembers; m++) {
            const Hearing& h = members_[m];
            if ((mask >> m & 1) && (h.back > from || to - h.last >= kQuietNs))
                return false;
        }
        return true;
    }

    mavbond::SourceTable<Source, 64> sources_;
    std::array<Hearing, kMembers> members_{};
};

/// Loss as a fraction of expected frames; negative totals (late frames filling gaps counted
/// in an earlier window) clamp to 0.
inline double loss_fraction(int64_t received, int64_t lost) {
    if (lost <= 0 || received + lost <= 0)
        return 0.0;
    return static_cast<double>(lost) / static_cast<double>(received + lost);
}

}  // namespace mavbond_plugins
