// The daemon's status: taken once (Daemon::status()) and rendered four ways, each from the same
// figures: the status socket's JSON (mavbondctl), Prometheus text (/metrics), the counters log
// lines (SIGUSR1, exit, an endpoint stopped by a reload) and the periodic problem report.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "routing/standby.h"

#include "core/clock.h"
#include "core/event_loop.h"
#include "core/metric_set.h"
#include "endpoints/endpoint.h"
#include "routing/filter_chain.h"

namespace mavbond {

struct Status {
    /// A configured endpoint: a server's figures are its own and every peer's or connection's
    /// it has had.
    struct Endpoint {
        std::string name;
        std::string kind;  // "udp-server", "uart", ...
        std::string bond;  // "" when not in one
        bool signing_required = false;
        uint64_t tx_rate = 0;  // its budget in bytes a second (tx_rate); 0: none
        LinkCounters counters;
        std::optional<RadioFlow> radio;  // `radio_status`: its radio's reports and their effect
        std::string open_error;  // why it is not open; "" when it is
        bool standby = false;       // its bond keeps it to control (a metered member)
        bool peer_standby = false;  // so does the far side, its count markers say
        /// "closed" (not open), "down" (a bond member the far side is not heard on: nothing
        /// for link_events' silent_after), "standby" (either side keeps it to control), "up".
        std::string state;
    };
    struct BondLink {
        std::string name;  // the member's endpoint (a server's peers together)
        bool active = false;
    };
    struct Bond {
        std::string name;
        bool tx_active = false;
        std::string active;          // the active link's name; "" when none is chosen
        uint64_t switches = 0;
        std::vector<BondLink> links;  // the members' links attached now
        std::vector<std::pair<const char*, uint64_t>> renumber;  // empty: no renumbering
        EgressNumbering::Counters numbering;  // of what it sends
        bool reports_radio_status = false;       // a member has `radio_status`
        uint64_t foreign_radio_status = 0;       // others' RADIO_STATUS dropped on its members
        uint64_t radio_status_sent = 0;          // its own sent to the local side
        std::optional<RadioReport> radio_status_last;  // the last of them
        /// With a metered member (routing/standby.h): its state and counters.
        bool has_standby = false;
        bool standby_active = false;
        uint64_t metered_tx_bytes = 0;  // sent on the metered members' links, every frame
        Standby::Counters standby;
        std::vector<std::pair<std::string, int32_t>> peer_loss;  // free link (peer's name), per mille
        /// With `signing:` (mavlink/bond_signing.h): the links it signs and what it did.
        std::vector<std::string> signed_links;  // empty: it signs none
        BondSigning::Counters signing;
    };

    TimePoint taken;
    Duration uptime{};
    uint64_t status_refused = 0;  // status socket connections refused by the credentials check
    EventLoop::Stalls stalls;     // the event loop's own evidence of a stall
    std::vector<Endpoint> endpoints;
    std::vector<Bond> bonds;
    uint64_t frames_routed = 0;
    uint64_t frames_without_destination = 0;
    uint64_t frames_held_back = 0;
    uint64_t standby_reports_dropped = 0;  // `mbl:` reports no bond's standby took (Router)
    std::vector<FilterReport> filters;
};

/// What one endpoint shows of itself at `now`; a bond member not heard for `silent_after` is
/// down.
Status::Endpoint endpoint_status(const Endpoint& endpoint, TimePoint now, Duration silent_after);

/// The status socket's document: version, uptime, endpoints with every counter, bonds, filters.
std::string status_json(const Status& status);
/// The /metrics document, as Prometheus families.
MetricSet status_metrics(const Status& status);
/// "WHAT endpoint=NAME kind=KIND counter=value..." (WHAT: "stats" for the periodic and exit
/// lines, which tools parse).
std::string counters_line(const Status::Endpoint& endpoint, const char* what = "stats");

/// Per-frame problems are never logged one by one: every report_interval, one line per
/// endpoint that had any says how many of each.
class ProblemReport {
public:
    void run(const Status& status, Duration interval);
    /// Forgets an endpoint that goes away (a new one by its name starts from zero).
    void forget(const std::string& endpoint) { last_.erase(endpoint); }

private:
    std::map<std::string, LinkCounters> last_;  // by endpoint name
};

}  // namespace mavbond
