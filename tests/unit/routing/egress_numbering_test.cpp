// A bond's numbering of what it sends: a frame takes its number when its first copy goes, every
// later copy the same, one that never goes none; the source's own gaps stay gaps.
#include "routing/egress_numbering.h"

#include <gtest/gtest.h>

namespace mavbond {
namespace {

Frame from(uint8_t sysid, uint8_t compid, uint8_t seq, bool is_signed = false) {
    Frame f;
    f.sysid = sysid;
    f.compid = compid;
    f.seq = seq;
    f.version = 2;
    f.incompat_flags = is_signed ? kIncompatSigned : 0;
    return f;
}

TEST(EgressNumbering, AFrameNoLinkSentTakesNoNumber) {
    EgressNumbering n;
    // The autopilot's 10..14: 11 and 13 thinned on the radio (never sent), the rest sent.
    uint64_t t[5];
    for (uint8_t i = 0; i < 5; i++)
        t[i] = n.issue(from(1, 1, static_cast<uint8_t>(10 + i)));
    EXPECT_EQ(10, n.number(t[0], 1, 1)) << "the source's first number is where it starts";
    EXPECT_EQ(11, n.number(t[2], 1, 1));
    EXPECT_EQ(12, n.number(t[4], 1, 1));
    EXPECT_EQ(3u, n.counters().numbered);
}

TEST(EgressNumbering, EveryCopyGoesWithTheNumberOfTheFirst) {
    EgressNumbering n;
    uint64_t a = n.issue(from(1, 1, 0));
    uint64_t b = n.issue(from(1, 1, 1));
    // b's LTE copy went at once, a's radio copy waited in a budget and goes after it.
    EXPECT_EQ(0, n.number(b, 1, 1));
    EXPECT_EQ(1, n.number(a, 1, 1));
    EXPECT_EQ(0, n.number(b, 1, 1)) << "its radio copy, later, or a resend";
    EXPECT_EQ(1, n.number(a, 1, 1));
    EXPECT_EQ(2u, n.counters().numbered);
}

TEST(EgressNumbering, AHeldCopyFarBehindItsSourceIsSupersededNotSent) {
    // A parameter download: the LTE sends each PARAM_VALUE at once, the radio's copies wait
    // in its budget while the burst goes on. A copy still near the newest number goes; one so
    // far behind that the far side would read its step back as a step forward does not.
    EgressNumbering n;
    const uint64_t first = n.issue(from(1, 1, 0));
    EXPECT_EQ(0, n.number(first, 1, 1));
    EXPECT_FALSE(n.superseded(first)) << "the newest number: its radio copy goes";
    const uint64_t unnumbered = n.issue(from(1, 1, 1));
    uint64_t last = 0;
    for (uint64_t i = 1; i < EgressNumbering::kMaxLag; i++) {
        last = n.issue(from(1, 1, static_cast<uint8_t>(1 + i)));
        n.number(last, 1, 1);
    }
    EXPECT_FALSE(n.superseded(first)) << "kMaxLag - 1 behind: the far side steps back to it";
    last = n.issue(from(1, 1, static_cast<uint8_t>(1 + EgressNumbering::kMaxLag)));
    n.number(last, 1, 1);
    EXPECT_TRUE(n.superseded(first)) << "kMaxLag behind: a spare the far side cannot place";
    EXPECT_FALSE(n.superseded(unnumbered)) << "no copy went yet: it takes the next number";
    EXPECT_FALSE(n.superseded(last));
    EXPECT_EQ(1u, n.counters().superseded);
    // 300 numbers on (past a wrap of the sequence byte): still far behind, not 44.
    for (int i = 0; i < 300; i++)
        n.number(n.issue(from(1, 1, static_cast<uint8_t>(i))), 1, 1);
    EXPECT_TRUE(n.superseded(last));
}

TEST(EgressNumbering, TheSourcesOwnGapsStayGaps) {
    EgressNumbering n;
    // 0, 1, then 5 (2..4 lost before mavbond), then 255 -> 1 across the wrap (0 lost).
    EXPECT_EQ(0, n.number(n.issue(from(1, 1, 0)), 1, 1));
    EXPECT_EQ(1, n.number(n.issue(from(1, 1, 1)), 1, 1));
    uint64_t thinned = n.issue(from(1, 1, 5));
    (void)thinned;
    EXPECT_EQ(5, n.number(n.issue(from(1, 1, 6)), 1, 1)) << "3 owed, 5 itself taken by nobody";
    uint8_t last = 0;
    for (uint8_t s = 7; s != 0; s++)
        last = n.number(n.issue(from(1, 1, s)), 1, 1);
    EXPECT_EQ(254, last) << "one behind the source: 5 took no number";
    EXPECT_EQ(0, n.number(n.issue(from(1, 1, 1)), 1, 1)) << "its 0 lost: 255 stepped over";
}

TEST(EgressNumbering, SourcesAreNumberedApart) {
    EgressNumbering n;
    uint64_t a = n.issue(from(1, 1, 50));
    uint64_t b = n.issue(from(2, 1, 200));
    uint64_t c = n.issue(from(1, 1, 51));
    EXPECT_EQ(200, n.number(b, 2, 1));
    EXPECT_EQ(50, n.number(c, 1, 1)) << "a never went";
    (void)a;
}

TEST(EgressNumbering, ASignedFrameKeepsItsNumber) {
    EgressNumbering n;
    EXPECT_EQ(0u, n.issue(from(1, 1, 9, true)));
}

TEST(EgressNumbering, ATicketReusedLongAfterTakesAFreshNumber) {
    EgressNumbering n;
    uint64_t old = n.issue(from(1, 1, 0));
    for (size_t i = 1; i <= EgressNumbering::kTickets; i++)
        n.number(n.issue(from(1, 1, static_cast<uint8_t>(i))), 1, 1);
    // 1..8192 took 0..8191 (the source's first frame, 0, never went: 1 took its place).
    const auto next = static_cast<uint8_t>(EgressNumbering::kTickets);
    EXPECT_EQ(next, n.number(old, 1, 1));
    EXPECT_EQ(1u, n.counters().expired);
}

TEST(EgressNumbering, ASourceTableFullLeavesNewSourcesAlone) {
    EgressNumbering n;
    for (uint32_t i = 0; i < EgressNumbering::kMaxSources; i++)
        EXPECT_NE(0u, n.issue(from(static_cast<uint8_t>(i + 1), 1, 0)));
    EXPECT_EQ(0u, n.issue(from(200, 1, 0)));
    EXPECT_EQ(1u, n.counters().untracked);
}

}  // namespace
}  // namespace mavbond
