#include "filters/stream_positions.h"

namespace mavbond {

StreamPositions::Source* StreamPositions::find(uint8_t sysid, uint8_t compid) {
    auto key = static_cast<uint16_t>(sysid << 8 | compid);
    uint32_t i = (key * 40503u >> 4) % kCapacity;  // spreads neighbouring compids
    for (uint32_t n = 0; n < kCapacity; n++, i = (i + 1) % kCapacity) {
        Source& s = sources_[i];
        if (s.used && s.key == key)
            return &s;
        if (!s.used) {
            if (used_ * 4 >= kCapacity * 3)  // keeps probe runs short
                return nullptr;
            s.used = true;
            s.key = key;
            used_++;
            return &s;
        }
    }
    return nullptr;
}

namespace {

/// The 128-bit history moved on by n positions (bit 0 the newest).
void shift(uint64_t (&seen)[2], unsigned n) {
    if (n >= 128) {
        seen[0] = seen[1] = 0;
    } else if (n >= 64) {
        seen[1] = seen[0] << (n - 64);
        seen[0] = 0;
    } else if (n > 0) {
        seen[1] = seen[1] << n | seen[0] >> (64 - n);
        seen[0] <<= n;
    }
}

bool has(const uint64_t (&seen)[2], unsigned i) { return seen[i / 64] >> (i % 64) & 1; }
void set(uint64_t (&seen)[2], unsigned i) { seen[i / 64] |= uint64_t{1} << (i % 64); }

}  // namespace

StreamStep StreamPositions::track(uint8_t sysid, uint8_t compid, uint8_t seq) {
    Source* s = find(sysid, compid);
    if (!s)
        return {seq, 0, MAVBOND_STREAM_UNTRACKED};
    if (!s->started) {  // the first frame: nothing before it to fill
        s->started = true;
        s->last = seq;
        s->seen[0] = s->seen[1] = ~uint64_t{0};
        return {seq, 0, 0};
    }
    auto ahead = static_cast<uint8_t>(seq - s->last);
    if (ahead != 0 && ahead < kMaxStep) {
        s->last += ahead;
        shift(s->seen, ahead);
        set(s->seen, 0);
        s->odd_run = 0;
        return {s->last, ahead - 1, 0};
    }
    auto behind = static_cast<uint8_t>(s->last - seq);
    if (behind < kHistory && !has(s->seen, behind)) {
        set(s->seen, behind);
        s->odd_run = 0;
        return {s->last - behind, -1, 0};
    }
    if (++s->odd_run < kResyncRun)
        return {s->last - behind, 0, MAVBOND_STREAM_REPEAT};
    // A restarted counter: carry on from here, forward (positions never go back).
    s->last += ahead == 0 ? 256 : ahead;
    s->seen[0] = 1;
    s->seen[1] = 0;
    s->odd_run = 0;
    return {s->last, 0, MAVBOND_STREAM_RESYNC};
}

}  // namespace mavbond
