// The places mavbond writes MAVLink bytes itself: frames it originates (HEARTBEAT and
// STATUSTEXT from its own identity), the sequence number of a received frame it renumbers and
// the signed flag a bond's signature sets and takes off (mavlink/signing.h).
#pragma once

#include <cstdint>
#include <span>

#include "mavlink/frame.h"

namespace mavbond {

struct FrameSource {
    uint8_t sysid;
    uint8_t compid;
    uint8_t seq;
};

/// Writes an unsigned MAVLink 2 frame of a message c_library_v2 knows into `out` (at least
/// kMaxFrameLen bytes). `payload` is the message's wire layout up to max_len; trailing zero
/// bytes are cut as MAVLink 2 requires (at least one byte stays). Returns the frame's length,
/// or 0 for an unknown msgid or a payload longer than the message.
size_t write_frame_v2(std::span<uint8_t> out, FrameSource source, uint32_t msgid,
                      std::span<const uint8_t> payload);

/// Gives a received frame a new sequence number in place: the seq byte in the receive buffer
/// the frame is a view over, and its CRC, updated for that change alone (CRC-16/MCRF4XX is
/// affine, so the delta needs no CRC_EXTRA: an unknown msgid is renumbered too, and a CRC that
/// did not check still does not). Receivers own their buffers and keep them unshared until
/// the frame sink's end_batch(); that is why this, and nothing else, writes into a lent
/// frame. Call it before the frame is routed. Signed frames are refused (the signature
/// covers seq): false.
bool rewrite_seq_in_place(const Frame& frame, uint8_t seq);

/// The same for a frame's bytes of one's own (a budget's held copy): its seq byte and CRC.
bool rewrite_seq(std::span<uint8_t> frame, uint8_t seq);

/// Sets or clears the signed flag of the MAVLink 2 frame at `bytes` (its header, payload and
/// CRC; the signature itself is the caller's), its CRC updated from a table by payload length:
/// what a bond's signing does to every frame, in both directions.
void set_signed_flag_in_place(uint8_t* bytes, bool on);

/// The sequence number on the wire (a renumbered frame's Frame::seq still holds the old one).
inline uint8_t wire_seq(const Frame& frame) {
    return frame.bytes[frame.version == 2 ? 4 : 2];
}

}  // namespace mavbond
