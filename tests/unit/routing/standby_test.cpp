#include "routing/standby.h"

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <deque>
#include <string>
#include <vector>

#include "mavlink/frame_parser.h"
#include "mavlink/frame_writer.h"

namespace mavbond {
namespace {

constexpr uint32_t kHeartbeat = 0, kAttitude = 30, kFtp = 110;

/// A NAMED_VALUE_INT as a peer sends it, parsed back as the router gets it (the frame's spans
/// point into buf: a Wire never moves).
struct Wire {
    Wire(const Wire&) = delete;
    Wire& operator=(const Wire&) = delete;
    std::array<uint8_t, kMaxFrameLen> buf{};
    Frame frame;
    Wire(const std::string& name, int32_t value, uint8_t seq = 0) {
        std::array<uint8_t, 18> payload{};
        std::memcpy(payload.data() + 4, &value, 4);
        std::memcpy(payload.data() + 8, name.data(), std::min<size_t>(name.size(), 10));
        size_t n = write_frame_v2(buf, FrameSource{1, 191, seq}, Standby::kMsgNamedValueInt,
                                  std::span<const uint8_t>(payload.data(), payload.size()));
        ParserCounters counters;
        DatagramParser parser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop,
                              counters);
        EXPECT_TRUE(parser.next(frame));
    }
};

class StandbyTest : public ::testing::Test {
protected:
    StandbyTest() {
        radio_.name = "radio";
        lte_.name = "lte";
        lte_.metered = true;
        classes_.control = {kHeartbeat};
        classes_.bulk = {kFtp};
        bond_.failback_after = seconds(10);
    }
    Standby make() { return Standby(bond_, {&radio_, &lte_}, classes_, t0_); }

    EndpointConfig radio_, lte_;
    TxClassesConfig classes_;
    BondConfig bond_;
    TimePoint t0_ = TimePoint(seconds(100));
};

TEST_F(StandbyTest, StandbyCarriesOnlyItsClassesOnTheMeteredMember) {
    Standby s = make();
    EXPECT_TRUE(s.lets_send(1, kHeartbeat));
    EXPECT_FALSE(s.lets_send(1, kAttitude));
    EXPECT_FALSE(s.lets_send(1, kFtp));
    EXPECT_TRUE(s.lets_send(0, kAttitude));  // a free member carries everything
    lte_.standby_classes = 0b011;            // control and telemetry
    Standby t = make();
    EXPECT_TRUE(t.lets_send(1, kAttitude));
    EXPECT_FALSE(t.lets_send(1, kFtp));
}

TEST_F(StandbyTest, AReportIsTakenAndNamesTheLink) {
    Standby s = make();
    Wire w("mbl:radio", 25);
    EXPECT_TRUE(s.take_report(w.frame, t0_));
    ASSERT_EQ(1u, s.peer_links().size());
    EXPECT_EQ("radio", s.peer_links()[0].name);
    EXPECT_EQ(25, s.peer_links()[0].permille);
    // A short name (its zeros trimmed off the wire) and another one.
    Wire v("mbl:m1", 7);
    EXPECT_TRUE(s.take_report(v.frame, t0_));
    EXPECT_EQ("m1", s.peer_links()[1].name);
    // Not ours: another prefix, or characters no endpoint name has.
    EXPECT_FALSE(s.take_report(Wire("batt", 1).frame, t0_));
    EXPECT_FALSE(s.take_report(Wire("mbl:a\"b", 1).frame, t0_));
    EXPECT_EQ(2u, s.counters().reports_received);
}

TEST_F(StandbyTest, GoesActiveAboveFailoverAndBackAfterFailbackWithHysteresis) {
    Standby s = make();
    TimePoint t = t0_ + seconds(1);
    s.take_report(Wire("mbl:radio", 50).frame, t);  // 5%: below 10%
    EXPECT_FALSE(s.judge(t));
    EXPECT_FALSE(s.active());
    t += milliseconds(500);
    s.take_report(Wire("mbl:radio", 150).frame, t);  // 15%
    EXPECT_TRUE(s.judge(t));
    EXPECT_TRUE(s.active());
    // Between the thresholds: stays active however long.
    for (int i = 0; i < 30; i++) {
        t += seconds(1);
        s.take_report(Wire("mbl:radio", 50).frame, t);
        EXPECT_FALSE(s.judge(t));
        EXPECT_TRUE(s.active());
    }
    // Below failback_loss: back once its average over failback_after is (the 5 % before it
    // weighs in: half of the last 10 s at 5 % is 2.5 %).
    TimePoint healthy = t + seconds(1);
    for (t = healthy; t < healthy + seconds(5); t += seconds(1)) {
        s.take_report(Wire("mbl:radio", 0).frame, t);
        s.judge(t);
        EXPECT_TRUE(s.active());
    }
    for (; s.active() && t < healthy + seconds(20); t += seconds(1)) {
        s.take_report(Wire("mbl:radio", 0).frame, t);
        s.judge(t);
    }
    EXPECT_FALSE(s.active());
    EXPECT_LE(t, healthy + seconds(10));
    EXPECT_EQ(1u, s.counters().to_active);
    EXPECT_EQ(1u, s.counters().to_standby);
}

TEST_F(StandbyTest, FailsBackOnTheAverageNotOnEveryWindow) {
    Standby s = make();
    TimePoint t = t0_ + seconds(1);
    s.take_report(Wire("mbl:radio", 1000).frame, t);
    EXPECT_TRUE(s.judge(t));
    // A 1 % link: windows of 0.4 % to 2.8 %, some above failback_loss (2 %), average 1.3 %.
    const int32_t windows[] = {4, 28, 8, 24, 12, 8, 20, 4, 16, 8, 4, 28};
    for (int32_t w : windows) {
        t += seconds(1);
        s.take_report(Wire("mbl:radio", w).frame, t);
        s.judge(t);
    }
    EXPECT_FALSE(s.active());
    EXPECT_EQ(1u, s.counters().to_standby);
}

TEST_F(StandbyTest, NoReportForTheTimeoutIsFailing) {
    Standby s = make();
    // A peer not heard yet is given time to start.
    EXPECT_FALSE(s.judge(t0_ + seconds(1)));
    TimePoint t = t0_ + seconds(6);
    s.take_report(Wire("mbl:radio", 0).frame, t);
    EXPECT_FALSE(s.judge(t + Standby::kReportTimeout));
    EXPECT_TRUE(s.judge(t + Standby::kReportTimeout + milliseconds(1)));
}

TEST_F(StandbyTest, MeasuresLossAndSilenceOfWhatItReceives) {
    Standby s = make();
    TimePoint t = t0_;
    for (int i = 0; i < 200; i++) {
        t += milliseconds(8);
        s.received(0, StreamStep{i, i % 10 == 0 ? 1 : 0, 0}, t);  // one lost in eleven
    }
    int32_t loss = s.measured_permille(0, t, t);
    EXPECT_NEAR(1000 / 11, loss, 3);
    // Silent after four usual gaps (8 ms), but no sooner than kMinSilence.
    EXPECT_NE(1000, s.measured_permille(0, t + milliseconds(200), t));
    EXPECT_EQ(1000, s.measured_permille(0, t + milliseconds(260), t));
    // One frame heard: its usual gap unknown, silent only after the longest wait.
    Standby once = make();
    once.received(0, StreamStep{0, 0, 0}, t0_ + seconds(1));
    EXPECT_EQ(0, once.measured_permille(0, t0_ + seconds(3), t0_ + seconds(1)));
    EXPECT_EQ(1000, once.measured_permille(0, t0_ + seconds(5), t0_ + seconds(1)));
    // Too few frames to judge: only silence counts.
    Standby sparse = make();
    sparse.received(0, StreamStep{0, 0, 0}, t0_ + seconds(1));
    sparse.received(0, StreamStep{2, 1, 0}, t0_ + seconds(2));
    EXPECT_EQ(0, sparse.measured_permille(0, t0_ + seconds(2), t0_ + seconds(2)));
}

TEST_F(StandbyTest, ReportsGoEverySecondAndAtOnceOnAChange) {
    Standby s = make();
    std::vector<TimePoint> heard{t0_, TimePoint{}};
    TimePoint t = t0_;
    for (int i = 0; i < 100; i++) {
        t += milliseconds(8);
        s.received(0, StreamStep{i, 0, 0}, t);
    }
    heard[0] = t;
    auto first = s.reports(t, heard);
    ASSERT_EQ(1u, first.size());  // the free member only
    EXPECT_EQ(0, std::strncmp(first[0].name.data(), "mbl:radio", 9));
    EXPECT_EQ(0, first[0].permille);
    EXPECT_TRUE(s.reports(t + milliseconds(100), heard).empty());  // nothing changed
    // Silent: reported at once.
    auto silent = s.reports(t + milliseconds(300), heard);
    ASSERT_EQ(1u, silent.size());
    EXPECT_EQ(1000, silent[0].permille);
}

TEST_F(StandbyTest, HeldFramesOfTheResendWindowGoOldestFirstOnce) {
    bond_.resend = seconds(1);
    Standby s = make();
    std::deque<Wire> frames;  // emplace_back moves none already there
    for (uint8_t i = 0; i < 30; i++)
        frames.emplace_back("mbl:x", i, i);
    for (uint8_t i = 0; i < 30; i++) {
        s.hold(1, frames[i].frame, i, t0_ + milliseconds(100) * i);
        s.hold(1, frames[i].frame, i, t0_ + milliseconds(100) * i);  // a second link: once
    }
    std::vector<uint8_t> seqs;
    s.take_held(t0_ + milliseconds(2900), [&](uint32_t member, std::span<const uint8_t> bytes) {
        EXPECT_EQ(1u, member);
        seqs.push_back(bytes[4]);
    });
    ASSERT_EQ(11u, seqs.size());  // 1.9 s .. 2.9 s
    EXPECT_EQ(19, seqs.front());
    EXPECT_EQ(29, seqs.back());
    s.take_held(t0_ + milliseconds(2900), [&](uint32_t, std::span<const uint8_t>) { FAIL(); });
}

TEST_F(StandbyTest, AReloadGoesOnFromWhatTheOldOneLearned) {
    bond_.resend = seconds(1);
    Standby old = make();
    TimePoint t = t0_ + seconds(1);
    old.take_report(Wire("mbl:radio", 1000).frame, t);  // the radio is silent
    ASSERT_TRUE(old.judge(t));
    std::deque<Wire> frames;
    for (uint8_t i = 0; i < 5; i++) {
        frames.emplace_back("mbl:x", i, i);
        old.hold(1, frames[i].frame, i, t);
    }
    // The reload changes the thresholds: the new standby is active at once (a fresh one would
    // withhold telemetry until the next report) and has what was held for a resend.
    bond_.failover_loss = 0.2;
    bond_.failback_after = seconds(3);
    Standby next = make();
    ASSERT_TRUE(next.continue_from(old));
    EXPECT_TRUE(next.active());
    EXPECT_TRUE(next.lets_send(1, kAttitude));
    EXPECT_EQ(1u, next.counters().to_active);
    ASSERT_EQ(1u, next.peer_links().size());
    EXPECT_FALSE(next.judge(t + milliseconds(100)));  // no second switch
    size_t held = 0;
    next.take_held(t, [&](uint32_t, std::span<const uint8_t>) { held++; });
    EXPECT_EQ(5u, held);
    // The radio is back: the new failback_after (3 s, not 10) decides.
    TimePoint back = t + seconds(1);
    for (t = back; next.active() && t < back + seconds(12); t += milliseconds(500)) {
        next.take_report(Wire("mbl:radio", 0).frame, t);
        next.judge(t);
    }
    EXPECT_FALSE(next.active());
    EXPECT_LE(t, back + seconds(4));
    // Other members: nothing is taken.
    EndpointConfig other;
    other.name = "radio2";
    Standby elsewhere(bond_, {&other, &lte_}, classes_, t0_);
    EXPECT_FALSE(elsewhere.continue_from(old));
    EXPECT_FALSE(elsewhere.active());
    EXPECT_EQ(0u, elsewhere.counters().to_active);
}

}  // namespace
}  // namespace mavbond
