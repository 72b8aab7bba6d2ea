#include "endpoints/tx_queue.h"

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstring>

#include "mavlink/frame.h"
#include "routing/link_account.h"

namespace mavbond {
namespace {

constexpr size_t kMaxLent = 256;      // frames lent to one endpoint per receive batch
constexpr size_t kWriteBatch = 64;    // datagrams per sendmmsg
constexpr size_t kRecordHeader = 2;   // u16 length before each backlog record

bool would_block(int err) { return err == EAGAIN || err == EWOULDBLOCK || err == ENOBUFS; }

}  // namespace

TxQueue::TxQueue(Mode mode, size_t capacity_bytes)
    // Whatever the config says, the backlog holds at least two of the largest frames.
    : mode_(mode), capacity_(std::max(capacity_bytes, 2 * (kMaxFrameLen + kRecordHeader))) {
    lent_.reserve(kMaxLent);
    backlog_.resize(2 * capacity_);
    scratch_.reserve(std::max<size_t>(kMaxLent + 64, IOV_MAX));
}

bool TxQueue::put_marker(MarkerWriter writer, void* ctx) {
    if (marker_ != MarkerState::None)
        return false;
    marker_ = MarkerState::Waiting;
    marker_writer_ = writer;
    marker_ctx_ = ctx;
    return true;
}

iovec TxQueue::stamp_marker(uint64_t ahead) {
    if (marker_ == MarkerState::Waiting)
        marker_len_ = marker_writer_(marker_ctx_, marker_bytes_, frames_written_ + ahead);
    return iovec{marker_bytes_.data() + marker_done_, marker_len_ - marker_done_};
}

void TxQueue::written(const void* frame, size_t len, WriteResult& result) {
    result.frames_sent++;
    result.bytes_sent += len;
    if (!is_radio_own_report(static_cast<const uint8_t*>(frame)))
        frames_written_++;
}

bool TxQueue::lend(std::span<const uint8_t> frame) {
    if (lent_.size() >= kMaxLent)
        return false;
    lent_.push_back(iovec{const_cast<uint8_t*>(frame.data()), frame.size()});
    return true;
}

void TxQueue::push_backlog(std::span<const uint8_t> frame, WriteResult& result) {
    size_t record = kRecordHeader + frame.size();
    while (backlog_bytes() + record > capacity_) {
        if (!drop_oldest_whole()) {
            result.frames_dropped++;  // nothing older can go: drop the new frame
            return;
        }
        result.frames_dropped++;
    }
    if (tail_ + record > backlog_.size()) {
        std::memmove(backlog_.data(), backlog_.data() + head_, backlog_bytes());
        tail_ -= head_;
        head_ = 0;
    }
    auto len = static_cast<uint16_t>(frame.size());
    std::memcpy(backlog_.data() + tail_, &len, kRecordHeader);
    std::memcpy(backlog_.data() + tail_ + kRecordHeader, frame.data(), frame.size());
    tail_ += record;
    backlog_frames_++;
}

bool TxQueue::drop_oldest_whole() {
    if (backlog_frames_ == 0)
        return false;
    if (head_written_ == 0) {
        pop_backlog_front();
        return true;
    }
    // The head frame is half on the wire and must finish: drop the one after it by sliding
    // the head record forward over it.
    if (backlog_frames_ < 2)
        return false;
    uint16_t head_len, second_len;
    std::memcpy(&head_len, backlog_.data() + head_, kRecordHeader);
    std::memcpy(&second_len, backlog_.data() + head_ + kRecordHeader + head_len, kRecordHeader);
    size_t second = kRecordHeader + second_len;
    std::memmove(backlog_.data() + head_ + second, backlog_.data() + head_, kRecordHeader + head_len);
    head_ += second;
    backlog_frames_--;
    return true;
}

void TxQueue::pop_backlog_front() {
    uint16_t len;
    std::memcpy(&len, backlog_.data() + head_, kRecordHeader);
    head_ += kRecordHeader + len;
    head_written_ = 0;
    if (--backlog_frames_ == 0)
        head_ = tail_ = 0;
}

void TxQueue::collect_backlog_iov(std::vector<iovec>& out, size_t max) const {
    size_t pos = head_;
    for (size_t i = 0; i < backlog_frames_ && out.size() < max; i++) {
        uint16_t len;
        std::memcpy(&len, backlog_.data() + pos, kRecordHeader);
        size_t skip = i == 0 ? head_written_ : 0;
        out.push_back(iovec{const_cast<uint8_t*>(backlog_.data() + pos + kRecordHeader + skip),
                            len - skip});
        pos += kRecordHeader + len;
    }
}

TxQueue::WriteResult TxQueue::write_datagrams(DatagramWriter writer, void* ctx) {
    WriteResult result;
    bool blocked = false;
    if (marker_ == MarkerState::Waiting) {
        // Ahead of everything: one datagram of its own, counting every one sent before it.
        iovec marker = stamp_marker(0);
        int n = writer(ctx, &marker, 1);
        if (n == 1) {
            written(marker.iov_base, marker.iov_len, result);
            marker_ = MarkerState::None;
        } else if (n < 0 && !would_block(-n)) {
            result.error = -n;
            marker_ = MarkerState::None;  // not a routed frame: not counted as dropped
        } else {
            blocked = true;  // it waits for the kernel, and so does everything behind it
        }
    }
    while (backlog_frames_ != 0 && !blocked) {
        scratch_.clear();
        collect_backlog_iov(scratch_, kWriteBatch);
        int n = writer(ctx, scratch_.data(), scratch_.size());
        if (n < 0) {
            if (would_block(-n)) {
                blocked = true;
            } else {
                result.error = -n;
                result.frames_dropped++;
                pop_backlog_front();
            }
            continue;
        }
        for (int i = 0; i < n; i++) {
            const iovec& f = scratch_[static_cast<size_t>(i)];
            written(f.iov_base, f.iov_len, result);
            pop_backlog_front();
        }
        blocked = n == 0;
    }
    size_t next = 0;
    while (!blocked && next < lent_.size()) {
        size_t count = std::min(kWriteBatch, lent_.size() - next);
        int n = writer(ctx, &lent_[next], count);
        if (n < 0) {
            if (would_block(-n)) {
                blocked = true;
            } else {
                result.error = -n;
                result.frames_dropped++;
                next++;
            }
            continue;
        }
        for (size_t i = next; i < next + static_cast<size_t>(n); i++)
            written(lent_[i].iov_base, lent_[i].iov_len, result);
        next += static_cast<size_t>(n);
        blocked = n == 0;
    }
    for (size_t i = next; i < lent_.size(); i++)
        push_backlog({static_cast<const uint8_t*>(lent_[i].iov_base), lent_[i].iov_len}, result);
    lent_.clear();
    return result;
}

TxQueue::WriteResult TxQueue::write_stream(StreamWriter writer, void* ctx) {
    WriteResult result;
    size_t next_lent = 0;
    constexpr size_t kNone = SIZE_MAX;
    while (backlog_frames_ != 0 || next_lent < lent_.size() || marker_ != MarkerState::None) {
        // The iovecs in wire order: a marker partly written first; else the backlog (its head
        // perhaps partly written), a waiting marker right after that head frame; the lent.
        scratch_.clear();
        size_t marker_at = kNone;
        if (marker_ == MarkerState::Started) {
            marker_at = 0;
            scratch_.push_back(stamp_marker(0));
        }
        collect_backlog_iov(scratch_, IOV_MAX - 1);
        if (marker_ == MarkerState::Waiting) {
            const bool head_started = head_written_ != 0;
            uint64_t ahead = 0;
            if (head_started) {
                const uint8_t* head = backlog_.data() + head_ + kRecordHeader;
                ahead = is_radio_own_report(head) ? 0 : 1;
            }
            marker_at = head_started ? 1 : 0;
            scratch_.insert(scratch_.begin() + static_cast<ptrdiff_t>(marker_at), stamp_marker(ahead));
        }
        const size_t lent_from = scratch_.size();
        for (size_t i = next_lent; i < lent_.size() && scratch_.size() < IOV_MAX; i++)
            scratch_.push_back(lent_[i]);
        ssize_t n = writer(ctx, scratch_.data(), scratch_.size());
        if (n < 0) {
            if (!would_block(static_cast<int>(-n)))
                result.error = static_cast<int>(-n);
            break;
        }
        auto left = static_cast<size_t>(n);
        // Consume in wire order: what the kernel took whole goes; a frame cut short stays (or
        // goes) at the head of the backlog, the marker in its own place, so the line never
        // carries half a frame followed by another.
        bool short_write = false;
        for (size_t i = 0; i < scratch_.size() && !short_write; i++) {
            const size_t len = scratch_[i].iov_len;
            const bool whole = left >= len;
            const size_t took = whole ? len : left;
            left -= took;
            if (i == marker_at) {
                if (whole) {
                    written(marker_bytes_.data(), marker_len_, result);
                    result.bytes_sent -= marker_done_;  // counted when that part went
                    marker_ = MarkerState::None;
                    marker_done_ = 0;
                } else {
                    result.bytes_sent += took;
                    marker_done_ += took;
                    if (took != 0)
                        marker_ = MarkerState::Started;
                    short_write = true;
                }
            } else if (i < lent_from) {  // a backlog record
                if (whole) {
                    const uint8_t* record = backlog_.data() + head_ + kRecordHeader;
                    written(record, len, result);
                    pop_backlog_front();
                } else {
                    result.bytes_sent += took;
                    head_written_ += took;
                    short_write = true;
                }
            } else {  // a lent frame
                if (whole) {
                    written(scratch_[i].iov_base, len, result);
                    next_lent++;
                } else {
                    if (took > 0) {
                        push_backlog({static_cast<const uint8_t*>(scratch_[i].iov_base), len}, result);
                        result.bytes_sent += took;
                        head_written_ = took;
                        next_lent++;
                    }
                    short_write = true;
                }
            }
        }
        if (short_write || backlog_frames_ != 0)
            break;  // the kernel took less than offered: it is full for now
    }
    if (result.error == 0) {
        for (size_t i = next_lent; i < lent_.size(); i++)
            push_backlog({static_cast<const uint8_t*>(lent_[i].iov_base), lent_[i].iov_len}, result);
    } else {
        result.frames_dropped += lent_.size() - next_lent;
    }
    lent_.clear();
    return result;
}

uint64_t TxQueue::clear() {
    uint64_t dropped = backlog_frames_ + lent_.size();
    lent_.clear();
    head_ = tail_ = head_written_ = backlog_frames_ = 0;
    marker_ = MarkerState::None;
    marker_done_ = 0;
    return dropped;
}

}  // namespace mavbond
