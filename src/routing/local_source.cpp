#include "routing/local_source.h"

#include <algorithm>
#include <array>
#include <cstring>

#include "core/log.h"
#include "mavlink/frame_parser.h"
#include "mavlink/frame_writer.h"

namespace mavbond {

namespace {
constexpr uint32_t kMsgHeartbeat = 0;
constexpr uint32_t kMsgStatustext = 253;
constexpr uint32_t kMsgNamedValueInt = 252;
constexpr uint8_t kTypeOnboardController = 18;  // MAV_TYPE_ONBOARD_CONTROLLER
constexpr uint8_t kAutopilotInvalid = 8;        // MAV_AUTOPILOT_INVALID: not a flight controller
constexpr uint8_t kStateActive = 4;             // MAV_STATE_ACTIVE
constexpr uint8_t kMavlinkVersion = 3;
constexpr size_t kStatustextLen = 50;           // char text[50], NUL-terminated only if shorter
}  // namespace

LocalSource::LocalSource(const IdentityConfig& identity, EventLoop& loop, Router& router)
    : identity_(identity), loop_(loop), router_(router) {
    if (identity.heartbeat > Duration::zero()) {
        heartbeat_timer_ = loop.schedule(identity.heartbeat, [this] {
            send_heartbeat();
            return identity_.heartbeat;
        });
    }
}

void LocalSource::send_heartbeat() {
    // custom_mode (uint32), type, autopilot, base_mode, system_status, mavlink_version
    const uint8_t payload[9] = {0, 0, 0, 0, kTypeOnboardController, kAutopilotInvalid, 0,
                                kStateActive, kMavlinkVersion};
    send(kMsgHeartbeat, payload, sizeof payload);
}

std::array<uint8_t, 54> statustext_payload(Severity severity, std::string_view text) {
    // severity, text[50]; the extensions id and chunk_seq stay 0 (a message in one piece).
    std::array<uint8_t, 1 + kStatustextLen + 3> payload{};
    payload[0] = static_cast<uint8_t>(severity);
    std::copy_n(text.begin(), std::min(text.size(), kStatustextLen), payload.begin() + 1);
    return payload;
}

void LocalSource::send_statustext(Severity severity, std::string_view text) {
    const auto payload = statustext_payload(severity, text);
    send(kMsgStatustext, payload.data(), payload.size());
}

void LocalSource::send_named_value_int(const std::array<char, 10>& name, int32_t value,
                                       uint32_t bond) {
    // time_boot_ms (uint32), value (int32), name[10]: little-endian on the wire.
    std::array<uint8_t, 18> payload{};
    const auto ms = static_cast<uint32_t>(
        std::chrono::duration_cast<std::chrono::milliseconds>(loop_.now().time_since_epoch()).count());
    std::memcpy(payload.data(), &ms, 4);
    std::memcpy(payload.data() + 4, &value, 4);
    std::memcpy(payload.data() + 8, name.data(), name.size());
    send(kMsgNamedValueInt, payload.data(), payload.size(), bond);
}

bool inject_local_frame(Router& router, FrameSource source, uint32_t msgid,
                        std::span<const uint8_t> payload, Router::Reach reach) {
    std::array<uint8_t, kMaxFrameLen> buf;
    size_t n = write_frame_v2(buf, source, msgid, payload);
    // Parsed back like any received frame: the router gets a Frame as complete as theirs.
    ParserCounters counters;
    DatagramParser parser(std::span<const uint8_t>(buf.data(), n), UnknownIdPolicy::Drop, counters);
    Frame frame;
    if (n == 0 || !parser.next(frame)) {
        log_error("local frame msgid=%u could not be built", msgid);  // a bug, never input
        return false;
    }
    router.inject(frame, reach);
    return true;
}

void LocalSource::send(uint32_t msgid, const uint8_t* payload, size_t len,
                       std::optional<uint32_t> bond_only) {
    const std::span<const uint8_t> bytes(payload, len);
    const auto& bonds = router_.bonds();
    if (bond_only) {
        if (*bond_only < bonds.size())
            send_numbered(seq_by_bond_[bonds[*bond_only].name()], msgid, bytes,
                          Router::Reach::to_bond(*bond_only));
    } else {
        send_numbered(seq_outside_, msgid, bytes, Router::Reach(Router::Reach::OutsideBonds));
        for (uint32_t b = 0; b < bonds.size(); b++)
            send_numbered(seq_by_bond_[bonds[b].name()], msgid, bytes,
                          Router::Reach(Router::Reach::BondRouted, b));
    }
    frames_sent_++;
}

void LocalSource::send_numbered(uint8_t& seq, uint32_t msgid, std::span<const uint8_t> payload,
                                Router::Reach reach) {
    if (inject_local_frame(router_, FrameSource{identity_.sysid, identity_.compid, seq}, msgid,
                           payload, reach))
        seq++;
}

}  // namespace mavbond
