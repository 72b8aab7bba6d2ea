// A lock-free single-producer single-consumer ring of byte records: the event loop pushes
// (a copy, never a wait), one other thread pops. Each record is stored as [u16 length][bytes];
// positions only grow and wrap by a mask, so the capacity is a power of two.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <span>

namespace mavbond {

class RecordRing {
public:
    static constexpr size_t kLengthBytes = 2;
    static constexpr size_t kMaxRecord = UINT16_MAX;

    /// `capacity` is rounded up to a power of two.
    explicit RecordRing(size_t capacity) : mask_(round_up_pow2(capacity) - 1) {
        buf_ = std::make_unique_for_overwrite<uint8_t[]>(mask_ + 1);
    }

    size_t capacity() const { return mask_ + 1; }

    /// Producer: stores `head` then `body` as one record; false (nothing stored) when it does
    /// not fit now.
    bool push(std::span<const uint8_t> head, std::span<const uint8_t> body) {
        size_t len = head.size() + body.size();
        size_t need = kLengthBytes + len;
        uint64_t h = head_.load(std::memory_order_relaxed);
        if (h + need - cached_tail_ > capacity()) {
            cached_tail_ = tail_.load(std::memory_order_acquire);
            if (h + need - cached_tail_ > capacity())
                return false;
        }
        auto len16 = static_cast<uint16_t>(len);
        copy_in(h, &len16, kLengthBytes);
        copy_in(h + kLengthBytes, head.data(), head.size());
        copy_in(h + kLengthBytes + head.size(), body.data(), body.size());
        head_.store(h + need, std::memory_order_release);
        return true;
    }

    /// Consumer: copies the oldest record into `out` (room for kMaxRecord bytes is enough) and
    /// returns its length; 0 when the ring is empty.
    size_t pop(uint8_t* out) {
        uint64_t t = tail_.load(std::memory_order_relaxed);
        if (head_.load(std::memory_order_acquire) == t)
            return 0;
        uint16_t len;
        copy_out(t, &len, kLengthBytes);
        copy_out(t + kLengthBytes, out, len);
        tail_.store(t + kLengthBytes + len, std::memory_order_release);
        return len;
    }

    /// Bytes stored now (exact on either side for its own position, approximate for the other).
    size_t used() const {
        return static_cast<size_t>(head_.load(std::memory_order_acquire) -
                                   tail_.load(std::memory_order_acquire));
    }

private:
    static size_t round_up_pow2(size_t n) {
        size_t p = 64;
        while (p < n)
            p <<= 1;
        return p;
    }
    void copy_in(uint64_t pos, const void* src, size_t n) {
        size_t at = static_cast<size_t>(pos) & mask_;
        size_t first = std::min(n, capacity() - at);
        std::memcpy(buf_.get() + at, src, first);
        std::memcpy(buf_.get(), static_cast<const uint8_t*>(src) + first, n - first);
    }
    void copy_out(uint64_t pos, void* dst, size_t n) const {
        size_t at = static_cast<size_t>(pos) & mask_;
        size_t first = std::min(n, capacity() - at);
        std::memcpy(dst, buf_.get() + at, first);
        std::memcpy(static_cast<uint8_t*>(dst) + first, buf_.get(), n - first);
    }

    size_t mask_;
    std::unique_ptr<uint8_t[]> buf_;
    alignas(64) std::atomic<uint64_t> head_{0};  // written by the producer only
    alignas(64) std::atomic<uint64_t> tail_{0};  // written by the consumer only
    alignas(64) uint64_t cached_tail_ = 0;       // the producer's last look at tail_
};

}  // namespace mavbond
