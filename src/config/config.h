// The daemon's configuration as typed structs, loaded from YAML. Every error names
// file:line:column and the key; the daemon exits with 78 (EX_CONFIG) on any of them.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "config/endpoint_schema.h"
#include "core/clock.h"
#include "core/log.h"
#include "core/result.h"
#include "mavlink/frame_parser.h"

namespace mavbond {

constexpr int kExitConfig = 78;  // EX_CONFIG from sysexits.h

/// Where a value came from, for messages about it after loading.
struct SourceMark {
    std::string file;
    int line = 0;    // 1-based
    int column = 0;  // 1-based
    bool operator==(const SourceMark&) const = default;
};

/// Allow/block lists of message ids (given in the YAML as ids or names such as HEARTBEAT).
/// An empty allow list allows everything; block wins over allow.
struct MessageFilterConfig {
    std::vector<uint32_t> allow;
    std::vector<uint32_t> block;
    bool passes(uint32_t msgid) const {
        auto has = [msgid](const std::vector<uint32_t>& list) {
            return std::find(list.begin(), list.end(), msgid) != list.end();
        };
        return (allow.empty() || has(allow)) && !has(block);
    }
    bool operator==(const MessageFilterConfig&) const = default;
};

/// An endpoint's `signing:` block: incoming frames must carry a MAVLink 2 signature that
/// verifies against the key. Or, derived from its bond's (`by_bond`): the bond signs what it
/// sends on this link and verifies what comes in with the bond's key (mavlink/bond_signing.h).
struct SigningConfig {
    bool enabled = false;              // a `signing:` block is present, or the bond signs it
    bool require = true;               // false: unsigned frames pass (signed ones are checked)
    std::string key_file;              // as resolved (relative to the config file's directory)
    std::array<uint8_t, 32> key{};     // read at load time (a new key restarts the endpoint)
    bool by_bond = false;              // the bond's `signing:` covers this link (require: true)
    bool operator==(const SigningConfig&) const = default;
};

/// A bond's `signing:` block: both gateways hold the key; each signs what it sends on the
/// `links` and requires a verified signature on what it receives on them.
struct BondSigningConfig {
    bool enabled = false;
    std::string key_file;                // as resolved
    std::array<uint8_t, 32> key{};
    std::vector<std::string> links;      // member endpoint names, in config order (all by default)
    bool operator==(const BondSigningConfig&) const = default;
};

/// `tx_classes:`: the order in which a link with a budget (`tx_rate`) spends it. Control goes
/// at once, always; telemetry (every message in neither list) waits for the budget, the newest
/// sample of each message from each source (and instance) winning, each at most at its cap; bulk waits in
/// order behind telemetry.
/// A message's class on a link with a budget or in standby, named by kTxClassNames.
enum class TxClass : uint8_t { Control, Telemetry, Bulk };
constexpr size_t kTxClassCount = 3;
constexpr const char* kTxClassNames[kTxClassCount] = {"control", "telemetry", "bulk"};

struct TxClassesConfig {
    std::vector<uint32_t> control;  // sorted
    std::vector<uint32_t> bulk;     // sorted
    std::vector<std::pair<uint32_t, Duration>> caps;  // message id, least interval; sorted
    /// The class of message `msgid`: what a budget and a metered link's standby both go by.
    TxClass class_of(uint32_t msgid) const;
    bool operator==(const TxClassesConfig&) const = default;
};

/// `radio_status:`: whose RADIO_STATUS reports set a link's budget.
enum class RadioStatusSource : uint8_t {
    None,
    Sik,  // a SiK radio (3DR, RFD900): system 51 ('3'), component 68 ('D')
};

/// An endpoint's `tx_rate:` and the classes it spends it by.
struct TxBudgetConfig {
    uint64_t bytes_per_s = 0;  // what the line carries of frame bytes; 0: no budget
    bool uart_baud = false;    // `tx_rate: baud`: the UART's own `baud` option, 10 bits a byte
    bool serial = false;       // given in baud: a serial line, so no datagram headers charged
    TxClassesConfig classes;   // the file's `tx_classes:` (or their defaults)
    /// `radio_status: sik`: the radio on this link reports its transmit buffer, and the budget
    /// follows it below the rate above (the ceiling); see src/endpoints/radio_flow.h.
    RadioStatusSource radio_status = RadioStatusSource::None;
    bool enabled() const { return bytes_per_s != 0 || uart_baud; }
    bool operator==(const TxBudgetConfig&) const = default;
};

/// One `endpoints:` entry: the keys every endpoint takes, and its type's own (`options`, read
/// by its schema's table).
struct EndpointConfig {
    std::string name;
    const EndpointSchema* schema = nullptr;  // its type (and mode); the tables live for the run
    EndpointOptions options;                 // the keys of its type's table
    size_t tx_queue_bytes = 16384;           // bounded transmit queue
    TxBudgetConfig tx_budget;                // key `tx_rate` (and the file's `tx_classes`)
    MessageFilterConfig filter_in;           // keys allow_in / block_in
    MessageFilterConfig filter_out;          // keys allow_out / block_out
    std::string bond;                        // bond name ("" = none)
    SigningConfig signing;                   // key `signing`
    /// `cost: metered`: a bond member paid by the byte, in standby while the free members
    /// are healthy (routing/standby.h).
    bool metered = false;
    /// `standby_carries:` the classes (bit per TxClass) a metered member carries in standby.
    uint8_t standby_classes = 1u << static_cast<unsigned>(TxClass::Control);
    SourceMark mark;                         // where this endpoint was declared
    bool operator==(const EndpointConfig&) const = default;
};

struct BondConfig {
    std::string name;
    enum class Tx { Broadcast, Active } tx = Tx::Broadcast;
    SourceMark mark;
    SourceMark tx_mark;        // where `tx` is set
    /// Rewrite the sequence number of delivered unsigned frames so a GCS sees the bond's real
    /// loss (needs a filter that provides aligned positions on the bond: dedup; the filter
    /// chain checks it; see src/routing/renumber.h). Absent: on wherever a filter provides
    /// them (FilterChain::renumbers).
    std::optional<bool> renumber;
    SourceMark renumber_mark;  // where `renumber` is set
    /// When a metered member (`cost: metered`) leaves standby and comes back
    /// (routing/standby.h): the free members' loss as the peer reports it.
    double failover_loss = 0.10;      // `failover_loss`: active when every free link is above
    double failback_loss = 0.02;      // `failback_loss`: standby again once one is below...
    Duration failback_after = seconds(10);  // `failback_after`: ...for this long
    Duration resend = seconds(3);     // `resend`: frames standby held back, resent on failover
                                      // (3 s: the longest standby takes to find a radio silent)
    BondSigningConfig signing;        // `signing`: the bond signs its links (or some of them)
    bool operator==(const BondConfig&) const = default;
};

/// mavbond's own MAVLink identity, for the frames it makes itself (HEARTBEAT, STATUSTEXT).
struct IdentityConfig {
    uint8_t sysid = 1;
    uint8_t compid = 191;        // MAV_COMP_ID_ONBOARD_COMPUTER
    bool compid_given = false;   // set in the file: never derived (routing/identity.h)
    Duration heartbeat{0};       // period of our own HEARTBEAT; 0 = none
    bool operator==(const IdentityConfig&) const = default;
};

/// `link_events:` reports bond members going silent, coming back, and active-link switches.
struct LinkEventsConfig {
    bool enabled = false;        // the section is present
    /// Also tell the GCS (STATUSTEXT), not only the log; absent: the side facing the GCS does
    /// (LinkEventMonitor::announces).
    std::optional<bool> statustext;
    Duration silent_after = seconds(1);  // the least silence that loses a link (link_events.h)
    Duration min_interval = seconds(2);  // between two STATUSTEXTs about one link or bond
    bool operator==(const LinkEventsConfig&) const = default;
};

/// One `filters:` entry. The plugin's own options are kept as raw key/value text with their
/// marks, validated later against the plugin's declared options.
struct FilterConfig {
    std::string plugin;
    bool enabled = true;
    std::vector<std::string> bonds;      // scope; empty = everywhere
    std::vector<std::string> endpoints;  // scope; empty = everywhere
    struct Option {
        std::string key;
        std::string value;               // scalar text, or a flow-style sequence "[a, b]"
        std::vector<std::string> items;  // sequence items when the value is a sequence
        std::vector<SourceMark> item_marks;  // where each item is
        bool is_sequence = false;
        SourceMark mark;                 // the key
        SourceMark value_mark;           // the value (the key's mark when the value is empty)
        bool operator==(const Option&) const = default;
    };
    std::vector<Option> options;
    SourceMark mark;
    bool operator==(const FilterConfig&) const = default;
};

/// `metrics:`: the Prometheus endpoint (src/daemon/metrics_http.h). Off unless `listen` is given.
struct MetricsConfig {
    bool enabled = false;
    std::string host = "127.0.0.1";  // only a port given: loopback, never every interface
    uint16_t port = 0;
    Duration timeout = seconds(5);   // a connection is closed this long after it was accepted
    uint32_t max_connections = 8;    // beyond: 503
    bool operator==(const MetricsConfig&) const = default;
};

struct Config {
    std::string path;                              // the file it came from
    LogLevel log_level = LogLevel::Info;
    UnknownIdPolicy unknown_messages = UnknownIdPolicy::Forward;
    Duration route_timeout = seconds(30);          // forget a (sysid, compid) not heard for this
    Duration report_interval = seconds(10);        // aggregated problem lines
    std::string plugin_dir;                        // "" = compiled-in default
    std::string status_socket;                     // "" = none
    std::vector<EndpointConfig> endpoints;
    std::vector<BondConfig> bonds;
    TxClassesConfig tx_classes;                    // the file's `tx_classes:` (or the defaults)
    std::vector<FilterConfig> filters;
    IdentityConfig identity;
    LinkEventsConfig link_events;
    MetricsConfig metrics;
};

/// Whether two declarations mean the same, wherever in their files they were written: what a
/// reload compares to decide what must restart.
bool same_settings(const EndpointConfig& a, const EndpointConfig& b);
/// The same but for the transmit budget (which a running endpoint takes on in place).
bool same_but_budget(const EndpointConfig& a, const EndpointConfig& b);
bool same_settings(const std::vector<BondConfig>& a, const std::vector<BondConfig>& b);
bool same_settings(const std::vector<FilterConfig>& a, const std::vector<FilterConfig>& b);

/// A whole file as text; the error is "path: cannot open|read: reason".
Result<std::string> read_text_file(const std::string& path);

/// Loads and validates a config file, its endpoints by the tables of `types`. The error's
/// message is "file:line:column: what".
Result<Config> load_config(const std::string& path, EndpointSchemas types);
/// Same, from text (for tests); `name` stands in for the file name in messages.
Result<Config> parse_config(const std::string& text, const std::string& name,
                            EndpointSchemas types);
/// The manual's list of every endpoint type's options (roff, for mavbond.yaml(5)).
std::string endpoint_options_manual(EndpointSchemas types);

/// "250ms", "2s", "1.5s", "1m" -> Duration. Units: ns, us, ms, s, m; a unit is required, no
/// sign, no spaces, at most 9 fraction digits and no finer than 1ns; nullopt otherwise.
std::optional<Duration> parse_duration(std::string_view text);

/// A host and port as an endpoint's `address` writes them: "192.0.2.1:14550",
/// "[2001:db8::5]:14550" (an IPv6 address in brackets), "lte.example.net:14550";
/// "localhost" reads as 127.0.0.1. On error `error` says what is wrong (for the config's message).
struct HostPort {
    std::string host;  // an IPv4 or IPv6 literal (no brackets) or a host name
    uint16_t port = 0;
    std::string error;  // empty when it parsed
};
HostPort parse_host_port(std::string_view text);

}  // namespace mavbond
