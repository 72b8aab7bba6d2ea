// The one rule of link silence (routing/link_silence.h) on a manual clock: a gap is silence
// only when the far side evidently wrote on the link meanwhile (a report it sends on every
// member came on another and not here), else the gaps alone.
#include "routing/link_silence.h"

#include <gtest/gtest.h>

#include <utility>
#include <string>
#include <vector>

namespace mavbond {
namespace {

constexpr Duration kLeast = milliseconds(250), kMost = seconds(3);  // standby's bounds
constexpr uint32_t kRadio = 0, kLte = 1;

/// Two members (radio, lte) on 100 ms ticks: each tick the links flagged bring a frame, and
/// every second (at `report_at` within it) the far side's report comes on the links flagged
/// for it, each copy `lag` after the first (`lte_first`: LTE's is the first).
class LinkSilenceTest : public ::testing::Test {
protected:
    struct Links {
        bool radio = true, lte = true;
        bool radio_report = true, lte_report = true;
    };

    /// Runs `ticks` ticks; returns the first tick's time at which `member` was judged silent
    /// (epoch: never) with standby's bounds.
    TimePoint run(int ticks, Links on, uint32_t member = kRadio,
                  Duration radio_lag = milliseconds(0)) {
        TimePoint first_silent{};
        for (int i = 0; i < ticks; i++) {
            now_ += milliseconds(100);
            if (on.radio)
                heard_[kRadio] = now_;
            if (on.lte && tick_ % 5 == 0)  // a sparse link: a frame every half second
                heard_[kLte] = now_;
            if (tick_ % 10 == 0) {
                seq_++;
                if (on.lte_report) {
                    s_.report(kLte, FrameSource{1, 191, seq_}, now_);
                    heard_[kLte] = now_;
                }
                if (on.radio_report)
                    late_.push_back({now_ + radio_lag, seq_});
            }
            // The radio's copies as they come, `radio_lag` after LTE's.
            while (!late_.empty() && late_.front().first <= now_) {
                s_.report(kRadio, FrameSource{1, 191, late_.front().second}, late_.front().first);
                heard_[kRadio] = std::max(heard_[kRadio], late_.front().first);
                late_.erase(late_.begin());
            }
            tick_++;
            s_.heard(kRadio, heard_[kRadio], now_);
            s_.heard(kLte, heard_[kLte], now_);
            if (first_silent == TimePoint{} && judge(member).silent) {
                first_silent = now_;
                at_silence_ = judge(member);
            }
        }
        return first_silent;
    }
    LinkSilence::Verdict judge(uint32_t member) const {
        return s_.judge(member, heard_[member], now_, kLeast, kMost);
    }

    TimePoint now_ = TimePoint{} + seconds(100);
    LinkSilence s_{{"radio", "lte"}, now_};
    std::vector<TimePoint> heard_{TimePoint{}, TimePoint{}};
    std::vector<std::pair<TimePoint, uint8_t>> late_;
    LinkSilence::Verdict at_silence_;  // the verdict when run() first found it silent
    int tick_ = 0;
    uint8_t seq_ = 0;
};

// The healthy SITL run: ArduCopter paused its stream for up to 1.36 s now and then, the radio
// had nothing to carry, and the ground reported it silent (35 link events in 10 minutes, the
// metered link out of standby each time). Its far side's reports still came on it.
TEST_F(LinkSilenceTest, AFarSideWithNothingToSendIsNoSilence) {
    EXPECT_EQ(TimePoint{}, run(300, {}));
    // The vehicle pauses for 1.5 s, then 6 s: only the far side's reports come on the radio.
    EXPECT_EQ(TimePoint{}, run(15, {.radio = false}));
    EXPECT_EQ(TimePoint{}, run(20, {}));
    EXPECT_EQ(TimePoint{}, run(60, {.radio = false}));
    const LinkSilence::Verdict v = judge(kRadio);
    EXPECT_EQ(LinkSilence::Verdict::By::Evidence, v.by);
    EXPECT_FALSE(v.silent);
}

TEST_F(LinkSilenceTest, ALinkThatMissesAReportIsSilentOnceItsLagPassed) {
    run(300, {});
    const TimePoint cut = now_;
    const TimePoint silent = run(30, {.radio = false, .radio_report = false});
    ASSERT_NE(TimePoint{}, silent);
    // The next report came on LTE within the second; the radio's own lag (none) plus the slack.
    EXPECT_LE(silent - cut, seconds(1) + LinkSilence::kLagSlack + milliseconds(100));
    EXPECT_GE(silent - cut, LinkSilence::kLagSlack);
    const LinkSilence::Verdict v = at_silence_;
    EXPECT_TRUE(v.silent);
    EXPECT_EQ(LinkSilence::Verdict::By::Evidence, v.by);
    EXPECT_EQ(kLte, v.witness);
    EXPECT_NE(std::string::npos, s_.explain(v).find("the far side's report on lte")) << s_.explain(v);
    // Back at its first frame.
    run(1, {});
    EXPECT_FALSE(judge(kRadio).silent);
}

TEST_F(LinkSilenceTest, ALinkThatUsuallyLagsIsWaitedFor) {
    // The radio's copies of the reports come 600 ms after LTE's (a full radio buffer).
    run(300, {}, kRadio, milliseconds(600));
    EXPECT_EQ(Duration(milliseconds(850)), s_.allowed_lag(kRadio));
    EXPECT_EQ(Duration(LinkSilence::kLagSlack), s_.allowed_lag(kLte));
    // Paused: its copies still come, as late as ever: no silence.
    EXPECT_EQ(TimePoint{}, run(50, {.radio = false}, kRadio, milliseconds(600)));
    // Cut: silent 850 ms after the first report it missed.
    const TimePoint silent = run(30, {.radio = false, .radio_report = false});
    ASSERT_NE(TimePoint{}, silent);
    EXPECT_EQ(Duration(milliseconds(900)), at_silence_.witness_age)
        << "seen at the tick after 850 ms";
}

TEST_F(LinkSilenceTest, OneLostReportOnASparseLinkIsNoSilence) {
    // LTE brings a frame every half second with the reports: one frame lost (a report) leaves
    // a gap of a second, within three of its usual half-second gaps.
    run(300, {});
    EXPECT_EQ(Duration(milliseconds(500)), s_.usual_gap(kLte));
    EXPECT_EQ(TimePoint{}, run(5, {.lte = false, .lte_report = false}, kLte));
    EXPECT_EQ(TimePoint{}, run(20, {}, kLte));
    EXPECT_EQ(Duration(seconds(1)), s_.usual_gap(kLte)) << "a loss's gap is a usual one";
    // Cut: silent after three of them, a report it missed long overdue by then.
    ASSERT_NE(TimePoint{}, run(40, {.lte = false, .lte_report = false}, kLte));
    const LinkSilence::Verdict v = at_silence_;
    EXPECT_EQ(Duration(seconds(3)), v.quiet);
    EXPECT_EQ(LinkSilence::Verdict::By::Evidence, v.by);
    EXPECT_EQ(kRadio, v.witness);
}

TEST_F(LinkSilenceTest, WithNothingToGoByTheGapsDecideAndTheSilenceStays) {
    run(300, {});
    // Both links cut: no report anywhere. The radio is silent kEvidenceTimeout after the last
    // report (its gaps said so long before); LTE after its own gaps.
    const TimePoint cut = now_;
    const TimePoint silent = run(40, {false, false, false, false});
    ASSERT_NE(TimePoint{}, silent);
    EXPECT_LE(silent - cut, LinkSilence::kEvidenceTimeout);
    EXPECT_GT(silent - (cut - milliseconds(900)), LinkSilence::kEvidenceTimeout)
        << "the last report came 900 ms before the cut";
    EXPECT_EQ(LinkSilence::Verdict::By::NoEvidence, judge(kRadio).by);
    EXPECT_TRUE(judge(kLte).silent);
    // LTE comes back with a report: the radio, still cut, stays silent (no tick of it heard).
    for (int i = 0; i < 15; i++) {
        run(1, {.radio = false, .lte = true, .radio_report = false, .lte_report = true});
        EXPECT_TRUE(judge(kRadio).silent) << "tick " << i;
    }
    EXPECT_FALSE(judge(kLte).silent);
}

TEST(LinkSilence, ALoneLinkIsJudgedByItsGaps) {
    // A side that hears the ground about once a second, each frame up to 300 ms late.
    TimePoint now = TimePoint{} + seconds(100), heard{};
    LinkSilence s({"sik"}, now);
    for (int tick = 0; tick < 6000; tick++) {
        now += milliseconds(100);
        const int in_second = static_cast<int>((now.time_since_epoch() / milliseconds(100)) % 10);
        const int late = static_cast<int>((now.time_since_epoch() / seconds(1)) % 4);  // 0..300 ms
        if (in_second == late)
            heard = now;
        s.heard(0, heard, now);
        EXPECT_FALSE(s.judge(0, heard, now, seconds(1), seconds(10)).silent) << tick;
    }
    EXPECT_EQ(Duration(milliseconds(1100)), s.usual_gap(0));  // a second, each 100 ms later
    const TimePoint last = heard;
    LinkSilence::Verdict v;
    while (!(v = s.judge(0, last, now, seconds(1), seconds(10))).silent) {
        now += milliseconds(100);
        s.heard(0, last, now);
    }
    EXPECT_EQ(Duration(milliseconds(3300)), v.quiet);
    EXPECT_EQ(LinkSilence::Verdict::By::NoEvidence, v.by);
    // The outage's gap is no usual gap.
    now += seconds(10);
    s.heard(0, now, now);
    EXPECT_EQ(Duration(milliseconds(1100)), s.usual_gap(0));
}

TEST(LinkSilence, TheGapsAreBounded) {
    TimePoint now = TimePoint{} + seconds(100);
    LinkSilence s({"l"}, now);
    auto quiet_when_silent = [&](Duration least, Duration most) {
        const TimePoint last = now;
        TimePoint t = now;
        while (!s.judge(0, last, t, least, most).silent)
            t += milliseconds(100);
        return t - last;
    };
    // Until a few gaps are seen, a HEARTBEAT's period is assumed.
    s.heard(0, now, now);
    EXPECT_EQ(Duration(seconds(3)), quiet_when_silent(milliseconds(500), seconds(10)));
    // A link that carries a frame every 5 s is lost after `most` at most.
    for (int i = 0; i < 5; i++) {
        now += seconds(5);
        s.heard(0, now, now);
    }
    EXPECT_EQ(Duration(seconds(10)), quiet_when_silent(milliseconds(500), seconds(10)));
    // One that carries much, after `least` at least.
    for (int i = 0; i < 700; i++) {
        now += milliseconds(100);
        s.heard(0, now, now);
    }
    EXPECT_EQ(Duration(milliseconds(500)), quiet_when_silent(milliseconds(500), seconds(10)));
}

// Found with two gateways started a second apart: the later one's radio was reported silent,
// 3 s after the first one started, before its first frame could come, and the metered link
// went active for failback_after at every start.
TEST(LinkSilence, AMemberNeverHeardIsSilentOnlyOnceTheFarSideHadTimeToUseIt) {
    const TimePoint t0 = TimePoint{} + seconds(100);
    LinkSilence s({"radio", "lte"}, t0);
    const TimePoint peer_up = t0 + milliseconds(2500);  // its first frame, over the LTE link
    s.heard(kLte, peer_up, peer_up);
    EXPECT_FALSE(s.judge(kRadio, TimePoint{}, t0 + milliseconds(3100), kLeast, kMost).silent);
    EXPECT_FALSE(s.judge(kRadio, TimePoint{}, peer_up + kMost, kLeast, kMost).silent);
    const auto v = s.judge(kRadio, TimePoint{}, peer_up + kMost + milliseconds(1), kLeast, kMost);
    EXPECT_TRUE(v.silent);
    EXPECT_EQ(LinkSilence::Verdict::By::NeverHeard, v.by);
    // Nothing of the far side at all: counted from the start.
    LinkSilence alone({"radio", "lte"}, t0);
    EXPECT_TRUE(alone.judge(kRadio, TimePoint{}, t0 + kMost + milliseconds(1), kLeast, kMost).silent);
}

TEST(LinkSilence, AReportsCopiesAreKnownByTheirSourceAndNumber) {
    // The radio's last frame was a report of 1/192 numbered 7; 1/191's number 7, on LTE, is
    // another report, which the radio did not bring. Had it brought that one, nothing is due.
    const TimePoint t0 = TimePoint{} + seconds(100);
    for (uint8_t radio_has : {192, 191}) {
        LinkSilence s({"radio", "lte"}, t0);
        TimePoint now = t0;
        for (int i = 1; i <= 50; i++) {
            now += milliseconds(100);
            if (i % 10 == 0) {  // reports on both, at once: neither lags
                s.report(kLte, FrameSource{1, 191, static_cast<uint8_t>(i / 10)}, now);
                s.report(kRadio, FrameSource{1, 191, static_cast<uint8_t>(i / 10)}, now);
            }
            s.heard(kRadio, now, now);
            s.heard(kLte, now, now);
        }
        const TimePoint last = now;
        s.report(kRadio, FrameSource{1, radio_has, 7}, last);
        s.report(kLte, FrameSource{1, 191, 7}, last + milliseconds(50));
        const TimePoint due = last + milliseconds(50) + LinkSilence::kLagSlack;
        EXPECT_FALSE(s.judge(kRadio, last, due - milliseconds(1), kLeast, kMost).silent);
        EXPECT_EQ(radio_has == 192, s.judge(kRadio, last, due, kLeast, kMost).silent);
    }
}

}  // namespace
}  // namespace mavbond
