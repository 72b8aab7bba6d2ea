#include "routing/stream_positions.h"

namespace mavbond {

StreamStep StreamPositions::track(uint8_t sysid, uint8_t compid, uint8_t seq) {
    Source* s = sources_.find(sysid, compid);
    if (!s)
        return {seq, 0, MAVBOND_STREAM_UNTRACKED};
    if (!s->started) {  // the first frame: nothing before it to fill
        s->started = true;
        s->last = seq;
        s->seen.fill();
        return {seq, 0, 0};
    }
    auto ahead = static_cast<uint8_t>(seq - s->last);
    if (ahead != 0 && ahead < kMaxStep) {
        s->last += ahead;
        s->seen.shift(ahead);
        s->seen.set(0);
        s->odd_run = 0;
        return {s->last, ahead - 1, 0};
    }
    auto behind = static_cast<uint8_t>(s->last - seq);
    if (behind < kHistory && !s->seen.has(behind)) {
        s->seen.set(behind);
        s->odd_run = 0;
        return {s->last - behind, -1, 0};
    }
    if (++s->odd_run < kResyncRun)
        return {s->last - behind, 0, MAVBOND_STREAM_REPEAT};
    // A restarted counter: carry on from here, forward (positions never go back).
    s->last += ahead == 0 ? 256 : ahead;
    s->seen.reset();
    s->seen.set(0);
    s->odd_run = 0;
    return {s->last, 0, MAVBOND_STREAM_RESYNC};
}

}  // namespace mavbond
