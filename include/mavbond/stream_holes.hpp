// The delivered stream of one source, by position (the bond's numbering, as dedup notes it):
// a position skipped is a hole until a late copy fills it, or until it has waited `hold` or
// fallen `Window` positions behind the newest; then it is lost. Positions, not sequence
// numbers: a burst (a 300-parameter list) moves the stream hundreds of positions in
// milliseconds while a copy is still on its way on a slower link, and the copy must still fill
// its hole. Header only, so the host (renumbering) and plugins (stats) share it.
#ifndef MAVBOND_STREAM_HOLES_HPP
#define MAVBOND_STREAM_HOLES_HPP

#include <algorithm>
#include <array>
#include <bitset>
#include <cstdint>

namespace mavbond {

class StreamHoles {
public:
    static constexpr int64_t kWindow = 1024;           // positions behind the newest that may wait
    static constexpr int64_t kHoldNs = 1'000'000'000;  // how long a hole waits for a late copy

    /// What a delivered frame was.
    enum class Arrival {
        New,        // at or after the newest position: any positions skipped are holes now
        Filled,     // a late copy, in its hole
        AfterLoss,  // later still: its position was already counted lost (or a repeat)
    };

    bool started() const { return started_; }
    /// The highest position delivered (once started).
    int64_t newest() const { return newest_; }

    /// A frame delivered at `pos`, at t_ns. `lost` grows by the positions that fell more than
    /// kWindow behind.
    Arrival deliver(int64_t pos, int64_t t_ns, uint64_t& lost) {
        if (!started_) {
            started_ = true;
            newest_ = oldest_ = pos;
        }
        if (pos > newest_ || (pos == newest_ && !seen_first_)) {
            seen_first_ = true;
            for (; oldest_ <= pos - kWindow; oldest_++)
                lost += take(oldest_);
            int64_t from = std::max(newest_ + 1, pos - kWindow + 1);
            if (pos > newest_)
                lost += static_cast<uint64_t>(std::max<int64_t>(0, from - newest_ - 1));
            for (int64_t p = from; p < pos; p++) {
                hole_[slot(p)] = true;
                skipped_at_[slot(p)] = t_ns;
            }
            hole_[slot(pos)] = false;
            newest_ = pos;
            return Arrival::New;
        }
        if (pos >= oldest_ && hole_[slot(pos)]) {
            hole_[slot(pos)] = false;
            return Arrival::Filled;
        }
        return Arrival::AfterLoss;
    }

    /// Holes that have waited `hold_ns` at t_ns become lost, oldest first; returns how many.
    uint64_t expire(int64_t t_ns, int64_t hold_ns = kHoldNs) {
        uint64_t lost = 0;
        // Holes were made in position order, each no later than the ones after it.
        for (; started_ && oldest_ < newest_; oldest_++) {
            if (hole_[slot(oldest_)] && t_ns - skipped_at_[slot(oldest_)] < hold_ns)
                break;
            lost += take(oldest_);
        }
        return lost;
    }

private:
    static size_t slot(int64_t pos) { return static_cast<uint64_t>(pos) % kWindow; }
    /// 1 when `pos` was a hole (now lost), 0 otherwise.
    uint64_t take(int64_t pos) {
        bool was = hole_[slot(pos)];
        hole_[slot(pos)] = false;
        return was ? 1 : 0;
    }

    bool started_ = false;
    bool seen_first_ = false;
    int64_t newest_ = 0;  // the highest position delivered
    int64_t oldest_ = 0;  // no hole below it
    std::bitset<kWindow> hole_;                 // by position % kWindow
    std::array<int64_t, kWindow> skipped_at_{};  // by position % kWindow: when it became a hole
};

}  // namespace mavbond

#endif  // MAVBOND_STREAM_HOLES_HPP
