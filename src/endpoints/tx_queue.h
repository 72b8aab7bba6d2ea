// A bounded transmit queue that copies nothing in the common case: frames are lent (views into
// the receive buffer they arrived in) and written at the end of the receive batch. Only what
// the kernel will not take right now is copied into the backlog, which is bounded: when it is
// full the oldest whole frames are dropped (fresh telemetry beats stale) and counted.
//
// A link's count marker (routing/link_account.h) waits here too, apart: it goes ahead of
// everything not yet begun on the wire (after a frame half written), and its bytes are written
// right before each write that may carry it, with the number of frames written whole before
// it then, so it counts exactly what went on the wire ahead of it.
#pragma once

#include <sys/uio.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "mavlink/frame.h"

namespace mavbond {

class TxQueue {
public:
    enum class Mode { Datagram, Stream };

    TxQueue(Mode mode, size_t capacity_bytes);

    /// Lends a frame until the next write(). False when the lend table is full (write first).
    bool lend(std::span<const uint8_t> frame);
    Mode mode() const { return mode_; }
    bool has_lent() const { return !lent_.empty(); }
    /// Something the kernel did not take yet waits (EPOLLOUT is wanted): frames, or a marker.
    bool has_backlog() const { return backlog_frames_ != 0 || marker_ != MarkerState::None; }
    bool empty() const { return !has_lent() && !has_backlog(); }
    /// Stream mode: the head frame (or the marker) is partly written (the line stops mid-frame
    /// for now).
    bool mid_frame() const { return head_written_ != 0 || marker_ == MarkerState::Started; }

    /// Writes a count marker into `out` (kMaxFrameLen bytes) for `frames_before` frames written
    /// whole before it; returns its length, the same at every call for one marker.
    using MarkerWriter = size_t (*)(void* ctx, std::span<uint8_t> out, uint64_t frames_before);
    /// Puts a marker ahead of everything not yet begun on the wire; `writer` writes its bytes
    /// before each write that may carry it. False when one waits already.
    bool put_marker(MarkerWriter writer, void* ctx);
    bool marker_waiting() const { return marker_ != MarkerState::None; }
    /// Frames written whole since the queue was made: markers included, a radio's own reports
    /// not (neither side of a link counts those: routing/link_account.h).
    uint64_t frames_written() const { return frames_written_; }

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

    /// Drops everything queued (a reconnect starts at a frame boundary), a waiting marker too;
    /// returns the count of frames.
    uint64_t clear();

private:
    enum class MarkerState { None, Waiting, Started };  // Started: partly written (a stream)
    /// The marker's bytes, for the frames written whole so far and `ahead` more.
    iovec stamp_marker(uint64_t ahead);
    /// A frame written whole (its first bytes at `frame`).
    void written(const void* frame, size_t len, WriteResult& result);

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
    uint64_t frames_written_ = 0;
    MarkerState marker_ = MarkerState::None;
    MarkerWriter marker_writer_ = nullptr;
    void* marker_ctx_ = nullptr;
    size_t marker_len_ = 0;
    size_t marker_done_ = 0;  // Started: bytes of it written
    std::array<uint8_t, kMaxFrameLen> marker_bytes_{};
};

}  // namespace mavbond
