#include "routing/renumber.h"

#include <bit>

namespace mavbond {

SeqRenumberer::SeqRenumberer() : sources_(kMaxSources) {}

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

void SeqRenumberer::expire_holes(Source& s, int64_t t_ns) {
    // Higher bits are older positions, skipped no later than lower ones.
    while (s.holes != 0) {
        int j = 63 - std::countl_zero(s.holes);
        int64_t pos = s.frontier - 1 - j;
        if (t_ns - s.skipped_at[static_cast<uint64_t>(pos) % kHoles] < kHoldNs)
            return;
        s.holes &= ~(uint64_t{1} << j);
        s.owed++;
    }
}

void SeqRenumberer::place(Source& s, int64_t pos, int64_t t_ns) {
    if (pos >= s.frontier) {
        // pos is new: the positions between the frontier and pos become holes.
        int64_t ahead = pos - s.frontier;
        uint64_t shift = static_cast<uint64_t>(ahead) + 1;
        uint64_t dropped = shift >= 64 ? s.holes : s.holes >> (64 - shift);
        s.owed += static_cast<uint32_t>(std::popcount(dropped));  // too old to track: lost
        s.holes = shift >= 64 ? 0 : s.holes << shift;
        for (int64_t j = 1; j <= ahead; j++) {
            if (j >= kHoles) {
                s.owed += static_cast<uint32_t>(ahead - j + 1);
                break;
            }
            s.holes |= uint64_t{1} << j;
            s.skipped_at[static_cast<uint64_t>(pos - j) % kHoles] = t_ns;
        }
        s.frontier = pos + 1;
        return;
    }
    int64_t behind = s.frontier - 1 - pos;
    if (behind < kHoles && (s.holes >> behind & 1)) {
        s.holes &= ~(uint64_t{1} << behind);  // a late copy: its hole is filled
        counters_.late_filled++;
    }
    // Else a frame older than the holes kept: delivered, and already counted lost.
}

uint8_t SeqRenumberer::next_number(Source& s) {
    auto out = static_cast<uint8_t>(s.next_out + s.owed);
    counters_.gaps += s.owed;
    s.owed = 0;
    s.next_out = static_cast<uint8_t>(out + 1);
    counters_.renumbered++;
    return out;
}

uint8_t SeqRenumberer::deliver(uint8_t sysid, uint8_t compid, uint8_t seq, int64_t pos,
                               int64_t t_ns) {
    Source* s = source(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return seq;
    }
    if (!s->started) {
        s->started = true;
        s->frontier = pos;
        s->next_out = seq;  // the first frame keeps its number
    }
    expire_holes(*s, t_ns);
    place(*s, pos, t_ns);
    return next_number(*s);
}

uint8_t SeqRenumberer::deliver_unplaced(uint8_t sysid, uint8_t compid, uint8_t seq) {
    Source* s = source(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return seq;
    }
    counters_.unplaced++;
    if (!s->started)
        return seq;  // nothing to continue yet: its own number
    return next_number(*s);
}

}  // namespace mavbond
