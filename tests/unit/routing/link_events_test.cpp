// The link-event rules on a manual clock: detection from arrival times, severities, texts,
// and the rate limit counted exactly.
#include "routing/link_events.h"

#include <gtest/gtest.h>

#include <optional>
#include <string>
#include <vector>

namespace mavbond {
namespace {

/// A bond without standby, as the monitor has it: its links judged by their gaps alone.
class LinkEventsTest : public ::testing::Test {
protected:
    LinkEventsTest() : ev_(milliseconds(1000), milliseconds(2000)) {
        bond_ = ev_.add_bond("telemetry");
        radio_ = ev_.add_link(bond_, "radio");
        lte_ = ev_.add_link(bond_, "lte");
    }

    /// Advances the clock in 100 ms ticks for `ms`, the links whose flag is set receiving a
    /// frame each tick; collects every notice and event.
    void run(int ms, bool radio_up, bool lte_up) {
        for (int t = 0; t < ms; t += 100) {
            now_ += milliseconds(100);
            if (radio_up)
                radio_heard_ = now_;
            if (lte_up)
                lte_heard_ = now_;
            observe(radio_, radio_heard_);
            observe(lte_, lte_heard_);
            ev_.observe_bond(bond_, active_, switches_, now_);
            auto out = ev_.poll(now_);
            for (auto& n : out.notices) {
                notices_.push_back(n);
                notice_times_.push_back(now_);
            }
            events_.insert(events_.end(), out.events.begin(), out.events.end());
        }
    }
    void observe(uint32_t link, TimePoint last) {
        silence_.heard(link, last, now_);
        const auto v = silence_.judge(link, last, now_, ev_.least_silence(), ev_.most_silence());
        ev_.observe_link(link, last, v.silent, now_);
    }

    LinkEvents ev_;
    uint32_t bond_, radio_, lte_;
    TimePoint now_ = TimePoint{} + seconds(1000);
    LinkSilence silence_{{"radio", "lte"}, now_};
    TimePoint radio_heard_{}, lte_heard_{};  // epoch: never
    uint64_t switches_ = 0;
    std::string active_;
    std::vector<LinkEvents::Notice> notices_;
    std::vector<TimePoint> notice_times_;
    std::vector<std::string> events_;
};

TEST_F(LinkEventsTest, FirstHeardIsLoggedNotAnnounced) {
    run(3000, true, true);
    EXPECT_TRUE(notices_.empty());
    ASSERT_EQ(2u, events_.size());
    EXPECT_EQ("link radio up (bond telemetry, 1 of 2 up)", events_[0]);
}

TEST_F(LinkEventsTest, LostThenBackWithSeverities) {
    run(3000, true, true);
    TimePoint stopped = now_;
    run(3000, true, false);
    ASSERT_EQ(1u, notices_.size());
    EXPECT_EQ(Severity::Warning, notices_[0].severity);
    EXPECT_EQ("mavbond: link lte lost (bond telemetry, 1 of 2 up)", notices_[0].text);
    // Silent for a second, seen at the next 100 ms tick at most.
    EXPECT_GE(notice_times_[0] - stopped, milliseconds(1000));
    EXPECT_LE(notice_times_[0] - stopped, milliseconds(1100));
    run(3000, true, true);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ(Severity::Notice, notices_[1].severity);
    EXPECT_EQ("mavbond: link lte back (bond telemetry, 2 of 2 up)", notices_[1].text);
}

TEST_F(LinkEventsTest, LastLinkLostIsCritical) {
    run(3000, true, true);
    run(3000, false, true);
    run(3000, false, false);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ(Severity::Warning, notices_[0].severity);
    EXPECT_EQ("mavbond: radio lost (telemetry 1/2 up)", notices_[0].text) << "52 characters in full";
    EXPECT_EQ(Severity::Critical, notices_[1].severity);
    EXPECT_EQ("mavbond: link lte lost (bond telemetry, 0 of 2 up)", notices_[1].text);
}

TEST_F(LinkEventsTest, FlappingThatEndsAsAnnouncedSaysNothingMore) {
    run(3000, true, true);
    run(1100, true, false);  // lte lost: announced at once
    ASSERT_EQ(1u, notices_.size());
    run(300, true, true);    // back, then lost again, within the 2 s that follow
    run(1100, true, false);
    run(3000, true, false);
    EXPECT_EQ(1u, notices_.size()) << "lost-back-lost is no news";
    EXPECT_EQ(5u, events_.size()) << "every change is logged: up, up, lost, back, lost";
}

TEST_F(LinkEventsTest, FlappingThatEndsUpSaysBackOnceWhenTheIntervalEnds) {
    run(3000, true, true);
    run(1100, true, false);
    ASSERT_EQ(1u, notices_.size());
    TimePoint first = notice_times_[0];
    run(300, true, true);
    run(1100, true, false);
    run(3000, true, true);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ("mavbond: link lte back (bond telemetry, 2 of 2 up)", notices_[1].text);
    EXPECT_EQ(milliseconds(2000), notice_times_[1] - first);
}

TEST_F(LinkEventsTest, HeldChangeIsSentWhenTheIntervalEnds) {
    run(3000, true, true);
    run(1100, true, false);  // lost, announced at t0
    TimePoint t0 = notice_times_.at(0);
    run(200, true, true);    // back 0.2 s later: held
    EXPECT_EQ(1u, notices_.size());
    run(2000, true, true);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ(milliseconds(2000), notice_times_[1] - t0) << "sent the tick the interval ended";
}

TEST_F(LinkEventsTest, SwitchIsAnnouncedTheFirstChoiceIsNot) {
    active_ = "radio";
    switches_ = 1;
    run(1000, true, true);
    EXPECT_TRUE(notices_.empty());
    active_ = "lte";
    switches_ = 2;
    run(100, true, true);
    ASSERT_EQ(1u, notices_.size());
    EXPECT_EQ(Severity::Warning, notices_[0].severity);
    EXPECT_EQ("mavbond: bond telemetry switched to lte", notices_[0].text);
    // Two switches within the interval that end where the last notice said: nothing more.
    active_ = "radio";
    switches_ = 3;
    run(100, true, true);
    active_ = "lte";
    switches_ = 4;
    run(3000, true, true);
    EXPECT_EQ(1u, notices_.size());
}

TEST(LinkEvents, GlobalCapHoldsTheRestOldestFirst) {
    LinkEvents ev(milliseconds(500), seconds(10));
    uint32_t bond = ev.add_bond("b");
    std::vector<uint32_t> links;
    for (int i = 0; i < 8; i++)
        links.push_back(ev.add_link(bond, "l" + std::to_string(i)));
    TimePoint now = TimePoint{} + seconds(100);
    // Heard for a while, then all silent at once.
    for (int tick = 0; tick < 5; tick++) {
        now += milliseconds(100);
        for (uint32_t l : links)
            ev.observe_link(l, now, false, now);
    }
    const TimePoint heard = now;
    ev.poll(now);
    // Announced in link order, five now, three 10 s later.
    std::vector<std::string> sent;
    for (int tick = 1; tick <= 120; tick++) {
        now += milliseconds(100);
        for (uint32_t l : links)
            ev.observe_link(l, heard, tick >= 5, now);
        for (auto& n : ev.poll(now).notices)
            sent.push_back(n.text);
        if (tick == 20) {
            EXPECT_EQ(LinkEvents::kGlobalBurst, sent.size()) << "five within min_interval";
        }
    }
    ASSERT_EQ(8u, sent.size()) << "the other three after the interval";
    EXPECT_NE(std::string::npos, sent[5].find("link l5 lost"));
    EXPECT_NE(std::string::npos, sent[7].find("0 of 8 up"));
}

TEST(LinkEvents, ALinkFollowingTheTrafficItCarriesIsOneLostOneBack) {
    // A vehicle's side hears the ground about once a second, each frame up to 300 ms late:
    // with silence fixed at silent_after (1 s) the link flapped (458 events in 14 minutes).
    // Judged by its usual gaps: none in ten minutes; a 10 s cut is one lost, one back.
    LinkEvents ev(seconds(1), seconds(2));
    uint32_t bond = ev.add_bond("vehicle");
    uint32_t link = ev.add_link(bond, "sik");
    TimePoint now = TimePoint{} + seconds(100), heard{};
    LinkSilence silence({"sik"}, now);
    std::vector<std::string> notices, events;
    auto run = [&](int seconds_, bool up) {
        for (int tick = 0; tick < seconds_ * 10; tick++) {
            now += milliseconds(100);
            const int in_second = static_cast<int>((now.time_since_epoch() / milliseconds(100)) % 10);
            const int late = static_cast<int>((now.time_since_epoch() / seconds(1)) % 4);  // 0..300 ms
            if (up && in_second == late)
                heard = now;
            silence.heard(0, heard, now);
            const auto v = silence.judge(0, heard, now, ev.least_silence(), ev.most_silence());
            ev.observe_link(link, heard, v.silent, now);
            auto out = ev.poll(now);
            for (auto& n : out.notices)
                notices.push_back(n.text);
            events.insert(events.end(), out.events.begin(), out.events.end());
        }
    };
    run(600, true);
    EXPECT_TRUE(notices.empty()) << notices.front();
    ASSERT_EQ(1u, events.size()) << events.back();  // first heard
    run(10, false);
    run(60, true);
    ASSERT_EQ(2u, notices.size());
    EXPECT_EQ("mavbond: link sik lost (bond vehicle, 0 of 1 up)", notices[0]);
    EXPECT_EQ("mavbond: link sik back (bond vehicle, 1 of 1 up)", notices[1]);
}

/// The ground side of the shipped pair: what it receives comes from the vehicle (downlink);
/// what the vehicle's side receives (uplink), the far side's standby reports say.
class BothWaysTest : public ::testing::Test {
protected:
    BothWaysTest() : ev_(seconds(1), seconds(2)) {
        bond_ = ev_.add_bond("vehicle");
        sik_ = ev_.add_link(bond_, "sik");
        lte_ = ev_.add_link(bond_, "lte");
        ev_.set_direction("downlink");
    }
    /// `ms` of 100 ms ticks: sik heard here or not, what the far side reports of it (nullopt:
    /// no report lately); LTE healthy and not reported (a metered link is not).
    void run(int ms, bool down, std::optional<bool> up) {
        for (int t = 0; t < ms; t += 100) {
            now_ += milliseconds(100);
            if (down)
                sik_heard_ = now_;
            ev_.observe_link(sik_, sik_heard_, !down, now_);
            ev_.observe_reported(sik_, up, now_);
            ev_.observe_link(lte_, now_, false, now_);
            ev_.observe_reported(lte_, std::nullopt, now_);
            auto out = ev_.poll(now_);
            for (auto& n : out.notices) {
                notices_.push_back(n);
                times_.push_back(now_);
            }
            events_.insert(events_.end(), out.events.begin(), out.events.end());
        }
    }
    LinkEvents ev_;
    uint32_t bond_, sik_, lte_;
    TimePoint now_ = TimePoint{} + seconds(100), sik_heard_{};
    std::vector<LinkEvents::Notice> notices_;
    std::vector<TimePoint> times_;
    std::vector<std::string> events_;
};

// The SITL operator stage: MAVProxy showed "sik uplink lost (vehicle 0/1 up)", "sik downlink
// lost (vehicle 1/2 up)", "sik downlink back (vehicle 2/2 up)", "sik uplink back (vehicle 1/1
// up)" for one radio cut: two per change, counted each way apart.
TEST_F(BothWaysTest, ARadioCutIsOneLostAndOneBack) {
    run(3000, true, true);
    EXPECT_TRUE(notices_.empty());
    // This side finds it first, the far side's report follows 1.5 s later.
    run(1500, false, true);
    EXPECT_TRUE(notices_.empty()) << "lost one way only: waiting for the other";
    run(8500, false, false);
    ASSERT_EQ(1u, notices_.size());
    EXPECT_EQ("mavbond: link sik lost (bond vehicle, 1 of 2 up)", notices_[0].text);
    EXPECT_EQ(Severity::Warning, notices_[0].severity);
    EXPECT_EQ(bond_, notices_[0].bond);
    // Back: the far side's report says so first this time.
    run(700, false, true);
    const TimePoint both = now_;
    run(3000, true, true);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ("mavbond: link sik back (bond vehicle, 2 of 2 up)", notices_[1].text);
    EXPECT_EQ(Severity::Notice, notices_[1].severity);
    EXPECT_EQ(Duration(milliseconds(100)), times_[1] - both) << "at once, both ways back";
    // The log has each way's change.
    std::vector<std::string> changes;
    for (const auto& e : events_)
        if (e.find(" lost") != std::string::npos || e.find(" back") != std::string::npos)
            changes.push_back(e.substr(0, e.find(" (")));
    EXPECT_EQ((std::vector<std::string>{"link sik downlink lost", "link sik uplink lost",
                                        "link sik uplink back", "link sik downlink back"}),
              changes);
}

TEST_F(BothWaysTest, ALinkLostOneWayIsToldOnceThatHeld) {
    run(3000, true, true);
    const TimePoint failed = now_;
    run(10000, true, false);  // the vehicle no longer hears the ground on the radio
    ASSERT_EQ(1u, notices_.size());
    EXPECT_EQ("mavbond: sik uplink lost (vehicle 1/2 up)", notices_[0].text);
    EXPECT_EQ(Severity::Warning, notices_[0].severity);
    EXPECT_EQ(LinkEvents::kSettle + milliseconds(100), times_[0] - failed);
    run(3000, true, true);
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ("mavbond: link sik back (bond vehicle, 2 of 2 up)", notices_[1].text);
    // A one-way blip shorter than kSettle says nothing.
    run(4000, false, true);
    run(3000, true, true);
    EXPECT_EQ(2u, notices_.size());
}

TEST_F(BothWaysTest, BackOneWayFromLostIsSaidSo) {
    run(3000, true, true);
    run(3000, false, false);
    ASSERT_EQ(1u, notices_.size());
    run(10000, true, false);  // the downlink is back, the uplink is not
    ASSERT_EQ(2u, notices_.size());
    EXPECT_EQ("mavbond: sik downlink back (vehicle 1/2 up)", notices_[1].text);
    EXPECT_EQ(Severity::Notice, notices_[1].severity);
}

TEST_F(BothWaysTest, WithNoReportTheFarSideGoesWithThisOne) {
    // Both links cut: no report comes (nor anything else): the radio is lost, told at once.
    run(3000, true, true);
    const TimePoint cut = now_;
    run(3000, false, std::nullopt);
    ASSERT_EQ(1u, notices_.size());
    EXPECT_EQ("mavbond: link sik lost (bond vehicle, 1 of 2 up)", notices_[0].text);
    EXPECT_EQ(Duration(milliseconds(100)), times_[0] - cut);
}

TEST(LinkEvents, TextFitsStatustext) {
    EXPECT_EQ("mavbond: link lte lost (bond telemetry, 1 of 2 up)",
              LinkEvents::link_text("lte", "lost", "telemetry", 1, 2));
    std::string t = LinkEvents::link_text("a-very-long-link-name", "back", "ground-telemetry", 3, 4);
    EXPECT_LE(t.size(), 50u);
    EXPECT_EQ("mavbond: a-very-long-link-name back (ground-teleme", t);
    EXPECT_EQ("mavbond: radio2 back (telemetry-bond 2/3 up)",
              LinkEvents::link_text("radio2", "back", "telemetry-bond", 2, 3));
    EXPECT_EQ("mavbond: lte downlink lost (telemetry 1/2 up)",
              LinkEvents::link_text("lte", "downlink lost", "telemetry", 1, 2));
}

}  // namespace
}  // namespace mavbond
