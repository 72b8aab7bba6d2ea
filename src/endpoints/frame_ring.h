// Frames waiting in order, copied into one ring of bytes allocated once: a transmit budget's
// queues (tx_budget.h). Each record is a frame with what its queue keeps of it: when it began
// to wait and its numbering ticket (routing/egress_numbering.h).
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <span>
#include <vector>

#include "core/clock.h"
#include "mavlink/frame.h"

namespace mavbond {

class FrameRing {
public:
    struct Record {
        TimePoint at;         // when it began to wait
        uint64_t ticket = 0;  // 0: none
        size_t len = 0;
        uint8_t extra = 0;    // bytes it will take on the line beyond its own (a signature)
    };

    /// Room for `capacity` bytes of records (at least one largest frame).
    explicit FrameRing(size_t capacity)
        : ring_(std::max(capacity, kMaxFrameLen + kHeader)) {}

    bool empty() const { return frames_ == 0; }
    size_t frames() const { return frames_; }

    /// Whether a frame of `len` bytes fits without making room.
    bool fits(size_t len) const { return ring_.size() - used_ >= kHeader + len; }
    /// Appends a frame; the caller made room (fits) or pops the oldest until it does.
    void push(std::span<const uint8_t> frame, TimePoint at, uint64_t ticket, uint8_t extra) {
        Header h{at.time_since_epoch().count(), ticket, static_cast<uint16_t>(frame.size()), extra};
        size_t tail = head_ + used_;
        write(tail, reinterpret_cast<const uint8_t*>(&h), kHeader);
        write(tail + kHeader, frame.data(), frame.size());
        used_ += kHeader + frame.size();
        frames_++;
    }
    /// The oldest record's header.
    Record front() const {
        Header h;
        read(head_, reinterpret_cast<uint8_t*>(&h), kHeader);
        return Record{TimePoint(Duration(h.at_ns)), h.ticket, h.len, h.extra};
    }
    /// Removes the oldest record, its bytes copied to `into` unless null.
    void pop(uint8_t* into) {
        Record r = front();
        if (into)
            read(head_ + kHeader, into, r.len);
        head_ = (head_ + kHeader + r.len) % ring_.size();
        used_ -= kHeader + r.len;
        frames_--;
    }
    void clear() { head_ = used_ = frames_ = 0; }

private:
    struct Header {
        int64_t at_ns;
        uint64_t ticket;
        uint16_t len;
        uint8_t extra;
    };
    static constexpr size_t kHeader = sizeof(Header);

    void read(size_t at, uint8_t* into, size_t n) const {
        at %= ring_.size();
        size_t first = std::min(n, ring_.size() - at);
        std::memcpy(into, ring_.data() + at, first);
        std::memcpy(into + first, ring_.data(), n - first);
    }
    void write(size_t at, const uint8_t* from, size_t n) {
        at %= ring_.size();
        size_t first = std::min(n, ring_.size() - at);
        std::memcpy(ring_.data() + at, from, first);
        std::memcpy(ring_.data(), from + first, n - first);
    }

    std::vector<uint8_t> ring_;
    size_t head_ = 0, used_ = 0, frames_ = 0;
};

}  // namespace mavbond
