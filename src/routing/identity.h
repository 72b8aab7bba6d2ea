// mavbond's own MAVLink identity against the frames that come in. Two gateways face one GCS
// through a bond: with one identity (the man page's advice, the default 1/191) their frames
// interleave two sequence counters and the GCS counts the difference as loss. So:
//   - where `identity: compid` is not in the file, the side that faces the ground station (the
//     vehicle's autopilot is heard through one of its bonds, and not on a link of its own)
//     becomes kGroundCompid; the vehicle's side keeps the default (its onboard computer's);
//   - a frame from the identity mavbond uses now, coming in on any link for kClashAfter, means
//     another sender uses it (a gateway set alike, a routing loop): logged once, with the fix.
#pragma once

#include <cstdint>
#include <functional>

#include "config/config.h"
#include "core/event_loop.h"
#include "routing/local_source.h"
#include "routing/router.h"

namespace mavbond {

class OwnIdentity {
public:
    static constexpr uint8_t kGroundCompid = 192;  // MAV_COMP_ID_ONBOARD_COMPUTER2
    static constexpr Duration kClashAfter = seconds(5);
    static constexpr Duration kTick = seconds(1);

    /// `changed`: called with the identity once it is derived (the endpoints' count markers
    /// come from it too).
    OwnIdentity(const IdentityConfig& config, Router& router, EventLoop& loop, LocalSource& source,
                std::function<void(uint8_t sysid, uint8_t compid)> changed);

    /// Derives the identity when it may and reports a clash; the timer calls it every kTick.
    void review();

private:
    const IdentityConfig config_;
    Router& router_;
    LocalSource& source_;
    std::function<void(uint8_t, uint8_t)> changed_;
    bool derived_ = false;
    bool clash_logged_ = false;
    EventLoop::Timer timer_;
};

}  // namespace mavbond
