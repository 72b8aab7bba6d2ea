#include "mavlink/replay_window.h"

namespace mavbond {

void ReplayWindow::clear() {
    head_ = count_ = 0;
    newest_ = floor_ = 0;
}

void ReplayWindow::forget_oldest() {
    floor_ = ts_of(at(0)) + 1;
    head_ = (head_ + 1) & kMask;
    count_--;
}

size_t ReplayWindow::lower_bound(uint64_t ts) {
    size_t lo = 0, hi = count_;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        if (ts_of(at(mid)) < ts)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

bool ReplayWindow::first_delivery(uint64_t ts) {
    size_t pos = count_ != 0 && ts <= newest_ ? lower_bound(ts) : count_;
    if (pos == count_ || ts_of(at(pos)) != ts)
        return true;
    if (at(pos) & kDelivered)
        return false;
    at(pos) |= kDelivered;
    return true;
}

bool ReplayWindow::admit(uint64_t ts, unsigned link) {
    const uint64_t bit = uint64_t{1} << link;
    if (ts < floor_ || (count_ != 0 && ts + kSpan < newest_))
        return false;
    if (!ring_)
        ring_ = std::make_unique<uint64_t[]>(kCapacity);
    size_t pos = count_;
    if (count_ != 0 && ts <= newest_) {
        // A late frame, or another link's copy: found, or placed among the others.
        pos = lower_bound(ts);
        if (pos < count_ && ts_of(at(pos)) == ts) {
            if (at(pos) & bit)
                return false;
            at(pos) |= bit;
            return true;
        }
    }
    if (count_ == kCapacity) {
        if (pos == 0)
            return false;  // older than everything kept, and no room: as if forgotten
        forget_oldest();
        pos--;
    }
    for (size_t i = count_; i > pos; i--)
        at(i) = at(i - 1);
    at(pos) = ts << 9 | bit;
    count_++;
    if (ts > newest_)
        newest_ = ts;
    while (ts_of(at(0)) + kSpan < newest_)
        forget_oldest();
    return true;
}

}  // namespace mavbond
