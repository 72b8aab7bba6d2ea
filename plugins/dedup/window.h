// How long dedup remembers a delivered frame. A copy is known for one only while its first copy
// is remembered, so the memory must cover how late the bond's links really bring copies, and
// that is no setting a user can know: a saturated radio lags an LTE link by a second, and the
// far side's standby resends, on its failover, what it held back over its `resend`.
//
// The user's `window` is the least it remembers. Per bond it needs, from what dedup measures
// and what the host says of the far side:
//   - kHeadroom times the latest copies' lateness behind their first copies, plus kMargin: a
//     link's lag grows as its queue fills, and the window must be ahead of it, not behind;
//   - the far side's resend plus that lateness plus kMargin: a resent frame comes up to its
//     resend later than the frame's first copy, plus the skew of the link it comes on.
// It grows at once (in the frame that shows the lateness); it comes down once the lateness
// that made it grow has not been seen for one to two kEpoch. Never beyond kMaxWindow (or the
// user's window if longer): a copy later than that is an outage's backlog, not a link's delay,
// and passes (drop_stale still catches the samples among it). The window is what is known of
// the links' lateness; a lateness not seen yet (a queue that stood still longer than ever) is
// covered by expiry itself, which keeps what a link behind has not had (Dedup::awaited). What it costs is memory, and
// that is bounded by max_entries; matching by identity makes a long window no less exact.
#pragma once

#include <array>
#include <cstdint>

namespace mavbond::dedup {

class Window {
public:
    static constexpr uint64_t kMs = 1'000'000;
    static constexpr uint64_t kSecond = 1'000 * kMs;
    static constexpr uint64_t kHeadroom = 2;
    static constexpr uint64_t kMargin = 250 * kMs;
    static constexpr uint64_t kMaxWindow = 15 * kSecond;
    static constexpr uint64_t kEpoch = 30 * kSecond;
    static constexpr uint32_t kMaxBonds = 16;

    /// `floor_ns`: the user's window (0: dedup is off, and so is this).
    explicit Window(uint64_t floor_ns = 0) : floor_(floor_ns), window_(floor_ns) {}

    /// How long a frame is remembered now.
    uint64_t ns() const { return window_; }
    uint64_t floor() const { return floor_; }

    /// A frame of bond `bond` came `late_ns` after its first copy (another link's). Once per
    /// copy: a comparison, and more only when the lateness is the bond's largest yet.
    void late(uint32_t bond, uint64_t late_ns, uint64_t now) {
        Bond& b = bonds_[bond];
        if (late_ns <= b.current)
            return;
        if (b.epoch_start == 0)
            b.epoch_start = now;
        b.current = late_ns;
        if (need(bond).ns > window_)
            window_ = need(bond).ns;
    }
    /// The far side of bond `bond` resends this far back on its failover (0: it does not).
    void peer_resend(uint32_t bond, uint64_t resend_ns);
    /// Forgets lateness not seen for an epoch and re-derives; `now` only moves forward.
    void age(uint64_t now);

    /// What bond `bond` needs, and from what.
    struct Need {
        uint64_t ns = 0;         // how long its frames must be remembered
        uint64_t late_ns = 0;    // the latest lateness of its copies (over one to two epochs)
        uint64_t resend_ns = 0;  // the far side's resend
    };
    Need need(uint32_t bond) const;

private:
    struct Bond {
        uint64_t current = 0, previous = 0;  // the largest lateness in this epoch, the last
        uint64_t epoch_start = 0;
        uint64_t resend = 0;
    };
    void derive();

    uint64_t floor_;
    uint64_t window_;
    std::array<Bond, kMaxBonds> bonds_{};
};

}  // namespace mavbond::dedup
