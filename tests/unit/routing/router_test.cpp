#include "routing/router.h"

#include <gtest/gtest.h>

#include <array>
#include <memory>
#include <vector>

namespace mavbond {
namespace {

/// A link that records the frames it was asked to send (and sends them at flush()).
class RecordingLink : public Link {
public:
    RecordingLink(std::string name, std::string bond = "")
        : Link(name, name, std::move(bond), false) {}
    bool send(const Frame& frame) override {
        lent.emplace_back(frame.bytes.begin(), frame.bytes.end());
        return lent.size() == 1;
    }
    void flush() override {
        for (auto& f : lent)
            sent.push_back(std::move(f));
        lent.clear();
    }
    const LinkCounters& counters() const override { return counters_; }
    std::vector<std::vector<uint8_t>> lent, sent;

private:
    LinkCounters counters_;
};

class RouterTest : public ::testing::Test {
protected:
    void SetUp() override {
        for (const char* name : {"gcs", "autopilot", "camera"}) {
            links_.push_back(std::make_unique<RecordingLink>(name));
            router_.attach(*links_.back());
        }
    }
    void TearDown() override {
        for (auto& l : links_)
            router_.detach(*l);
    }

    RecordingLink& gcs() { return *links_[0]; }
    RecordingLink& autopilot() { return *links_[1]; }
    RecordingLink& camera() { return *links_[2]; }

    /// A frame from (sysid, compid); target -1 means the message has no target field.
    Frame frame(uint8_t sysid, uint8_t compid, int16_t ts = -1, int16_t tc = -1, bool checked = true) {
        auto& bytes = storage_.emplace_back();
        bytes = {0xFD, sysid, compid, static_cast<uint8_t>(storage_.size())};
        Frame f;
        f.bytes = bytes;
        f.sysid = sysid;
        f.compid = compid;
        f.target_system = ts;
        f.target_component = tc;
        f.crc_checked = checked;
        f.version = 2;
        return f;
    }
    void receive(RecordingLink& from, const Frame& f, bool routed = true) {
        ReceivedBatch batch(router_);
        batch.add(f, from, now_, routed);
        batch.submit();
        router_.end_batch();
    }
    void clear_sent() {
        for (auto& l : links_)
            l->sent.clear();
    }

    std::unique_ptr<EventLoop> loop_ = EventLoop::create().value();
    Router router_{*loop_, seconds(10)};
    TimePoint now_ = Clock::now();
    std::vector<std::unique_ptr<RecordingLink>> links_;
    std::vector<std::vector<uint8_t>> storage_;
};

TEST_F(RouterTest, BroadcastGoesEverywhereButItsSource) {
    receive(autopilot(), frame(1, 1));
    EXPECT_EQ(1u, gcs().sent.size());
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(0u, autopilot().sent.size());
}

TEST_F(RouterTest, TargetZeroIsABroadcast) {
    receive(gcs(), frame(255, 190, 0, 0));
    EXPECT_EQ(1u, autopilot().sent.size());
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(0u, gcs().sent.size());
}

TEST_F(RouterTest, TargetedFrameGoesOnlyWhereTheTargetWasHeard) {
    receive(autopilot(), frame(1, 1));
    receive(camera(), frame(1, 100));
    clear_sent();
    receive(gcs(), frame(255, 190, 1, 100));  // to the camera component
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(0u, autopilot().sent.size());
    clear_sent();
    receive(gcs(), frame(255, 190, 1, 1));    // to the autopilot
    EXPECT_EQ(1u, autopilot().sent.size());
    EXPECT_EQ(0u, camera().sent.size());
    clear_sent();
    receive(gcs(), frame(255, 190, 1, 0));    // every component of system 1
    EXPECT_EQ(1u, autopilot().sent.size());
    EXPECT_EQ(1u, camera().sent.size());
    clear_sent();
    receive(gcs(), frame(255, 190, 1, 55));   // unknown component of a known system
    EXPECT_EQ(1u, autopilot().sent.size());
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(0u, gcs().sent.size());
}

TEST_F(RouterTest, UnknownTargetIsSentEverywhereButTheSource) {
    receive(gcs(), frame(255, 190, 42, 1));
    EXPECT_EQ(1u, autopilot().sent.size());
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(0u, gcs().sent.size());
}

TEST_F(RouterTest, NeverEchoesToTheSourceEvenWhenTheTargetIsThere) {
    receive(autopilot(), frame(1, 1));
    clear_sent();
    receive(autopilot(), frame(1, 1, 1, 1));  // addressed to itself
    EXPECT_EQ(0u, autopilot().sent.size());
}

TEST_F(RouterTest, UncheckedFramesNeverTeachARoute) {
    receive(camera(), frame(7, 1, -1, -1, /*checked=*/false));
    EXPECT_FALSE(router_.knows(camera(), 7, 1));
    receive(camera(), frame(7, 1));
    EXPECT_TRUE(router_.knows(camera(), 7, 1));
}

TEST_F(RouterTest, RoutesExpireAfterTheTimeout) {
    receive(autopilot(), frame(1, 1));
    router_.expire_routes(now_ + seconds(5));
    EXPECT_TRUE(router_.knows(autopilot(), 1, 1));
    router_.expire_routes(now_ + seconds(11));
    EXPECT_FALSE(router_.knows(autopilot(), 1, 1));
}

TEST_F(RouterTest, AFrameTheEndpointRefusedTeachesItsRouteButGoesNowhere) {
    receive(autopilot(), frame(1, 1), /*routed=*/false);
    EXPECT_TRUE(router_.knows(autopilot(), 1, 1));
    EXPECT_EQ(0u, gcs().sent.size());
    EXPECT_EQ(0u, camera().sent.size());
    EXPECT_EQ(0u, router_.frames_routed());
}

TEST_F(RouterTest, DetachedLinkGetsNothingAndItsIdIsReused) {
    LinkId camera_id = camera().id();
    router_.detach(camera());
    EXPECT_EQ(kNoLink, camera().id());
    receive(autopilot(), frame(1, 1));
    EXPECT_EQ(0u, camera().sent.size());
    RecordingLink late("late");
    router_.attach(late);
    EXPECT_EQ(camera_id, late.id());
    router_.detach(late);
    router_.attach(camera());
}

/// radio and lte are the two links of bond "vehicle"; gcs is a plain endpoint.
class BondRouterTest : public RouterTest {
protected:
    void SetUp() override {}
    /// `radio_reports`: the radio has `radio_status: sik`.
    void make(BondConfig::Tx tx, bool radio_reports = false) {
        Config config;
        config.bonds = {BondConfig{"vehicle", tx, {}}};
        for (auto [name, bond] : {std::pair{"radio", "vehicle"}, {"lte", "vehicle"}, {"gcs", ""}}) {
            config.endpoints.emplace_back();
            config.endpoints.back().name = name;
            config.endpoints.back().bond = bond;
            links_.push_back(std::make_unique<RecordingLink>(name, bond));
            router_.attach(*links_.back());
        }
        if (radio_reports)
            config.endpoints[0].tx_budget.radio_status = RadioStatusSource::Sik;
        router_.replace_bonds(config);
        router_.mark_radio_status_bonds(config);
    }
    Frame radio_status(uint8_t sysid, uint8_t compid, uint32_t msgid = 109) {
        Frame f = frame(sysid, compid);
        f.msgid = msgid;
        return f;
    }
    RecordingLink& radio() { return *links_[0]; }
    RecordingLink& lte() { return *links_[1]; }
    RecordingLink& ground() { return *links_[2]; }
};

TEST_F(BondRouterTest, FrameFromOneLinkIsNeverReflectedIntoTheOther) {
    make(BondConfig::Tx::Broadcast);
    receive(radio(), frame(1, 1));
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_EQ(0u, lte().sent.size());
    EXPECT_EQ(0u, radio().sent.size());
}

TEST_F(BondRouterTest, BroadcastBondSendsOnEveryLink) {
    make(BondConfig::Tx::Broadcast);
    receive(ground(), frame(255, 190));
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
}

TEST_F(BondRouterTest, WhatOneLinkLearnedIsReachableThroughTheBond) {
    make(BondConfig::Tx::Broadcast);
    receive(radio(), frame(1, 1));      // the vehicle is heard on the radio only
    clear_sent();
    receive(ground(), frame(255, 190, 1, 1));
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size()) << "the LTE link reaches the same vehicle";
}

TEST_F(BondRouterTest, ActiveBondSendsOnTheActiveLinkOnly) {
    make(BondConfig::Tx::Active);
    receive(ground(), frame(255, 190));  // nothing chosen yet: every link
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
    ASSERT_TRUE(router_.set_active_link(0, lte().id()));
    EXPECT_FALSE(router_.set_active_link(0, ground().id())) << "not a member";
    clear_sent();
    receive(ground(), frame(255, 190));
    EXPECT_EQ(0u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
    EXPECT_EQ(1u, router_.bonds()[0].switches());
}

TEST_F(BondRouterTest, InjectedFrameGoesEverywhereTheTxPolicyAllows) {
    make(BondConfig::Tx::Active);
    router_.inject(frame(1, 191));
    EXPECT_EQ(1u, radio().sent.size()) << "no active link chosen yet: every member";
    EXPECT_EQ(1u, lte().sent.size());
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_FALSE(router_.knows(ground(), 1, 191)) << "a local frame teaches no route";
    ASSERT_TRUE(router_.set_active_link(0, radio().id()));
    clear_sent();
    router_.inject(frame(1, 191));  // flushed by inject itself: no end_batch()
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(0u, lte().sent.size());
    EXPECT_EQ(1u, ground().sent.size());
}

TEST_F(BondRouterTest, ABondWhoseRadioReportsDropsEveryOtherRadioStatus) {
    make(BondConfig::Tx::Broadcast, true);
    ASSERT_TRUE(router_.bonds()[0].reports_radio_status);
    receive(lte(), radio_status(51, 68));        // the far side's radio, over the bond
    receive(radio(), radio_status(52, 68));      // another system on the radio's line
    receive(radio(), radio_status(51, 68, 166)); // RADIO, the older twin (the endpoint takes
                                                 // its radio's own before routing sees them)
    EXPECT_EQ(0u, ground().sent.size());
    EXPECT_EQ(3u, router_.bonds()[0].foreign_radio_status);
    receive(lte(), frame(1, 1));                 // anything else goes on
    EXPECT_EQ(1u, ground().sent.size());
    // From the local side: routed like any frame, not the bond's to judge.
    receive(ground(), radio_status(51, 68));
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
    EXPECT_EQ(3u, router_.bonds()[0].foreign_radio_status);
}

TEST_F(BondRouterTest, ABondWithoutReportsForwardsRadioStatus) {
    make(BondConfig::Tx::Broadcast);
    receive(radio(), radio_status(51, 68));
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_EQ(0u, router_.bonds()[0].foreign_radio_status);
}

TEST_F(BondRouterTest, AFrameMadeForTheLocalSideStaysOutOfTheBonds) {
    make(BondConfig::Tx::Broadcast, true);
    router_.inject(radio_status(51, 68), Router::Reach::OutsideBonds);
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_EQ(0u, radio().sent.size());
    EXPECT_EQ(0u, lte().sent.size());
    router_.inject(frame(1, 191), Router::Reach::Everywhere);
    EXPECT_EQ(2u, ground().sent.size());
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
}

}  // namespace
}  // namespace mavbond
