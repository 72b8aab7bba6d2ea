#include "endpoints/tx_queue.h"

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstring>

#include "mavlink/frame.h"

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
    while (has_backlog() && !blocked) {
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
            result.bytes_sent += scratch_[static_cast<size_t>(i)].iov_len;
            pop_backlog_front();
        }
        result.frames_sent += static_cast<uint64_t>(n);
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
            result.bytes_sent += lent_[i].iov_len;
        result.frames_sent += static_cast<uint64_t>(n);
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
    while (has_backlog() || next_lent < lent_.size()) {
        scratch_.clear();
        collect_backlog_iov(scratch_, IOV_MAX);
        size_t from_backlog = scratch_.size();
        for (size_t i = next_lent; i < lent_.size() && scratch_.size() < IOV_MAX; i++)
            scratch_.push_back(lent_[i]);
        ssize_t n = writer(ctx, scratch_.data(), scratch_.size());
        if (n < 0) {
            if (!would_block(static_cast<int>(-n)))
                result.error = static_cast<int>(-n);
            break;
        }
        result.bytes_sent += static_cast<uint64_t>(n);
        auto written = static_cast<size_t>(n);
        // Consume whole backlog records, then lent frames; a frame cut short stays (or goes)
        // at the head of the backlog so the line never carries half a frame followed by another.
        for (size_t i = 0; i < from_backlog; i++) {
            size_t len = scratch_[i].iov_len;
            if (written >= len) {
                written -= len;
                pop_backlog_front();
                result.frames_sent++;
            } else {
                head_written_ += written;
                written = 0;
                break;
            }
        }
        bool short_write = false;
        for (size_t i = from_backlog; i < scratch_.size(); i++) {
            size_t len = scratch_[i].iov_len;
            if (written >= len) {
                written -= len;
                next_lent++;
                result.frames_sent++;
            } else {
                if (written > 0) {
                    push_backlog({static_cast<const uint8_t*>(scratch_[i].iov_base), len}, result);
                    head_written_ = written;
                    next_lent++;
                    written = 0;
                }
                short_write = true;
                break;
            }
        }
        if (short_write || has_backlog())
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
    return dropped;
}

}  // namespace mavbond
