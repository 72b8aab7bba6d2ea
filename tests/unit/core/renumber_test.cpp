// The renumberer's rules on made-up streams: two links numbering one source's frames with
// different counters, known losses, the slower link's copies arriving after later frames,
// duplicates as dedup reports them.
#include "core/renumber.h"

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

SeqRenumberer::Key key_of(int frame) {
    return {0x9E3779B97F4A7C15ull * static_cast<uint64_t>(frame + 1), static_cast<uint64_t>(frame)};
}

struct Delivery {
    int frame;
    uint8_t out;
};

/// Frame i of source (1, 1) leaves every 10 ms; link A carries it as a0 + i, link B as
/// b0 + i, 25 ms later than A (so B's copy of a frame A lost comes after A's next two frames).
/// Events are fed in arrival order, as dedup would report them. Returns the deliveries.
std::vector<Delivery> run(SeqRenumberer& r, int n, uint8_t a0, uint8_t b0,
                          const std::set<int>& lost_a, const std::set<int>& lost_b) {
    std::vector<std::tuple<int64_t, int, uint32_t>> arrivals;  // time, frame, link
    for (int i = 0; i < n; i++) {
        if (!lost_a.count(i))
            arrivals.emplace_back(i * 10 * kMs, i, kA);
        if (!lost_b.count(i))
            arrivals.emplace_back(i * 10 * kMs + 25 * kMs, i, kB);
    }
    std::sort(arrivals.begin(), arrivals.end());
    std::vector<Delivery> out;
    std::vector<int64_t> first_at(n, -1);
    for (auto [t, i, link] : arrivals) {
        auto seq = static_cast<uint8_t>((link == kA ? a0 : b0) + i);
        auto k = key_of(i);
        if (first_at[i] >= 0) {
            r.duplicate(1, 1, link, seq, k, t, t - first_at[i]);
            continue;
        }
        first_at[i] = t;
        out.push_back({i, r.deliver(1, 1, link, seq, &k, t)});
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
    // A hole waits a second or 64 numbers, whichever ends first: at 100 frames/s, 64 frames.
    std::vector<int> gap_at;
    for (size_t i = 1; i < d.size(); i++) {
        if (static_cast<uint8_t>(d[i].out - d[i - 1].out) > 1)
            gap_at.push_back(d[i].frame);
    }
    EXPECT_EQ((std::vector<int>{300 + 64, 301 + 64, 450 + 64}), gap_at);
}

TEST(Renumber, AtLowRatesAHoleWaitsASecond) {
    SeqRenumberer r;
    // 20 frames/s: B's copies come 25 ms late; frame 10 is lost on both links.
    std::vector<Delivery> d;
    for (int i = 0; i < 60; i++) {
        auto k = key_of(i);
        int64_t t = i * 50 * kMs;
        if (i == 10)
            continue;
        d.push_back({i, r.deliver(1, 1, kA, static_cast<uint8_t>(i), &k, t)});
        r.duplicate(1, 1, kB, static_cast<uint8_t>(i + 9), k, t + 25 * kMs, 25 * kMs);
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

TEST(Renumber, LinkWithoutOffsetContinuesThenItsHolesExpireIntoGaps) {
    SeqRenumberer r;
    auto k0 = key_of(0), k1 = key_of(1), k2 = key_of(2), k3 = key_of(3);
    EXPECT_EQ(50, r.deliver(1, 1, kA, 50, &k0, 0)) << "the first link keeps its numbers";
    EXPECT_EQ(51, r.deliver(1, 1, kB, 200, &k1, kMs)) << "B has no offset yet: continue";
    EXPECT_EQ(52, r.deliver(1, 1, kB, 202, &k2, 2 * kMs)) << "201 is a hole, not yet a gap";
    EXPECT_EQ(54, r.deliver(1, 1, kB, 203, &k3, 1100 * kMs)) << "a second later it is";
    EXPECT_EQ(1u, r.counters().gaps);
}

TEST(Renumber, SenderRestartIsFollowedAndRelearned) {
    SeqRenumberer r;
    auto before = run(r, 50, 0, 100, {}, {});
    EXPECT_EQ(49, before.back().out);
    // B's sender restarts its counter at 0 while A is silent (frames 50..59 come from B
    // with B's old offset: a jump, shown once); then A is back (its numbers now behind the
    // frontier: after three the renumberer follows), and B re-learns from the duplicates.
    std::vector<Delivery> after;
    int64_t t = 50 * 10 * kMs;
    for (int i = 50; i < 120; i++, t += 10 * kMs) {
        auto k = key_of(i);
        auto b_seq = static_cast<uint8_t>(i - 50);
        if (i < 60) {
            after.push_back({i, r.deliver(1, 1, kB, b_seq, &k, t)});
        } else if (i % 10 == 5) {  // A loses every tenth frame from here: B rescues it
            after.push_back({i, r.deliver(1, 1, kB, b_seq, &k, t + 5 * kMs)});
        } else {
            after.push_back({i, r.deliver(1, 1, kA, static_cast<uint8_t>(i), &k, t)});
            r.duplicate(1, 1, kB, b_seq, k, t + 5 * kMs, 5 * kMs);
        }
    }
    std::vector<Delivery> settled(after.begin() + 20, after.end());
    EXPECT_EQ(0, skipped(settled)) << "once re-learned, B's rescues fill A's losses exactly";
    EXPECT_GE(r.counters().offsets_learned, 2u);
}

TEST(Renumber, CopyOfAnOlderInstanceOfRecurringContentTeachesNothing) {
    SeqRenumberer r;
    auto hb = key_of(1000);  // a HEARTBEAT: the same bytes every second
    auto k = key_of(1);
    r.deliver(1, 1, kA, 10, &k, 0);
    r.duplicate(1, 1, kB, 60, k, 5 * kMs, 5 * kMs);  // B's offset: 10 - 60
    r.deliver(1, 1, kA, 11, &hb, 1000 * kMs);        // HEARTBEAT #1
    r.deliver(1, 1, kA, 12, &hb, 2000 * kMs);        // HEARTBEAT #2 overwrites the slot
    // A late copy of #1 (skew 1.3 s) must not be taken for a copy of #2.
    r.duplicate(1, 1, kB, 61, hb, 2300 * kMs, 1300 * kMs);
    EXPECT_EQ(1u, r.counters().unmatched);
    auto k2 = key_of(2);
    EXPECT_EQ(13, r.deliver(1, 1, kB, 63, &k2, 2400 * kMs)) << "B's offset is still 10 - 60";
    EXPECT_EQ(0u, r.counters().gaps);
}

TEST(Renumber, SourcesAreNumberedApart) {
    SeqRenumberer r;
    auto k = key_of(1), k2 = key_of(2);
    EXPECT_EQ(5, r.deliver(1, 1, kA, 5, &k, 0));
    EXPECT_EQ(77, r.deliver(1, 100, kB, 77, &k2, 0)) << "another source: its own first link";
}

TEST(Renumber, SourcesBeyondTheTableAreLeftAlone) {
    SeqRenumberer r;
    for (uint32_t s = 0; s < SeqRenumberer::kMaxSources; s++)
        r.deliver(static_cast<uint8_t>(s + 1), 1, kA, 0, nullptr, 0);
    EXPECT_EQ(42, r.deliver(200, 1, kB, 42, nullptr, 0));
    EXPECT_EQ(1u, r.counters().untracked);
}

}  // namespace
}  // namespace mavbond
