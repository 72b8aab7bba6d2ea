// Loss of a bond's delivered stream, per source (sysid, compid), for stats (each link's loss
// comes from the host's stream positions): by the bond's positions where dedup notes them,
// else from MAVLink sequence numbers.
//
// MAVLink has one 8-bit sequence counter per source, so loss is only measurable per source and
// only modulo 256: a forward step of g (1 <= g < 128) means g - 1 frames were lost; anything
// else is a late frame (reordering), a repeat, or a source that restarted. A late frame that
// fills a gap already counted as lost gives that loss back, so reordering never inflates loss.
#pragma once

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

private:
    static constexpr uint8_t kMaxGap = 128;   // forward steps at least this far are not gaps
    static constexpr uint8_t kHistory = 64;   // how far back a late frame can fill a gap
    static constexpr uint8_t kResyncRun = 3;  // odd frames in a row that mean "start over"

    void restart(uint8_t seq) {
        started_ = true;
        last_ = seq;
        seen_ = ~uint64_t{0};  // before the first frame: nothing to fill
        odd_run_ = 0;
    }

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
class DeliveredLoss {
public:
    /// A delivered frame; `pos` its bond position, nullptr when dedup did not place it.
    SeqStep step(uint8_t sysid, uint8_t compid, const int64_t* pos, uint8_t seq, int64_t t_ns) {
        Source* s = sources_.find(sysid, compid);
        if (!s)
            return SeqStep{1, 0};
        if (!pos)
            return s->seq.step(seq);
        if (!s->holes)
            s->holes = std::make_unique<mavbond::StreamHoles>();
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
    struct Source {
        SeqTracker seq;
        std::unique_ptr<mavbond::StreamHoles> holes;  // from its first frame with a position
    };
    mavbond::SourceTable<Source, 64> sources_;
};

/// Loss as a fraction of expected frames; negative totals (late frames filling gaps counted
/// in an earlier window) clamp to 0.
inline double loss_fraction(int64_t received, int64_t lost) {
    if (lost <= 0 || received + lost <= 0)
        return 0.0;
    return static_cast<double>(lost) / static_cast<double>(received + lost);
}

}  // namespace mavbond_plugins
