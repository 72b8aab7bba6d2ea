#include "mavlink/frame_writer.h"

#include <array>
#include <cstring>

#include "mavlink/frame_parser.h"
#include "mavlink/message_table.h"

namespace mavbond {

size_t write_frame_v2(std::span<uint8_t> out, FrameSource source, uint32_t msgid,
                      std::span<const uint8_t> payload) {
    const MessageInfo* info = find_message(msgid);
    if (!info || payload.size() > info->max_len || out.size() < kMaxFrameLen)
        return 0;
    size_t len = payload.size();
    while (len > 1 && payload[len - 1] == 0)
        len--;
    uint8_t* p = out.data();
    p[0] = kMagicV2;
    p[1] = static_cast<uint8_t>(len);
    p[2] = 0;  // incompat flags: unsigned
    p[3] = 0;
    p[4] = source.seq;
    p[5] = source.sysid;
    p[6] = source.compid;
    p[7] = static_cast<uint8_t>(msgid);
    p[8] = static_cast<uint8_t>(msgid >> 8);
    p[9] = static_cast<uint8_t>(msgid >> 16);
    if (len > 0)
        std::memcpy(p + kHeaderLenV2, payload.data(), len);
    uint16_t crc = crc_x25(std::span<const uint8_t>(p + 1, kHeaderLenV2 - 1 + len));
    crc = crc_x25_byte(info->crc_extra, crc);
    p[kHeaderLenV2 + len] = static_cast<uint8_t>(crc);
    p[kHeaderLenV2 + len + 1] = static_cast<uint8_t>(crc >> 8);
    return kHeaderLenV2 + len + kChecksumLen;
}

namespace {

/// Writes `value` at `at` (a header or payload byte) of the frame at `bytes`, whose CRC is at
/// `crc_at`, and updates the CRC for that change alone.
void rewrite_byte_in_place(uint8_t* bytes, size_t at, size_t crc_at, uint8_t value) {
    const auto delta = static_cast<uint8_t>(bytes[at] ^ value);
    if (delta == 0)
        return;
    // crc(a) ^ crc(b) == crc(a ^ b) with a zero initial value. The difference is the delta
    // byte, then zeros: the rest of header and payload (crc_at - at - 1 bytes) and
    // CRC_EXTRA's place (one more).
    static constexpr std::array<uint8_t, kHeaderLenV2 + 256> kZeros{};
    uint16_t diff = crc_x25_byte(delta, 0);
    diff = crc_x25(std::span<const uint8_t>(kZeros.data(), crc_at - at), diff);
    uint16_t crc = static_cast<uint16_t>(bytes[crc_at] | bytes[crc_at + 1] << 8);
    crc ^= diff;
    bytes[at] = value;
    bytes[crc_at] = static_cast<uint8_t>(crc);
    bytes[crc_at + 1] = static_cast<uint8_t>(crc >> 8);
}

}  // namespace

void set_signed_flag_in_place(uint8_t* bytes, bool on) {
    // The CRC's difference for the flag's bit, by payload length: the bit, then the zeros of
    // the rest of the header, the payload and CRC_EXTRA's place (see rewrite_byte_in_place).
    static const std::array<uint16_t, 256> kDiff = [] {
        std::array<uint16_t, 256> t{};
        static constexpr std::array<uint8_t, kHeaderLenV2 + 256> kZeros{};
        for (size_t len = 0; len < t.size(); len++)
            t[len] = crc_x25(std::span<const uint8_t>(kZeros.data(), kHeaderLenV2 + len - 2),
                             crc_x25_byte(kIncompatSigned, 0));
        return t;
    }();
    const uint8_t flags = on ? bytes[2] | kIncompatSigned : bytes[2] & ~kIncompatSigned;
    if (flags == bytes[2])
        return;
    const size_t crc_at = kHeaderLenV2 + bytes[1];
    const uint16_t crc = static_cast<uint16_t>((bytes[crc_at] | bytes[crc_at + 1] << 8) ^ kDiff[bytes[1]]);
    bytes[2] = flags;
    bytes[crc_at] = static_cast<uint8_t>(crc);
    bytes[crc_at + 1] = static_cast<uint8_t>(crc >> 8);
}

bool rewrite_seq(std::span<uint8_t> frame, uint8_t seq) {
    if (frame.size() < kHeaderLenV1)
        return false;
    const bool v2 = frame[0] == kMagicV2;
    const size_t header_len = v2 ? kHeaderLenV2 : kHeaderLenV1;
    if (frame.size() < header_len + frame[1] + kChecksumLen || (v2 && (frame[2] & kIncompatSigned)))
        return false;
    rewrite_byte_in_place(frame.data(), v2 ? 4 : 2, header_len + frame[1], seq);
    return true;
}

bool rewrite_seq_in_place(const Frame& frame, uint8_t seq) {
    if (frame.is_signed())
        return false;
    // The receiver's buffer is writable; Frame only promises the routing code it will not be.
    return rewrite_seq(std::span<uint8_t>(const_cast<uint8_t*>(frame.bytes.data()), frame.bytes.size()),
                       seq);
}

}  // namespace mavbond
