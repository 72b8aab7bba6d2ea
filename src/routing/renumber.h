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
// a second, or before 1024 newer positions of the source passed (mavbond/stream_holes.hpp),
// is a frame lost on every link, and the next frame delivered steps over it. Gaps appear that late, and count
// exactly the frames lost on every link; a copy later still is delivered and also counted
// lost. (The holes are kept by position, not by count: a burst, such as a 300-parameter list,
// moves the stream hundreds of positions in milliseconds while a copy is still on its way on
// the slower link. With only 64 kept, such a copy came too late to fill its hole, and the GCS
// counted a frame lost that the bond delivered.)
//
// A source's holes are allocated with its first frame; nothing per frame, O(1) amortised.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>

#include "mavbond/source_table.hpp"
#include "mavbond/stream_holes.hpp"

namespace mavbond {

class SeqRenumberer {
public:
    struct Counters {
        uint64_t renumbered = 0;   // delivered frames given an output number
        uint64_t gaps = 0;         // output numbers skipped: frames lost on every link
        uint64_t late_filled = 0;  // delivered after a later frame, in their hole
        uint64_t unplaced = 0;     // delivered before dedup could place them (given the next number)
        uint64_t untracked = 0;    // frames of sources beyond the table (left alone)
        uint64_t added = 0;        // frames mavbond added to a source's stream
    };

    static constexpr uint32_t kSourceSlots = 128;
    static constexpr uint32_t kMaxSources = SourceTable<char, kSourceSlots>::kMaxSources;


    /// A frame the bond delivers, at position `pos` of its source's stream (as dedup numbers
    /// it), received at t_ns; `seq` is its own number, kept for a source's first frame.
    /// Returns the number it goes out with.
    uint8_t deliver(uint8_t sysid, uint8_t compid, uint8_t seq, int64_t pos, int64_t t_ns);
    /// A frame the bond delivers without a position (dedup could not place it yet): it goes
    /// out with the next number, leaving the holes as they are.
    uint8_t deliver_unplaced(uint8_t sysid, uint8_t compid, uint8_t seq);
    /// A frame mavbond adds to a source's stream (a link event told as the vehicle): the next
    /// number, so a GCS counts it in sequence; nullopt before the source's first frame.
    std::optional<uint8_t> add(uint8_t sysid, uint8_t compid);

    const Counters& counters() const { return counters_; }

private:
    struct Source {
        uint8_t next_out = 0;   // the output number the next frame gets, before owed gaps
        uint64_t owed = 0;      // holes lost (on every link), not yet stepped over
        std::unique_ptr<StreamHoles> holes;  // from the source's first placed frame
    };

    /// The output number for the next delivered frame of `s`, stepping over the gaps owed.
    uint8_t next_number(Source& s);

    SourceTable<Source, kSourceSlots> sources_;
    Counters counters_;
};

}  // namespace mavbond
