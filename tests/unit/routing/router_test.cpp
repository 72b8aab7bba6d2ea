#include "routing/router.h"

#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <memory>
#include <vector>

#include "mavlink/frame_parser.h"
#include "mavlink/frame_writer.h"
#include "routing/standby.h"

namespace mavbond {
namespace {

/// A link that records the frames it was asked to send (and sends them at flush()).
class RecordingLink : public Link {
public:
    RecordingLink(std::string name, std::string bond = "")
        : Link(name, name, std::move(bond), false) {}
    bool send(const Frame& frame, BondCopy* copy) override {
        // As an endpoint sends at once: its bond's copy (numbered, signed where it signs).
        const Frame* out = copy ? copy->now(bond_signs) : &frame;
        if (!out)
            return false;
        lent.emplace_back(out->bytes.begin(), out->bytes.end());
        return lent.size() == 1;
    }
    bool bond_signs = false;  // its bond signs what it sends on it
    void flush() override {
        for (auto& f : lent)
            sent.push_back(std::move(f));
        lent.clear();
    }
    const LinkCounters& counters() const override { return counters_; }
    void route_evicted() override { counters_.routes_evicted++; }
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

TEST_F(RouterTest, ALinkKeepsItsCapOfRoutesForgettingTheLeastRecentlyHeardFirst) {
    receive(autopilot(), frame(1, 1));
    // The camera's link carries the vehicle's camera, heard all along, and a sender cycling
    // through ids: past the cap, the least recently heard ids go, counted on that link.
    constexpr size_t kCycled = Router::kMaxRoutesPerLink + 300;
    for (size_t i = 0; i < kCycled; i++) {
        now_ += milliseconds(1);
        receive(camera(), frame(1, 100));
        receive(camera(), frame(static_cast<uint8_t>(10 + i / 200), static_cast<uint8_t>(i % 200)));
    }
    EXPECT_EQ(kCycled + 1 - Router::kMaxRoutesPerLink, camera().counters().routes_evicted);
    EXPECT_EQ(0u, autopilot().counters().routes_evicted);
    EXPECT_TRUE(router_.knows(camera(), 1, 100)) << "heard all along, never the oldest";
    EXPECT_TRUE(router_.knows(autopilot(), 1, 1)) << "another link's routes are its own";
    EXPECT_FALSE(router_.knows(camera(), 10, 0)) << "cycled out";
    size_t last = kCycled - 1;
    EXPECT_TRUE(router_.knows(camera(), static_cast<uint8_t>(10 + last / 200),
                              static_cast<uint8_t>(last % 200)));
    // A frame to a forgotten target goes to every link but its source, as to one never heard.
    clear_sent();
    receive(gcs(), frame(255, 190, 10, 0));
    EXPECT_EQ(1u, camera().sent.size());
    EXPECT_EQ(1u, autopilot().sent.size());
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
    /// `radio_reports`: the radio has `radio_status: sik`. `signed_links`: the bond signs
    /// these members.
    void make(BondConfig::Tx tx, bool radio_reports = false,
              std::vector<std::string> signed_links = {}) {
        Config config;
        config.bonds = {BondConfig{"vehicle", tx, {}}};
        if (!signed_links.empty()) {
            config.bonds[0].signing.enabled = true;
            config.bonds[0].signing.key = signing_key();
            config.bonds[0].signing.links = signed_links;
        }
        for (auto [name, bond] : {std::pair{"radio", "vehicle"}, {"lte", "vehicle"}, {"gcs", ""}}) {
            config.endpoints.emplace_back();
            config.endpoints.back().name = name;
            config.endpoints.back().bond = bond;
            links_.push_back(std::make_unique<RecordingLink>(name, bond));
            links_.back()->bond_signs = std::find(signed_links.begin(), signed_links.end(),
                                                  name) != signed_links.end();
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
    /// A real MAVLink 2 frame (parsed from bytes kept in storage_): `msgid` from (sysid, compid)
    /// with `payload`.
    Frame wire(uint8_t sysid, uint8_t compid, uint32_t msgid, std::vector<uint8_t> payload,
               uint8_t seq = 7) {
        auto& bytes = storage_.emplace_back(kMaxFrameLen);
        bytes.resize(write_frame_v2(bytes, FrameSource{sysid, compid, seq}, msgid, payload));
        ParserCounters counters;
        Frame f;
        EXPECT_TRUE(DatagramParser(bytes, UnknownIdPolicy::Forward, counters).next(f));
        return f;
    }
    Frame attitude() { return wire(255, 190, 30, std::vector<uint8_t>(28, 3)); }
    static SigningKey signing_key() {
        SigningKey key;
        key.fill(9);
        return key;
    }
    BondSigning& signing() { return *router_.bonds()[0].signing(); }
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

TEST_F(BondRouterTest, ASignedBondSignsOnceAndEveryLinkGetsTheSameBytes) {
    make(BondConfig::Tx::Broadcast, false, {"radio", "lte"});
    const Frame f = attitude();
    receive(ground(), f);
    ASSERT_EQ(1u, radio().sent.size());
    ASSERT_EQ(1u, lte().sent.size());
    EXPECT_EQ(radio().sent[0], lte().sent[0]) << "one signature for both links";
    EXPECT_EQ(f.bytes.size() + kSignatureLen, lte().sent[0].size());
    EXPECT_TRUE(BondSigning::signed_by_bond(lte().sent[0]));
    EXPECT_EQ(1u, signing().counters().signed_frames);
    // mavbond's own frames are signed too, each with a timestamp of its own.
    router_.inject(attitude());
    ASSERT_EQ(2u, lte().sent.size());
    EXPECT_TRUE(BondSigning::signed_by_bond(lte().sent[1]));
    EXPECT_NE(lte().sent[0], lte().sent[1]);
    EXPECT_EQ(2u, signing().counters().signed_frames);
    EXPECT_EQ(std::vector<uint8_t>(f.bytes.begin(), f.bytes.end()), ground().sent.at(0))
        << "outside the bond, as it was";
}

/// A link that keeps what it is lent as views, and copies the bytes only at flush(): as an
/// endpoint does (its queue lends until the batch's end).
class LendingLink : public RecordingLink {
public:
    using RecordingLink::RecordingLink;
    bool send(const Frame& frame, BondCopy* copy) override {
        const Frame* out = copy ? copy->now(bond_signs) : &frame;
        if (!out)
            return false;
        views.push_back(out->bytes);
        return views.size() == 1;
    }
    void flush() override {
        for (auto v : views)
            sent.emplace_back(v.begin(), v.end());
        views.clear();
    }
    std::vector<std::span<const uint8_t>> views;
};

TEST_F(BondRouterTest, WhatABatchSignsStaysIntactUntilTheBatchEnds) {
    make(BondConfig::Tx::Broadcast, false, {"radio", "lte"});
    // Swap the lte member for a lending one: 400 largest frames (112 KB signed) in one batch,
    // several of the arena's chunks, all lent until end_batch().
    LendingLink lending("lte", "vehicle");
    lending.bond_signs = true;
    router_.detach(lte());
    router_.attach(lending);
    std::vector<Frame> frames;
    for (int i = 0; i < 400; i++)
        frames.push_back(wire(255, 190, 110, std::vector<uint8_t>(251, static_cast<uint8_t>(i)),
                              static_cast<uint8_t>(i)));  // a gapless stream: the bond keeps its numbers
    ReceivedBatch batch(router_);
    for (const Frame& f : frames) {
        batch.add(f, ground(), now_, true);
        if (batch.size() == ReceivedBatch::kCapacity)
            batch.submit();
    }
    batch.submit();
    EXPECT_EQ(400u, lending.views.size());
    router_.end_batch();
    // The far side verifies every one: none was written over before the links wrote it.
    BondSigning far(signing_key());
    unsigned member = *far.member("lte");
    ASSERT_EQ(400u, lending.sent.size());
    for (size_t i = 0; i < lending.sent.size(); i++) {
        ParserCounters counters;
        Frame g;
        ASSERT_TRUE(DatagramParser(lending.sent[i], UnknownIdPolicy::Forward, counters).next(g));
        ASSERT_EQ(far.verify(g, member), SignatureVerifier::Verdict::Accept) << i;
        EXPECT_EQ(std::vector<uint8_t>(frames[i].bytes.begin(), frames[i].bytes.end()),
                  std::vector<uint8_t>(g.bytes.begin(), g.bytes.end()));
    }
    router_.detach(lending);
    router_.attach(lte());
}

TEST_F(BondRouterTest, AReloadKeepsTheBondsSigningWhileItsKeyStays) {
    make(BondConfig::Tx::Broadcast, false, {"radio", "lte"});
    std::shared_ptr<BondSigning> before = router_.bond_signing("vehicle");
    ASSERT_TRUE(before);
    // The bond rebuilt (its tx changed), the same key: the endpoints kept verify with the
    // signing they had, its replay window and clock go on.
    Config config;
    config.bonds = {BondConfig{"vehicle", BondConfig::Tx::Active, {}}};
    config.bonds[0].signing.enabled = true;
    config.bonds[0].signing.key = signing_key();
    config.bonds[0].signing.links = {"radio", "lte"};
    for (const char* name : {"radio", "lte"}) {
        config.endpoints.emplace_back();
        config.endpoints.back().name = name;
        config.endpoints.back().bond = "vehicle";
    }
    router_.replace_bonds(config);
    EXPECT_EQ(before, router_.bond_signing("vehicle"));
    // Another key: another signing (the links it signs restart with it).
    config.bonds[0].signing.key[0] ^= 1;
    router_.replace_bonds(config);
    EXPECT_NE(before, router_.bond_signing("vehicle"));
    EXPECT_TRUE(router_.bond_signing("vehicle"));
}

TEST_F(BondRouterTest, ABondSigningSomeLinksSendsTheOthersTheFrameAsItCame) {
    make(BondConfig::Tx::Broadcast, false, {"lte"});
    const Frame f = attitude();
    receive(ground(), f);
    EXPECT_EQ(std::vector<uint8_t>(f.bytes.begin(), f.bytes.end()), radio().sent.at(0));
    EXPECT_TRUE(BondSigning::signed_by_bond(lte().sent.at(0)));
}

TEST_F(BondRouterTest, FramesSignedAlreadyGoAsTheyAreAndMavlink1StaysOffSignedLinks) {
    make(BondConfig::Tx::Broadcast, false, {"lte"});
    Frame pre = attitude();
    auto& signed_bytes = storage_.emplace_back(kMaxFrameLen);
    FrameSigner other(SigningKey{}, 3);
    signed_bytes.resize(other.sign(pre.bytes, signed_bytes));
    ParserCounters counters;
    ASSERT_TRUE(DatagramParser(signed_bytes, UnknownIdPolicy::Forward, counters).next(pre));
    receive(ground(), pre);
    EXPECT_EQ(signed_bytes, lte().sent.at(0)) << "its source's signature, untouched";
    // A MAVLink 1 HEARTBEAT: no signature possible; the radio carries it, LTE does not.
    auto& v1 = storage_.emplace_back(std::vector<uint8_t>{0xFE, 9, 0, 255, 190, 0, 0, 0, 0, 0,
                                                          6, 8, 0, 0, 3, 0, 0});
    Frame f;
    f.bytes = v1;
    f.version = 1;
    f.sysid = 255;
    f.compid = 190;
    receive(ground(), f);
    EXPECT_EQ(2u, radio().sent.size());
    EXPECT_EQ(1u, lte().sent.size());
    EXPECT_EQ(1u, signing().counters().refused_v1);
    EXPECT_EQ(0u, signing().counters().signed_frames);
}

TEST_F(BondRouterTest, ASignedFrameIsDeliveredOnceWhateverTheFiltersLetThrough) {
    // The air side signs; here (no filter: nothing drops the second copy) both links bring it.
    make(BondConfig::Tx::Broadcast, false, {"radio", "lte"});
    BondSigning air(signing_key());
    Frame f = wire(1, 1, 30, std::vector<uint8_t>(28, 4));
    std::vector<uint8_t> signed_bytes(kMaxFrameLen);
    signed_bytes.resize(air.sign(f.bytes, signed_bytes));
    // One signature, a copy on each link (as the air side's router sends them).
    for (RecordingLink* link : {&radio(), &lte()}) {
        auto& copy = storage_.emplace_back(signed_bytes);
        ParserCounters counters;
        Frame g;
        ASSERT_TRUE(DatagramParser(copy, UnknownIdPolicy::Forward, counters).next(g));
        SignedId id;
        ASSERT_EQ(signing().verify(g, *signing().member(link->name()), &id),
                  SignatureVerifier::Verdict::Accept);
        ReceivedBatch batch(router_);
        batch.add(g, *link, now_, true, id);
        batch.submit();
        router_.end_batch();
    }
    EXPECT_EQ(1u, ground().sent.size());
    EXPECT_EQ(std::vector<uint8_t>(f.bytes.begin(), f.bytes.end()), ground().sent[0]);
    EXPECT_EQ(1u, signing().counters().redelivered);
}

TEST_F(BondRouterTest, AStandbyReportFromOutsideTheBondsIsNeverRoutedIntoOne) {
    make(BondConfig::Tx::Broadcast);
    std::vector<uint8_t> payload(18, 0);
    std::memcpy(payload.data() + 8, "mbl:radio", 9);
    Frame report = wire(255, 190, Standby::kMsgNamedValueInt, payload);
    ASSERT_TRUE(Standby::is_report(report));
    receive(ground(), report);
    EXPECT_EQ(0u, radio().sent.size());
    EXPECT_EQ(0u, lte().sent.size());
    EXPECT_EQ(1u, router_.standby_reports_dropped());
    // Nor a bond's own (it has no metered member to take it): consumed, not routed on.
    receive(radio(), report);
    EXPECT_EQ(0u, ground().sent.size());
    EXPECT_EQ(2u, router_.standby_reports_dropped());
    std::memcpy(payload.data() + 8, "battery", 7);
    receive(ground(), wire(255, 190, Standby::kMsgNamedValueInt, payload));
    EXPECT_EQ(1u, lte().sent.size()) << "any other NAMED_VALUE_INT goes on";
}

}  // namespace
}  // namespace mavbond
