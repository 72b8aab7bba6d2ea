#include "routing/link_account.h"

#include <algorithm>
#include <array>
#include <cstring>

#include "mavlink/radio_status.h"

namespace mavbond {
namespace {

constexpr uint32_t kMsgNamedValueInt = 252;
constexpr size_t kNameLen = 10;  // NAMED_VALUE_INT.name
constexpr size_t kNameAt = 8;    // after time_boot_ms and value
constexpr char kPrefixCarries[] = "mbw:";
constexpr char kPrefixStandby[] = "mbs:";
constexpr size_t kPrefixLen = sizeof kPrefixCarries - 1;

uint32_t read_u32(const uint8_t* p) {
    return static_cast<uint32_t>(p[0] | p[1] << 8 | p[2] << 16) | static_cast<uint32_t>(p[3]) << 24;
}

}  // namespace

bool read_count_marker(const Frame& frame, CountMarker& out) {
    // A v2 payload may end early (its trailing zeros cut): the prefix is always there.
    if (frame.msgid != kMsgNamedValueInt || frame.payload.size() < kNameAt + kPrefixLen)
        return false;
    const uint8_t* p = frame.payload.data();
    const bool carries = std::memcmp(p + kNameAt, kPrefixCarries, kPrefixLen) == 0;
    if (!carries && std::memcmp(p + kNameAt, kPrefixStandby, kPrefixLen) != 0)
        return false;
    out.session = read_u32(p);
    out.written = read_u32(p + 4);
    out.standby = !carries;
    // The name's characters after the prefix, up to its NUL or the payload's trimmed end.
    const size_t at = kNameAt + kPrefixLen;
    size_t len = std::min(frame.payload.size(), kNameAt + kNameLen) - at;
    len = static_cast<size_t>(std::find(p + at, p + at + len, 0) - (p + at));
    out.link = std::string_view(reinterpret_cast<const char*>(p + at), len);
    return true;
}

size_t write_count_marker(std::span<uint8_t> out, FrameSource source, std::string_view link,
                          const CountMarker& marker) {
    std::array<uint8_t, kNameAt + kNameLen> payload{};
    std::memcpy(payload.data(), &marker.session, 4);  // little-endian, as on every host we run on
    std::memcpy(payload.data() + 4, &marker.written, 4);
    std::memcpy(payload.data() + kNameAt, marker.standby ? kPrefixStandby : kPrefixCarries,
                kPrefixLen);
    std::memcpy(payload.data() + kNameAt + kPrefixLen, link.data(),
                std::min(link.size(), kNameLen - kPrefixLen));
    return write_frame_v2(out, source, kMsgNamedValueInt, payload);
}

size_t count_marker_length(std::string_view link) {
    // The name's characters are never zeros: the payload ends with its last one.
    return kHeaderLenV2 + kNameAt + kPrefixLen + std::min(link.size(), kNameLen - kPrefixLen) +
           kChecksumLen;
}

bool is_radio_own_report(const uint8_t* f) {
    // MAVLink 1: magic, len, seq, sysid, compid, msgid; MAVLink 2: magic, len, incompat,
    // compat, seq, sysid, compid, msgid (3 bytes).
    if (f[0] == kMagicV1)
        return f[3] == kSikSysid && f[4] == kSikCompid && is_radio_status(f[5]);
    return f[0] == kMagicV2 && f[5] == kSikSysid && f[6] == kSikCompid &&
           is_radio_status(read_u32(f + 7) & 0xFFFFFF);
}

void LinkAccount::continue_from(LinkAccount& older) {
    older.moved_ = true;
    if (!exact()) {
        const uint64_t mine = received_;
        *this = older;
        received_ += mine;
        moved_ = false;
        return;
    }
    if (!older.exact())
        return;  // nothing exact to go on from: this one's count stands alone
    // This one took markers of its own before the move was known. Its figures go on from
    // older's as if older had taken them: its first marker either continues older's count
    // (the frames written between older's last marker and it are expected, whichever address
    // brought them) or starts a new one (older's figures of now go into the totals).
    if (first_session_ == older.session_) {
        const auto ahead = static_cast<int32_t>(first_written_ - static_cast<uint32_t>(older.written_));
        expected_done_ = expected_done_ - before_first_ + older.expected() +
                         static_cast<uint64_t>(static_cast<int64_t>(ahead));
    } else {
        expected_done_ += older.expected_now();
        sessions_++;
    }
    received_done_ += older.received_now();
    sessions_ += older.sessions_;
    markers_ += older.markers_;
    markers_late_ += older.markers_late_;
    last_marker_at_ = std::max(last_marker_at_, older.last_marker_at_);
}

void LinkAccount::take_marker(const CountMarker& marker, TimePoint arrival) {
    if (markers_ == 0 || marker.session != session_) {
        // The far side's first marker, or its count started again: what stood goes into the
        // totals, with the frames that came since the last marker (written, by one count or
        // the other, and arrived: the figures of now never go back), and the new count goes on
        // from here.
        expected_done_ = expected_now();
        received_done_ = received_now();
        if (markers_ != 0) {
            sessions_++;
        } else {
            first_session_ = marker.session;
            first_written_ = marker.written;
            before_first_ = received_;
        }
        session_ = marker.session;
        written_ = session_written_ = marker.written;
        at_marker_ = session_received_ = received_;
    } else {
        const auto ahead = static_cast<uint32_t>(marker.written - static_cast<uint32_t>(written_));
        if (ahead >= (1u << 31)) {
            // Behind the last one: a marker a reordering link let a later one overtake.
            markers_late_++;
            received_++;
            return;
        }
        written_ += ahead;
        at_marker_ = received_;
    }
    markers_++;
    received_++;  // the marker itself is a frame the far side counts
    last_marker_at_ = std::max(last_marker_at_, arrival);
    peer_standby_ = marker.standby;
}

}  // namespace mavbond
