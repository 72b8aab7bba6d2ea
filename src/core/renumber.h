// Sequence renumbering for a bond whose links number one stream each their own way (dedup
// key: content). A GCS measures link quality from sequence gaps per source (sysid, compid);
// the merged stream of two links with their own counters looks to it like heavy loss and
// repeats. Renumbering makes the gaps a GCS sees exactly the frames lost on every link.
//
// Two numberings are kept per source:
// - the exact number of each delivered frame: the number the source's first link would have
//   given it. A duplicate copy (dropped by dedup) of a frame delivered with exact number e,
//   arriving on link M with M's number s_M, gives M's offset e - s_M (mod 256); a frame from
//   link L with number s has exact number s + offset(L). The first link heard keeps its
//   numbers; a link with no offset yet continues from the highest exact number. Every
//   duplicate re-learns its link's offset (a sender that restarts its counter costs one jump).
// - the output number, given in delivery order. A copy rescued from a slower link arrives
//   after frames that followed it; given its exact number it would go backwards, and
//   QGroundControl and MAVProxy count a step back as ~255 lost frames. So output numbers only
//   ever step by one, plus the gaps owed: an exact number skipped is a hole; a late copy fills
//   it; a hole no copy filled within kHold (1 s), or before 64 newer numbers of the source
//   passed (the bits kept per source; 0.5 s at 124 frames/s), is a frame lost on every link,
//   and the next frame delivered steps over it. Gaps appear that late, and count exactly the
//   frames lost on every link; a copy later still is delivered and also counted lost.
//
// The exact number of recently delivered frames is kept by key hash in a direct-mapped
// table: a slot overwritten before the copy arrives only loses one learning sample. A copy is
// matched to its delivery by time too (dedup's skew), so the newer instance of a recurring
// message (the same HEARTBEAT every second) never teaches the offset of an older one's copy.
// Everything is sized at construction: no allocation per frame, O(1) per frame.
#pragma once

#include <cstdint>
#include <vector>

namespace mavbond {

class SeqRenumberer {
public:
    struct Key {
        uint64_t h1;
        uint64_t h2;
    };
    struct Counters {
        uint64_t renumbered = 0;       // delivered frames given an output number
        uint64_t gaps = 0;             // output numbers skipped: frames lost on every link
        uint64_t late_filled = 0;      // delivered after a later frame, in their hole
        uint64_t offsets_learned = 0;  // a link's offset set or changed by a duplicate
        uint64_t unmatched = 0;        // duplicates whose first copy was no longer remembered
        uint64_t untracked = 0;        // frames of sources beyond the table (left alone)
    };

    static constexpr uint32_t kMaxSources = 64;
    static constexpr uint32_t kLinksPerSource = 8;
    static constexpr uint32_t kSlots = 4096;       // delivered frames remembered (power of two)
    static constexpr uint32_t kHoles = 64;         // exact numbers behind the frontier tracked
    static constexpr int64_t kHoldNs = 1'000'000'000;  // kHold: how long a hole waits for a copy

    SeqRenumberer();

    /// A frame the bond delivers, from `link` with its number `seq`, received at t_ns; `key`
    /// is its dedup hash (nullptr when it has none). Returns the number it goes out with.
    uint8_t deliver(uint8_t sysid, uint8_t compid, uint32_t link, uint8_t seq, const Key* key,
                    int64_t t_ns);
    /// A copy dedup dropped: arrived at t_ns on `link` with number `seq`, skew_ns after the
    /// first copy. Learns the link's offset when the first copy is still remembered.
    void duplicate(uint8_t sysid, uint8_t compid, uint32_t link, uint8_t seq, const Key& key,
                   int64_t t_ns, int64_t skew_ns);

    const Counters& counters() const { return counters_; }

private:
    static constexpr uint32_t kNoLink = UINT32_MAX;
    struct LinkOffset {
        uint32_t link = kNoLink;
        uint8_t offset = 0;
        uint64_t used = 0;  // for replacing the least recently used when all are taken
    };
    struct Source {
        bool in_use = false;
        uint8_t sysid = 0;
        uint8_t compid = 0;
        uint8_t frontier = 0;   // the exact number expected next
        uint8_t next_out = 0;   // the output number the next frame gets, before owed gaps
        uint8_t odd_run = 0;    // frames in a row behind the frontier that filled no hole
        uint32_t owed = 0;      // holes expired (lost on every link), not yet stepped over
        uint64_t holes = 0;     // bit j: exact number frontier - 1 - j skipped, no copy yet
        int64_t skipped_at[kHoles] = {};  // by exact number % kHoles: when it became a hole
        LinkOffset links[kLinksPerSource];
    };
    struct Delivered {
        uint64_t h1 = 0;
        uint64_t h2 = 0;
        int64_t t_ns = 0;
        uint8_t exact = 0;
        bool valid = false;
    };

    Source* source(uint8_t sysid, uint8_t compid);
    /// The link's entry, or a new one (replacing the least recently used): *known tells which.
    LinkOffset& link_of(Source& s, uint32_t link, bool* known);
    /// Holes older than kHold become owed gaps, oldest first.
    void expire_holes(Source& s, int64_t t_ns);
    /// Moves the frontier past exact number e (a frame at or ahead of it), or fills e's hole.
    void place(Source& s, uint8_t e, int64_t t_ns);

    std::vector<Source> sources_;      // open addressing on (sysid, compid)
    std::vector<Delivered> delivered_; // direct-mapped on h1
    uint64_t tick_ = 0;
    Counters counters_;
};

}  // namespace mavbond
