// The link-event rules on a manual clock: detection from arrival times, severities, texts,
// and the rate limit counted exactly.
#include "routing/link_events.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

namespace mavbond {
namespace {

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
            ev_.observe_link(radio_, radio_heard_, now_);
            ev_.observe_link(lte_, lte_heard_, now_);
            ev_.observe_bond(bond_, active_, switches_, now_);
            auto out = ev_.poll(now_);
            for (auto& n : out.notices) {
                notices_.push_back(n);
                notice_times_.push_back(now_);
            }
            events_.insert(events_.end(), out.events.begin(), out.events.end());
        }
    }

    LinkEvents ev_;
    uint32_t bond_, radio_, lte_;
    TimePoint now_ = TimePoint{} + seconds(1000);
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
    const TimePoint heard = now;
    for (uint32_t l : links)
        ev.observe_link(l, heard, now);
    ev.poll(now);
    // All fall silent at once: announced in link order, five now, three 10 s later.
    std::vector<std::string> sent;
    for (int tick = 1; tick <= 120; tick++) {
        now += milliseconds(100);
        for (uint32_t l : links)
            ev.observe_link(l, heard, now);
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

TEST(LinkEvents, TextFitsStatustext) {
    EXPECT_EQ("mavbond: link lte lost (bond telemetry, 1 of 2 up)",
              LinkEvents::link_text("lte", false, "telemetry", 1, 2));
    std::string t = LinkEvents::link_text("a-very-long-link-name", true, "ground-telemetry", 3, 4);
    EXPECT_LE(t.size(), 50u);
    EXPECT_EQ("mavbond: a-very-long-link-name back (ground-teleme", t);
    EXPECT_EQ("mavbond: radio2 back (telemetry-bond 2/3 up)",
              LinkEvents::link_text("radio2", true, "telemetry-bond", 2, 3));
}

}  // namespace
}  // namespace mavbond
