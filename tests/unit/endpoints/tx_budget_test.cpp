// The transmit budget on a simulated clock: control never waits, telemetry is thinned to the
// newest sample and its caps, bulk keeps its order and a share, and what goes out keeps to the
// rate over any stretch.
#include "endpoints/tx_budget.h"

#include <gtest/gtest.h>

#include <map>
#include <vector>

#include "mavlink/frame_writer.h"
#include "mavlink/message_table.h"

namespace mavbond {
namespace {

uint32_t id(const char* name) { return *find_message_id(name); }

TxClassesConfig classes() {
    TxClassesConfig c;
    c.control = {id("HEARTBEAT"), id("COMMAND_LONG")};
    std::sort(c.control.begin(), c.control.end());
    c.bulk = {id("FILE_TRANSFER_PROTOCOL")};
    return c;
}

/// A frame of `msgid` from (sysid, 1) whose payload's first byte is `tag`, `payload` bytes long
/// (at most the message's own length).
struct Made {
    std::vector<uint8_t> bytes;
    Frame frame;
};
Made make(uint32_t msgid, uint16_t tag, size_t payload = 28, uint8_t sysid = 1,
          uint8_t instance = 0) {
    Made m;
    const MessageInfo* info = find_message(msgid);
    EXPECT_NE(nullptr, info);
    std::array<uint8_t, kMaxFrameLen> buf{};
    payload = std::min<size_t>(payload, info->max_len);
    std::vector<uint8_t> body(payload, 0x55);
    body[0] = static_cast<uint8_t>(tag);
    body[1] = static_cast<uint8_t>(tag >> 8);
    if (info->instance_size != 0) {  // the instance's low byte, the rest zero
        for (size_t i = 0; i < info->instance_size; i++)
            body.at(static_cast<size_t>(info->instance_ofs) + i) = i == 0 ? instance : 0;
    }
    size_t n = write_frame_v2(buf, FrameSource{sysid, 1, static_cast<uint8_t>(tag)}, msgid, body);
    m.bytes.assign(buf.begin(), buf.begin() + static_cast<ptrdiff_t>(n));
    m.frame.bytes = m.bytes;
    m.frame.payload = std::span<const uint8_t>(m.bytes).subspan(kHeaderLenV2, m.bytes[1]);
    m.frame.msgid = msgid;
    m.frame.sysid = sysid;
    m.frame.compid = 1;
    m.frame.info = info;
    return m;
}

/// What went on the line: when, which message, its tag.
struct Out {
    TimePoint at;
    uint32_t msgid;
    uint8_t sysid;
    uint16_t tag;
    size_t len;
    std::vector<uint8_t> bytes;
};

/// Drives a budget the way an endpoint does: offer() each frame at its time, release() at
/// every due time in between.
class Line {
public:
    Line(uint64_t rate, const TxClassesConfig& c, size_t bulk_capacity = 16384)
        : budget(rate, 0, c, bulk_capacity, counters) {}

    void offer(const Made& m, TimePoint at) {
        run_until(at);
        if (budget.offer(m.frame, at))
            record(at, m.frame.bytes);
        due_ = std::min(due_, release(at));
    }
    /// A new rate from `at` on (a radio's report), as Endpoint::apply_radio_rate sets it.
    void set_rate(uint64_t rate, TimePoint at) {
        run_until(at);
        budget.set_rate(rate, at);
        due_ = release(at);
    }
    /// Releases what is due up to `t`.
    void run_until(TimePoint t) {
        while (due_ <= t) {
            TimePoint at = due_;
            due_ = release(at);
        }
    }

    std::array<TxClassCounters, kTxClassCount> counters{};
    TxBudget budget;
    std::vector<Out> out;

private:
    TimePoint release(TimePoint at) {
        return budget.release(at, [&](std::span<uint8_t> b, uint64_t) { record(at, b); });
    }
    void record(TimePoint at, std::span<const uint8_t> b) {
        uint32_t msgid = b[7] | b[8] << 8 | b[9] << 16;
        out.push_back({at, msgid, b[5], static_cast<uint16_t>(b[10] | b[11] << 8), b.size(),
                       {b.begin(), b.end()}});
    }
    TimePoint due_ = TimePoint::max();
};

const TimePoint t0 = TimePoint{} + seconds(100);
Duration ms(double v) { return Duration(static_cast<int64_t>(v * 1e6)); }

TEST(TxBudgetTest, ControlGoesAtOnceEvenWithTheBucketEmpty) {
    Line line(1000, classes());
    // Empty the bucket with telemetry, then a command: it goes in the same instant.
    for (uint8_t i = 0; i < 20; i++)
        line.offer(make(id("ATTITUDE"), i, 28, static_cast<uint8_t>(i + 1)), t0);
    size_t before = line.out.size();
    line.offer(make(id("COMMAND_LONG"), 99, 33), t0);
    ASSERT_EQ(before + 1, line.out.size());
    EXPECT_EQ(id("COMMAND_LONG"), line.out.back().msgid);
    EXPECT_EQ(t0, line.out.back().at);
    EXPECT_EQ(1u, line.budget.counters(TxClass::Control).frames);
    EXPECT_EQ(0u, line.budget.counters(TxClass::Control).waited);
}

TEST(TxBudgetTest, HeldTelemetryIsThinnedToItsNewestSample) {
    Line line(1000, classes());
    // 40 bytes a frame at 1000 B/s: 25 frames/s fit. Offer one message at 100/s for 1 s.
    for (int i = 0; i < 100; i++)
        line.offer(make(id("ATTITUDE"), static_cast<uint16_t>(i)), t0 + ms(10 * i));
    line.run_until(t0 + seconds(2));
    const auto& k = line.budget.counters(TxClass::Telemetry);
    EXPECT_EQ(100u, k.frames + k.thinned);
    EXPECT_GT(k.thinned, 60u);
    // Every sample that went is newer than the one before it, and the last one offered went.
    for (size_t i = 1; i < line.out.size(); i++)
        EXPECT_GT(line.out[i].tag, line.out[i - 1].tag);
    EXPECT_EQ(99, line.out.back().tag);
    EXPECT_FALSE(line.budget.holding());
}

TEST(TxBudgetTest, NoStretchCarriesMoreThanTheRateAndABurst) {
    const uint64_t rate = 5760;  // 57600 baud
    Line line(rate, classes());
    // An ArduPilot-like stream of 248 frames/s over 10 messages, twice what the line carries.
    const char* names[] = {"ATTITUDE", "GLOBAL_POSITION_INT", "VFR_HUD", "SYS_STATUS",
                           "RAW_IMU", "SCALED_PRESSURE", "GPS_RAW_INT", "RC_CHANNELS",
                           "SERVO_OUTPUT_RAW", "NAV_CONTROLLER_OUTPUT"};
    for (int i = 0; i < 2480; i++) {
        uint32_t msgid = id(names[i % 10]);
        line.offer(make(msgid, static_cast<uint16_t>(i), 80), t0 + ms(1000.0 * i / 248));
    }
    line.run_until(t0 + seconds(12));
    const double burst = kMaxFrameLen;
    double sum = 0;
    size_t first = 0;
    for (size_t i = 0; i < line.out.size(); i++) {
        sum += static_cast<double>(line.out[i].len);
        while (first < i && line.out[first].at < line.out[i].at - seconds(1)) {
            sum -= static_cast<double>(line.out[first].len);
            first++;
        }
        double span = std::chrono::duration<double>(line.out[i].at - line.out[first].at).count();
        ASSERT_LE(sum, span * rate + burst + line.out[i].len) << "at frame " << i;
    }
    // It used what it had: over the 10 s, at least 95 % of the rate.
    double total = 0;
    for (const Out& o : line.out)
        total += static_cast<double>(o.len);
    EXPECT_GT(total, 0.95 * rate * 10);
    // Every message kept a share (none starved), and each went out newest-first-only.
    std::map<uint32_t, int> per;
    for (const Out& o : line.out)
        per[o.msgid]++;
    EXPECT_EQ(10u, per.size());
    for (const auto& [msgid, n] : per)
        EXPECT_GT(n, 40) << msgid;
}

TEST(TxBudgetTest, ACommandInASaturatedStreamWaitsForNothing) {
    Line line(5760, classes());
    for (int i = 0; i < 600; i++) {
        line.offer(make(id("RAW_IMU"), static_cast<uint16_t>(i), 100, static_cast<uint8_t>(i % 50)),
                   t0 + ms(5.0 * i));
        if (i % 30 == 7) {
            size_t before = line.out.size();
            line.offer(make(id("COMMAND_LONG"), static_cast<uint16_t>(i), 33), t0 + ms(5.0 * i));
            ASSERT_GT(line.out.size(), before);
            EXPECT_EQ(id("COMMAND_LONG"), line.out[before].msgid);
            EXPECT_EQ(t0 + ms(5.0 * i), line.out[before].at);
        }
    }
    EXPECT_EQ(20u, line.budget.counters(TxClass::Control).frames);
}

TEST(TxBudgetTest, ACapThinsAMessageWhateverTheBudget) {
    TxClassesConfig c = classes();
    c.caps = {{id("ATTITUDE"), milliseconds(100)}};
    Line line(1000000, c);
    for (int i = 0; i < 500; i++)  // 50 Hz for 10 s
        line.offer(make(id("ATTITUDE"), static_cast<uint16_t>(i)), t0 + ms(20 * i));
    line.run_until(t0 + seconds(11));
    // 10 Hz, the newest sample each time: 100 (+1 for the first, which goes at once).
    EXPECT_GE(line.out.size(), 100u);
    EXPECT_LE(line.out.size(), 101u);
    for (size_t i = 1; i < line.out.size(); i++)
        EXPECT_GE(line.out[i].at - line.out[i - 1].at, milliseconds(100));
    EXPECT_EQ(499, line.out.back().tag);
}

TEST(TxBudgetTest, BulkKeepsItsOrderAndAQuarterBesideSaturatedTelemetry) {
    Line line(5000, classes());
    int ftp = 0;
    for (int i = 0; i < 2000; i++) {  // 10 s: telemetry at 2x the rate, FTP offered at 100/s
        TimePoint at = t0 + ms(5.0 * i);
        line.offer(make(id("VFR_HUD"), static_cast<uint16_t>(i), 100, static_cast<uint8_t>(i % 40)),
                   at);
        if (i % 2 == 0)
            line.offer(make(id("FILE_TRANSFER_PROTOCOL"), static_cast<uint16_t>(ftp++), 100), at);
    }
    line.run_until(t0 + seconds(10));
    double bulk = 0, all = 0;
    int before = -1;
    for (const Out& o : line.out) {
        all += static_cast<double>(o.len);
        if (o.msgid != id("FILE_TRANSFER_PROTOCOL"))
            continue;
        bulk += static_cast<double>(o.len);
        EXPECT_GT(static_cast<int>(o.tag), before);  // in order (a gap: the oldest dropped)
        before = o.tag;
    }
    EXPECT_NEAR(0.25, bulk / all, 0.03);
    // Once the stream ends the queue drains: every FTP frame went or was counted dropped.
    line.run_until(t0 + seconds(100));
    const auto& k = line.budget.counters(TxClass::Bulk);
    EXPECT_EQ(1000u, k.frames + k.dropped);
    EXPECT_FALSE(line.budget.holding());
}

TEST(TxBudgetTest, TheBulkQueueDropsItsOldestWhenFull) {
    Line line(100, classes(), 1024);  // 1 KiB of queue: seven 136-byte frames and headers
    for (int i = 0; i < 20; i++)
        line.offer(make(id("FILE_TRANSFER_PROTOCOL"), static_cast<uint16_t>(i), 124), t0);
    const auto& k = line.budget.counters(TxClass::Bulk);
    EXPECT_GT(k.dropped, 0u);
    line.run_until(t0 + seconds(60));
    EXPECT_EQ(20u, k.frames + k.dropped);
    // What went is the first (it went at once) and then the newest ones, in order.
    for (size_t i = 1; i < line.out.size(); i++)
        EXPECT_GT(line.out[i].tag, line.out[i - 1].tag);
    EXPECT_EQ(19, line.out.back().tag);
}

TEST(TxBudgetTest, InstancesOfAMessageAreThinnedApart) {
    // Two batteries and two aircraft from one source, through a link that carries a tenth:
    // each battery and each aircraft keeps its own newest sample.
    Line line(300, classes());
    for (int i = 0; i < 100; i++) {
        TimePoint at = t0 + ms(10 * i);
        line.offer(make(id("BATTERY_STATUS"), static_cast<uint16_t>(i), 36, 1, 0), at);
        line.offer(make(id("BATTERY_STATUS"), static_cast<uint16_t>(i), 36, 1, 1), at);
        line.offer(make(id("ADSB_VEHICLE"), static_cast<uint16_t>(i), 38, 1, 0x21), at);
        line.offer(make(id("ADSB_VEHICLE"), static_cast<uint16_t>(i), 38, 1, 0x42), at);
    }
    line.run_until(t0 + seconds(20));
    std::map<std::pair<uint32_t, uint8_t>, int> last;
    for (const Out& o : line.out) {
        const MessageInfo* info = find_message(o.msgid);
        uint8_t instance = o.bytes.at(kHeaderLenV2 + static_cast<size_t>(info->instance_ofs));
        last[{o.msgid, instance}] = o.bytes[4];  // the sequence byte: ADS-B's tag is its address
    }
    EXPECT_EQ(4u, last.size()) << "both batteries and both aircraft went";
    for (const auto& [which, tag] : last)
        EXPECT_EQ(99, tag) << which.first << "/" << int(which.second) << ": its newest sample";
}

TEST(TxBudgetTest, ALinkThatStopsHandsOverEverythingHeld) {
    TxClassesConfig c = classes();
    c.caps = {{id("ATTITUDE"), seconds(10)}};
    Line line(100, c);
    for (int i = 0; i < 6; i++) {
        line.offer(make(id("ATTITUDE"), static_cast<uint16_t>(i), 28, static_cast<uint8_t>(i + 1)),
                   t0);
        line.offer(make(id("FILE_TRANSFER_PROTOCOL"), static_cast<uint16_t>(i), 100), t0);
    }
    ASSERT_TRUE(line.budget.holding());
    size_t before = line.out.size();
    std::vector<uint16_t> ftp;
    line.budget.drain(t0, [&](std::span<uint8_t> b, uint64_t) {
        if (static_cast<uint32_t>(b[7] | b[8] << 8) == id("FILE_TRANSFER_PROTOCOL"))
            ftp.push_back(static_cast<uint16_t>(b[10] | b[11] << 8));
        before++;
    });
    EXPECT_FALSE(line.budget.holding());
    EXPECT_EQ(12u, before) << "every frame offered went, at once or now";
    for (size_t i = 1; i < ftp.size(); i++)
        EXPECT_GT(ftp[i], ftp[i - 1]);
    const auto& t = line.budget.counters(TxClass::Telemetry);
    const auto& b = line.budget.counters(TxClass::Bulk);
    EXPECT_EQ(6u, t.frames);
    EXPECT_EQ(6u, b.frames);
    EXPECT_EQ(0u, t.thinned + t.dropped + b.dropped);
}

TEST(TxBudgetTest, SourcesAreThinnedApart) {
    Line line(500, classes());
    // Two vehicles' positions through one slow link: each keeps its own newest sample.
    for (int i = 0; i < 200; i++) {
        line.offer(make(id("GLOBAL_POSITION_INT"), static_cast<uint16_t>(i), 28, 1), t0 + ms(10 * i));
        line.offer(make(id("GLOBAL_POSITION_INT"), static_cast<uint16_t>(i), 28, 2), t0 + ms(10 * i));
    }
    line.run_until(t0 + seconds(5));
    // Each went at about half of what the line carries (13 frames/s), newest first-only, and
    // each source's last position went.
    int last[3] = {-1, -1, -1};
    int count[3] = {0, 0, 0};
    for (const Out& o : line.out) {
        ASSERT_TRUE(o.sysid == 1 || o.sysid == 2);
        EXPECT_GT(static_cast<int>(o.tag), last[o.sysid]);
        last[o.sysid] = o.tag;
        count[o.sysid]++;
    }
    EXPECT_EQ(199, last[1]);
    EXPECT_EQ(199, last[2]);
    EXPECT_LE(std::abs(count[1] - count[2]), 1);
}

TEST(TxBudgetTest, ARateSetMidStreamHoldsFromThenOn) {
    // 5760 B/s, then a radio's report halves it at 5 s, then raises it back at 10 s: each
    // stretch carries its own rate (within a burst), the telemetry held across a change
    // included, and none is lost but what thinning replaced.
    Line line(5760, classes());
    const int fps = 250;  // 40-byte frames: 10 kB/s offered, more than either rate
    for (int i = 0; i < 15 * fps; i++) {
        TimePoint at = t0 + ms(1000.0 * i / fps);
        if (i == 5 * fps)
            line.set_rate(2880, at);
        if (i == 10 * fps)
            line.set_rate(5760, at);
        line.offer(make(id("ATTITUDE"), static_cast<uint16_t>(i), 28,
                        static_cast<uint8_t>(1 + i % 8)), at);
    }
    line.run_until(t0 + seconds(16));
    auto bytes_between = [&](double from_s, double to_s) {
        size_t n = 0;
        for (const Out& o : line.out)
            n += o.at >= t0 + ms(1000 * from_s) && o.at < t0 + ms(1000 * to_s) ? o.len : 0;
        return static_cast<double>(n);
    };
    const double burst = kMaxFrameLen;
    EXPECT_LE(bytes_between(0, 5), 5760 * 5 + burst);
    EXPECT_GE(bytes_between(0, 5), 5760 * 5 - burst);
    EXPECT_LE(bytes_between(5, 10), 2880 * 5 + burst);
    EXPECT_GE(bytes_between(5, 10), 2880 * 5 - 2 * burst);
    EXPECT_LE(bytes_between(10, 15), 5760 * 5 + burst);
    EXPECT_GE(bytes_between(10, 15), 5760 * 5 - 2 * burst);
    const auto& k = line.budget.counters(TxClass::Telemetry);
    EXPECT_EQ(static_cast<uint64_t>(15 * fps), k.frames + k.thinned);
    EXPECT_EQ(0u, k.dropped);
    EXPECT_FALSE(line.budget.holding());
}


TEST(TxBudgetTest, ABurstOfControlWaitsInOrderOnceTheLineIsAQuarterSecondBehind) {
    // A parameter list: 400 PARAM_VALUEs (they are control) at once into a 3240 B/s radio.
    // What a radio's buffer would lose beyond the line's quarter second waits in mavbond, in
    // order, ahead of telemetry, and none is lost: it drains at the rate.
    TxClassesConfig c = classes();
    c.control.push_back(id("PARAM_VALUE"));
    std::sort(c.control.begin(), c.control.end());
    const uint64_t rate = 3240;
    Line line(rate, c, 65536);
    for (int i = 0; i < 400; i++)
        line.offer(make(id("PARAM_VALUE"), static_cast<uint16_t>(i), 25), t0);
    line.offer(make(id("ATTITUDE"), 1000), t0);
    const double ahead = rate * 0.25;
    double at_once = 0;
    for (const Out& o : line.out)
        at_once += static_cast<double>(o.len);
    EXPECT_LE(at_once, ahead + kMaxFrameLen + kMaxFrameLen) << "a quarter second of the rate, and the bucket";
    EXPECT_TRUE(line.budget.holding());
    line.run_until(t0 + seconds(2));
    // Two seconds drain a quarter second plus two seconds of the rate: the rest still waits.
    ASSERT_FALSE(line.out.empty());
    for (size_t i = 1; i < line.out.size(); i++) {
        ASSERT_EQ(id("PARAM_VALUE"), line.out[i].msgid) << "control first, telemetry after it";
        EXPECT_EQ(line.out[i - 1].tag + 1, line.out[i].tag) << "in order, none lost";
    }
    const auto& k = line.budget.counters(TxClass::Control);
    EXPECT_EQ(0u, k.dropped);
    EXPECT_GT(k.waited, 0u);
}

TEST(TxBudgetTest, ControlThatWaitedTwoSecondsIsDroppedAsTooLate) {
    // A burst far beyond what the line carries in kControlMaxWait: what could not go within
    // it is dropped (counted), the rest went in order; nothing waits past it.
    TxClassesConfig c = classes();
    c.control.push_back(id("PARAM_VALUE"));
    std::sort(c.control.begin(), c.control.end());
    Line line(1000, c, 65536);
    for (int i = 0; i < 500; i++)
        line.offer(make(id("PARAM_VALUE"), static_cast<uint16_t>(i), 25), t0);
    line.run_until(t0 + seconds(10));
    line.offer(make(id("HEARTBEAT"), 777, 9), t0 + seconds(10));  // releases and expires
    const auto& k = line.budget.counters(TxClass::Control);
    EXPECT_EQ(501u, k.frames + k.dropped);
    EXPECT_GT(k.dropped, 0u);
    for (const Out& o : line.out)
        EXPECT_LE(o.at - t0, TxBudget::kControlMaxWait + seconds(8)) << "none later than it could be of use";
    for (size_t i = 1; i + 1 < line.out.size(); i++)
        EXPECT_LT(line.out[i - 1].tag, line.out[i].tag);
    EXPECT_EQ(id("HEARTBEAT"), line.out.back().msgid);
    EXPECT_EQ(t0 + seconds(10), line.out.back().at) << "the line is free again: at once";
}

TEST(TxBudgetTest, ItsLoadSaysWhatWasOfferedAndWhatWasLost) {
    Line line(1000, classes());
    for (int i = 0; i < 100; i++)  // 40-byte samples at 100/s: four times the rate
        line.offer(make(id("ATTITUDE"), static_cast<uint16_t>(i)), t0 + ms(10 * i));
    line.run_until(t0 + seconds(2));
    const TxBudget::Load& l = line.budget.load();
    EXPECT_EQ(100u, l.offered_frames);
    EXPECT_EQ(100u * line.out.front().len, l.offered_bytes);
    const auto& k = line.budget.counters(TxClass::Telemetry);
    EXPECT_EQ(k.thinned, l.lost);
    EXPECT_EQ(k.waited, l.waited);
    EXPECT_GT(l.lost, 50u);
}

}  // namespace
}  // namespace mavbond
