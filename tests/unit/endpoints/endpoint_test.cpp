// What an endpoint decides before routing sees a frame (its signature, allow_in/block_in) and
// on the way out (allow_out/block_out), against a sink that only records what it is handed.
#include "endpoints/endpoint.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <vector>

#include "mavlink/frame_writer.h"
#include "routing/standby.h"

namespace mavbond {
namespace {

/// A frame sink that keeps what it is handed: each frame's msgid and whether it is routed.
class RecordingSink : public FrameSink {
public:
    struct Handed {
        uint32_t msgid;
        bool routed;
        const Link* from;
    };
    void attach(Link&) override { attached++; }
    void detach(Link&) override { attached--; }
    void attach(Input&) override {}
    void detach(Input&) override {}
    void ingress(ReceivedBatch& batch) override {
        for (size_t i = 0; i < batch.size(); i++)
            handed.push_back({batch[i].frame.msgid, batch[i].routed, batch[i].from});
    }
    void end_batch() override { batches++; }
    int attached = 0;
    int batches = 0;
    std::vector<Handed> handed;
};

/// An endpoint whose "socket" records the datagrams it was asked to send.
class RecordingEndpoint : public Endpoint {
public:
    RecordingEndpoint(const EndpointConfig& config, EventLoop& loop)
        : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram) {}
    const char* kind() const override { return "test"; }
    std::vector<std::vector<uint8_t>> written;

protected:
    int write_datagrams(const iovec* frames, size_t count) override {
        for (size_t i = 0; i < count; i++) {
            auto* p = static_cast<const uint8_t*>(frames[i].iov_base);
            written.emplace_back(p, p + frames[i].iov_len);
        }
        return static_cast<int>(count);
    }
};

constexpr uint32_t kHeartbeat = 0;
constexpr uint32_t kAttitude = 30;

/// A valid MAVLink 2 frame of `msgid` (HEARTBEAT or ATTITUDE) from (1, 1), its payload
/// all ones.
std::vector<uint8_t> datagram(uint32_t msgid, uint8_t seq = 0) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    std::vector<uint8_t> payload(msgid == kHeartbeat ? 9 : 28, 1);
    size_t n = write_frame_v2(buf, FrameSource{1, 1, seq}, msgid, payload);
    return {buf.begin(), buf.begin() + static_cast<ptrdiff_t>(n)};
}

class EndpointTest : public ::testing::Test {
protected:
    /// Hands the datagrams to `e` as one read.
    void receive(RecordingEndpoint& e, const std::vector<std::vector<uint8_t>>& datagrams) {
        ReceivedBatch batch(sink_);
        for (const auto& d : datagrams)
            e.receive_datagram(batch, d, Clock::now(), UnknownIdPolicy::Forward);
        batch.submit();
        sink_.end_batch();
    }
    EndpointConfig config(const char* name) {
        EndpointConfig c;
        c.name = name;
        return c;
    }
    std::unique_ptr<EventLoop> loop_ = EventLoop::create().value();
    RecordingSink sink_;
};

TEST_F(EndpointTest, AllowInRefusalsReachRoutingToTeachTheirSourceOnly) {
    EndpointConfig c = config("autopilot");
    c.filter_in.allow = {kHeartbeat};
    RecordingEndpoint e(c, *loop_);
    receive(e, {datagram(kHeartbeat), datagram(kAttitude, 1)});
    ASSERT_EQ(2u, sink_.handed.size());
    EXPECT_EQ(kHeartbeat, sink_.handed[0].msgid);
    EXPECT_TRUE(sink_.handed[0].routed);
    EXPECT_EQ(kAttitude, sink_.handed[1].msgid);
    EXPECT_FALSE(sink_.handed[1].routed);
    EXPECT_EQ(&e, sink_.handed[1].from);
    EXPECT_EQ(1u, e.counters().rx_filtered);
    EXPECT_EQ(2u, e.counters().rx.frames);
}

TEST_F(EndpointTest, BlockOutDropsAndCounts) {
    EndpointConfig c = config("gcs");
    c.filter_out.block = {kAttitude};
    RecordingEndpoint e(c, *loop_);
    auto att = datagram(kAttitude);
    auto hb = datagram(kHeartbeat);
    Frame f;
    ParserCounters counters;
    ASSERT_TRUE(DatagramParser(att, UnknownIdPolicy::Forward, counters).next(f));
    EXPECT_FALSE(e.send(f));
    ASSERT_TRUE(DatagramParser(hb, UnknownIdPolicy::Forward, counters).next(f));
    EXPECT_TRUE(e.send(f)) << "the first frame lent makes the endpoint need a flush";
    e.flush();
    ASSERT_EQ(1u, e.written.size());
    EXPECT_EQ(hb, e.written[0]);
    EXPECT_EQ(1u, e.counters().tx_filtered);
    EXPECT_EQ(1u, e.counters().tx_frames);
}

TEST_F(EndpointTest, AnUnsignedFrameNeverReachesRoutingWhenSigningIsRequired) {
    EndpointConfig c = config("radio");
    c.signing.enabled = true;
    c.signing.key.fill(7);
    RecordingEndpoint e(c, *loop_);
    receive(e, {datagram(kHeartbeat)});
    EXPECT_TRUE(sink_.handed.empty());
    EXPECT_EQ(1u, e.counters().sig_unsigned);
    EXPECT_EQ(TimePoint{}, e.counters().last_rx) << "a refused frame is no sign of life";
}

TEST_F(EndpointTest, AFullBatchGoesToTheSinkAndTheReadGoesOn) {
    RecordingEndpoint e(config("radio"), *loop_);
    std::vector<std::vector<uint8_t>> many;
    for (size_t i = 0; i < ReceivedBatch::kCapacity + 3; i++)
        many.push_back(datagram(kHeartbeat, static_cast<uint8_t>(i)));
    receive(e, many);
    EXPECT_EQ(ReceivedBatch::kCapacity + 3, sink_.handed.size());
    EXPECT_EQ(1, sink_.batches) << "one end of batch, after the read";
}

TEST_F(EndpointTest, ABudgetedLinkSendsWhatWaitsOnItsOwnTimer) {
    // 10 kB/s on a datagram link: an ATTITUDE costs its (up to) 40 bytes plus 28 of headers,
    // and the bucket holds 308 (one largest frame and its headers). A burst of 20 (from 20
    // sources, so none is thinned) sends the first four at once; the rest go on the
    // endpoint's timer, in order, with no one flushing.
    EndpointConfig c = config("lte");
    c.tx_budget.bytes_per_s = 10000;
    c.tx_budget.classes.control = {kHeartbeat};
    RecordingEndpoint e(c, *loop_);
    std::vector<std::vector<uint8_t>> sent;
    ParserCounters counters;
    for (uint8_t i = 0; i < 20; i++) {
        std::array<uint8_t, kMaxFrameLen> buf{};
        std::vector<uint8_t> payload(28, i);
        size_t n = write_frame_v2(buf, FrameSource{static_cast<uint8_t>(i + 1), 1, i}, kAttitude,
                                  payload);
        sent.emplace_back(buf.begin(), buf.begin() + static_cast<ptrdiff_t>(n));
        Frame f;
        ASSERT_TRUE(DatagramParser(sent.back(), UnknownIdPolicy::Forward, counters).next(f));
        e.send(f);
    }
    e.flush();
    const size_t at_once = e.written.size();
    EXPECT_EQ(4u, at_once);
    // A heartbeat (control) goes at once, ahead of every frame still held.
    auto hb = datagram(kHeartbeat);
    Frame f;
    ASSERT_TRUE(DatagramParser(hb, UnknownIdPolicy::Forward, counters).next(f));
    e.send(f);
    e.flush();
    ASSERT_EQ(at_once + 1, e.written.size());
    EXPECT_EQ(hb, e.written.back());
    // The loop runs the budget's timer until everything went (16 x 68 bytes: 0.1 s).
    auto deadline = Clock::now() + seconds(5);
    while (e.written.size() < 21 && Clock::now() < deadline)
        loop_->run_once(milliseconds(50));
    ASSERT_EQ(21u, e.written.size());
    std::vector<std::vector<uint8_t>> telemetry(e.written.begin(), e.written.end());
    telemetry.erase(telemetry.begin() + static_cast<ptrdiff_t>(at_once));
    EXPECT_EQ(sent, telemetry) << "every one, in the order sent";
    const TxClassCounters& t = e.counters().tx_class[1];
    EXPECT_EQ(20u, t.frames);
    EXPECT_EQ(16u, t.waited);
    size_t bytes = 0;
    for (const auto& d : sent)
        bytes += d.size() + 28;
    EXPECT_EQ(bytes, t.bytes) << "each with its IP and UDP headers";
    EXPECT_EQ(1u, e.counters().tx_class[0].frames);
}

// The operator stage: a starved radio budget held the air side's standby reports (telemetry
// to it, one sample slot for all of mavbond's NAMED_VALUE_INTs) for five seconds while they went
// on LTE, and the ground took the radio for silent. They go at once, paid for like a marker.
TEST_F(EndpointTest, StandbyReportsGoAtOnceWhateverTheBudgetHolds) {
    EndpointConfig c = config("radio");
    c.tx_budget.bytes_per_s = 1000;
    c.tx_budget.classes.control = {kHeartbeat};
    RecordingEndpoint e(c, *loop_);
    ParserCounters counters;
    std::vector<std::array<uint8_t, kMaxFrameLen>> bufs(12);
    std::vector<Frame> frames(12);
    for (uint8_t i = 0; i < 10; i++) {  // telemetry enough to hold the budget for a while
        std::vector<uint8_t> payload(28, i);
        size_t n = write_frame_v2(bufs[i], FrameSource{static_cast<uint8_t>(i + 1), 1, i},
                                  kAttitude, payload);
        ASSERT_TRUE(DatagramParser(std::span<const uint8_t>(bufs[i].data(), n),
                                   UnknownIdPolicy::Forward, counters).next(frames[i]));
        e.send(frames[i]);
    }
    e.flush();
    const size_t before = e.written.size();
    ASSERT_LT(before, 10u) << "the budget holds some";
    for (uint8_t k = 0; k < 2; k++) {  // a report of the radio, then the resend announcement
        std::array<uint8_t, 18> payload{};
        std::memcpy(payload.data() + 8, k == 0 ? "mbl:radio" : "mbp:resend", k == 0 ? 9 : 10);
        size_t n = write_frame_v2(bufs[10 + k], FrameSource{1, 191, k}, Standby::kMsgNamedValueInt,
                                  payload);
        ASSERT_TRUE(DatagramParser(std::span<const uint8_t>(bufs[10 + k].data(), n),
                                   UnknownIdPolicy::Forward, counters).next(frames[10 + k]));
        ASSERT_TRUE(Standby::is_report(frames[10 + k]));
        e.send(frames[10 + k]);
        e.flush();
        ASSERT_EQ(before + k + 1, e.written.size());
        EXPECT_TRUE(std::equal(frames[10 + k].bytes.begin(), frames[10 + k].bytes.end(),
                               e.written.back().begin(), e.written.back().end()));
    }
    EXPECT_EQ(0u, e.counters().tx_class[1].thinned);
}

}  // namespace
}  // namespace mavbond
