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
    Wire(const std::string& name, int32_t value, uint8_t seq = 0, uint8_t compid = 191) {
        std::array<uint8_t, 18> payload{};
        std::memcpy(payload.data() + 4, &value, 4);
        std::memcpy(payload.data() + 8, name.data(), std::min<size_t>(name.size(), 10));
        size_t n = write_frame_v2(buf, FrameSource{1, compid, seq}, Standby::kMsgNamedValueInt,
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

TEST_F(StandbyTest, WhatNoFreeMemberMayCarryGoesOnTheMeteredOneInStandby) {
    // The air side keeps file transfers off its slow radio: in standby, the metered member is
    // the only link that may carry them (else every FTP reply is lost).
    radio_.filter_out.block = {kFtp};
    Standby s = make();
    EXPECT_TRUE(s.lets_send(1, kFtp));
    EXPECT_FALSE(s.lets_send(1, kAttitude));
    EXPECT_EQ("control; and FILE_TRANSFER_PROTOCOL, which no free member may carry (allow_out, "
              "block_out)",
              s.carried_in_standby(1));
    // Two free members: one that may carry it is enough.
    EndpointConfig radio2;
    radio2.name = "radio2";
    Standby two(bond_, {&radio_, &radio2, &lte_}, classes_, t0_);
    EXPECT_FALSE(two.lets_send(2, kFtp));
    EXPECT_EQ("control", two.carried_in_standby(2));
    // An allow list on every free member: whatever it leaves out.
    radio_.filter_out = {{kHeartbeat, kAttitude}, {}};
    Standby allow = make();
    EXPECT_TRUE(allow.lets_send(1, kFtp));
    EXPECT_FALSE(allow.lets_send(1, kAttitude));
    EXPECT_EQ("control; and any message no free member allows, which no free member may carry "
              "(allow_out, block_out)",
              allow.carried_in_standby(1));
}

TEST_F(StandbyTest, AReportIsTakenAndNamesTheLink) {
    Standby s = make();
    Wire w("mbl:radio", 25);
    ASSERT_TRUE(Standby::is_report(w.frame));
    s.take_report(0, w.frame, t0_);
    ASSERT_EQ(1u, s.peer_links().size());
    EXPECT_EQ("radio", s.peer_links()[0].name);
    EXPECT_EQ(25, s.peer_links()[0].permille);
    // Not a report: another prefix.
    EXPECT_FALSE(Standby::is_report(Wire("batt", 1).frame));
    EXPECT_EQ(1u, s.counters().reports_received);
}

TEST_F(StandbyTest, OnlyReportsOfTheBondsFreeMembersCountAndTheyExpire) {
    // 16 names no member has (once enough to fill the table for good), the metered member's
    // own, characters no endpoint name has: each a report, none judged, none kept.
    Standby s = make();
    for (int i = 0; i < 16; i++)
        s.take_report(0, Wire("mbl:x" + std::to_string(i), 0).frame, t0_);
    s.take_report(0, Wire("mbl:lte", 0).frame, t0_);
    s.take_report(0, Wire("mbl:a\"b", 0).frame, t0_);
    EXPECT_TRUE(s.peer_links().empty());
    EXPECT_EQ(18u, s.counters().reports_ignored);
    EXPECT_EQ(18u, s.counters().reports_received);
    // The real one still counts; the first six characters name a longer member ("radio_1").
    radio_.name = "radio_1";
    Standby t = make();
    t.take_report(0, Wire("mbl:radio_", 40).frame, t0_);
    ASSERT_EQ(1u, t.peer_links().size());
    EXPECT_EQ(40, t.peer_links()[0].permille);
    // Not reported for kPeerExpiry: forgotten (and judged as no report at all).
    t.judge(t0_ + Standby::kPeerExpiry);
    EXPECT_EQ(1u, t.peer_links().size());
    t.judge(t0_ + Standby::kPeerExpiry + milliseconds(100));
    EXPECT_TRUE(t.peer_links().empty());
}

TEST_F(StandbyTest, EachSideTellsTheOtherItsResend) {
    // The far side's resend decides how long this side's dedup must remember: until it says,
    // this side's own is the guess; what it says is taken (and consumed, not routed).
    bond_.resend = milliseconds(1500);
    Standby s = make();
    bool announced = true;
    EXPECT_EQ(Duration(milliseconds(1500)), s.peer_resend(&announced));
    EXPECT_FALSE(announced);
    Wire w("mbp:resend", 4000);
    ASSERT_TRUE(Standby::is_report(w.frame));
    s.take_report(0, w.frame, t0_);
    EXPECT_EQ(Duration(seconds(4)), s.peer_resend(&announced));
    EXPECT_TRUE(announced);
    EXPECT_TRUE(s.peer_links().empty()) << "no link named 'resend'";
    // This side's goes with the first reports, then every kAnnounceEvery (it costs metered bytes).
    auto first = s.resend_announcement(t0_);
    ASSERT_TRUE(first);
    EXPECT_EQ(0, std::memcmp(first->name.data(), "mbp:resend", 10));
    EXPECT_EQ(1500, first->permille);
    EXPECT_FALSE(s.resend_announcement(t0_ + seconds(9)));
    EXPECT_TRUE(s.resend_announcement(t0_ + seconds(10)));
    // A reload goes on with what the peer said.
    Standby t = make();
    ASSERT_TRUE(t.continue_from(s));
    EXPECT_EQ(Duration(seconds(4)), t.peer_resend());
}

TEST_F(StandbyTest, GoesActiveAboveFailoverAndBackAfterFailbackWithHysteresis) {
    Standby s = make();
    TimePoint t = t0_ + seconds(1);
    s.take_report(0, Wire("mbl:radio", 50).frame, t);  // 5%: below 10%
    EXPECT_FALSE(s.judge(t));
    EXPECT_FALSE(s.active());
    t += milliseconds(500);
    s.take_report(0, Wire("mbl:radio", 150).frame, t);  // 15%
    EXPECT_TRUE(s.judge(t));
    EXPECT_TRUE(s.active());
    // Between the thresholds: stays active however long.
    for (int i = 0; i < 30; i++) {
        t += seconds(1);
        s.take_report(0, Wire("mbl:radio", 50).frame, t);
        EXPECT_FALSE(s.judge(t));
        EXPECT_TRUE(s.active());
    }
    // Below failback_loss: back once its average over failback_after is (the 5 % before it
    // weighs in: half of the last 10 s at 5 % is 2.5 %).
    TimePoint healthy = t + seconds(1);
    for (t = healthy; t < healthy + seconds(5); t += seconds(1)) {
        s.take_report(0, Wire("mbl:radio", 0).frame, t);
        s.judge(t);
        EXPECT_TRUE(s.active());
    }
    for (; s.active() && t < healthy + seconds(20); t += seconds(1)) {
        s.take_report(0, Wire("mbl:radio", 0).frame, t);
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
    s.take_report(0, Wire("mbl:radio", 1000).frame, t);
    EXPECT_TRUE(s.judge(t));
    // A 1 % link: windows of 0.4 % to 2.8 %, some above failback_loss (2 %), average 1.3 %.
    const int32_t windows[] = {4, 28, 8, 24, 12, 8, 20, 4, 16, 8, 4, 28};
    for (int32_t w : windows) {
        t += seconds(1);
        s.take_report(0, Wire("mbl:radio", w).frame, t);
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
    s.take_report(0, Wire("mbl:radio", 0).frame, t);
    EXPECT_FALSE(s.judge(t + Standby::kReportTimeout));
    EXPECT_TRUE(s.judge(t + Standby::kReportTimeout + milliseconds(1)));
}

TEST_F(StandbyTest, MeasuresLossAndSilenceOfWhatItReceives) {
    Standby s = make();
    TimePoint t = t0_;
    for (int i = 0; i < 500; i++) {
        t += milliseconds(8);
        s.received(0, StreamStep{i, i % 10 == 0 ? 1 : 0, 0}, t);  // one lost in eleven
        // A far side that sends no count markers: its sequence gaps, once they were waited for.
        if (t - t0_ < Standby::kAwaitMarkers) {
            EXPECT_EQ(0, s.measured_permille(0, t, t));
        }
    }
    int32_t loss = s.measured_permille(0, t, t);
    EXPECT_NEAR(1000 / 11, loss, 3);
    // Too few frames to judge: only silence counts.
    Standby sparse = make();
    sparse.received(0, StreamStep{0, 0, 0}, t0_ + seconds(1));
    sparse.received(0, StreamStep{2, 1, 0}, t0_ + seconds(2));
    EXPECT_EQ(0, sparse.measured_permille(0, t0_ + seconds(2), t0_ + seconds(2)));
}

// Silence is LinkSilence's (its own tests): what the standby reports of a free member is what
// it judges with standby's bounds, the far side's reports as they came on each member.
TEST_F(StandbyTest, ReportsSilenceAsTheLinksJudgeIt) {
    Standby s = make();
    TimePoint t = t0_;
    std::vector<TimePoint> heard{TimePoint{}, TimePoint{}};
    uint8_t seq = 0;
    auto second = [&](bool radio_frames, bool radio_reports) {
        for (int i = 0; i < 10; i++) {
            t += milliseconds(100);
            if (i == 0) {  // the far side's report, on every member
                Wire w("mbl:radio", 0, seq++);
                s.take_report(1, w.frame, t);
                heard[1] = t;
                if (radio_reports) {
                    s.take_report(0, w.frame, t);
                    heard[0] = t;
                }
            }
            if (radio_frames)
                heard[0] = t;
            s.reports(t, heard);
        }
        return s.measured_permille(0, t, heard[0]);
    };
    for (int i = 0; i < 10; i++)
        EXPECT_EQ(0, second(true, true));
    // The far side has nothing to send for 3 s (an autopilot's pause): its reports still come.
    for (int i = 0; i < 3; i++)
        EXPECT_EQ(0, second(false, true)) << i;
    EXPECT_EQ(0, second(true, true));
    // Cut: the report that came on LTE is not on the radio.
    EXPECT_EQ(1000, second(false, false));
    EXPECT_EQ(LinkSilence::Verdict::By::Evidence,
              s.silence().judge(0, heard[0], t, Standby::kMinSilence, Standby::kMaxSilence).by);
}

// Found with two gateways started a second apart: the later one's radio was reported silent,
// 3 s after the first one started, before its first frame could come, and the metered link
// went active for failback_after at every start.
TEST_F(StandbyTest, ALinkNeverHeardIsSilentOnlyOnceThePeerHadTimeToUseIt) {
    Standby s = make();
    const TimePoint peer_up = t0_ + milliseconds(2500);  // its first frame, over the LTE link
    s.heard({TimePoint{}, peer_up}, peer_up);
    EXPECT_EQ(0, s.measured_permille(0, t0_ + milliseconds(3100), TimePoint{}));
    EXPECT_EQ(0, s.measured_permille(0, peer_up + Standby::kMaxSilence, TimePoint{}));
    EXPECT_EQ(1000, s.measured_permille(0, peer_up + Standby::kMaxSilence + milliseconds(1),
                                         TimePoint{}));
    // Nothing of the peer at all: counted from our own start.
    Standby alone = make();
    EXPECT_EQ(1000, alone.measured_permille(0, t0_ + Standby::kMaxSilence + milliseconds(1),
                                            TimePoint{}));
}

// A radio whose far side's budget thins half of what is routed to it: its sequence numbers
// show 50 % gaps, its count markers say it lost 1 % of what it was given. Judged by those.
TEST_F(StandbyTest, ALinkIsJudgedByWhatItsFarSideWroteOnIt) {
    Standby s = make();
    TimePoint t = t0_;
    uint64_t written = 0, arrived = 0;
    for (int i = 0; i < 400; i++) {
        t += milliseconds(10);
        s.received(0, StreamStep{2 * i, 1, 0}, t);  // every other position skipped
        written += 1;
        arrived += i % 100 == 7 ? 0 : 1;
        if (i % 100 == 99)  // a marker a second
            s.accounted(0, Standby::Account{written, arrived, t});
    }
    EXPECT_EQ(10, s.measured_permille(0, t, t));  // 2 of the last 200 frames written
    // Markers that stop (the far side no longer counts): its sequence gaps again.
    for (int i = 400; i < 900; i++) {
        t += milliseconds(10);
        s.received(0, StreamStep{2 * i, 1, 0}, t);
    }
    EXPECT_EQ(500, s.measured_permille(0, t, t));
}

TEST_F(StandbyTest, ReportsGoEverySecondAndAtOnceOnAChange) {
    Standby s = make();
    std::vector<TimePoint> heard{TimePoint{}, TimePoint{}};
    TimePoint t = t0_;
    std::vector<Standby::Report> first;
    for (int i = 0; i < 100; i++) {
        t += milliseconds(8);
        s.received(0, StreamStep{i, 0, 0}, t);
        if (i % 12 == 0) {  // a tick
            heard[0] = t;
            first = s.reports(t, heard);
            if (i == 0) {
                ASSERT_EQ(1u, first.size());  // the free member only
                EXPECT_EQ(0, std::strncmp(first[0].name.data(), "mbl:radio", 9));
                EXPECT_EQ(0, first[0].permille);
            }
        }
    }
    EXPECT_TRUE(first.empty()) << "nothing changed within the second";
    // Silent (nothing from the far side to go by: its gaps alone): reported at once.
    TimePoint quiet = t;
    for (; quiet < t + Standby::kMaxSilence; quiet += Standby::kTick) {
        auto r = s.reports(quiet, heard);
        if (!r.empty() && r[0].permille == 1000)
            break;
    }
    EXPECT_LT(quiet, t + Standby::kMaxSilence);
    EXPECT_EQ(1000, s.measured_permille(0, quiet, heard[0]));
}

TEST_F(StandbyTest, HeldFramesOfTheResendWindowGoOldestFirstOnce) {
    bond_.resend = seconds(1);
    Standby s = make();
    std::deque<Wire> frames;  // emplace_back moves none already there
    for (uint8_t i = 0; i < 30; i++)
        frames.emplace_back("mbl:x", i, i);
    for (uint8_t i = 0; i < 30; i++) {
        s.hold(1, frames[i].frame, i, i + 1, t0_ + milliseconds(100) * i);
        s.hold(1, frames[i].frame, i, i + 1, t0_ + milliseconds(100) * i);  // a second link: once
    }
    std::vector<uint8_t> seqs;
    s.take_held(t0_ + milliseconds(2900), [&](uint32_t member, std::span<const uint8_t> bytes, uint64_t) {
        EXPECT_EQ(1u, member);
        seqs.push_back(bytes[4]);
    });
    ASSERT_EQ(11u, seqs.size());  // 1.9 s .. 2.9 s
    EXPECT_EQ(19, seqs.front());
    EXPECT_EQ(29, seqs.back());
    s.take_held(t0_ + milliseconds(2900), [&](uint32_t, std::span<const uint8_t>, uint64_t) { FAIL(); });
}

TEST_F(StandbyTest, AResendReachesNoFurtherBackThanTheFarSideCanPlaceIt) {
    // The metered member carried source 1/191 from routing 50 on (a control frame): nothing of
    // it from before goes again (the far side would take those for repeats, then for a
    // restarted counter), and of the rest the newest kResendPerSource (a step back of more
    // than 127 reads as one forward). Source 1/192, never on the member, goes whole.
    bond_.resend = seconds(3);
    Standby s = make();
    std::deque<Wire> frames;
    for (int i = 0; i < 250; i++)
        frames.emplace_back("x", i, static_cast<uint8_t>(i));
    for (int i = 0; i < 10; i++)
        frames.emplace_back("y", 1000 + i, static_cast<uint8_t>(i), 192);
    s.sent(1, frames[0].frame, 50);
    s.sent(1, frames[0].frame, 60);  // only the first counts
    for (int i = 0; i < 250; i++)
        s.hold(1, frames[i].frame, i, i + 1, t0_ + milliseconds(10) * i);
    for (int i = 0; i < 10; i++)
        s.hold(1, frames[250 + i].frame, 250 + i, 251 + i, t0_ + milliseconds(10) * (250 + i));
    std::vector<int32_t> got;
    s.take_held(t0_ + milliseconds(2600), [&](uint32_t, std::span<const uint8_t> bytes, uint64_t) {
        int32_t v;
        std::memcpy(&v, bytes.data() + kHeaderLenV2 + 4, 4);
        got.push_back(v);
    });
    ASSERT_EQ(static_cast<size_t>(Standby::kResendPerSource + 10), got.size());
    EXPECT_EQ(250 - Standby::kResendPerSource, got.front()) << "the newest of 1/191, oldest first";
    EXPECT_EQ(249, got[Standby::kResendPerSource - 1]);
    EXPECT_EQ(1000, got[Standby::kResendPerSource]);
    EXPECT_EQ(1009, got.back());
    EXPECT_EQ(static_cast<uint64_t>(200 - Standby::kResendPerSource), s.counters().resend_skipped);
}

TEST_F(StandbyTest, AReloadGoesOnFromWhatTheOldOneLearned) {
    bond_.resend = seconds(1);
    Standby old = make();
    TimePoint t = t0_ + seconds(1);
    old.take_report(0, Wire("mbl:radio", 1000).frame, t);  // the radio is silent
    ASSERT_TRUE(old.judge(t));
    std::deque<Wire> frames;
    for (uint8_t i = 0; i < 5; i++) {
        frames.emplace_back("mbl:x", i, i);
        old.hold(1, frames[i].frame, i, i + 1, t);
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
    next.take_held(t, [&](uint32_t, std::span<const uint8_t>, uint64_t) { held++; });
    EXPECT_EQ(5u, held);
    // The radio is back: the new failback_after (3 s, not 10) decides.
    TimePoint back = t + seconds(1);
    for (t = back; next.active() && t < back + seconds(12); t += milliseconds(500)) {
        next.take_report(0, Wire("mbl:radio", 0).frame, t);
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
