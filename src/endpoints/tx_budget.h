// A link's transmit budget (`tx_rate`): the bytes a second its line carries, spent by class, so
// that a slow radio carries commands at once and telemetry as fast as it can, rather than
// queueing everything and losing what overflows.
//
// A token bucket holds at most one largest frame (or 20 ms of the rate, if more): whatever is
// in the line's own buffer when a command comes is at most that, so a command waits at most
// one frame time of the budget. Per class:
//   control    goes at once, always; the bucket goes into debt and later frames wait it off.
//   telemetry  goes when the bucket has its cost; while it waits, the newest sample of each
//              message from each source (and instance: each battery, each aircraft) replaces
//              the one before (`thinned`): nothing is held past its usefulness. A capped
//              message goes at most at its cap.
//   bulk       goes in order behind telemetry, with a quarter of the budget whenever both
//              wait (a transfer slows, it does not stall); the oldest goes when the queue is
//              full (`dropped`).
// Held frames are copies (a lent frame lives only until the batch's flush); what goes out is
// charged its bytes plus the link's framing (a datagram's IP and UDP headers).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "mavlink/frame.h"
#include "routing/link.h"

namespace mavbond {

class TxBudget {
public:
    /// `bytes_per_s`: the line's rate; `overhead`: bytes charged per frame beyond its own;
    /// `bulk_capacity`: bytes the bulk queue holds.
    /// `counters`: where it counts, per class (the link's own).
    TxBudget(uint64_t bytes_per_s, uint32_t overhead, const TxClassesConfig& classes,
             size_t bulk_capacity, std::array<TxClassCounters, kTxClassCount>& counters);

    /// A frame to send at `now`: true when it may go now (charged), false when it was held
    /// (copied) for release().
    bool offer(const Frame& frame, TimePoint now);

    /// Hands `out` every held frame that may go by `now`, in order; returns when the next may
    /// go (TimePoint::max() when nothing waits). The bytes `out` gets live only during its call.
    template <typename Out>
    TimePoint release(TimePoint now, Out&& out) {
        refill(now);
        for (;;) {
            Pick p = pick(now, true);
            if (p.kind == Pick::None)
                return p.due;
            std::span<const uint8_t> bytes = take(p, now);
            out(bytes);
        }
    }

    /// Hands `out` everything held, budget or caps regardless (the link stops).
    template <typename Out>
    void drain(TimePoint now, Out&& out) {
        refill(now);
        while (held_telemetry_ != 0 || bulk_frames_ != 0) {
            Pick p = pick(TimePoint::max(), false);
            out(take(p, now));
        }
    }

    /// Forgets everything held (the link went away); returns how many frames that was.
    uint64_t clear();

    /// Spends `bytes_per_s` from `now` on (a radio's report moved it): what the bucket holds
    /// stays, up to the new burst.
    void set_rate(uint64_t bytes_per_s, TimePoint now);

    bool holding() const { return held_telemetry_ != 0 || bulk_frames_ != 0; }
    uint64_t bytes_per_s() const { return rate_; }
    const TxClassCounters& counters(TxClass c) const { return counters_[static_cast<size_t>(c)]; }

private:
    /// One message from one source: its cap, when it last went, and its newest held sample.
    struct Slot {
        uint64_t key = 0;           // slot_key()
        Duration cap{0};            // least time between two of it (0: none)
        TimePoint last_sent{};
        bool held = false;
        uint64_t order = 0;         // when it began to wait: the oldest goes first
        uint16_t len = 0;
        std::array<uint8_t, kMaxFrameLen> bytes{};
    };
    struct Pick {
        enum Kind { None, Telemetry, Bulk } kind = None;
        size_t slot = 0;
        TimePoint due = TimePoint::max();  // None: when the next may go
    };

    void refill(TimePoint now);
    uint64_t cost(size_t len) const { return len + overhead_; }
    static uint64_t slot_key(const Frame& frame);
    /// The slot of the frame's message, source and instance, made if new; null when every
    /// slot holds a frame.
    Slot* slot_for(const Frame& frame);
    bool telemetry_ready(const Slot& s, TimePoint now) const {
        return s.cap.count() == 0 || now - s.last_sent >= s.cap;
    }
    /// What goes next; with `affordable`, only if the bucket has its cost (else when it will).
    Pick pick(TimePoint now, bool affordable) const;
    std::span<const uint8_t> take(const Pick& p, TimePoint now);
    void charge(TxClass c, size_t len, bool waited);

    // Bulk queue: [u16 length][bytes] records in a ring of bytes.
    void bulk_push(std::span<const uint8_t> frame);
    size_t bulk_front_len() const;
    void bulk_pop(uint8_t* into);
    void ring_read(size_t at, uint8_t* into, size_t n) const;
    void ring_write(size_t at, const uint8_t* from, size_t n);

    static double burst_for(uint64_t bytes_per_s, uint32_t overhead);

    uint64_t rate_;
    const uint32_t overhead_;
    double burst_;
    const TxClassesConfig classes_;
    double tokens_;
    TimePoint refilled_{};
    bool started_ = false;

    std::vector<Slot> slots_;  // a few dozen (messages x sources): scanned, not indexed
    size_t held_telemetry_ = 0;
    uint64_t next_order_ = 0;

    std::vector<uint8_t> ring_;
    size_t ring_head_ = 0, ring_used_ = 0, bulk_frames_ = 0;
    std::array<uint8_t, kMaxFrameLen> bulk_out_{};
    // Weighted turns when telemetry and bulk both wait: each class's bytes over its weight.
    double telemetry_turn_ = 0, bulk_turn_ = 0;

    std::array<TxClassCounters, kTxClassCount>& counters_;
};

}  // namespace mavbond
