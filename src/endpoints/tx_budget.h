// A link's transmit budget (`tx_rate`): the bytes a second its line carries, spent by class, so
// that a slow radio carries commands at once and telemetry as fast as it can, rather than
// queueing everything and losing what overflows.
//
// A token bucket holds at most one largest frame (or 20 ms of the rate, if more): whatever is
// in the line's own buffer when a command comes is at most that, so a command waits at most
// one frame time of the budget. Per class:
//   control    goes at once while the line is less than kControlAhead behind (the bucket goes
//              into that much debt, and later frames wait it off); beyond that it waits in
//              order, ahead of every other class: a burst of control (a parameter list, a
//              mission) would otherwise overflow a radio's own buffer, which loses it. What
//              waited kControlMaxWait is dropped (`dropped`): it would come too late to be
//              of use, and the far side's dedup no longer knows its other copies.
//   telemetry  goes when the bucket has its cost; while it waits, the newest sample of each
//              message from each source (and instance: each battery, each aircraft) replaces
//              the one before (`thinned`): nothing is held past its usefulness. A capped
//              message goes at most at its cap.
//   bulk       goes in order behind telemetry, with a quarter of the budget whenever both
//              wait (a transfer slows, it does not stall); the oldest goes when the queue is
//              full (`dropped`).
// Held frames are copies (a lent frame lives only until the batch's flush), each with the
// numbering ticket it was offered with (routing/egress_numbering.h: a frame takes its number
// on the bond when it first goes on a line, so one a budget never sends takes none); what goes
// out is charged its bytes plus the link's framing (a datagram's IP and UDP headers).
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "endpoints/frame_ring.h"
#include "mavlink/frame.h"
#include "routing/link.h"

namespace mavbond {

class TxBudget {
public:
    static constexpr Duration kControlAhead = milliseconds(250);
    static constexpr Duration kControlMaxWait = seconds(2);

    /// `bytes_per_s`: the line's rate; `overhead`: bytes charged per frame beyond its own;
    /// `bulk_capacity`: bytes the bulk queue holds (the control queue as much).
    /// `counters`: where it counts, per class (the link's own).
    TxBudget(uint64_t bytes_per_s, uint32_t overhead, const TxClassesConfig& classes,
             size_t bulk_capacity, std::array<TxClassCounters, kTxClassCount>& counters);

    /// A frame to send at `now`: true when it may go now (charged), false when it was held
    /// (copied, with `ticket`) for release() or dropped (counted). `extra`: bytes it takes on
    /// the line beyond its own (the signature a link signs it with as it goes).
    bool offer(const Frame& frame, TimePoint now, uint64_t ticket = 0, uint8_t extra = 0);

    /// Hands `out(bytes, ticket)` every held frame that may go by `now`, in order; returns
    /// when the next may go (TimePoint::max() when nothing waits). The bytes `out` gets are
    /// the budget's copy, its to change, and live only during its call.
    template <typename Out>
    TimePoint release(TimePoint now, Out&& out) {
        refill(now);
        expire_control(now);
        for (;;) {
            Pick p = pick(now, true);
            if (p.kind == Pick::None)
                return p.due;
            Taken t = take(p, now);
            out(t.bytes, t.ticket);
        }
    }

    /// Hands `out(bytes, ticket)` everything held, budget or caps regardless (the link stops).
    template <typename Out>
    void drain(TimePoint now, Out&& out) {
        refill(now);
        while (holding()) {
            Pick p = pick(TimePoint::max(), false);
            Taken t = take(p, now);
            out(t.bytes, t.ticket);
        }
    }

    /// Pays for `len` bytes the link sends besides its frames (a count marker) at `now`: as a
    /// control frame, at once, into debt if need be; counted in no class.
    void spend(size_t len, TimePoint now) {
        refill(now);
        tokens_ -= static_cast<double>(cost(len));
    }

    /// Forgets everything held (the link went away); returns how many frames that was.
    uint64_t clear();

    /// Spends `bytes_per_s` from `now` on (a radio's report moved it): what the bucket holds
    /// stays, up to the new burst.
    void set_rate(uint64_t bytes_per_s, TimePoint now);

    /// What the line was asked for, since it began: what is offered against what it carries
    /// (the bond's RADIO_STATUS slows the autopilot by it; a radio's report raises the rate
    /// only where the rate was the limit). Readers keep their last copy and take differences.
    struct Load {
        uint64_t offered_frames = 0;
        uint64_t offered_bytes = 0;  // as charged (its framing included)
        uint64_t lost = 0;           // frames it will never carry: thinned, dropped, expired
        uint64_t waited = 0;         // frames that waited for the budget (the rate the limit)
        Load operator-(const Load& o) const {
            return {offered_frames - o.offered_frames, offered_bytes - o.offered_bytes,
                    lost - o.lost, waited - o.waited};
        }
    };
    const Load& load() const { return load_; }

    bool holding() const { return held_telemetry_ != 0 || queued(); }
    /// Whether frames wait in order (control beyond its lead, bulk): the rate holds them back.
    bool queued() const { return !bulk_.empty() || !control_.empty(); }
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
        uint64_t ticket = 0;
        uint16_t len = 0;
        uint8_t extra = 0;
        std::array<uint8_t, kMaxFrameLen> bytes{};
    };
    struct Pick {
        enum Kind { None, Control, Telemetry, Bulk } kind = None;
        size_t slot = 0;
        TimePoint due = TimePoint::max();  // None: when the next may go
    };
    struct Taken {
        std::span<uint8_t> bytes;  // the budget's copy: the link may number it in place
        uint64_t ticket;
    };

    void refill(TimePoint now);
    uint64_t cost(size_t len) const { return len + overhead_; }
    /// The debt control may run the bucket into before it waits.
    double control_debt() const {
        return std::max(burst_, static_cast<double>(rate_) *
                                    std::chrono::duration<double>(kControlAhead).count());
    }
    static uint64_t slot_key(const Frame& frame);
    /// The slot of the frame's message, source and instance, made if new; null when every
    /// slot holds a frame.
    Slot* slot_for(const Frame& frame);
    bool telemetry_ready(const Slot& s, TimePoint now) const {
        return s.cap.count() == 0 || now - s.last_sent >= s.cap;
    }
    /// What goes next; with `affordable`, only if the bucket has its cost (else when it will).
    Pick pick(TimePoint now, bool affordable) const;
    Taken take(const Pick& p, TimePoint now);
    /// Charges `len` bytes on the line (the frame's, and any it takes beyond them).
    void charge(TxClass c, size_t len, bool waited);
    /// Drops the control frames that waited kControlMaxWait by `now`.
    void expire_control(TimePoint now);
    /// Queues a frame of `c` in `ring`, the oldest dropped to make room.
    void enqueue(FrameRing& ring, TxClass c, const Frame& frame, TimePoint now, uint64_t ticket,
                 uint8_t extra);
    void lose(TxClass c, uint64_t TxClassCounters::*what) {
        counters_[static_cast<size_t>(c)].*what += 1;
        load_.lost++;
    }

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

    FrameRing control_;
    FrameRing bulk_;
    std::array<uint8_t, kMaxFrameLen> queued_out_{};
    // Weighted turns when telemetry and bulk both wait: each class's bytes over its weight.
    double telemetry_turn_ = 0, bulk_turn_ = 0;

    Load load_;
    std::array<TxClassCounters, kTxClassCount>& counters_;
};

}  // namespace mavbond
