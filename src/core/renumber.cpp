#include "core/renumber.h"

#include <bit>

namespace mavbond {

namespace {
// The first copy's arrival as the duplicate's skew tells it and as we stamped it are the same
// loop-round time; a millisecond covers any rounding, and recurring contents are much further
// apart (a HEARTBEAT every second).
constexpr int64_t kSameInstanceNs = 1'000'000;
// Frames in a row behind the frontier that fill no hole: the source (or its first link's
// sender) restarted its counter; follow it from there.
constexpr uint8_t kResyncRun = 3;
}  // namespace

SeqRenumberer::SeqRenumberer() : sources_(kMaxSources), delivered_(kSlots) {}

SeqRenumberer::Source* SeqRenumberer::source(uint8_t sysid, uint8_t compid) {
    uint32_t id = static_cast<uint32_t>(sysid) << 8 | compid;
    uint32_t i = (id * 2654435761u >> 16) % kMaxSources;
    for (uint32_t probes = 0; probes < kMaxSources; probes++, i = (i + 1) % kMaxSources) {
        Source& s = sources_[i];
        if (!s.in_use) {
            s.in_use = true;
            s.sysid = sysid;
            s.compid = compid;
            return &s;
        }
        if (s.sysid == sysid && s.compid == compid)
            return &s;
    }
    return nullptr;
}

SeqRenumberer::LinkOffset& SeqRenumberer::link_of(Source& s, uint32_t link, bool* known) {
    LinkOffset* oldest = &s.links[0];
    for (LinkOffset& l : s.links) {
        if (l.link == link) {
            l.used = ++tick_;
            *known = true;
            return l;
        }
        if (l.used < oldest->used)
            oldest = &l;
    }
    *oldest = LinkOffset{link, 0, ++tick_};
    *known = false;
    return *oldest;
}

void SeqRenumberer::expire_holes(Source& s, int64_t t_ns) {
    // Higher bits are older numbers, skipped no later than lower ones.
    while (s.holes != 0) {
        int j = 63 - std::countl_zero(s.holes);
        auto number = static_cast<uint8_t>(s.frontier - 1 - j);
        if (t_ns - s.skipped_at[number % kHoles] < kHoldNs)
            return;
        s.holes &= ~(uint64_t{1} << j);
        s.owed++;
    }
}

void SeqRenumberer::place(Source& s, uint8_t e, int64_t t_ns) {
    auto ahead = static_cast<uint8_t>(e - s.frontier);
    if (ahead < 128) {
        // e is new: the numbers between the frontier and e become holes.
        unsigned shift = ahead + 1u;
        uint64_t dropped = shift >= 64 ? s.holes : s.holes >> (64 - shift);
        s.owed += static_cast<uint32_t>(std::popcount(dropped));  // too old to track: lost
        s.holes = shift >= 64 ? 0 : s.holes << shift;
        for (unsigned j = 1; j <= ahead; j++) {
            if (j >= kHoles) {
                s.owed += ahead - j + 1;
                break;
            }
            s.holes |= uint64_t{1} << j;
            s.skipped_at[static_cast<uint8_t>(e - j) % kHoles] = t_ns;
        }
        s.frontier = static_cast<uint8_t>(e + 1);
        s.odd_run = 0;
        return;
    }
    auto behind = static_cast<uint8_t>(s.frontier - 1 - e);
    if (behind < kHoles && (s.holes >> behind & 1)) {
        s.holes &= ~(uint64_t{1} << behind);  // a late copy: its hole is filled
        counters_.late_filled++;
        s.odd_run = 0;
        return;
    }
    // A repeat, or far behind: one is noise (dedup let a copy through), a run is a restart.
    if (++s.odd_run >= kResyncRun) {
        s.frontier = static_cast<uint8_t>(e + 1);
        s.holes = 0;
        s.odd_run = 0;
    }
}

uint8_t SeqRenumberer::deliver(uint8_t sysid, uint8_t compid, uint32_t link, uint8_t seq,
                               const Key* key, int64_t t_ns) {
    Source* s = source(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return seq;
    }
    bool first_frame = true;
    for (const LinkOffset& l : s->links)
        first_frame = first_frame && l.link == kNoLink;
    bool known = false;
    LinkOffset& l = link_of(*s, link, &known);
    if (first_frame) {
        s->frontier = seq;  // the first link keeps its numbers, out and exact
        s->next_out = seq;
    } else if (!known) {
        l.offset = static_cast<uint8_t>(s->frontier - seq);  // continue the stream
    }
    auto exact = static_cast<uint8_t>(seq + l.offset);
    expire_holes(*s, t_ns);
    place(*s, exact, t_ns);

    auto out = static_cast<uint8_t>(s->next_out + s->owed);
    counters_.gaps += s->owed;
    s->owed = 0;
    s->next_out = static_cast<uint8_t>(out + 1);
    counters_.renumbered++;
    if (key)
        delivered_[key->h1 & (kSlots - 1)] = Delivered{key->h1, key->h2, t_ns, exact, true};
    return out;
}

void SeqRenumberer::duplicate(uint8_t sysid, uint8_t compid, uint32_t link, uint8_t seq,
                              const Key& key, int64_t t_ns, int64_t skew_ns) {
    const Delivered& d = delivered_[key.h1 & (kSlots - 1)];
    int64_t off_time = t_ns - skew_ns - d.t_ns;
    if (!d.valid || d.h1 != key.h1 || d.h2 != key.h2 || off_time > kSameInstanceNs ||
        off_time < -kSameInstanceNs) {
        counters_.unmatched++;
        return;
    }
    Source* s = source(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return;
    }
    bool known = false;
    LinkOffset& l = link_of(*s, link, &known);
    auto offset = static_cast<uint8_t>(d.exact - seq);
    if (!known || l.offset != offset) {
        l.offset = offset;
        counters_.offsets_learned++;
    }
}

}  // namespace mavbond
