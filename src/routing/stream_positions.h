// Where each frame stands in its source's stream on one link: MAVLink's 8-bit sequence
// number, per source (sysid, compid), unwrapped into a running position. The host tracks it
// once per frame for every link a filter sees and hands it over with the frame
// (mavbond_frame.stream_pos, stream_lost, stream_flags): loss counting (stats, linkswitch)
// and matching copies across links (dedup) all read the same figures.
//
// Modulo 256 a step is ambiguous: a step of 1..127 forward is taken as new frames (the
// frames between were lost on this link), a step back is a late frame (reordering), which
// fills its gap when that was counted (a late frame never inflates loss) and is a repeat
// otherwise. A run of frames that fit neither means the source restarted its counter: the
// position moves on past it (flagged MAVBOND_STREAM_RESYNC), never back.
#pragma once

#include <cstdint>

#include "mavbond/plugin.h"
#include "mavbond/source_table.hpp"

namespace mavbond {

/// What one frame is in its stream on this link.
struct StreamStep {
    int64_t pos = 0;
    int32_t lost = 0;     // frames skipped before it; -1: it fills a gap counted before
    uint32_t flags = 0;   // MAVBOND_STREAM_*
};

/// The positions of every source heard on one link: a fixed open-addressed table, so a frame
/// never allocates. Sources beyond it are flagged MAVBOND_STREAM_UNTRACKED.
class StreamPositions {
public:
    StreamStep track(uint8_t sysid, uint8_t compid, uint8_t seq);
    /// Forgets every source (a new link in this place).
    void clear() { *this = StreamPositions(); }

    static constexpr uint32_t kCapacity = 64;
    static constexpr int kHistory = 128;      // how far back a late frame can fill its gap
    static constexpr int kMaxStep = 128;      // forward steps at least this far are not gaps
    static constexpr uint8_t kResyncRun = 3;  // frames in a row that fit nothing: a restart

private:
    struct Source {
        bool started = false;
        uint8_t odd_run = 0;  // frames in a row that were repeats or far behind
        History128 seen;      // bit i: position last - i arrived
        int64_t last = 0;     // the highest position so far
    };
    SourceTable<Source, kCapacity> sources_;
};

}  // namespace mavbond
