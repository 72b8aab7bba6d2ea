// mavbond as a MAVLink component of its own (`identity:`): the frames it originates, sent
// through the router as from a local source. Its HEARTBEAT says what it is
// (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) so a GCS lists it as a component and
// not as a vehicle.
//
// Sequence numbers: one counter per destination, so each receiver sees a gapless stream of
// mavbond's frames (a GCS counts a gap as loss). The links outside bonds share one (every frame
// of theirs goes to all of them); each bond has its own, so a frame goes to its members as one
// frame, the same number on every link (the peer's dedup knows the copies by it), and the
// bond's standby reports, which go to its members only, leave no gap at the GCS.
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "config/config.h"
#include "core/event_loop.h"
#include "mavlink/frame_writer.h"
#include "routing/router.h"

namespace mavbond {

/// Sends one frame mavbond makes itself, from `source`, through `router` to `reach`; false
/// (logged) only on a bug (a payload the message table does not take).
bool inject_local_frame(Router& router, FrameSource source, uint32_t msgid,
                        std::span<const uint8_t> payload, Router::Reach reach);

/// MAV_SEVERITY values (MAVLink common.xml).
enum class Severity : uint8_t {
    Emergency = 0, Alert = 1, Critical = 2, Error = 3, Warning = 4, Notice = 5, Info = 6, Debug = 7
};

/// A STATUSTEXT's payload: the severity and the text, cut to its 50 characters.
std::array<uint8_t, 54> statustext_payload(Severity severity, std::string_view text);

class LocalSource {
public:
    /// Starts the HEARTBEAT timer when identity.heartbeat is set.
    LocalSource(const IdentityConfig& identity, EventLoop& loop, Router& router);

    void send_heartbeat();
    /// One STATUSTEXT; text beyond STATUSTEXT's 50 characters is cut.
    void send_statustext(Severity severity, std::string_view text);
    /// One NAMED_VALUE_INT to the member links of bond `bond` only (a standby report).
    void send_named_value_int(const std::array<char, 10>& name, int32_t value, uint32_t bond);

    uint64_t frames_sent() const { return frames_sent_; }
    uint8_t sysid() const { return identity_.sysid; }
    uint8_t compid() const { return identity_.compid; }
    /// Goes on as another component (routing/identity.h derives it), with a counter of its own.
    void set_compid(uint8_t compid) {
        identity_.compid = compid;
        seq_outside_ = 0;
        seq_by_bond_.clear();
    }

private:
    /// To every link (Everywhere: each destination with its own number) or to one bond's.
    void send(uint32_t msgid, const uint8_t* payload, size_t len,
              std::optional<uint32_t> bond_only = std::nullopt);
    void send_numbered(uint8_t& seq, uint32_t msgid, std::span<const uint8_t> payload,
                       Router::Reach reach);

    IdentityConfig identity_;  // a copy: a reload replaces the Config
    EventLoop& loop_;
    Router& router_;
    uint8_t seq_outside_ = 0;                     // the links in no bond
    std::map<std::string, uint8_t> seq_by_bond_;  // by name: a reload may renumber the bonds
    uint64_t frames_sent_ = 0;
    EventLoop::Timer heartbeat_timer_;
};

}  // namespace mavbond
