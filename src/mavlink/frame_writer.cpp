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

bool rewrite_seq_in_place(const Frame& frame, uint8_t seq) {
    if (frame.is_signed())
        return false;
    const size_t seq_at = frame.version == 2 ? 4 : 2;
    const size_t header_len = frame.version == 2 ? kHeaderLenV2 : kHeaderLenV1;
    const size_t crc_at = header_len + frame.payload.size();
    // The receiver's buffer is writable; Frame only promises the routing code it will not be.
    auto* bytes = const_cast<uint8_t*>(frame.bytes.data());
    const auto delta = static_cast<uint8_t>(bytes[seq_at] ^ seq);
    if (delta == 0)
        return true;
    // crc(a) ^ crc(b) == crc(a ^ b) with a zero initial value. The difference is the delta
    // byte, then zeros: the rest of header and payload (crc_at - seq_at - 1 bytes) and
    // CRC_EXTRA's place (one more).
    static constexpr std::array<uint8_t, kHeaderLenV2 + 256> kZeros{};
    uint16_t diff = crc_x25_byte(delta, 0);
    diff = crc_x25(std::span<const uint8_t>(kZeros.data(), crc_at - seq_at), diff);
    uint16_t crc = static_cast<uint16_t>(bytes[crc_at] | bytes[crc_at + 1] << 8);
    crc ^= diff;
    bytes[seq_at] = seq;
    bytes[crc_at] = static_cast<uint8_t>(crc);
    bytes[crc_at + 1] = static_cast<uint8_t>(crc >> 8);
    return true;
}

}  // namespace mavbond
