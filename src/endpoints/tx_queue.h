// A bounded transmit queue that copies nothing in the common case: frames are lent (views into
// the receive buffer they arrived in) and written at the end of the receive batch. Only what
// the kernel will not take right now is copied into the backlog, which is bounded: when it is
// full the oldest whole frames are dropped (fresh telemetry beats stale) and counted.
#pragma once

#include <sys/uio.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace mavbond {

class TxQueue {
public:
    enum class Mode { Datagram, Stream };

    TxQueue(Mode mode, size_t capacity_bytes);

    /// Lends a frame until the next write(). False when the lend table is full (write first).
    bool lend(std::span<const uint8_t> frame);
    Mode mode() const { return mode_; }
    bool has_lent() const { return !lent_.empty(); }
    bool has_backlog() const { return backlog_frames_ != 0; }
    bool empty() const { return !has_lent() && !has_backlog(); }
    /// Stream mode: the head frame is partly written (the line stops mid-frame for now).
    bool mid_frame() const { return head_written_ != 0; }

    struct WriteResult {
        uint64_t frames_sent = 0;
        uint64_t bytes_sent = 0;
        uint64_t frames_dropped = 0;  // backlog overflow (oldest dropped) or write errors
        int error = 0;                // errno of a hard error (not EAGAIN), 0 if none
    };

    /// Datagram writer: sends frames[i] as one datagram each; returns how many were sent
    /// (>= 0) or -errno.
    using DatagramWriter = int (*)(void* ctx, const iovec* frames, size_t count);
    /// Stream writer: writes the iovecs in order; returns bytes written (>= 0) or -errno.
    using StreamWriter = ssize_t (*)(void* ctx, const iovec* iov, size_t count);

    /// Writes the backlog then the lent frames, in order; what the kernel refuses (EAGAIN)
    /// goes to the backlog. For datagrams a hard error drops the frame it hit (counted) and
    /// the rest continue; for streams a hard error stops and is reported (the caller closes).
    WriteResult write_datagrams(DatagramWriter writer, void* ctx);
    WriteResult write_stream(StreamWriter writer, void* ctx);

    /// Drops everything queued (a reconnect starts at a frame boundary); returns the count.
    uint64_t clear();

private:
    // Backlog records: [u16 length][frame bytes], contiguous, compacted lazily.
    void push_backlog(std::span<const uint8_t> frame, WriteResult& result);
    void pop_backlog_front();
    /// Drops the oldest frame not yet partly written; false when there is none.
    bool drop_oldest_whole();
    size_t backlog_bytes() const { return tail_ - head_; }
    void collect_backlog_iov(std::vector<iovec>& out, size_t max) const;

    Mode mode_;
    size_t capacity_;
    std::vector<iovec> lent_;
    std::vector<uint8_t> backlog_;
    size_t head_ = 0;          // first record
    size_t tail_ = 0;          // one past the last record
    size_t head_written_ = 0;  // stream mode: bytes of the first record already written
    size_t backlog_frames_ = 0;
    std::vector<iovec> scratch_;  // reused for each write, never shrinks
};

}  // namespace mavbond
