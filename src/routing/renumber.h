// Sequence renumbering for a bond whose links number one stream each their own way (dedup
// key: content). A GCS measures link quality from sequence gaps per source (sysid, compid);
// the merged stream of two links with their own counters looks to it like heavy loss and
// repeats. Renumbering makes the gaps a GCS sees exactly the frames lost on every link.
//
// dedup gives every frame the bond delivers its position in the source's stream, the same
// for every link's copy (it aligns each link's numbering to the bond's by identity). Output
// numbers are given in delivery order: a copy rescued from a slower link arrives after frames
// that followed it, and given its own number it would go backwards, which QGroundControl and
// MAVProxy count as ~255 lost frames. So output numbers only ever step by one, plus the gaps
// owed: a position skipped is a hole; a late copy fills it; a hole no copy filled within
// kHold (1 s), or before 64 newer positions of the source passed (the bits kept per source;
// 0.5 s at 124 frames/s), is a frame lost on every link, and the next frame delivered steps
// over it. Gaps appear that late, and count exactly the frames lost on every link; a copy
// later still is delivered and also counted lost.
//
// Everything is sized at construction: no allocation per frame, O(1) per frame.
#pragma once

#include <cstdint>
#include <vector>

namespace mavbond {

class SeqRenumberer {
public:
    struct Counters {
        uint64_t renumbered = 0;   // delivered frames given an output number
        uint64_t gaps = 0;         // output numbers skipped: frames lost on every link
        uint64_t late_filled = 0;  // delivered after a later frame, in their hole
        uint64_t unplaced = 0;     // delivered before dedup could place them (given the next number)
        uint64_t untracked = 0;    // frames of sources beyond the table (left alone)
    };

    static constexpr uint32_t kMaxSources = 64;
    static constexpr uint32_t kHoles = 64;             // positions behind the frontier tracked
    static constexpr int64_t kHoldNs = 1'000'000'000;  // kHold: how long a hole waits for a copy

    SeqRenumberer();

    /// A frame the bond delivers, at position `pos` of its source's stream (as dedup numbers
    /// it), received at t_ns; `seq` is its own number, kept for a source's first frame.
    /// Returns the number it goes out with.
    uint8_t deliver(uint8_t sysid, uint8_t compid, uint8_t seq, int64_t pos, int64_t t_ns);
    /// A frame the bond delivers without a position (dedup could not place it yet): it goes
    /// out with the next number, leaving the holes as they are.
    uint8_t deliver_unplaced(uint8_t sysid, uint8_t compid, uint8_t seq);

    const Counters& counters() const { return counters_; }

private:
    struct Source {
        bool in_use = false;
        bool started = false;
        uint8_t sysid = 0;
        uint8_t compid = 0;
        int64_t frontier = 0;   // the position expected next
        uint8_t next_out = 0;   // the output number the next frame gets, before owed gaps
        uint32_t owed = 0;      // holes expired (lost on every link), not yet stepped over
        uint64_t holes = 0;     // bit j: position frontier - 1 - j skipped, no copy yet
        int64_t skipped_at[kHoles] = {};  // by position % kHoles: when it became a hole
    };

    Source* source(uint8_t sysid, uint8_t compid);
    /// Holes older than kHold become owed gaps, oldest first.
    void expire_holes(Source& s, int64_t t_ns);
    /// Moves the frontier past position `pos` (a frame at or ahead of it), or fills its hole.
    void place(Source& s, int64_t pos, int64_t t_ns);
    /// The output number for the next delivered frame of `s`, stepping over the gaps owed.
    uint8_t next_number(Source& s);

    std::vector<Source> sources_;  // open addressing on (sysid, compid)
    Counters counters_;
};

}  // namespace mavbond
