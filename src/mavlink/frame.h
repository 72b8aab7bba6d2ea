// A MAVLink v1/v2 frame as a view over the bytes it arrived in: no copy is made.
#pragma once

#include <cstdint>
#include <span>

namespace mavbond {

struct MessageInfo;

constexpr uint8_t kMagicV1 = 0xFE;
constexpr uint8_t kMagicV2 = 0xFD;
constexpr uint8_t kIncompatSigned = 0x01;
constexpr size_t kHeaderLenV1 = 6;     // magic, len, seq, sysid, compid, msgid
constexpr size_t kHeaderLenV2 = 10;    // magic, len, incompat, compat, seq, sysid, compid, msgid[3]
constexpr size_t kChecksumLen = 2;
constexpr size_t kSignatureLen = 13;
constexpr size_t kMaxFrameLen = kHeaderLenV2 + 255 + kChecksumLen + kSignatureLen;  // 280

/// The length on the wire of the frame whose first bytes are at `p` (magic, payload length,
/// and for MAVLink 2 the incompatibility flags: 3 bytes are read).
constexpr size_t frame_length(const uint8_t* p) {
    if (p[0] == kMagicV2)
        return kHeaderLenV2 + p[1] + kChecksumLen + ((p[2] & kIncompatSigned) ? kSignatureLen : 0);
    return kHeaderLenV1 + p[1] + kChecksumLen;
}

struct Frame {
    std::span<const uint8_t> bytes;    // the whole frame as on the wire, signature included
    std::span<const uint8_t> payload;  // the payload as on the wire (v2: possibly truncated)
    uint32_t msgid = 0;
    uint8_t version = 0;               // 1 or 2
    uint8_t incompat_flags = 0;
    uint8_t seq = 0;
    uint8_t sysid = 0;
    uint8_t compid = 0;
    int16_t target_system = -1;        // -1: the message has no target_system field
    int16_t target_component = -1;    // -1: the message has no target_component field
    bool crc_checked = false;          // false: unknown msgid, forwarded unverified
    const MessageInfo* info = nullptr; // the message table entry; nullptr for an unknown msgid

    bool is_signed() const { return (incompat_flags & kIncompatSigned) != 0; }
    /// True for frames addressed to everybody: no target field, or target_system 0.
    bool is_broadcast() const { return target_system <= 0; }
};

}  // namespace mavbond
