// mavbond as a MAVLink component of its own (`identity:`): the frames it originates, with its
// own sequence counter, sent through the router as from a local source. Its HEARTBEAT says
// what it is (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) so a GCS lists it as a
// component and not as a vehicle.
#pragma once

#include <array>
#include <cstdint>
#include <span>
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

private:
    void send(uint32_t msgid, const uint8_t* payload, size_t len, Router::Reach reach = {});

    const IdentityConfig identity_;  // a copy: a reload replaces the Config
    EventLoop& loop_;
    Router& router_;
    uint8_t seq_ = 0;
    uint64_t frames_sent_ = 0;
    EventLoop::Timer heartbeat_timer_;
};

}  // namespace mavbond
