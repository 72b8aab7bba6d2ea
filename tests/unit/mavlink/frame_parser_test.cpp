#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "mavlink/frame_parser.h"
#include "mavlink/message_table.h"
#include "vectors.h"

namespace mavbond {
namespace {

using test::Bytes;
using test::vec;
using test::Vector;

Bytes cat(std::initializer_list<Bytes> parts) {
    Bytes out;
    for (const auto& p : parts)
        out.insert(out.end(), p.begin(), p.end());
    return out;
}

Bytes to_bytes(std::span<const uint8_t> s) { return Bytes(s.begin(), s.end()); }

void expect_matches(const Frame& f, const Vector& v) {
    SCOPED_TRACE(v.label);
    EXPECT_EQ(to_bytes(f.bytes), v.bytes);
    EXPECT_EQ(f.version, v.version);
    EXPECT_EQ(f.msgid, v.msgid);
    EXPECT_EQ(f.seq, v.seq);
    EXPECT_EQ(f.sysid, v.sysid);
    EXPECT_EQ(f.compid, v.compid);
    EXPECT_EQ(f.target_system, v.target_system);
    EXPECT_EQ(f.target_component, v.target_component);
    EXPECT_EQ(f.is_signed(), v.is_signed);
    EXPECT_EQ(f.payload.size(), v.payload_len);
    EXPECT_EQ(f.payload.data(), f.bytes.data() + (v.version == 2 ? kHeaderLenV2 : kHeaderLenV1));
}

/// Every frame a datagram yields.
std::vector<Bytes> parse_datagram(const Bytes& d, ParserCounters& c,
                                  UnknownIdPolicy policy = UnknownIdPolicy::Forward) {
    DatagramParser p(d, policy, c);
    std::vector<Bytes> out;
    Frame f;
    while (p.next(f))
        out.push_back(to_bytes(f.bytes));
    return out;
}

/// Feeds `data` to a stream parser in chunks of the given sizes (cycled), draining after each.
std::vector<Bytes> parse_stream(StreamParser& p, const Bytes& data, const std::vector<size_t>& chunks) {
    std::vector<Bytes> out;
    size_t pos = 0;
    size_t i = 0;
    Frame f;
    while (pos < data.size()) {
        auto area = p.write_area();
        EXPECT_FALSE(area.empty());
        const size_t n = std::min({chunks[i++ % chunks.size()], area.size(), data.size() - pos});
        std::memcpy(area.data(), data.data() + pos, n);
        p.commit(n);
        pos += n;
        while (p.next(f))
            out.push_back(to_bytes(f.bytes));
    }
    return out;
}

bool is_good(const Vector& v) {
    return v.label != "unknown_id" && v.label != "bad_flags";
}

Bytes garbage_without_magic(std::mt19937& rng, size_t n) {
    Bytes g(n);
    for (auto& b : g) {
        do {
            b = static_cast<uint8_t>(rng());
        } while (b == kMagicV1 || b == kMagicV2);
    }
    return g;
}

TEST(DatagramParser, EveryVectorAlone) {
    size_t checked = 0;
    for (const auto& v : test::vectors()) {
        if (!is_good(v))
            continue;
        ParserCounters c;
        DatagramParser p(v.bytes, UnknownIdPolicy::Forward, c);
        Frame f;
        ASSERT_TRUE(p.next(f)) << v.label;
        expect_matches(f, v);
        EXPECT_TRUE(f.crc_checked);
        ASSERT_NE(f.info, nullptr);
        EXPECT_EQ(f.info->msgid, v.msgid);
        EXPECT_FALSE(p.next(f));
        EXPECT_EQ(c.frames, 1u);
        EXPECT_EQ(c.bytes, v.bytes.size());
        EXPECT_EQ(c.garbage_bytes, 0u);
        EXPECT_EQ(c.crc_errors, 0u);
        ++checked;
    }
    EXPECT_GT(checked, 80u);
}

TEST(DatagramParser, Targets) {
    struct Case {
        const char* label;
        int ts;
        int tc;
    };
    for (const Case& k : {Case{"v1_command_long", 1, 1}, Case{"v2_command_long", 1, 1},
                          Case{"v2_param_request_read", 7, 190}, Case{"v1_heartbeat", -1, -1},
                          Case{"v2_heartbeat", -1, -1}, Case{"v2_attitude", -1, -1},
                          Case{"trunc_command_long", 5, 0}, Case{"trunc_param_request_read", 0, 0},
                          Case{"v2_device_op_read", 11, 12},
                          Case{"v2_open_drone_id_basic_id", 9, 8}}) {
        ParserCounters c;
        DatagramParser p(vec(k.label).bytes, UnknownIdPolicy::Forward, c);
        Frame f;
        ASSERT_TRUE(p.next(f)) << k.label;
        EXPECT_EQ(f.target_system, k.ts) << k.label;
        EXPECT_EQ(f.target_component, k.tc) << k.label;
        EXPECT_EQ(f.is_broadcast(), k.ts <= 0) << k.label;
    }
}

TEST(DatagramParser, TruncatedPayloads) {
    const Vector& cmd = vec("trunc_command_long");
    EXPECT_LT(cmd.payload_len, find_message(76)->min_len);   // the sender trimmed zeros
    const Vector& hb = vec("trunc_heartbeat_zero");
    EXPECT_EQ(hb.payload_len, 1u);
    for (const auto* v : {&cmd, &hb, &vec("trunc_param_request_read")}) {
        ParserCounters c;
        DatagramParser p(v->bytes, UnknownIdPolicy::Forward, c);
        Frame f;
        ASSERT_TRUE(p.next(f));
        expect_matches(f, *v);
    }
}

TEST(DatagramParser, SignedFramesKeepTheirSignature) {
    for (const auto* v : test::vectors_with_prefix("signed_")) {
        ParserCounters c;
        DatagramParser p(v->bytes, UnknownIdPolicy::Forward, c);
        Frame f;
        ASSERT_TRUE(p.next(f)) << v->label;
        EXPECT_TRUE(f.is_signed());
        EXPECT_EQ(f.bytes.size(), kHeaderLenV2 + v->payload_len + kChecksumLen + kSignatureLen);
        expect_matches(f, *v);
    }
}

TEST(DatagramParser, SeveralFramesAndGarbage) {
    std::mt19937 rng(7);
    Bytes d = garbage_without_magic(rng, 5);
    std::vector<Bytes> expected;
    size_t garbage = 5;
    for (const auto& v : test::vectors()) {
        if (!is_good(v))
            continue;
        d.insert(d.end(), v.bytes.begin(), v.bytes.end());
        expected.push_back(v.bytes);
        const size_t n = rng() % 4;   // sometimes frames are back to back
        const Bytes g = garbage_without_magic(rng, n);
        d.insert(d.end(), g.begin(), g.end());
        garbage += n;
    }
    ParserCounters c;
    EXPECT_EQ(parse_datagram(d, c), expected);
    EXPECT_EQ(c.frames, expected.size());
    EXPECT_EQ(c.garbage_bytes, garbage);
    EXPECT_EQ(c.bytes + c.garbage_bytes, d.size());
    EXPECT_EQ(c.crc_errors, 0u);
}

TEST(DatagramParser, TruncatedTailIsGarbage) {
    const Bytes a = vec("v2_attitude").bytes;
    const Bytes b = vec("v1_heartbeat").bytes;
    Bytes d = cat({a, Bytes(b.begin(), b.begin() + 10)});
    ParserCounters c;
    EXPECT_EQ(parse_datagram(d, c), std::vector<Bytes>{a});
    EXPECT_EQ(c.garbage_bytes, 10u);
}

TEST(DatagramParser, BadCrcIsRejectedAndTheNextFrameSurvives) {
    for (const auto& v : test::vectors()) {
        if (!is_good(v))
            continue;
        const size_t header_len = v.version == 2 ? kHeaderLenV2 : kHeaderLenV1;
        for (size_t at : {header_len + v.payload_len / 2, header_len + v.payload_len}) {
            SCOPED_TRACE(v.label + " byte " + std::to_string(at));
            Bytes bad = v.bytes;
            bad[at] ^= 0x40;   // a payload byte, or the CRC
            const Bytes good = vec("v2_heartbeat").bytes;
            // Drop: bytes inside the rejected frame may look like an unknown-id frame.
            ParserCounters c;
            EXPECT_EQ(parse_datagram(cat({bad, good}), c, UnknownIdPolicy::Drop),
                      std::vector<Bytes>{good});
            // At least the frame itself; start bytes inside it may make more candidates.
            EXPECT_GE(c.crc_errors + c.bad_flags, 1u);
            EXPECT_EQ(c.bytes, good.size());
        }
    }
}

TEST(DatagramParser, OneBitFlippedInTheMsgidNeverPasses) {
    // The commonest damage on a radio link. The new id is either known (the CRC fails) or
    // unknown, and then the CRC still proves it was a known frame one bit away: rejected.
    for (const char* label : {"v2_heartbeat", "v1_heartbeat"}) {
        const Bytes good = vec(label).bytes;
        const bool v2 = good[0] == kMagicV2;
        const std::vector<size_t> id_bytes = v2 ? std::vector<size_t>{7, 8, 9} : std::vector<size_t>{5};
        for (size_t byte : id_bytes) {
            for (int bit = 0; bit < 8; bit++) {
                Bytes bad = good;
                bad[byte] ^= static_cast<uint8_t>(1 << bit);
                ParserCounters c;
                EXPECT_TRUE(parse_datagram(bad, c).empty()) << label << " byte " << byte << " bit " << bit;
                EXPECT_EQ(c.unknown_ids, 0u);
                EXPECT_GE(c.crc_errors, 1u);
            }
        }
    }
}

TEST(DatagramParser, CorruptedMsgidMayLookUnknown) {
    // Several bits of the msgid corrupted can turn a frame into one with an unknown id that
    // no single flip explains: it cannot be checked, so under Forward it goes out unverified
    // (crc_checked false), under Drop not.
    Bytes bad = vec("v2_heartbeat").bytes;
    bad[8] = 0x77;
    ASSERT_EQ(find_message(0x7700), nullptr);
    ParserCounters c;
    DatagramParser p(bad, UnknownIdPolicy::Forward, c);
    Frame f;
    ASSERT_TRUE(p.next(f));
    EXPECT_FALSE(f.crc_checked);
    EXPECT_EQ(f.msgid, 0x7700u);
    EXPECT_EQ(c.unknown_ids, 1u);
}

TEST(DatagramParser, UnknownIdForwardAndDrop) {
    const Vector& u = vec("unknown_id");
    ASSERT_EQ(find_message(u.msgid), nullptr);
    const Bytes hb = vec("v1_heartbeat").bytes;
    const Bytes d = cat({u.bytes, hb});
    {
        ParserCounters c;
        DatagramParser p(d, UnknownIdPolicy::Forward, c);
        Frame f;
        ASSERT_TRUE(p.next(f));
        expect_matches(f, u);
        EXPECT_FALSE(f.crc_checked);
        EXPECT_EQ(f.info, nullptr);
        ASSERT_TRUE(p.next(f));
        EXPECT_EQ(to_bytes(f.bytes), hb);
        EXPECT_FALSE(p.next(f));
        EXPECT_EQ(c.unknown_ids, 1u);
        EXPECT_EQ(c.frames, 2u);
        EXPECT_EQ(c.garbage_bytes, 0u);
    }
    {
        ParserCounters c;
        EXPECT_EQ(parse_datagram(d, c, UnknownIdPolicy::Drop), std::vector<Bytes>{hb});
        EXPECT_EQ(c.unknown_ids, 1u);
        EXPECT_EQ(c.frames, 1u);
        EXPECT_EQ(c.garbage_bytes, 0u);
    }
}

TEST(DatagramParser, UnknownIncompatFlagsRejected) {
    const Vector& bad = vec("bad_flags");
    const Bytes good = vec("flags_base").bytes;
    ParserCounters c;
    EXPECT_EQ(parse_datagram(cat({bad.bytes, good}), c), std::vector<Bytes>{good});
    EXPECT_EQ(c.bad_flags, 1u);
    EXPECT_EQ(c.crc_errors, 0u);
    EXPECT_EQ(c.garbage_bytes, bad.bytes.size());
}

TEST(DatagramParser, NoiseShapedLikeAnUnknownFrameDoesNotSwallowAGoodOne) {
    // A false v2 header with an unknown msgid claiming 60 bytes of payload, then a good frame
    // that starts inside the span the false header claims.
    const Bytes noise = {0xFD, 60, 0, 0, 1, 1, 1, 0x98, 0x3A, 0x00, 0x11, 0x22};
    const Bytes good = vec("v2_attitude").bytes;
    Bytes tail(60, 0x33);
    ParserCounters c;
    EXPECT_EQ(parse_datagram(cat({noise, good, tail}), c), std::vector<Bytes>{good});
    EXPECT_EQ(c.unknown_ids, 0u);
    EXPECT_EQ(c.garbage_bytes, noise.size() + tail.size());
}

TEST(StreamParser, EverySplitPoint) {
    const Bytes trailer = vec("v2_heartbeat").bytes;
    for (const char* label : {"v1_command_long", "v2_attitude", "signed_param_request_read",
                              "trunc_heartbeat_zero", "v2_device_op_read", "unknown_id"}) {
        const Vector& v = vec(label);
        const Bytes lead = {0x01, 0x02};   // a little garbage first
        const Bytes data = cat({lead, v.bytes, trailer});
        const size_t frame_end = lead.size() + v.bytes.size();
        for (size_t split = 0; split <= data.size(); ++split) {
            SCOPED_TRACE(std::string(label) + " split " + std::to_string(split));
            StreamParser p(UnknownIdPolicy::Forward);
            Frame f;
            auto area = p.write_area();
            std::memcpy(area.data(), data.data(), split);
            p.commit(split);
            std::vector<Bytes> got;
            while (p.next(f))
                got.push_back(to_bytes(f.bytes));
            // A known frame comes out as soon as it is complete; an unknown-id one once the
            // next frame's start byte shows where it ends.
            const bool known = find_message(v.msgid) != nullptr;
            const size_t needed = known ? frame_end : frame_end + 1;
            EXPECT_EQ(got.size(), split >= data.size() ? 2u : split >= needed ? 1u : 0u);
            if (!got.empty()) {
                EXPECT_EQ(got[0], v.bytes);
            }
            area = p.write_area();
            std::memcpy(area.data(), data.data() + split, data.size() - split);
            p.commit(data.size() - split);
            while (p.next(f))
                got.push_back(to_bytes(f.bytes));
            ASSERT_EQ(got.size(), 2u);
            EXPECT_EQ(got[0], v.bytes);
            EXPECT_EQ(got[1], trailer);
            EXPECT_EQ(p.counters().frames, 2u);
            EXPECT_EQ(p.counters().garbage_bytes, lead.size());
        }
    }
}

TEST(StreamParser, SeveralFramesInOneRead) {
    std::vector<Bytes> expected;
    Bytes data;
    for (const auto* v : test::vectors_with_prefix("mix_")) {
        data.insert(data.end(), v->bytes.begin(), v->bytes.end());
        expected.push_back(v->bytes);
    }
    ASSERT_LT(data.size(), 4096u);
    StreamParser p(UnknownIdPolicy::Forward);
    EXPECT_EQ(parse_stream(p, data, {data.size()}), expected);
    EXPECT_EQ(p.counters().frames, expected.size());
    EXPECT_EQ(p.counters().garbage_bytes, 0u);
}

TEST(StreamParser, RandomGarbageBetweenFramesLosesNothing) {
    for (unsigned seed = 1; seed <= 20; ++seed) {
        SCOPED_TRACE("seed " + std::to_string(seed));
        std::mt19937 rng(seed);
        std::vector<Bytes> expected;
        Bytes data;
        for (int round = 0; round < 5; ++round) {
            for (const auto* v : test::vectors_with_prefix("mix_")) {
                // Garbage full of start bytes, some of them followed by plausible headers.
                const size_t n = rng() % 40;
                for (size_t i = 0; i < n; ++i) {
                    const unsigned r = rng() % 8;
                    data.push_back(r == 0 ? kMagicV1 : r == 1 ? kMagicV2 : static_cast<uint8_t>(rng()));
                }
                data.insert(data.end(), v->bytes.begin(), v->bytes.end());
                expected.push_back(v->bytes);
            }
        }
        std::vector<size_t> chunks;
        for (int i = 0; i < 64; ++i)
            chunks.push_back(1 + rng() % 300);
        // Drop: noise can never be mistaken for a frame (an unknown-id lookalike is dropped).
        StreamParser p(UnknownIdPolicy::Drop, 1024);
        const auto frames = parse_stream(p, data, chunks);
        EXPECT_EQ(frames, expected);
        const auto& c = p.counters();
        EXPECT_EQ(c.bytes, [&] {
            size_t n = 0;
            for (const auto& e : expected)
                n += e.size();
            return n;
        }());
        // Forward: every good frame still comes out, in order (noise may be forwarded too).
        StreamParser q(UnknownIdPolicy::Forward, 1024);
        const auto all = parse_stream(q, data, chunks);
        size_t k = 0;
        for (const auto& fr : all) {
            if (k < expected.size() && fr == expected[k])
                ++k;
        }
        EXPECT_EQ(k, expected.size());
    }
}

TEST(StreamParser, FalseStartBytesInsideGarbage) {
    const Bytes good = vec("v2_heartbeat").bytes;
    // Each lookalike is rejected at once (impossible length, unknown flags, or an unknown id
    // whose span holds a good frame), so the good frame comes out of the same commit.
    const std::vector<Bytes> lookalikes = {
        {0xFE, 200, 0, 1, 1, 0},                  // v1 HEARTBEAT claiming 200 bytes
        {0xFD, 100, 0, 0, 0, 1, 1, 0, 0, 0},      // v2 HEARTBEAT claiming 100 > 9
        {0xFD, 9, 0x80, 0},                       // unknown incompat flag
        {0xFD, 250, 0, 0, 0, 1, 1, 0x98, 0x3A},   // unknown id claiming 250 bytes
        {0xFE, 0xFD, 0xFE, 0xFD},                 // a run of start bytes
    };
    for (const auto& noise : lookalikes) {
        StreamParser p(UnknownIdPolicy::Forward);
        const auto frames = parse_stream(p, cat({noise, good}), {4096});
        EXPECT_EQ(frames, std::vector<Bytes>{good});
        EXPECT_EQ(p.counters().garbage_bytes, noise.size());
        EXPECT_EQ(p.counters().unknown_ids, 0u);
    }
}

TEST(StreamParser, CorruptedLengthThenGoodFrameInTheSameLoop) {
    const Bytes good = vec("v2_heartbeat").bytes;
    struct Case {
        const char* label;
        uint8_t len;
    };
    // Shorter (CRC fails), longer but possible (CRC fails once complete), impossible (> max_len).
    for (const Case& k : {Case{"v2_statustext", 30}, Case{"v2_statustext", 45},
                          Case{"v2_attitude", 200}, Case{"v1_attitude", 20},
                          Case{"v1_command_long", 34}}) {
        SCOPED_TRACE(std::string(k.label) + " len " + std::to_string(k.len));
        Bytes bad = vec(k.label).bytes;
        bad[1] = k.len;
        const Bytes data = cat({bad, good, good});
        StreamParser p(UnknownIdPolicy::Forward);
        auto area = p.write_area();
        std::memcpy(area.data(), data.data(), data.size());
        p.commit(data.size());
        Frame f;
        ASSERT_TRUE(p.next(f));   // no further commit needed
        EXPECT_EQ(to_bytes(f.bytes), good);
        ASSERT_TRUE(p.next(f));
        EXPECT_EQ(to_bytes(f.bytes), good);
        EXPECT_FALSE(p.next(f));
        EXPECT_EQ(p.counters().crc_errors, 1u);
        EXPECT_EQ(p.counters().garbage_bytes, bad.size());
    }
}

TEST(StreamParser, ImpossibleLengthRejectedWithoutWaiting) {
    StreamParser p(UnknownIdPolicy::Forward);
    const Bytes hdr = {0xFE, 100, 0, 1, 1, 0};   // v1 HEARTBEAT is 9 bytes long
    auto area = p.write_area();
    std::memcpy(area.data(), hdr.data(), hdr.size());
    p.commit(hdr.size());
    Frame f;
    EXPECT_FALSE(p.next(f));
    EXPECT_EQ(p.counters().bad_lengths, 1u);
    EXPECT_EQ(p.counters().crc_errors, 1u);
    EXPECT_EQ(p.counters().garbage_bytes, hdr.size());
}

TEST(StreamParser, KnownIdCandidateWaitsForItsBytes) {
    // A possible frame is never given up before it is complete: the bytes may be real.
    const Bytes v = vec("v2_statustext").bytes;
    StreamParser p(UnknownIdPolicy::Forward);
    auto area = p.write_area();
    std::memcpy(area.data(), v.data(), v.size() - 1);
    p.commit(v.size() - 1);
    Frame f;
    EXPECT_FALSE(p.next(f));
    EXPECT_EQ(p.counters().garbage_bytes, 0u);
    area = p.write_area();
    area[0] = v.back();
    p.commit(1);
    ASSERT_TRUE(p.next(f));
    EXPECT_EQ(to_bytes(f.bytes), v);
}

TEST(StreamParser, UnknownIdWaitsThenYields) {
    const Vector& u = vec("unknown_id");
    StreamParser p(UnknownIdPolicy::Forward);
    const auto frames = parse_stream(p, cat({u.bytes, vec("v2_heartbeat").bytes}), {3});
    ASSERT_EQ(frames.size(), 2u);
    EXPECT_EQ(frames[0], u.bytes);
    EXPECT_EQ(p.counters().unknown_ids, 1u);
    StreamParser d(UnknownIdPolicy::Drop);
    EXPECT_EQ(parse_stream(d, cat({u.bytes, vec("v2_heartbeat").bytes}), {3}).size(), 1u);
    EXPECT_EQ(d.counters().unknown_ids, 1u);
    EXPECT_EQ(d.counters().garbage_bytes, 0u);
}

TEST(StreamParser, SmallCapacityLongStream) {
    // Capacity is raised to 2 * kMaxFrameLen; a long stream goes through in odd-sized reads.
    StreamParser p(UnknownIdPolicy::Forward, 16);
    EXPECT_GE(p.write_area().size(), 2 * kMaxFrameLen);
    std::vector<Bytes> expected;
    Bytes data;
    for (int i = 0; i < 50; ++i) {
        for (const auto& v : test::vectors()) {
            if (!is_good(v))
                continue;
            data.insert(data.end(), v.bytes.begin(), v.bytes.end());
            expected.push_back(v.bytes);
        }
    }
    EXPECT_EQ(parse_stream(p, data, {7, 300, 1, 64, 513}), expected);
    EXPECT_EQ(p.counters().garbage_bytes, 0u);
    EXPECT_EQ(p.counters().bytes, data.size());
}

TEST(StreamParser, ResetCountsBufferedBytesAsGarbage) {
    StreamParser p(UnknownIdPolicy::Forward);
    const Bytes v = vec("v2_attitude").bytes;
    auto area = p.write_area();
    std::memcpy(area.data(), v.data(), 10);
    p.commit(10);
    Frame f;
    EXPECT_FALSE(p.next(f));
    p.reset();
    EXPECT_EQ(p.counters().garbage_bytes, 10u);
    const auto frames = parse_stream(p, v, {v.size()});
    EXPECT_EQ(frames, std::vector<Bytes>{v});
}

// A false v2 header (unknown msgid, 254 bytes claimed, more than the stream holds yet) spans
// an 8-byte v1 frame of an unknown msgid, then a good frame. The stream parser rejects only
// the false start byte and yields the unknown-id frame, as the datagram parser does; it used
// to skip straight to the good frame (found by tests/fuzz/fuzz_stream).
TEST(StreamParser, UnknownIdFrameInsideAnIncompleteCandidateIsKept) {
    const Bytes false_start = {0xFD};
    const Bytes unknown_v1 = {0xFE, 0, 0, 0, 0xFD, 96, 0xED, 0x36};   // msgid 96: unknown
    const Bytes good = vec("v2_heartbeat").bytes;
    const Bytes data = cat({false_start, unknown_v1, good});
    ASSERT_EQ(find_message(96), nullptr);
    ParserCounters dc;
    const std::vector<Bytes> want = {unknown_v1, good};
    EXPECT_EQ(parse_datagram(data, dc), want);
    StreamParser p(UnknownIdPolicy::Forward);
    EXPECT_EQ(parse_stream(p, data, {data.size()}), want);
    EXPECT_EQ(p.counters().garbage_bytes, 1u);
    EXPECT_EQ(p.counters().unknown_ids, 1u);
}

// A known frame whose msgid lost a bit in transit (so it looks unknown) and whose payload
// holds a whole good frame: the good frame is yielded, and the damaged one counts the same
// whether it arrived whole or byte by byte (it used to be a CRC error only when whole; found
// by tests/fuzz/fuzz_stream).
TEST(StreamParser, DamagedKnownFrameHidingAGoodOneCountsTheSameInAnySplit) {
    const Bytes good = vec("v2_heartbeat").bytes;
    uint32_t id = 0;
    uint32_t flipped = 0;
    for (uint32_t m = 0; m < 512 && flipped == 0; ++m) {
        const MessageInfo* info = find_message(m);
        for (unsigned bit = 0; info != nullptr && info->max_len >= good.size() + 4 && bit < 24;
             ++bit) {
            if (find_message(m ^ (1u << bit)) == nullptr) {
                id = m;
                flipped = m ^ (1u << bit);
                break;
            }
        }
    }
    ASSERT_NE(flipped, 0u);
    Bytes payload = cat({{1, 2}, good, {3, 4}});
    Bytes frame = {0xFD, static_cast<uint8_t>(payload.size()), 0, 0, 7, 1, 1,
                   static_cast<uint8_t>(id), static_cast<uint8_t>(id >> 8),
                   static_cast<uint8_t>(id >> 16)};
    frame.insert(frame.end(), payload.begin(), payload.end());
    uint16_t crc = crc_x25(std::span<const uint8_t>(frame).subspan(1));
    crc = crc_x25_byte(find_message(id)->crc_extra, crc);
    frame.push_back(static_cast<uint8_t>(crc));
    frame.push_back(static_cast<uint8_t>(crc >> 8));
    frame[7] = static_cast<uint8_t>(flipped);
    frame[8] = static_cast<uint8_t>(flipped >> 8);
    frame[9] = static_cast<uint8_t>(flipped >> 16);

    StreamParser whole(UnknownIdPolicy::Forward);
    StreamParser bytewise(UnknownIdPolicy::Forward);
    EXPECT_EQ(parse_stream(whole, frame, {frame.size()}), std::vector<Bytes>{good});
    EXPECT_EQ(parse_stream(bytewise, frame, {1}), std::vector<Bytes>{good});
    EXPECT_EQ(whole.counters().crc_errors, bytewise.counters().crc_errors);
    EXPECT_EQ(whole.counters().garbage_bytes, frame.size() - good.size());
    EXPECT_EQ(bytewise.counters().garbage_bytes, frame.size() - good.size());
}

}  // namespace
}  // namespace mavbond
