// Samples older than the newest delivered of their (sysid, compid, msgid): the ones that would
// make the vehicle jump back on the map.
#include "dedup.h"

#include <algorithm>

namespace mavbond::dedup {
namespace {

uint64_t read_le(const uint8_t* p, uint32_t avail, uint32_t size) {
    uint64_t v = 0;
    for (uint32_t i = 0; i < size; i++)
        v |= uint64_t{i < avail ? p[i] : uint8_t{0}} << (8 * i);
    return v;
}

}  // namespace

bool Dedup::stale(uint32_t bond, const mavbond_frame* f) {
    if (f->timestamp_offset < 0 || (f->timestamp_size != 4 && f->timestamp_size != 8))
        return false;
    // A v2 payload may be truncated: the bytes cut off were zeros.
    uint32_t off = static_cast<uint32_t>(f->timestamp_offset);
    uint32_t avail = f->payload_len > off ? f->payload_len - off : 0;
    uint64_t raw = read_le(f->payload + std::min(off, f->payload_len), avail, f->timestamp_size);
    uint64_t ts_ns = f->timestamp_us ? raw * 1000 : raw * kMs;
    uint64_t k = uint64_t{bond} << 48 | uint64_t{f->sysid} << 40 | uint64_t{f->compid} << 32 |
                 (f->msgid & 0xffffff);
    uint32_t i = static_cast<uint32_t>((k * 0x9e3779b97f4a7c15ull) >> 52) & (kSampleStreams - 1);
    for (uint32_t probes = 0; samples_[i].key != k; i = (i + 1) & (kSampleStreams - 1)) {
        if (samples_[i].key == UINT64_MAX) {
            if (samples_used_ * 4 >= kSampleStreams * 3) {
                untracked_samples_++;
                if (!samples_full_logged_) {
                    samples_full_logged_ = true;
                    api_->log(host_, MAVBOND_LOG_WARNING,
                              "too many message streams: new ones are not checked for staleness");
                }
                return false;
            }
            samples_[i].key = k;
            samples_[i].newest_ns = ts_ns;
            samples_used_++;
            return false;
        }
        if (++probes == kSampleStreams)
            return false;
    }
    SampleStream& s = samples_[i];
    if (ts_ns < s.newest_ns) {
        uint64_t behind = s.newest_ns - ts_ns;
        // Further back than a late copy can be (the window covers the links' lateness): the
        // source restarted its clock.
        if (behind <= std::max({kMinRebootJump, 2 * window_.ns(), 2 * stale_after_ns_}))
            return behind > stale_after_ns_;  // late, and by how much decides
    }
    // Newer, or so much older that the source restarted its clock.
    s.newest_ns = ts_ns;
    return false;
}

}  // namespace mavbond::dedup
