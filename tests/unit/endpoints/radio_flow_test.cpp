// A radio's reports on a simulated clock: the budget starts at half the ceiling, halves or loses
// a quarter on a low txbuf, climbs a tenth of the ceiling on a high one, never leaves [floor,
// ceiling], goes to the ceiling when the reports stop (or never come); only a SiK radio's RADIO_STATUS is a report; a bond reports
// what its best member can carry.
#include "endpoints/radio_flow.h"

#include <gtest/gtest.h>

#include <vector>

#include "mavlink/frame_writer.h"
#include "mavlink/message_table.h"

namespace mavbond {
namespace {

const TimePoint t0 = TimePoint{} + seconds(100);

/// A radio's flow whose link began kStale before t0 with no report since: at its ceiling, where
/// the tests of the reports' steps start.
RadioFlow at_ceiling(uint64_t ceiling) {
    RadioFlow flow(ceiling, t0 - RadioFlow::kStale);
    flow.check(t0);
    return flow;
}

RadioReport txbuf(uint8_t free_percent) {
    RadioReport r;
    r.txbuf = free_percent;
    return r;
}

TEST(RadioReportTest, FieldsRoundTripInWireOrder) {
    RadioReport r{0x1234, 0x0506, 200, 180, 42, 30, 25};
    auto p = r.encode();
    EXPECT_EQ(0x34, p[0]);  // rxerrors, little-endian, first: the uint16 fields lead the payload
    EXPECT_EQ(0x06, p[2]);
    EXPECT_EQ(42, p[6]);
    EXPECT_EQ(r, RadioReport::decode(p));
}

TEST(RadioReportTest, ATrimmedPayloadReadsAsZeros) {
    // MAVLink 2 drops a payload's trailing zeros: noise and remnoise 0 leave 7 bytes.
    RadioReport r{1, 2, 3, 4, 5, 0, 0};
    auto p = r.encode();
    EXPECT_EQ(r, RadioReport::decode(std::span<const uint8_t>(p).first(7)));
}

TEST(RadioReportTest, TheMessageTableKnowsBothMessagesAtNineBytes) {
    for (uint32_t id : {kMsgRadioStatus, kMsgRadio}) {
        const MessageInfo* info = find_message(id);
        ASSERT_NE(nullptr, info) << id;
        EXPECT_EQ(RadioReport::kPayloadLen, info->min_len) << id;
    }
}

Frame frame_of(uint32_t msgid, uint8_t sysid, uint8_t compid) {
    Frame f;
    f.msgid = msgid;
    f.sysid = sysid;
    f.compid = compid;
    return f;
}

TEST(RadioReportTest, OnlyASikRadiosStatusIsItsReport) {
    const auto sik = RadioStatusSource::Sik;
    EXPECT_TRUE(is_radio_report(frame_of(kMsgRadioStatus, 51, 68), sik));
    EXPECT_TRUE(is_radio_report(frame_of(kMsgRadio, 51, 68), sik));
    EXPECT_FALSE(is_radio_report(frame_of(kMsgRadioStatus, 52, 68), sik));  // another system
    EXPECT_FALSE(is_radio_report(frame_of(kMsgRadioStatus, 51, 1), sik));   // another component
    EXPECT_FALSE(is_radio_report(frame_of(kMsgRadioStatus, 1, 1), sik));    // an autopilot's
    EXPECT_FALSE(is_radio_report(frame_of(0, 51, 68), sik));                // not a status
    EXPECT_FALSE(is_radio_report(frame_of(kMsgRadioStatus, 51, 68), RadioStatusSource::None));
}

TEST(RadioFlowTest, AFullBufferHalvesTheRateDownToTheFloor) {
    RadioFlow flow = at_ceiling(5760);
    EXPECT_EQ(5760u, flow.rate());
    EXPECT_EQ(360u, flow.floor());  // a sixteenth
    std::vector<uint64_t> rates;
    for (int i = 0; i < 6; i++)
        rates.push_back(flow.report(txbuf(10), t0 + seconds(i)));
    EXPECT_EQ((std::vector<uint64_t>{2880, 1440, 720, 360, 360, 360}), rates);
    EXPECT_EQ(4u, flow.counters().decreases);
    EXPECT_EQ(6u, flow.counters().reports);
}

TEST(RadioFlowTest, ALowBufferTakesAQuarterAMiddlingOneHolds) {
    RadioFlow flow = at_ceiling(8000);
    EXPECT_EQ(6000u, flow.report(txbuf(49), t0));
    EXPECT_EQ(6000u, flow.report(txbuf(50), t0 + seconds(1)));
    EXPECT_EQ(6000u, flow.report(txbuf(90), t0 + seconds(2)));
    EXPECT_EQ(3000u, flow.report(txbuf(19), t0 + seconds(3)));
    EXPECT_EQ(2250u, flow.report(txbuf(20), t0 + seconds(4)));
}

TEST(RadioFlowTest, AnEmptyBufferClimbsATenthOfTheCeilingAtATime) {
    RadioFlow flow = at_ceiling(5000);
    for (int i = 0; i < 4; i++)
        flow.report(txbuf(0), t0 + seconds(i));
    ASSERT_EQ(flow.floor(), flow.rate());
    std::vector<uint64_t> rates;
    for (int i = 0; i < 12; i++)
        rates.push_back(flow.report(txbuf(91), t0 + seconds(10 + i)));
    EXPECT_EQ(812u, rates[0]);  // 312 + 500
    for (size_t i = 1; i < rates.size(); i++)
        EXPECT_EQ(std::min<uint64_t>(rates[i - 1] + 500, 5000), rates[i]);
    EXPECT_EQ(5000u, rates.back());
    EXPECT_EQ(10u, flow.counters().increases);  // the last two were at the ceiling already
}

TEST(RadioFlowTest, ReportsThatStopPutTheRateBackToTheCeiling) {
    RadioFlow flow = at_ceiling(5760);
    flow.report(txbuf(5), t0);
    ASSERT_EQ(2880u, flow.rate());
    EXPECT_TRUE(flow.fresh(t0 + seconds(4)));
    EXPECT_EQ(2880u, flow.check(t0 + seconds(4)));
    EXPECT_EQ(0u, flow.counters().stale);
    EXPECT_FALSE(flow.fresh(t0 + seconds(5)));
    EXPECT_EQ(5760u, flow.check(t0 + seconds(5)));
    EXPECT_EQ(1u, flow.counters().stale);
    EXPECT_EQ(5760u, flow.check(t0 + seconds(9)));  // counted once per silence
    EXPECT_EQ(1u, flow.counters().stale);
    // The next report works from the ceiling.
    EXPECT_EQ(2880u, flow.report(txbuf(5), t0 + seconds(10)));
    EXPECT_EQ(2880u, flow.check(t0 + seconds(11)));
}

TEST(RadioFlowTest, TheRateStartsAtHalfTheCeilingAndTheReportsRaiseIt) {
    // A SiK radio behind a 57600-baud line airs less than the line carries: the first burst
    // must not go at the line's rate before the radio's first report.
    RadioFlow flow(5760, t0);
    EXPECT_EQ(2880u, flow.rate());
    EXPECT_EQ(2880u, flow.check(t0 + seconds(4)));
    EXPECT_EQ(3456u, flow.report(txbuf(95), t0 + seconds(1)));  // room, and the rate held back
    EXPECT_EQ(3456u, flow.check(t0 + seconds(5)));  // kStale from the start, a report since
    EXPECT_EQ(0u, flow.counters().stale);
}

TEST(RadioFlowTest, ARadioThatNeverReportsGetsTheCeilingAfterKStale) {
    RadioFlow flow(1000, t0);
    EXPECT_FALSE(flow.fresh(t0));
    EXPECT_EQ(500u, flow.check(t0 + RadioFlow::kStale - milliseconds(1)));
    EXPECT_EQ(1000u, flow.check(t0 + RadioFlow::kStale));
    EXPECT_EQ(1000u, flow.check(t0 + seconds(60)));
    EXPECT_EQ(0u, flow.counters().stale) << "no report stopped: none ever came";
}

TEST(RadioFlowTest, ANewCeilingKeepsWhatTheReportsLearnedWithinIt) {
    RadioFlow flow = at_ceiling(8000);
    flow.report(txbuf(45), t0);  // 6000
    flow.set_ceiling(4000);
    EXPECT_EQ(4000u, flow.rate());
    flow.set_ceiling(16000);
    EXPECT_EQ(4000u, flow.rate());  // not raised by the new ceiling: the reports raise it
    flow.report(txbuf(0), t0 + seconds(1));
    flow.report(txbuf(0), t0 + seconds(2));
    flow.report(txbuf(0), t0 + seconds(3));
    EXPECT_EQ(1000u, flow.rate());  // the floor of 16000
    flow.set_ceiling(800);
    EXPECT_EQ(800u, flow.rate());
    EXPECT_EQ(100u, flow.floor());  // a sixteenth would be under the least tx_rate
}

RadioVote radio(uint8_t free_percent, uint8_t rssi, uint16_t rxerrors = 0, bool fresh = true) {
    RadioVote v;
    v.reports = true;
    v.fresh = fresh;
    v.last = RadioReport{rxerrors, 1, rssi, static_cast<uint8_t>(rssi - 10), free_percent, 40, 35};
    return v;
}

TEST(BondReportTest, AFastMemberKeepsTheBondFree) {
    RadioVote votes[] = {radio(8, 150, 3), radio(97, 120, 4)};
    auto r = bond_report(votes);
    ASSERT_TRUE(r);
    EXPECT_EQ(97, r->txbuf);
    EXPECT_EQ(120, r->rssi);    // the fast radio's signal
    EXPECT_EQ(110, r->remrssi);
    EXPECT_EQ(7, r->rxerrors);  // summed
    EXPECT_EQ(2, r->fixed);
}

TEST(BondReportTest, TheBondIsSlowWhenEveryMemberIs) {
    RadioVote votes[] = {radio(8, 150), radio(15, 120)};
    EXPECT_EQ(15, bond_report(votes)->txbuf);
}

TEST(BondReportTest, TiesGoToTheStrongerSignal) {
    RadioVote votes[] = {radio(100, 90), radio(100, 200), radio(100, 255)};  // 255: unknown
    EXPECT_EQ(200, bond_report(votes)->rssi);
}

TEST(BondReportTest, AStaleRadioHasNoSay) {
    RadioVote votes[] = {radio(100, 200, 5, false), radio(10, 100, 2)};
    auto r = bond_report(votes);
    EXPECT_EQ(10, r->txbuf);
    EXPECT_EQ(100, r->rssi);
    EXPECT_EQ(2, r->rxerrors);
}

TEST(BondReportTest, ALiveMemberWithoutARadioCountsAsFree) {
    RadioVote lte;  // reports nothing, hears its peer
    lte.alive = true;
    RadioVote votes[] = {radio(10, 100, 2), lte};
    auto r = bond_report(votes);
    EXPECT_EQ(100, r->txbuf);
    EXPECT_EQ(100, r->rssi);  // the signal is still the radio's
    votes[1].alive = false;
    EXPECT_EQ(10, bond_report(votes)->txbuf);
}

TEST(BondReportTest, AMeteredMemberInStandbyIsNoRoom) {
    // LTE in standby carries control only: the autopilot must slow to what the radio carries,
    // and may speed up once LTE is active.
    RadioVote lte;
    lte.alive = true;
    lte.standby = true;
    RadioVote votes[] = {radio(10, 100, 2), lte};
    EXPECT_EQ(10, bond_report(votes)->txbuf);
    votes[1].standby = false;
    EXPECT_EQ(100, bond_report(votes)->txbuf);
}

TEST(BondReportTest, NobodyToAskMeansNoReport) {
    RadioVote silent;
    RadioVote votes[] = {radio(50, 100, 0, false), silent};
    EXPECT_FALSE(bond_report(votes));
    EXPECT_FALSE(bond_report({}));
    // Only an LTE link that hears: free, signal unknown.
    votes[1].alive = true;
    auto r = bond_report(votes);
    EXPECT_EQ(100, r->txbuf);
    EXPECT_EQ(255, r->rssi);
    EXPECT_EQ(0, r->rxerrors);
}

TEST(BondReportTest, ErrorCountsSaturate) {
    RadioVote votes[] = {radio(50, 100, 60000), radio(50, 100, 60000)};
    EXPECT_EQ(65535, bond_report(votes)->rxerrors);
}


TEST(RadioFlowTest, AnEmptyBufferRaisesNoRateThatHeldNothingBack) {
    // The buffer of a radio given less than its budget lets stays empty, whatever the radio
    // could carry: that says nothing of a higher rate.
    RadioFlow flow = at_ceiling(5000);
    flow.report(txbuf(10), t0);
    ASSERT_EQ(2500u, flow.rate());
    for (int i = 1; i < 5; i++)
        EXPECT_EQ(2500u, flow.report(txbuf(100), t0 + seconds(i), false));
    EXPECT_EQ(3000u, flow.report(txbuf(100), t0 + seconds(5), true));
}

TEST(BudgetRoomTest, LostFramesSlowTheAutopilotAndANearlyFullLineHoldsIt) {
    // 1 s at 3000 B/s.
    EXPECT_EQ(10, budget_room(100, 5000, 11, 3000, 1.0)) << "more than a tenth thinned";
    EXPECT_EQ(40, budget_room(100, 3100, 3, 3000, 1.0));
    EXPECT_EQ(70, budget_room(100, 2600, 0, 3000, 1.0)) << "87 %: one step up would overflow";
    EXPECT_EQ(92, budget_room(100, 2200, 0, 3000, 1.0));
    EXPECT_EQ(100, budget_room(100, 1000, 0, 3000, 1.0));
    EXPECT_EQ(100, budget_room(0, 0, 0, 3000, 0.0)) << "nothing known yet";
}

TEST(BondReportTest, AFreeRadioBehindAFullBudgetIsNoRoom) {
    // mavbond keeps the radio's buffer from filling, so the radio says it is free while the
    // budget thins what the autopilot sends: the budget's word counts.
    RadioVote sik = radio(100, 150);
    sik.room = 40;
    RadioVote lte;
    lte.alive = true;
    lte.standby = true;
    RadioVote votes[] = {sik, lte};
    EXPECT_EQ(40, bond_report(votes)->txbuf);
    votes[0].room = 100;
    EXPECT_EQ(100, bond_report(votes)->txbuf);
    votes[1].standby = false;  // LTE carries the stream: room, whatever the radio's budget
    votes[0].room = 10;
    EXPECT_EQ(100, bond_report(votes)->txbuf);
}

}  // namespace
}  // namespace mavbond
