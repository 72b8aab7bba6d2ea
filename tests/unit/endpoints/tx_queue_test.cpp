#include "endpoints/tx_queue.h"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/uio.h>

#include <algorithm>
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

}  // namespace
}  // namespace mavbond
