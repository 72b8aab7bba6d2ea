#include "routing/link_account.h"

#include <gtest/gtest.h>

#include <array>
#include <cstring>

#include "mavlink/frame_parser.h"

namespace mavbond {
namespace {

TimePoint at(int ms) { return TimePoint(milliseconds(ms)); }

TEST(CountMarker, WrittenAndReadBackWithAFixedLength) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    for (auto m : {CountMarker{0, 7, false}, CountMarker{0xFFFFFFFFu, 123456, true},
                   CountMarker{1u << 31, 0, false}}) {
        size_t n = write_count_marker(buf, FrameSource{1, 191, 9}, "radio_link", m);
        ASSERT_EQ(count_marker_length("radio_link"), n);
        ParserCounters counters;
        DatagramParser parser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop,
                              counters);
        Frame f;
        ASSERT_TRUE(parser.next(f));
        EXPECT_TRUE(f.crc_checked);
        EXPECT_EQ(252u, f.msgid);
        EXPECT_EQ(std::string("mb") + (m.standby ? "s:" : "w:") + "radio_",
                  std::string(reinterpret_cast<const char*>(f.payload.data() + 8), 10));
        CountMarker back;
        ASSERT_TRUE(read_count_marker(f, back));
        EXPECT_EQ(m.written, back.written);
        EXPECT_EQ(m.session, back.session);
        EXPECT_EQ(m.standby, back.standby);
    }
    EXPECT_EQ(count_marker_length("ab"), write_count_marker(buf, {1, 1, 0}, "ab", {5, 5, false}));
}

TEST(CountMarker, ItCountsOnlyOnTheLinkItNames) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    for (const char* writer : {"sik", "radio_link", "lte"}) {
        size_t n = write_count_marker(buf, FrameSource{1, 191, 0}, writer, {3, 4, false});
        ParserCounters counters;
        Frame f;
        ASSERT_TRUE(DatagramParser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop,
                                   counters).next(f));
        CountMarker m;
        ASSERT_TRUE(read_count_marker(f, m));
        EXPECT_TRUE(m.names(writer)) << writer;
        EXPECT_EQ(std::string(writer) == "lte", m.names("lte")) << writer;
        EXPECT_FALSE(m.names("sik2")) << writer << ": a longer name is another link";
    }
    // Six characters are all a marker carries: endpoints that share them share markers.
    size_t n = write_count_marker(buf, FrameSource{1, 191, 0}, "radio_link", {3, 4, false});
    ParserCounters counters;
    Frame f;
    ASSERT_TRUE(DatagramParser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop,
                               counters).next(f));
    CountMarker m;
    ASSERT_TRUE(read_count_marker(f, m));
    EXPECT_EQ("radio_", m.link);
    EXPECT_TRUE(m.names("radio_other"));
}

TEST(CountMarker, AStandbyReportIsNotOne) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    std::array<uint8_t, 18> payload{};
    std::memcpy(payload.data() + 8, "mbl:sik", 7);
    size_t n = write_frame_v2(buf, {1, 191, 0}, 252, payload);
    ParserCounters counters;
    DatagramParser parser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop, counters);
    Frame f;
    ASSERT_TRUE(parser.next(f));
    CountMarker m;
    EXPECT_FALSE(read_count_marker(f, m));
}

// The far side wrote `written` frames before each marker; we received some of them.
TEST(LinkAccount, LossIsWrittenMinusReceivedAtEachMarker) {
    LinkAccount a;
    for (int i = 0; i < 5; i++)
        a.frame_in();  // before the first marker: written and arrived, no loss known
    EXPECT_FALSE(a.exact());
    a.take_marker({100, 1, false}, at(1000));  // 100 written before it, by a count begun before
    EXPECT_TRUE(a.exact());
    EXPECT_EQ(5u, a.expected());
    EXPECT_EQ(0, a.lost());
    // 50 frames written after it; 45 arrive; then a marker: 51 written since the first (it
    // counts itself).
    for (int i = 0; i < 45; i++)
        a.frame_in();
    a.take_marker({151, 1, true}, at(2000));
    EXPECT_EQ(5u + 51u, a.expected());
    EXPECT_EQ(5u + 46u, a.received());  // the first marker and the 45
    EXPECT_EQ(5, a.lost());
    EXPECT_TRUE(a.peer_standby());
    // A lost marker is a lost frame: the next one tells.
    for (int i = 0; i < 10; i++)
        a.frame_in();
    a.take_marker({151 + 1 + 10 + 1 + 10, 1, false}, at(4000));  // marker, 10, lost marker, 10
    EXPECT_EQ(5u + 51u + 22u, a.expected());
    EXPECT_EQ(5u + 46u + 11u, a.received());
    EXPECT_EQ(16, a.lost());
    EXPECT_EQ(at(4000), a.last_marker());
}

// What the operator is shown between two markers: the frames that came since the last one
// count as written and arrived; what was lost among them, the next marker tells.
TEST(LinkAccount, NowCountsEveryFrameInSinceTheLastMarker) {
    LinkAccount a;
    a.take_marker({0, 1, false}, at(0));
    for (int i = 0; i < 99; i++)
        a.frame_in();
    a.take_marker({110, 1, false}, at(1000));  // 110 written, 100 arrived (the first marker too)
    EXPECT_EQ(110u, a.expected());
    EXPECT_EQ(110u + 1u, a.expected_now());  // the marker itself came in after it
    EXPECT_EQ(10, a.lost());
    for (int i = 0; i < 30; i++)
        a.frame_in();
    EXPECT_EQ(110u, a.expected());  // at the last marker, for standby
    EXPECT_EQ(141u, a.expected_now());
    EXPECT_EQ(131u, a.received_now());
    // The next marker: 40 written since the last, the 31 in and 9 lost.
    a.take_marker({150, 1, false}, at(2000));
    EXPECT_EQ(151u, a.expected_now());
    EXPECT_EQ(132u, a.received_now());
    EXPECT_EQ(19, a.lost());
}

TEST(LinkAccount, AReorderedMarkerIsSkippedAndAWrapIsNot) {
    LinkAccount a;
    a.take_marker({0xFFFFFFF0u, 3, false}, at(0));
    for (int i = 0; i < 30; i++)
        a.frame_in();
    a.take_marker({0x0000000Fu, 3, false}, at(1000));  // 31 on, across the wrap
    EXPECT_EQ(31u, a.expected());
    EXPECT_EQ(31u, a.received());
    a.take_marker({0xFFFFFFFFu, 3, false}, at(1100));  // an older one, late
    EXPECT_EQ(1u, a.markers_late());
    EXPECT_EQ(31u, a.expected());
    a.take_marker({0x0000000Fu + 2, 3, false}, at(2000));  // the late one counted as arrived
    EXPECT_EQ(33u, a.expected());
    EXPECT_EQ(33u, a.received());
    EXPECT_EQ(0, a.lost());
}

TEST(LinkAccount, ANewSessionGoesOnFromTheTotals) {
    LinkAccount a;
    a.take_marker({10, 1, false}, at(0));
    for (int i = 0; i < 8; i++)
        a.frame_in();
    a.take_marker({20, 1, false}, at(1000));  // 10 written, 9 arrived (the marker and 8)
    EXPECT_EQ(1, a.lost());
    // The far side's link restarted: its count starts again; what came between (the marker
    // and the 4) counts as arrived, no loss known, so the figures of now never go back.
    for (int i = 0; i < 4; i++)
        a.frame_in();
    const uint64_t before = a.expected_now();
    a.take_marker({3, 2, false}, at(2000));
    EXPECT_EQ(1u, a.sessions());
    EXPECT_EQ(15u, a.expected());
    EXPECT_EQ(before + 1, a.expected_now());
    EXPECT_EQ(1, a.lost());
    for (int i = 0; i < 5; i++)
        a.frame_in();
    a.take_marker({3 + 1 + 7, 2, false}, at(3000));  // 8 written, 6 arrived
    EXPECT_EQ(23u, a.expected());
    EXPECT_EQ(3, a.lost());
}

TEST(LinkAccount, APeerAtANewPortGoesOnWithTheOldOnesCount) {
    LinkAccount old;
    old.take_marker({50, 4, false}, at(0));
    for (int i = 0; i < 9; i++)
        old.frame_in();
    LinkAccount moved;
    for (int i = 0; i < 3; i++)
        moved.frame_in();  // its first datagram, before the rebinding was seen
    moved.continue_from(old);
    EXPECT_TRUE(old.moved());  // its figures go on in `moved`: not to be summed with them
    EXPECT_FALSE(moved.moved());
    moved.take_marker({50 + 1 + 9 + 1 + 3, 4, false}, at(1000));  // one frame lost in the move
    EXPECT_EQ(14u, moved.expected());
    EXPECT_EQ(13u, moved.received());
    EXPECT_EQ(0u, moved.sessions());
}

// What the old and the new address brought, fed to one account as one link would have had it:
// the figures of a move judged late (markers taken at the new address meanwhile) must be these.
struct Move {
    LinkAccount old, fresh, one;
    void in_old(int n) { for (int i = 0; i < n; i++) old.frame_in(), one.frame_in(); }
    void in_fresh(int n) { for (int i = 0; i < n; i++) fresh.frame_in(), one.frame_in(); }
    void marker_old(CountMarker m, int ms) { old.take_marker(m, at(ms)), one.take_marker(m, at(ms)); }
    void marker_fresh(CountMarker m, int ms) {
        fresh.take_marker(m, at(ms)), one.take_marker(m, at(ms));
    }
    void expect_one() const {
        EXPECT_EQ(one.expected(), fresh.expected());
        EXPECT_EQ(one.received(), fresh.received());
        EXPECT_EQ(one.expected_now(), fresh.expected_now());
        EXPECT_EQ(one.received_now(), fresh.received_now());
        EXPECT_EQ(one.markers(), fresh.markers());
        EXPECT_EQ(one.sessions(), fresh.sessions());
        EXPECT_EQ(one.last_marker(), fresh.last_marker());
    }
};

TEST(LinkAccount, AMoveJudgedAfterTheNewAddressTookMarkersIsOneCount) {
    // An unsigned peer's move is judged over 2 s, and a first datagram may hold a marker: the
    // new address has taken markers of the same count by then, and the frames lost in the move
    // (between the old address's last marker and the new one's first) are the link's loss.
    Move m;
    m.marker_old({50, 4, false}, 0);
    m.in_old(9);
    m.marker_old({50 + 1 + 9 + 2, 4, false}, 1000);  // 2 lost
    m.in_old(4);
    m.in_fresh(3);
    m.marker_fresh({62 + 1 + 4 + 2 + 3, 4, true}, 2000);  // 2 lost in the move
    m.in_fresh(7);
    m.marker_fresh({72 + 1 + 7 + 1, 4, true}, 3000);  // 1 lost
    m.in_fresh(5);
    m.fresh.continue_from(m.old);
    EXPECT_TRUE(m.old.moved());
    EXPECT_FALSE(m.fresh.moved());
    m.expect_one();
    EXPECT_EQ(5, m.fresh.lost());
    EXPECT_TRUE(m.fresh.peer_standby());  // the newest marker's word
    m.marker_fresh({81 + 1 + 5, 4, false}, 4000);  // and it goes on as one
    m.expect_one();
}

TEST(LinkAccount, AMoveAcrossARestartOfTheFarSidesCountIsOneCount) {
    Move m;
    m.marker_old({10, 1, false}, 0);
    m.in_old(8);
    m.marker_old({20, 1, false}, 1000);  // 1 lost
    m.in_old(2);
    m.in_fresh(4);
    m.marker_fresh({3, 2, false}, 2000);  // its link restarted: a new count
    m.in_fresh(6);
    m.marker_fresh({3 + 1 + 6 + 3, 2, false}, 3000);  // 3 lost
    m.fresh.continue_from(m.old);
    m.expect_one();
    EXPECT_EQ(1u, m.fresh.sessions());
    EXPECT_EQ(4, m.fresh.lost());
}

}  // namespace
}  // namespace mavbond
