// The RADIO_STATUS the local side (the autopilot) gets for a bond whose radios report
// (`radio_status` on a member): about once a second, from the SiK radio's system and component
// (51, 68), one for the whole bond in place of the radios' own (which their endpoints take,
// src/endpoints/endpoint.h). ArduPilot takes a RADIO_STATUS from any system, even with
// SYSID_ENFORCE, acts on its txbuf (slower streams below 50 %, faster above 90 %) and does not
// forward it; a GCS shows its rssi. It goes to every link in no bond (the bonds' far sides
// have their own radios), through the egress filters like any frame mavbond makes.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/event_loop.h"
#include "endpoints/endpoint.h"
#include "endpoints/radio_flow.h"
#include "routing/router.h"

namespace mavbond {

class RadioStatusReporter {
public:
    static constexpr Duration kInterval = seconds(1);
    /// A member without radio reports counts as free while it heard its peer this lately (and,
    /// metered, is not in standby).
    static constexpr Duration kAlive = seconds(3);

    /// What one bond's reports were, for the status.
    struct BondReports {
        std::string bond;
        uint64_t sent = 0;
        std::optional<RadioReport> last;  // the last one sent
    };

    /// `endpoints`: the daemon's (read at each report, so a reload's changes count at once).
    RadioStatusReporter(EventLoop& loop, Router& router, const std::vector<Endpoint::Ptr>& endpoints);

    /// The bond's figures; null when it never reported.
    const BondReports* find(const std::string& bond) const;

private:
    void report();
    BondReports& entry(const std::string& bond);

    EventLoop& loop_;
    Router& router_;
    const std::vector<Endpoint::Ptr>& endpoints_;
    std::vector<BondReports> bonds_;  // by name: kept across reloads
    std::vector<RadioVote> votes_;    // reused
    uint8_t seq_ = 0;
    EventLoop::Timer timer_;
};

}  // namespace mavbond
