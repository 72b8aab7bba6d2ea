// The dedup plugin one frame at a time: copies, keys, windows, staleness and the options it
// takes (simulations of whole links: dedup_links_test.cpp, dedup_window_test.cpp).
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <string>
#include <tuple>
#include <vector>

#include "dedup.h"

#include "dedup_test_support.h"

namespace mavbond {
namespace {

using namespace dedup_testing;
using namespace std::chrono_literals;

// A span in which the head did not move forward (a correction moved it back behind the span's
// start) keeps the interval known; before, it divided by zero (SIGFPE in the operator stage).
TEST(DedupFrameInterval, ASpanWithTheHeadNoFurtherKeepsTheIntervalKnown) {
    EXPECT_EQ(8'000'000u, dedup::frame_interval(dedup::kSecond, 125, 0));
    EXPECT_EQ(8'000'000u, dedup::frame_interval(dedup::kSecond, 0, 8'000'000));
    EXPECT_EQ(8'000'000u, dedup::frame_interval(dedup::kSecond, -3, 8'000'000));
    EXPECT_EQ(0u, dedup::frame_interval(dedup::kSecond, 0, 0));
}

TEST_F(DedupTest, CopyFromAnotherLinkIsDropped) {
    ASSERT_TRUE(create("window: 500ms"));
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    mavbond_frame_notes notes{};
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f, now(), &notes));
    EXPECT_TRUE(notes.flags & MAVBOND_NOTE_HASHED);
    EXPECT_FALSE(notes.flags & MAVBOND_NOTE_DUPLICATE);
    ASSERT_TRUE(notes.flags & MAVBOND_NOTE_POSITION);
    EXPECT_EQ(7, notes.bond_pos);  // the first link's numbering is the bond's
    uint64_t first_hash = notes.hash[0];
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f, now() + 40 * kMs, &notes));
    EXPECT_TRUE(notes.flags & MAVBOND_NOTE_DUPLICATE);
    EXPECT_EQ(first_hash, notes.hash[0]);
    EXPECT_EQ(a_->id, notes.first_link_id);
    EXPECT_EQ(static_cast<int64_t>(40 * kMs), notes.skew_ns);
    EXPECT_EQ(7, notes.bond_pos);
    std::string s = status();
    EXPECT_NE(std::string::npos, s.find("\"name\":\"a\",\"passed\":1,\"duplicates\":0")) << s;
    EXPECT_NE(std::string::npos, s.find("\"name\":\"b\",\"passed\":0,\"duplicates\":1")) << s;
}

TEST_F(DedupTest, TheSameBytes256FramesLaterAreANewFrame) {
    // One cycle of 256 frames, sent twice: frame k of the second cycle is byte for byte frame
    // k of the first. Link b brings every frame 300 ms late (1,000 frames/s): when its copy of
    // the first cycle's frame k comes, a has already delivered the second cycle's. Link a lost
    // the first cycle's frame 10 and the second's frame 20, b lost the first's 30.
    ASSERT_TRUE(create("window: 2s"));
    std::vector<Bytes> cycle;
    for (int k = 0; k < 256; k++)
        cycle.push_back(v2(static_cast<uint8_t>(k), kHeartbeat, heartbeat_payload()));
    uint64_t t = now();
    std::vector<std::tuple<uint64_t, const mavbond_link*, int>> arrivals;
    for (int i = 0; i < 512; i++) {
        if (i != 10 && i != 256 + 20)
            arrivals.emplace_back(t + i * kMs, a_, i);
        if (i != 30)
            arrivals.emplace_back(t + i * kMs + 300 * kMs, b_, i);
    }
    std::stable_sort(arrivals.begin(), arrivals.end(),
                     [](const auto& x, const auto& y) { return std::get<0>(x) < std::get<0>(y); });
    std::vector<int> delivered(512, 0);
    for (const auto& [at, link, i] : arrivals) {
        if (feed(*link, cycle[i % 256], at) == MAVBOND_PASS)
            delivered[i]++;
    }
    for (int i = 0; i < 512; i++)
        EXPECT_EQ(1, delivered[i]) << "frame " << i;
}

TEST_F(DedupTest, ContentKeyMatchesStreamsWithTheirOwnSequence) {
    ASSERT_TRUE(create("window: 1s\nkey: content"));
    Bytes p = attitude_payload(5000);
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(10, kAttitude, p)));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(200, kAttitude, p)));
    // v1 with its zeros against v2 with the zeros truncated: one message.
    Bytes hb = heartbeat_payload();
    hb[8] = 0;
    Bytes truncated(hb.begin(), hb.end() - 1);
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v1(11, 0, hb)));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(201, kHeartbeat, truncated)));
    // Another sender is another message.
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(202, kAttitude, p, 2)));
}

TEST_F(DedupTest, ContentKeyTellsRecurringContentApartByPosition) {
    // Two autopilot ports with their own counters (b = a + 77), the same HEARTBEAT content
    // every 10 frames (as every second at 10 frames/s), 5% loss on each, b 15 ms behind.
    // Each heartbeat is a frame of its own: its content recurs, its position does not.
    ASSERT_TRUE(create("window: 2s\nkey: content"));
    std::mt19937_64 rng(6);
    std::bernoulli_distribution lost(0.05);
    std::vector<int> delivered(2000, 0), reached(2000, 0);
    std::vector<std::tuple<uint64_t, int, int>> arrivals;
    for (int i = 0; i < 2000; i++) {
        uint64_t t = now() + i * 10 * kMs;
        bool la = i > 0 && lost(rng), lb = lost(rng);
        if (!la)
            arrivals.emplace_back(t, 0, i);
        if (!lb)
            arrivals.emplace_back(t + 15 * kMs, 1, i);
        reached[i] = !(la && lb);
    }
    std::stable_sort(arrivals.begin(), arrivals.end(),
                     [](const auto& x, const auto& y) { return std::get<0>(x) < std::get<0>(y); });
    for (const auto& [t, link, i] : arrivals) {
        uint8_t seq = static_cast<uint8_t>(i + (link ? 77 : 0));
        Bytes f = i % 10 == 0 ? v2(seq, kHeartbeat, heartbeat_payload())
                              : v2(seq, kAttitude, attitude_payload(static_cast<uint32_t>(i)));
        if (feed(link ? *b_ : *a_, f, t) == MAVBOND_PASS)
            delivered[i]++;
    }
    for (int i = 0; i < 2000; i++)
        EXPECT_EQ(reached[i], delivered[i]) << "frame " << i;
}

TEST_F(DedupTest, FrameKeyKeepsSequenceApart) {
    ASSERT_TRUE(create("window: 1s\nkey: frame"));
    Bytes p = attitude_payload(5000);
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(10, kAttitude, p)));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(200, kAttitude, p)));
}

TEST_F(DedupTest, ACopyLaterThanTheWindowIsKnownWhileItsLinkIsBehind) {
    ASSERT_TRUE(create("window: 500ms\ndrop_stale: false"));
    Bytes f = v2(1, kAttitude, attitude_payload(1000));
    uint64_t t = now();
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f, t));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f, t + 500 * kMs));  // the window's last instant
    // That copy came 500 ms late: the window is twice that and a margin now (1.25 s).
    EXPECT_NE(std::string::npos, status().find("\"window_ms\":1250.0,\"window_floor_ms\":500.0"))
        << status();
    // b has had nothing since f: it is behind, and g is kept for it past the window. Its copy
    // 1.25 s later is known, and the window grows to cover such a copy from now on.
    Bytes g = v2(2, kAttitude, attitude_payload(1001));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, g, t + 1000 * kMs));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, g, t + 2251 * kMs));
    EXPECT_NE(std::string::npos, status().find("\"beyond_window\":0,")) << status();
    EXPECT_NE(std::string::npos, status().find("\"window_ms\":2752.0")) << status();
}

TEST_F(DedupTest, ACopyLaterThanTheLongestWindowPasses) {
    // Beyond 15 s a copy is an outage's backlog, not a link's delay: nothing is kept for it.
    ASSERT_TRUE(create("window: 500ms\ndrop_stale: false"));
    Bytes f = v2(1, kAttitude, attitude_payload(1000));
    uint64_t t = now();
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f, t));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f, t + 100 * kMs));
    Bytes g = v2(2, kAttitude, attitude_payload(1001));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, g, t + 1000 * kMs));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, g, t + 16'001 * kMs));
    // Counted, and the window grows to its longest.
    EXPECT_NE(std::string::npos, status().find("\"beyond_window\":1,")) << status();
    EXPECT_NE(std::string::npos, status().find("\"window_ms\":15000.0")) << status();
}

TEST_F(DedupTest, WindowZeroDisablesDedup) {
    ASSERT_TRUE(create("window: 0s"));
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, f));
}

TEST_F(DedupTest, LinksOutsideBondsPassUntouchedAndLeaveNoTrace) {
    const mavbond_link& c = host_.add_link("c");
    ASSERT_TRUE(create("window: 1s"));
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    mavbond_frame_notes notes{};
    EXPECT_EQ(MAVBOND_PASS, feed(c, f, now(), &notes));
    EXPECT_EQ(0u, notes.flags);
    EXPECT_EQ(MAVBOND_PASS, feed(c, f));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f));  // c's frames were not remembered
    EXPECT_EQ(MAVBOND_PASS, feed(c, f));
}

TEST_F(DedupTest, BondsHaveSeparateMemories) {
    const mavbond_link& x = host_.add_link("x", "other");
    ASSERT_TRUE(create("window: 1s"));
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f));
    EXPECT_EQ(MAVBOND_PASS, feed(x, f));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f));
}

TEST_F(DedupTest, OnlyScopedBondsAreDeduplicated) {
    const mavbond_link& x = host_.add_link("x", "other");
    const mavbond_link& y = host_.add_link("y", "other");
    ASSERT_TRUE(create("bonds: [vehicle]\nwindow: 1s")) << host_.last_error();
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    EXPECT_EQ(MAVBOND_PASS, feed(x, f));
    EXPECT_EQ(MAVBOND_PASS, feed(y, f));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f));
}

TEST_F(DedupTest, DroppedFramesAreNotRemembered) {
    ASSERT_TRUE(create("window: 1s"));
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    mavbond_frame_notes notes{};
    // An earlier filter dropped a's copy: it must not shadow b's good one.
    feed(*a_, f, now(), &notes, MAVBOND_NOTE_DROPPED);
    EXPECT_EQ(MAVBOND_NOTE_DROPPED, notes.flags);
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, f, now() + 10 * kMs));
    EXPECT_EQ(MAVBOND_DROP, feed(*a_, f, now() + 20 * kMs));
    std::string s = status();
    EXPECT_NE(std::string::npos, s.find("\"name\":\"a\",\"passed\":0,\"duplicates\":1")) << s;
}

class DedupStrayFrameTest : public DedupTest, public ::testing::WithParamInterface<bool> {};

TEST_P(DedupStrayFrameTest, AStrayFrameOnOneLinkDoesNotShiftTheCopiesAfterIt) {
    // Link b carries one frame of the source nobody else has, numbered 80 ahead (a frame of
    // another sender using the same ids): b's numbering jumps, then comes back. The copies
    // after it are still recognised: by their position while the host calls them repeats,
    // by identity once it follows the restarted numbering. With signing, the signature
    // (link id, 48-bit timestamp) alone makes each frame unique.
    bool sign = GetParam();
    ASSERT_TRUE(create("window: 2s"));
    auto frame = [sign](uint8_t seq, uint32_t i) {
        Bytes f = v2(seq, kAttitude, attitude_payload(i));
        if (sign) {
            f[2] = 0x01;  // signed: link id, 6-byte timestamp, 6-byte signature follow
            for (int k = 0; k < 13; k++)
                f.push_back(static_cast<uint8_t>(i * 13 + k));
        }
        return f;
    };
    uint64_t t = now();
    for (uint32_t i = 0; i < 40; i++)
        EXPECT_EQ(MAVBOND_PASS, feed(*a_, frame(static_cast<uint8_t>(i), i), t + i * kMs));
    for (uint32_t i = 0; i < 20; i++)
        EXPECT_EQ(MAVBOND_DROP, feed(*b_, frame(static_cast<uint8_t>(i), i), t + 50 * kMs + i * kMs));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(100, kHeartbeat, heartbeat_payload()), t + 70 * kMs));
    for (uint32_t i = 20; i < 40; i++)
        EXPECT_EQ(MAVBOND_DROP, feed(*b_, frame(static_cast<uint8_t>(i), i), t + 71 * kMs + i * kMs))
            << "copy " << i;
}

INSTANTIATE_TEST_SUITE_P(Signing, DedupStrayFrameTest, ::testing::Values(false, true),
                         [](const auto& p) { return p.param ? "signed" : "unsigned"; });

TEST_F(DedupTest, Murmur3_32ReproducesThePaperSettings) {
    ASSERT_TRUE(create("hash: murmur3_32\nwindow: 5s\ndrop_stale: false")) << host_.last_error();
    Bytes f = v2(7, kHeartbeat, heartbeat_payload());
    mavbond_frame_notes notes{};
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, f, now(), &notes));
    EXPECT_EQ(0u, notes.hash[1]);
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, f, now() + 4900 * kMs));
    EXPECT_NE(std::string::npos, status().find("\"hash\":\"murmur3_32\""));
}

TEST_F(DedupTest, StaleMeansLateEnoughToMatter) {
    ASSERT_TRUE(create("window: 1s\nstale_after: 250ms"));
    uint64_t t = now();
    mavbond_frame_notes notes{};
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(1, kAttitude, attitude_payload(2000)), t));
    // b's sample from 30 ms before (a lost it): a few centimetres on the map, delivered.
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(0, kAttitude, attitude_payload(1970)), t + kMs));
    // 250 ms behind, the tolerance itself: delivered.
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(2, kAttitude, attitude_payload(1750)), t + 2 * kMs));
    // 500 ms behind: it would move the vehicle back on the map.
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(3, kAttitude, attitude_payload(1500)), t + 3 * kMs, &notes));
    EXPECT_TRUE(notes.flags & MAVBOND_NOTE_STALE);
    EXPECT_FALSE(notes.flags & MAVBOND_NOTE_DUPLICATE);
    // The same time from another sender, or a newer one, passes.
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(4, kAttitude, attitude_payload(1500), 2), t + 4 * kMs));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(5, kAttitude, attitude_payload(2001)), t + 5 * kMs));
    // Messages without a timestamp are never late, whatever order they come in.
    for (uint8_t seq = 20; seq > 10; seq--)
        EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(seq, kHeartbeat, heartbeat_payload()), t + 6 * kMs));
    // The autopilot reboots: time_boot_ms starts again near 0.
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(2, kAttitude, attitude_payload(50000)), t + 7 * kMs));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(3, kAttitude, attitude_payload(100)), t + 8 * kMs));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(4, kAttitude, attitude_payload(1000)), t + 9 * kMs));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(21, kAttitude, attitude_payload(150)), t + 10 * kMs));
    std::string s = status();
    EXPECT_NE(std::string::npos, s.find("\"name\":\"b\",\"passed\":14,\"duplicates\":0,\"stale\":2"))
        << s;
    EXPECT_NE(std::string::npos, s.find("\"stale_after_ms\":250.0")) << s;
}

TEST_F(DedupTest, StaleAfterZeroDropsAnyOlderSample) {
    ASSERT_TRUE(create("window: 1s\nstale_after: 0s"));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(1, kAttitude, attitude_payload(1000))));
    // A v2 payload cut to 2 bytes: time_boot_ms = 0x00000102 ms, 1000 - 258 ms back.
    Bytes p = attitude_payload(0x0102);
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(2, kAttitude, Bytes(p.begin(), p.begin() + 2))));
    EXPECT_EQ(MAVBOND_DROP, feed(*b_, v2(3, kAttitude, attitude_payload(999))));
}

TEST_F(DedupTest, DropStaleOff) {
    ASSERT_TRUE(create("window: 1s\ndrop_stale: false"));
    EXPECT_EQ(MAVBOND_PASS, feed(*a_, v2(1, kAttitude, attitude_payload(2000))));
    EXPECT_EQ(MAVBOND_PASS, feed(*b_, v2(0, kAttitude, attitude_payload(1500))));
}

TEST_F(DedupTest, BadOptionValuesNameFileLineColumn) {
    EXPECT_FALSE(create("window: 1s\nhash: md5"));
    const std::string& e = host_.last_error();
    EXPECT_NE(std::string::npos, e.find("test.yaml:")) << e;
    EXPECT_NE(std::string::npos, e.find("option 'hash'")) << e;
    EXPECT_NE(std::string::npos, e.find("murmur3_128")) << e;
    // file:line:column, then the message.
    size_t colon = e.find(':');
    ASSERT_NE(std::string::npos, colon);
    EXPECT_TRUE(std::isdigit(static_cast<unsigned char>(e[colon + 1]))) << e;
    EXPECT_NE(std::string::npos, e.find(':', colon + 1)) << e;

    EXPECT_FALSE(create("key: bytes"));
    EXPECT_NE(std::string::npos, host_.last_error().find("option 'key'")) << host_.last_error();
    EXPECT_FALSE(create("max_entries: 0"));
    EXPECT_NE(std::string::npos, host_.last_error().find("option 'max_entries'"));
    EXPECT_FALSE(create("window: soon"));
    EXPECT_NE(std::string::npos, host_.last_error().find("'window'")) << host_.last_error();
    EXPECT_FALSE(create("stale_after: -5ms"));
    EXPECT_NE(std::string::npos, host_.last_error().find("'stale_after'")) << host_.last_error();
}

TEST_F(DedupTest, UnknownOptionIsRejectedByTheHost) {
    EXPECT_FALSE(create("windw: 1s"));
    EXPECT_NE(std::string::npos, host_.last_error().find("unknown option 'windw'"))
        << host_.last_error();
}

TEST_F(DedupTest, DescriptorDeclaresOptionsWithDefaultsAndHelp) {
    int n = 0;
    for (const mavbond_option* o = plugin_->options; o->key; o++, n++) {
        EXPECT_NE(nullptr, o->default_value) << o->key;
        EXPECT_NE(nullptr, o->help) << o->key;
    }
    EXPECT_EQ(6, n);
    EXPECT_STREQ("dedup", plugin_->name);
    EXPECT_EQ(MAVBOND_PLUGIN_ABI_VERSION, plugin_->abi_version);
    ASSERT_TRUE(create(""));  // every default is valid
    EXPECT_NE(std::string::npos, status().find("\"window_ms\":2000.0")) << status();
    EXPECT_NE(std::string::npos, status().find("\"stale_after_ms\":250.0")) << status();
}

}  // namespace
}  // namespace mavbond
