#include "routing/router.h"

#include <gtest/gtest.h>

#include <array>
#include <memory>
#include <vector>

#include "endpoints/endpoint.h"

namespace mavbond {
namespace {

/// An endpoint whose "socket" records the datagrams it was asked to send.
class RecordingEndpoint : public Endpoint {
public:
    RecordingEndpoint(const EndpointConfig& config, std::string name)
        : Endpoint(config, std::move(name), TxQueue::Mode::Datagram) {}
    const char* kind() const override { return "test"; }
    std::vector<std::vector<uint8_t>> sent;

protected:
    int write_datagrams(const iovec* frames, size_t count) override {
        for (size_t i = 0; i < count; i++) {
            auto* p = static_cast<const uint8_t*>(frames[i].iov_base);
            sent.emplace_back(p, p + frames[i].iov_len);
        }
        return static_cast<int>(count);
    }
};

class RouterTest : public ::testing::Test {
protected:
    void SetUp() override {
        for (const char* name : {"gcs", "autopilot", "camera"}) {
            configs_.push_back(std::make_unique<EndpointConfig>());
            configs_.back()->name = name;
            endpoints_.push_back(std::make_unique<RecordingEndpoint>(*configs_.back(), name));
            router_.add(*endpoints_.back());
        }
    }
    void TearDown() override {
        for (auto& e : endpoints_)
            router_.remove(*e);
    }

    /// Makes endpoint i anew from its config, which it copied when it was made.
    void rebuild(size_t i) {
        router_.remove(*endpoints_[i]);
        endpoints_[i] = std::make_unique<RecordingEndpoint>(*configs_[i], configs_[i]->name);
        router_.add(*endpoints_[i]);
    }

    RecordingEndpoint& gcs() { return *endpoints_[0]; }
    RecordingEndpoint& autopilot() { return *endpoints_[1]; }
    RecordingEndpoint& camera() { return *endpoints_[2]; }

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
    void receive(RecordingEndpoint& from, const Frame& f) {
        router_.handle_frame(from, f, now_);
        router_.end_batch();
    }
    void clear_sent() {
        for (auto& e : endpoints_)
            e->sent.clear();
    }

    std::unique_ptr<EventLoop> loop_ = EventLoop::create().value();
    Router router_{*loop_, seconds(10)};
    TimePoint now_ = Clock::now();
    std::vector<std::unique_ptr<EndpointConfig>> configs_;
    std::vector<std::unique_ptr<RecordingEndpoint>> endpoints_;
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

TEST_F(RouterTest, OutFilterBlocksAndCounts) {
    configs_[0]->filter_out.block = {30};
    rebuild(0);
    Frame f = frame(1, 1);
    f.msgid = 30;
    receive(autopilot(), f);
    EXPECT_EQ(0u, gcs().sent.size());
    EXPECT_EQ(1u, gcs().stats().tx_filtered);
    EXPECT_EQ(1u, camera().sent.size());
}

TEST_F(RouterTest, InFilterAllowListDropsTheRest) {
    configs_[1]->filter_in.allow = {0};
    rebuild(1);
    Frame hb = frame(1, 1);
    Frame att = frame(1, 1);
    att.msgid = 30;
    receive(autopilot(), hb);
    receive(autopilot(), att);
    EXPECT_EQ(1u, gcs().sent.size());
    EXPECT_EQ(1u, autopilot().stats().rx_filtered);
}

TEST_F(RouterTest, RemovedEndpointGetsNothingAndItsIdIsReused) {
    uint32_t camera_id = camera().id();
    router_.remove(camera());
    receive(autopilot(), frame(1, 1));
    EXPECT_EQ(0u, camera().sent.size());
    EndpointConfig cfg;
    RecordingEndpoint late(cfg, "late");
    router_.add(late);
    EXPECT_EQ(camera_id, late.id());
    router_.remove(late);
    router_.add(camera());
}

/// radio and lte are the two links of bond "vehicle"; gcs is a plain endpoint.
class BondRouterTest : public RouterTest {
protected:
    void SetUp() override {}
    void make(BondConfig::Tx tx) {
        router_.replace_bonds({BondConfig{"vehicle", tx, {}}});
        for (auto [name, bond] : {std::pair{"radio", "vehicle"}, {"lte", "vehicle"}, {"gcs", ""}}) {
            configs_.push_back(std::make_unique<EndpointConfig>());
            configs_.back()->name = name;
            configs_.back()->bond = bond;
            endpoints_.push_back(std::make_unique<RecordingEndpoint>(*configs_.back(), name));
            router_.add(*endpoints_.back());
        }
    }
    RecordingEndpoint& radio() { return *endpoints_[0]; }
    RecordingEndpoint& lte() { return *endpoints_[1]; }
    RecordingEndpoint& ground() { return *endpoints_[2]; }
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
    EXPECT_EQ(1u, router_.bonds()[0].switches);
}

TEST_F(BondRouterTest, InjectedFrameGoesEverywhereTheTxPolicyAllows) {
    make(BondConfig::Tx::Active);
    router_.inject(frame(1, 191), now_);
    EXPECT_EQ(1u, radio().sent.size()) << "no active link chosen yet: every member";
    EXPECT_EQ(1u, lte().sent.size());
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_FALSE(router_.knows(ground(), 1, 191)) << "a local frame teaches no route";
    ASSERT_TRUE(router_.set_active_link(0, radio().id()));
    clear_sent();
    router_.inject(frame(1, 191), now_);  // flushed by inject itself: no end_batch()
    EXPECT_EQ(1u, radio().sent.size());
    EXPECT_EQ(0u, lte().sent.size());
    EXPECT_EQ(1u, ground().sent.size());
}

}  // namespace
}  // namespace mavbond
