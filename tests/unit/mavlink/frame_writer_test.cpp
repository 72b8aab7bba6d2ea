// Frames mavbond writes itself parse back as valid; a renumbered frame's CRC equals the one
// computed from scratch, for v1, v2, truncated payloads and ids c_library_v2 does not know.
#include "mavlink/frame_writer.h"

#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "mavlink/frame_parser.h"
#include "mavlink/message_table.h"

namespace mavbond {
namespace {

using Bytes = std::vector<uint8_t>;

Frame parse_one(const Bytes& bytes) {
    ParserCounters c;
    DatagramParser p(bytes, UnknownIdPolicy::Forward, c);
    Frame f;
    EXPECT_TRUE(p.next(f));
    EXPECT_EQ(0u, c.crc_errors);
    return f;
}

Bytes write(uint8_t seq, uint32_t msgid, const Bytes& payload) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    size_t n = write_frame_v2(buf, FrameSource{1, 191, seq}, msgid, payload);
    return Bytes(buf.begin(), buf.begin() + static_cast<long>(n));
}

/// A v1 frame, or a v2 frame of any msgid with the CRC_EXTRA given: built by hand.
Bytes by_hand(uint8_t version, uint8_t seq, uint32_t msgid, const Bytes& payload, uint8_t extra) {
    Bytes b = version == 1 ? Bytes{kMagicV1, static_cast<uint8_t>(payload.size()), seq, 1, 1,
                                   static_cast<uint8_t>(msgid)}
                           : Bytes{kMagicV2, static_cast<uint8_t>(payload.size()), 0, 0, seq, 1, 1,
                                   static_cast<uint8_t>(msgid), static_cast<uint8_t>(msgid >> 8),
                                   static_cast<uint8_t>(msgid >> 16)};
    b.insert(b.end(), payload.begin(), payload.end());
    uint16_t crc = crc_x25_byte(extra, crc_x25(std::span<const uint8_t>(b.data() + 1, b.size() - 1)));
    b.push_back(static_cast<uint8_t>(crc));
    b.push_back(static_cast<uint8_t>(crc >> 8));
    return b;
}

TEST(FrameWriter, StatustextParsesBackTruncated) {
    Bytes payload(54, 0);
    payload[0] = 4;
    const char text[] = "mavbond: link lte lost";
    std::copy(text, text + sizeof text - 1, payload.begin() + 1);
    Bytes b = write(7, 253, payload);
    Frame f = parse_one(b);
    EXPECT_TRUE(f.crc_checked);
    EXPECT_EQ(253u, f.msgid);
    EXPECT_EQ(7, f.seq);
    EXPECT_EQ(1, f.sysid);
    EXPECT_EQ(191, f.compid);
    EXPECT_EQ(1u + sizeof text - 1, f.payload.size()) << "trailing zeros cut";
}

TEST(FrameWriter, AllZeroPayloadKeepsOneByte) {
    Bytes b = write(0, 0, Bytes(9, 0));
    EXPECT_EQ(1u, parse_one(b).payload.size());
}

TEST(FrameWriter, RefusesUnknownIdsAndOversizedPayloads) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    EXPECT_EQ(0u, write_frame_v2(buf, FrameSource{1, 1, 0}, 0xABCDEF, Bytes(4, 1)));
    EXPECT_EQ(0u, write_frame_v2(buf, FrameSource{1, 1, 0}, 0, Bytes(10, 1)));
}

TEST(FrameWriter, RenumberedV2FrameEqualsOneWrittenWithThatSeq) {
    Bytes payload(28, 0);
    for (size_t i = 0; i < payload.size(); i++)
        payload[i] = static_cast<uint8_t>(i * 37 + 1);
    for (int seq : {0, 1, 128, 255}) {
        Bytes b = write(99, 30, payload);  // ATTITUDE
        Frame f = parse_one(b);
        ASSERT_TRUE(rewrite_seq_in_place(f, static_cast<uint8_t>(seq)));
        EXPECT_EQ(write(static_cast<uint8_t>(seq), 30, payload), b) << "seq " << seq;
        EXPECT_EQ(seq, wire_seq(f));
    }
}

TEST(FrameWriter, RenumberedV1AndUnknownIdFramesKeepAValidCrc) {
    const MessageInfo* hb = find_message(0);
    ASSERT_NE(nullptr, hb);
    Bytes payload{1, 2, 3, 4, 5, 6, 7, 8, 9};
    Bytes v1 = by_hand(1, 10, 0, payload, hb->crc_extra);
    ASSERT_TRUE(rewrite_seq_in_place(parse_one(v1), 211));
    EXPECT_EQ(by_hand(1, 211, 0, payload, hb->crc_extra), v1);
    // An id c_library_v2 does not know: its CRC_EXTRA is unknown to us, the update needs none.
    for (uint8_t extra : {0, 77, 255}) {
        Bytes u = by_hand(2, 3, 0xABCDEF, payload, extra);
        ASSERT_TRUE(rewrite_seq_in_place(parse_one(u), 4));
        EXPECT_EQ(by_hand(2, 4, 0xABCDEF, payload, extra), u);
    }
}

TEST(FrameWriter, SignedFramesAreNeverRewritten) {
    Bytes b = write(5, 0, Bytes{1, 2, 3, 4, 5, 6, 7, 8, 9});
    Bytes before = b;
    Frame f = parse_one(b);
    f.incompat_flags = kIncompatSigned;  // the flag is all rewrite_seq_in_place looks at
    EXPECT_FALSE(rewrite_seq_in_place(f, 6));
    EXPECT_EQ(before, b);
}

}  // namespace
}  // namespace mavbond
