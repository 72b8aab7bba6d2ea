// The renumberer's rules on made-up streams: two links numbering one source's frames with
// different counters, known losses, the slower link's copies arriving after later frames,
// each delivered frame with its position as dedup gives it.
#include "routing/renumber.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <set>
#include <tuple>
#include <vector>

namespace mavbond {
namespace {

constexpr uint32_t kA = 3;   // link ids
constexpr uint32_t kB = 7;
constexpr int64_t kMs = 1'000'000;

struct Delivery {
    int frame;
    uint8_t out;
};

/// Frame i of source (1, 1) leaves every 10 ms at position p0 + i of the bond's numbering
/// (dedup's, the same on every link); link A carries it with its own number a0 + i, link B
/// 25 ms later (so B's copy of a frame A lost comes after A's next two frames). Copies dedup
/// dropped never reach the renumberer. Returns the deliveries, in arrival order.
std::vector<Delivery> run(SeqRenumberer& r, int n, uint8_t a0, uint8_t b0,
                          const std::set<int>& lost_a, const std::set<int>& lost_b,
                          int64_t p0 = 1000) {
    std::vector<std::tuple<int64_t, int, uint32_t>> arrivals;  // time, frame, link
    for (int i = 0; i < n; i++) {
        if (!lost_a.count(i))
            arrivals.emplace_back(i * 10 * kMs, i, kA);
        if (!lost_b.count(i))
            arrivals.emplace_back(i * 10 * kMs + 25 * kMs, i, kB);
    }
    std::sort(arrivals.begin(), arrivals.end());
    std::vector<Delivery> out;
    std::vector<bool> delivered(n, false);
    for (auto [t, i, link] : arrivals) {
        if (delivered[i])
            continue;  // a copy: dedup dropped it
        delivered[i] = true;
        auto seq = static_cast<uint8_t>((link == kA ? a0 : b0) + i);
        out.push_back({i, r.deliver(1, 1, seq, p0 + i, t)});
    }
    return out;
}

/// Output steps: every one must be forward; returns the numbers skipped in all.
int skipped(const std::vector<Delivery>& d) {
    int total = 0;
    for (size_t i = 1; i < d.size(); i++) {
        auto step = static_cast<uint8_t>(d[i].out - d[i - 1].out);
        EXPECT_GE(step, 1) << "a repeat at delivery " << i << " (frame " << d[i].frame << ")";
        EXPECT_LT(step, 128) << "a step back at delivery " << i << " (frame " << d[i].frame << ")";
        total += step - 1;
    }
    return total;
}

TEST(Renumber, CleanFirstLinkKeepsItsNumbers) {
    SeqRenumberer r;
    auto d = run(r, 600, 10, 110, {}, {});
    ASSERT_EQ(600u, d.size());
    for (const auto& x : d)
        EXPECT_EQ(static_cast<uint8_t>(10 + x.frame), x.out);
}

TEST(Renumber, GapsAreExactlyTheFramesLostOnEveryLink) {
    SeqRenumberer r;
    // 600 frames (6 s, the counters wrap twice); B's numbering is 100 ahead of A's. Frames
    // lost on one link only are rescued by the other, late; 300, 301 and 450 are lost on both.
    std::set<int> lost_a{5, 6, 7, 100, 300, 301, 450, 599}, lost_b{1, 2, 300, 301, 450, 451};
    auto d = run(r, 600, 200, 44, lost_a, lost_b);
    EXPECT_EQ(600u - 3, d.size());
    EXPECT_EQ(3, skipped(d));
    EXPECT_EQ(3u, r.counters().gaps);
    EXPECT_EQ(3u, r.counters().late_filled) << "6, 7 and 100 came from B after a later frame";
    // A hole waits a second (or 1024 positions): at 100 frames/s, 100 frames. 300 and 301
    // became holes together (when 302 came) and are stepped over together; 450 when 451 came.
    std::vector<int> gap_at;
    for (size_t i = 1; i < d.size(); i++) {
        if (static_cast<uint8_t>(d[i].out - d[i - 1].out) > 1)
            gap_at.push_back(d[i].frame);
    }
    EXPECT_EQ((std::vector<int>{302 + 100, 451 + 100}), gap_at);
}

// Found with MAVProxy behind a bond whose second link is 300 ms behind: a 300-parameter list
// moves the stream hundreds of positions in milliseconds; a parameter the fast link lost comes
// by the slow one 300 ms later, and must fill its hole, not be counted lost.
TEST(Renumber, ACopyLateBehindABurstFillsItsHole) {
    SeqRenumberer r;
    std::vector<Delivery> d;
    int64_t t = 0;
    for (int i = 0; i < 100; i++, t += 10 * kMs)
        d.push_back({i, r.deliver(1, 1, static_cast<uint8_t>(i), i, t)});
    for (int i = 100; i < 400; i++) {  // the burst, all at once; 150 lost on the fast link
        if (i != 150)
            d.push_back({i, r.deliver(1, 1, static_cast<uint8_t>(i), i, t)});
    }
    d.push_back({150, r.deliver(1, 1, 150, 150, t + 300 * kMs)});  // the slow link's copy
    for (int i = 400; i < 500; i++, t += 10 * kMs)
        d.push_back({i, r.deliver(1, 1, static_cast<uint8_t>(i), i, t + 310 * kMs)});
    EXPECT_EQ(0, skipped(d));
    EXPECT_EQ(0u, r.counters().gaps);
    EXPECT_EQ(1u, r.counters().late_filled);
}

TEST(Renumber, AtLowRatesAHoleWaitsASecond) {
    SeqRenumberer r;
    // 20 frames/s; frame 10 is lost on both links.
    std::vector<Delivery> d;
    for (int i = 0; i < 60; i++) {
        if (i != 10)
            d.push_back({i, r.deliver(1, 1, static_cast<uint8_t>(i), i, i * 50 * kMs)});
    }
    EXPECT_EQ(1, skipped(d));
    for (size_t i = 1; i < d.size(); i++) {
        if (static_cast<uint8_t>(d[i].out - d[i - 1].out) > 1) {
            EXPECT_EQ(11 + 20, d[i].frame) << "hole made by frame 11, a second (20 frames) on";
        }
    }
}

TEST(Renumber, WithoutRenumberingTheSameStreamWouldStepBack) {
    // The reason output numbers follow delivery order: exact numbers alone go backwards.
    SeqRenumberer r;
    auto d = run(r, 20, 0, 0, {5}, {});
    std::vector<int> frames;
    for (const auto& x : d)
        frames.push_back(x.frame);
    EXPECT_EQ((std::vector<int>{0, 1, 2, 3, 4, 6, 7, 5, 8}), std::vector<int>(frames.begin(), frames.begin() + 9));
    EXPECT_EQ(0, skipped(d));
}

TEST(Renumber, AFrameWithoutAPositionTakesTheNextNumber) {
    SeqRenumberer r;
    EXPECT_EQ(50, r.deliver(1, 1, 50, 1000, 0)) << "a source's first frame keeps its number";
    EXPECT_EQ(51, r.deliver_unplaced(1, 1, 200));
    EXPECT_EQ(52, r.deliver(1, 1, 51, 1001, kMs));
    EXPECT_EQ(53, r.deliver(1, 1, 53, 1003, 2 * kMs)) << "1002 is a hole, not yet a gap";
    EXPECT_EQ(55, r.deliver(1, 1, 54, 1004, 1100 * kMs)) << "a second later it is";
    EXPECT_EQ(1u, r.counters().gaps);
    EXPECT_EQ(1u, r.counters().unplaced);
}

TEST(Renumber, PositionsAcrossAWrapAndFarAheadCountEveryFrameLost) {
    SeqRenumberer r;
    EXPECT_EQ(250, r.deliver(1, 1, 250, 250, 0));
    // 300 positions later (an outage of every link): 299 lost. They wait as holes for a late
    // copy, a second; then every one is owed.
    EXPECT_EQ(251, r.deliver(1, 1, 38, 550, kMs));
    EXPECT_EQ(static_cast<uint8_t>(252 + 299), r.deliver(1, 1, 39, 551, 2000 * kMs));
    EXPECT_EQ(299u, r.counters().gaps);
    // 2,000 positions later: those more than 1024 behind are owed at once, the rest wait.
    EXPECT_EQ(static_cast<uint8_t>(253 + 299 + 1999 - 1023), r.deliver(1, 1, 40, 2551, 2001 * kMs));
    EXPECT_EQ(static_cast<uint8_t>(254 + 299 + 1999), r.deliver(1, 1, 41, 2552, 4000 * kMs));
    EXPECT_EQ(299u + 1999u, r.counters().gaps);
}

TEST(Renumber, SourcesAreNumberedApart) {
    SeqRenumberer r;
    EXPECT_EQ(5, r.deliver(1, 1, 5, 5, 0));
    EXPECT_EQ(77, r.deliver(1, 100, 77, 77, 0)) << "another source: its own first frame";
}

TEST(Renumber, SourcesBeyondTheTableAreLeftAlone) {
    SeqRenumberer r;
    for (uint32_t s = 0; s < SeqRenumberer::kMaxSources; s++)
        r.deliver(static_cast<uint8_t>(s + 1), 1, 0, 0, 0);
    EXPECT_EQ(42, r.deliver(200, 1, 42, 0, 0));
    EXPECT_EQ(1u, r.counters().untracked);
}

}  // namespace
}  // namespace mavbond
