// The host's stream positions: a link's sequence numbers per source, unwrapped.
#include "routing/stream_positions.h"

#include <gtest/gtest.h>

namespace mavbond {
namespace {

TEST(StreamPositions, UnwrapsForwardStepsAndCountsGaps) {
    StreamPositions p;
    EXPECT_EQ(250, p.track(1, 1, 250).pos);
    StreamStep s = p.track(1, 1, 251);
    EXPECT_EQ(251, s.pos);
    EXPECT_EQ(0, s.lost);
    s = p.track(1, 1, 4);  // 251 -> 260: 8 frames lost across the wrap
    EXPECT_EQ(260, s.pos);
    EXPECT_EQ(8, s.lost);
    EXPECT_EQ(0u, s.flags);
    EXPECT_EQ(261, p.track(1, 1, 5).pos);
}

TEST(StreamPositions, ALateFrameFillsItsGapOnce) {
    StreamPositions p;
    p.track(1, 1, 10);
    EXPECT_EQ(2, p.track(1, 1, 13).lost);  // 11 and 12 missing
    StreamStep late = p.track(1, 1, 11);
    EXPECT_EQ(11, late.pos);
    EXPECT_EQ(-1, late.lost);
    StreamStep again = p.track(1, 1, 11);  // the same position twice on one link
    EXPECT_EQ(11, again.pos);
    EXPECT_EQ(0, again.lost);
    EXPECT_EQ(MAVBOND_STREAM_REPEAT, again.flags);
}

TEST(StreamPositions, ReorderingUpTo127FramesIsNotARestart) {
    // An LTE modem delivers a burst late: frames 100 behind the newest fill their gaps.
    StreamPositions q;
    q.track(1, 1, 0);
    for (int i = 1; i < 200; i++) {
        if (i >= 80 && i < 90)
            continue;  // come late
        q.track(1, 1, static_cast<uint8_t>(i));
    }
    for (int i = 80; i < 90; i++) {  // 119 to 110 behind the newest
        StreamStep s = q.track(1, 1, static_cast<uint8_t>(i));
        EXPECT_EQ(i, s.pos);
        EXPECT_EQ(-1, s.lost);
        EXPECT_EQ(0u, s.flags);
    }
    EXPECT_EQ(200, q.track(1, 1, 200).pos);
}

TEST(StreamPositions, ARunOfFramesFittingNothingIsARestart) {
    StreamPositions p;
    for (int i = 0; i < 100; i++)
        p.track(1, 1, static_cast<uint8_t>(i));
    // The sender restarts at 0: behind by 99, 98, 97, all seen before.
    EXPECT_EQ(MAVBOND_STREAM_REPEAT, p.track(1, 1, 0).flags);
    EXPECT_EQ(MAVBOND_STREAM_REPEAT, p.track(1, 1, 1).flags);
    StreamStep s = p.track(1, 1, 2);
    EXPECT_EQ(MAVBOND_STREAM_RESYNC, s.flags);
    EXPECT_GT(s.pos, 99);  // positions never go back
    EXPECT_EQ(2, s.pos % 256);
    StreamStep next = p.track(1, 1, 3);
    EXPECT_EQ(s.pos + 1, next.pos);
    EXPECT_EQ(0u, next.flags);
}

TEST(StreamPositions, SourcesAreApartAndBoundedInNumber) {
    StreamPositions p;
    EXPECT_EQ(5, p.track(1, 1, 5).pos);
    EXPECT_EQ(200, p.track(1, 2, 200).pos);
    EXPECT_EQ(6, p.track(1, 1, 6).pos);
    int untracked = 0;
    for (int c = 0; c < 100; c++)
        untracked += (p.track(9, static_cast<uint8_t>(c), 0).flags & MAVBOND_STREAM_UNTRACKED) != 0;
    EXPECT_GT(untracked, 0);
    EXPECT_EQ(7, p.track(1, 1, 7).pos);  // the ones known stay known
}

}  // namespace
}  // namespace mavbond
