#include "endpoints/tx_queue.h"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/uio.h>

#include <algorithm>
#include <cstring>
#include <span>
#include <cerrno>
#include <numeric>
#include <set>
#include <vector>

#include "core/unique_fd.h"

namespace mavbond {
namespace {

// A frame whose bytes say which frame it is: [index lo, index hi, length, filler...].
std::vector<uint8_t> numbered_frame(uint16_t index, size_t len) {
    std::vector<uint8_t> f(len, 0xAB);
    f[0] = static_cast<uint8_t>(index);
    f[1] = static_cast<uint8_t>(index >> 8);
    f[2] = static_cast<uint8_t>(len);
    return f;
}

ssize_t stream_write(void* ctx, const iovec* iov, size_t count) {
    ssize_t n = writev(*static_cast<int*>(ctx), iov, static_cast<int>(count));
    return n < 0 ? -errno : n;
}

int dgram_write(void* ctx, const iovec* frames, size_t count) {
    int fd = *static_cast<int*>(ctx);
    int sent = 0;
    for (size_t i = 0; i < count; i++) {
        if (send(fd, frames[i].iov_base, frames[i].iov_len, MSG_DONTWAIT) < 0)
            return sent > 0 ? sent : -errno;
        sent++;
    }
    return sent;
}

// Reads a byte stream of numbered frames back, keeping a frame still in flight for the next
// call, and checks every frame is whole: no bytes of another frame inside it.
class StreamReader {
public:
    explicit StreamReader(int fd) : fd_(fd) {}
    void read_available(std::vector<uint16_t>& indices) {
        uint8_t buf[65536];
        ssize_t n;
        while ((n = recv(fd_, buf, sizeof buf, MSG_DONTWAIT)) > 0)
            bytes_.insert(bytes_.end(), buf, buf + n);
        size_t pos = 0;
        while (pos + 3 <= bytes_.size() && pos + bytes_[pos + 2] <= bytes_.size()) {
            size_t len = bytes_[pos + 2];
            for (size_t i = pos + 3; i < pos + len; i++)
                EXPECT_EQ(0xAB, bytes_[i]) << "frame bytes interleaved at offset " << i;
            indices.push_back(static_cast<uint16_t>(bytes_[pos] | bytes_[pos + 1] << 8));
            pos += len;
        }
        bytes_.erase(bytes_.begin(), bytes_.begin() + static_cast<ptrdiff_t>(pos));
    }
    bool idle() const { return bytes_.empty(); }

private:
    int fd_;
    std::vector<uint8_t> bytes_;
};

TEST(TxQueue, StreamPartialWritesNeverSplitFramesAndKeepOrder) {
    int sv[2];
    ASSERT_EQ(0, socketpair(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK, 0, sv));
    UniqueFd a(sv[0]), b(sv[1]);
    int small = 4096;
    setsockopt(a.get(), SOL_SOCKET, SO_SNDBUF, &small, sizeof small);
    setsockopt(b.get(), SOL_SOCKET, SO_RCVBUF, &small, sizeof small);

    TxQueue q(TxQueue::Mode::Stream, 8192);
    std::vector<std::vector<uint8_t>> frames;
    for (uint16_t i = 0; i < 3000; i++)
        frames.push_back(numbered_frame(i, 40 + i % 200));
    uint64_t sent = 0, dropped = 0;
    std::vector<uint16_t> received;
    StreamReader reader(b.get());
    // Lend in batches, write, drain the reader only now and then: the queue must hit EAGAIN,
    // partial writes and overflow, and the reader must still see whole frames in order.
    for (size_t i = 0; i < frames.size(); i++) {
        ASSERT_TRUE(q.lend(frames[i]));
        if (i % 10 == 9) {
            int fd = a.get();
            auto r = q.write_stream(stream_write, &fd);
            EXPECT_EQ(0, r.error);
            sent += r.frames_sent;
            dropped += r.frames_dropped;
        }
        if (i % 1000 == 999)
            reader.read_available(received);
    }
    for (int round = 0; round < 100 && !q.empty(); round++) {
        int fd = a.get();
        auto r = q.write_stream(stream_write, &fd);
        sent += r.frames_sent;
        dropped += r.frames_dropped;
        reader.read_available(received);
    }
    reader.read_available(received);
    EXPECT_TRUE(q.empty());
    EXPECT_TRUE(reader.idle()) << "half a frame left on the stream";
    EXPECT_GT(dropped, 0u) << "the test did not overflow the queue";
    EXPECT_EQ(frames.size(), sent + dropped);
    EXPECT_EQ(sent, received.size());
    EXPECT_TRUE(std::is_sorted(received.begin(), received.end()));
    EXPECT_EQ(received.size(), std::set<uint16_t>(received.begin(), received.end()).size());
    // Drop-oldest: the newest frame always makes it.
    EXPECT_EQ(frames.size() - 1, received.back());
}

// What the daemon's stop relies on: mid_frame() says when the line stops inside a frame, and
// writing on from there completes that frame first.
TEST(TxQueue, MidFrameUntilTheCutFrameIsComplete) {
    struct Budget {
        size_t bytes;  // what the "kernel" takes on the next write
        std::vector<uint8_t> out;
    } budget{50, {}};
    auto writer = [](void* ctx, const iovec* iov, size_t count) -> ssize_t {
        auto& b = *static_cast<Budget*>(ctx);
        size_t taken = 0;
        for (size_t i = 0; i < count && taken < b.bytes; i++) {
            size_t n = std::min(iov[i].iov_len, b.bytes - taken);
            auto* p = static_cast<const uint8_t*>(iov[i].iov_base);
            b.out.insert(b.out.end(), p, p + n);
            taken += n;
        }
        b.bytes = 0;
        return static_cast<ssize_t>(taken);
    };
    TxQueue q(TxQueue::Mode::Stream, 4096);
    auto f0 = numbered_frame(0, 40), f1 = numbered_frame(1, 40);
    q.lend(f0);
    q.lend(f1);
    EXPECT_FALSE(q.mid_frame());
    auto r = q.write_stream(writer, &budget);  // 50 bytes: frame 0 and a quarter of frame 1
    EXPECT_EQ(1u, r.frames_sent);
    EXPECT_TRUE(q.mid_frame());
    budget.bytes = 30;  // the rest of frame 1 exactly
    r = q.write_stream(writer, &budget);
    EXPECT_EQ(1u, r.frames_sent);
    EXPECT_FALSE(q.mid_frame());
    EXPECT_TRUE(q.empty());
    std::vector<uint8_t> want(f0);
    want.insert(want.end(), f1.begin(), f1.end());
    EXPECT_EQ(want, budget.out);
}

TEST(TxQueue, DatagramBacklogKeepsOrderAfterEagain) {
    int sv[2];
    ASSERT_EQ(0, socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK, 0, sv));
    UniqueFd a(sv[0]), b(sv[1]);
    TxQueue q(TxQueue::Mode::Datagram, 1 << 20);
    std::vector<std::vector<uint8_t>> frames;
    for (uint16_t i = 0; i < 2000; i++)
        frames.push_back(numbered_frame(i, 60));
    uint64_t sent = 0;
    for (size_t i = 0; i < frames.size(); i++) {
        ASSERT_TRUE(q.lend(frames[i]));
        if (i % 100 == 99) {
            int fd = a.get();
            sent += q.write_datagrams(dgram_write, &fd).frames_sent;
        }
    }
    EXPECT_TRUE(q.has_backlog()) << "socket buffer never filled";
    std::vector<uint16_t> received;
    for (int round = 0; round < 1000 && received.size() < frames.size(); round++) {
        uint8_t buf[256];
        while (recv(b.get(), buf, sizeof buf, MSG_DONTWAIT) > 0)
            received.push_back(static_cast<uint16_t>(buf[0] | buf[1] << 8));
        int fd = a.get();
        sent += q.write_datagrams(dgram_write, &fd).frames_sent;
    }
    ASSERT_EQ(frames.size(), received.size());
    for (size_t i = 0; i < received.size(); i++)
        ASSERT_EQ(i, received[i]);
    EXPECT_EQ(frames.size(), sent);
}

TEST(TxQueue, HardDatagramErrorDropsOnlyTheFrameItHit) {
    TxQueue q(TxQueue::Mode::Datagram, 4096);
    auto f1 = numbered_frame(1, 20), f2 = numbered_frame(2, 20);
    q.lend(f1);
    q.lend(f2);
    int calls = 0;
    auto r = q.write_datagrams(
        [](void* ctx, const iovec*, size_t count) {
            int& c = *static_cast<int*>(ctx);
            return c++ == 0 ? -ECONNREFUSED : static_cast<int>(count);
        },
        &calls);
    EXPECT_EQ(1u, r.frames_dropped);
    EXPECT_EQ(1u, r.frames_sent);
    EXPECT_EQ(ECONNREFUSED, r.error);
    EXPECT_TRUE(q.empty());
}

// --- count markers ---------------------------------------------------------------------------

// A marker in the numbered-frame format: index 0xFFFF, then the count it was given (8 bytes).
constexpr size_t kMarkerLen = 12;
size_t write_test_marker(void* ctx, std::span<uint8_t> out, uint64_t before) {
    ++*static_cast<int*>(ctx);  // how often it was written (it is rewritten before each write)
    std::fill(out.begin(), out.begin() + kMarkerLen, 0);
    out[0] = out[1] = 0xFF;
    out[2] = kMarkerLen;
    std::memcpy(out.data() + 3, &before, 8);
    out[11] = 0xAB;
    return kMarkerLen;
}

// Reads numbered frames and markers from a stream or datagrams: for every marker, the frames
// that came before it and the count it carried.
struct MarkerCheck {
    std::vector<uint8_t> bytes;
    uint64_t frames = 0;  // every frame so far, markers included
    std::vector<std::pair<uint64_t, uint64_t>> markers;  // (carried, frames before it)
    void take(const uint8_t* p, size_t n) {
        bytes.insert(bytes.end(), p, p + n);
        size_t pos = 0;
        while (pos + 3 <= bytes.size() && pos + bytes[pos + 2] <= bytes.size()) {
            size_t len = bytes[pos + 2];
            if (bytes[pos] == 0xFF && bytes[pos + 1] == 0xFF && len == kMarkerLen) {
                uint64_t carried;
                std::memcpy(&carried, bytes.data() + pos + 3, 8);
                markers.emplace_back(carried, frames);
            }
            frames++;
            pos += len;
        }
        bytes.erase(bytes.begin(), bytes.begin() + static_cast<ptrdiff_t>(pos));
    }
};

TEST(TxQueue, StreamMarkersCountExactlyTheFramesWrittenBeforeThem) {
    // A line that takes a few bytes at a time, cutting frames and markers anywhere, with a
    // queue that overflows (frames dropped are never written, so never counted).
    struct Line {
        size_t budget = 0;
        MarkerCheck check;
    } line;
    auto writer = [](void* ctx, const iovec* iov, size_t count) -> ssize_t {
        auto& l = *static_cast<Line*>(ctx);
        size_t taken = 0;
        for (size_t i = 0; i < count && taken < l.budget; i++) {
            size_t n = std::min(iov[i].iov_len, l.budget - taken);
            l.check.take(static_cast<const uint8_t*>(iov[i].iov_base), n);
            taken += n;
        }
        l.budget = 0;
        return taken == 0 ? -EAGAIN : static_cast<ssize_t>(taken);
    };
    TxQueue q(TxQueue::Mode::Stream, 1024);
    std::vector<std::vector<uint8_t>> frames;
    for (uint16_t i = 0; i < 4000; i++)
        frames.push_back(numbered_frame(i, 20 + i % 90));
    int stamped = 0;
    uint64_t sent = 0, dropped = 0;
    for (size_t i = 0; i < frames.size(); i++) {
        ASSERT_TRUE(q.lend(frames[i]));
        if (i % 37 == 0)
            q.put_marker(write_test_marker, &stamped);
        if (i % 5 == 4) {
            line.budget = 7 + (i * 13) % 150;  // often less than what waits: cuts and a backlog
            auto r = q.write_stream(writer, &line);
            sent += r.frames_sent;
            dropped += r.frames_dropped;
        }
    }
    for (int round = 0; round < 10000 && !q.empty(); round++) {
        line.budget = 64;
        auto r = q.write_stream(writer, &line);
        sent += r.frames_sent;
        dropped += r.frames_dropped;
    }
    ASSERT_TRUE(q.empty());
    EXPECT_TRUE(line.check.bytes.empty()) << "half a frame left on the stream";
    EXPECT_GT(dropped, 100u) << "the test did not overflow the queue";
    ASSERT_GT(line.check.markers.size(), 50u);
    EXPECT_GT(static_cast<size_t>(stamped), line.check.markers.size()) << "never rewritten";
    for (const auto& [carried, before] : line.check.markers)
        ASSERT_EQ(before, carried);
    EXPECT_EQ(line.check.frames, q.frames_written());
    EXPECT_EQ(sent, q.frames_written());
    EXPECT_EQ(frames.size() + line.check.markers.size(), sent + dropped);
}

TEST(TxQueue, DatagramMarkerGoesAheadOfTheBacklogWithTheCountBeforeIt) {
    struct Kernel {
        size_t room = 0;  // datagrams it takes before EAGAIN
        MarkerCheck check;
    } kernel;
    auto writer = [](void* ctx, const iovec* frames, size_t count) -> int {
        auto& k = *static_cast<Kernel*>(ctx);
        size_t n = std::min(count, k.room);
        for (size_t i = 0; i < n; i++)
            k.check.take(static_cast<const uint8_t*>(frames[i].iov_base), frames[i].iov_len);
        k.room -= n;
        return n == 0 ? -EAGAIN : static_cast<int>(n);
    };
    TxQueue q(TxQueue::Mode::Datagram, 1 << 16);
    std::vector<std::vector<uint8_t>> frames;
    for (uint16_t i = 0; i < 300; i++)
        frames.push_back(numbered_frame(i, 30));
    int stamped = 0;
    for (size_t i = 0; i < frames.size(); i++) {
        q.lend(frames[i]);
        if (i % 20 == 0)
            q.put_marker(write_test_marker, &stamped);
        if (i % 10 == 9) {
            kernel.room = i % 30 == 29 ? 0 : 6;  // a backlog builds, a marker waits on EAGAIN
            q.write_datagrams(writer, &kernel);
            EXPECT_EQ(q.has_backlog(), q.marker_waiting() || !q.empty());
        }
    }
    for (int round = 0; round < 1000 && !q.empty(); round++) {
        kernel.room = 3;
        q.write_datagrams(writer, &kernel);
    }
    ASSERT_TRUE(q.empty());
    ASSERT_GE(kernel.check.markers.size(), 10u);
    for (const auto& [carried, before] : kernel.check.markers)
        ASSERT_EQ(before, carried);
    EXPECT_EQ(kernel.check.frames, q.frames_written());
    EXPECT_FALSE(q.put_marker(write_test_marker, &stamped) && q.put_marker(write_test_marker, &stamped))
        << "a second marker while one waits";
}

TEST(TxQueue, ARadiosOwnReportIsNotCountedAsWritten) {
    TxQueue q(TxQueue::Mode::Datagram, 4096);
    // RADIO_STATUS from a SiK radio (MAVLink 1, system 51, component 68), then any frame.
    std::vector<uint8_t> report = {0xFE, 9, 0, 51, 68, 109, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    std::vector<uint8_t> other = {0xFE, 9, 0, 1, 1, 109, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    q.lend(report);
    q.lend(other);
    int fd_ok = 0;
    auto r = q.write_datagrams([](void*, const iovec*, size_t count) { return static_cast<int>(count); },
                               &fd_ok);
    EXPECT_EQ(2u, r.frames_sent);
    EXPECT_EQ(1u, q.frames_written());
}

}  // namespace
}  // namespace mavbond
