// Config loader: the shipped files load, valid YAML maps to the right values, and every kind of
// malformed config is refused with its exact "file:line:column: message".
#include "config/config.h"
#include "config/listeners.h"
#include "endpoints/endpoint_types.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <sys/stat.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

namespace mavbond {
namespace {

using std::chrono::microseconds;
using std::chrono::minutes;
using std::chrono::nanoseconds;

/// Inline YAML is written as R"(
/// key: ...)": the newline after the opening quote is dropped so the text starts at line 1.
Result<Config> parse(const char* text) {
    std::string s = text;
    if (!s.empty() && s.front() == '\n')
        s.erase(0, 1);
    return parse_config(s, "t.yaml", endpoint_schemas());
}

std::string source_root() {
    const char* root = std::getenv("MAVBOND_SOURCE_ROOT");
    return root ? root : "";
}

/// A key file (64 hex digits, mode 0600) in a fresh directory, removed with it.
class TempKey {
public:
    TempKey() {
        char tmpl[] = "/tmp/mavbond-config-XXXXXX";
        dir_ = mkdtemp(tmpl);
        path_ = dir_ + "/bond.key";
        FILE* f = fopen(path_.c_str(), "w");
        fputs("000102030405060708090a0b0c0d0e0f101112131415161718191a1b1c1d1e1f\n", f);
        fclose(f);
        chmod(path_.c_str(), 0600);
    }
    ~TempKey() {
        unlink(path_.c_str());
        rmdir(dir_.c_str());
    }
    const std::string& path() const { return path_; }

private:
    std::string dir_, path_;
};

/// A shipped file as the loader reads it, its signed bond's key (/etc/mavbond/bond.key, which
/// a test machine has not) a temporary one: the only change.
Result<Config> load_shipped(const std::string& path, const TempKey& key) {
    auto text = read_text_file(path);
    if (!text)
        return text.error();
    std::string s = text.value();
    const std::string shipped_key = "/etc/mavbond/bond.key";
    for (size_t at = s.find(shipped_key); at != std::string::npos; at = s.find(shipped_key, at))
        s.replace(at, shipped_key.size(), key.path());
    return parse_config(s, path, endpoint_schemas());
}

// --- the shipped files -----------------------------------------------------------------------

class ShippedConfig : public testing::TestWithParam<const char*> {};

TEST_P(ShippedConfig, Loads) {
    ASSERT_FALSE(source_root().empty()) << "MAVBOND_SOURCE_ROOT is not set (run via meson test)";
    std::string path = source_root() + "/" + GetParam();
    TempKey key;
    auto config = load_shipped(path, key);
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_EQ(path, config->path);
    EXPECT_FALSE(config->endpoints.empty());
}

INSTANTIATE_TEST_SUITE_P(Files, ShippedConfig,
                         testing::Values("conf/mavbond.yaml", "conf/examples/air-side.yaml",
                                         "conf/examples/ground-side.yaml",
                                         "conf/examples/link-events.yaml"));

TEST(ShippedConfig, DefaultIsHarmless) {
    auto config = load_config(source_root() + "/conf/mavbond.yaml", endpoint_schemas());
    ASSERT_TRUE(config.has_value()) << config.error().message;
    ASSERT_EQ(2u, config->endpoints.size());
    const auto& gcs = config->endpoints[0];
    EXPECT_EQ("gcs", gcs.name);
    EXPECT_STREQ("udp", gcs.schema->type);
    EXPECT_STREQ("server", gcs.schema->mode);
    EXPECT_EQ("0.0.0.0", gcs.options.text("address"));
    EXPECT_EQ(14550, gcs.options.port("address"));
    const auto& autopilot = config->endpoints[1];
    EXPECT_STREQ("udp", autopilot.schema->type);
    EXPECT_STREQ("server", autopilot.schema->mode);
    EXPECT_EQ("127.0.0.1", autopilot.options.text("address"));
    EXPECT_EQ(14540, autopilot.options.port("address"));
    // No serial port, no bond, no plugin to load on a fresh install.
    for (const auto& ep : config->endpoints)
        EXPECT_STRNE("uart", ep.schema->type) << ep.name;
    EXPECT_TRUE(config->bonds.empty());
    EXPECT_TRUE(config->filters.empty());
}

TEST(ShippedConfig, AirSide) {
    TempKey key;
    auto config = load_shipped(source_root() + "/conf/examples/air-side.yaml", key);
    ASSERT_TRUE(config.has_value()) << config.error().message;
    ASSERT_EQ(3u, config->endpoints.size());
    const auto& fc = config->endpoints[0];
    EXPECT_STREQ("uart", fc.schema->type);
    EXPECT_EQ("/dev/ttyAMA0", fc.options.text("device"));
    EXPECT_EQ(921600u, fc.options.number("baud"));
    EXPECT_TRUE(fc.options.flag("flow_control"));
    EXPECT_EQ("", fc.bond);
    EXPECT_STREQ("uart", config->endpoints[1].schema->type);
    EXPECT_EQ(57600u, config->endpoints[1].options.number("baud"));
    EXPECT_EQ("vehicle", config->endpoints[1].bond);
    EXPECT_STREQ("udp", config->endpoints[2].schema->type);
    EXPECT_STREQ("client", config->endpoints[2].schema->mode);
    EXPECT_EQ("vehicle", config->endpoints[2].bond);
    ASSERT_EQ(1u, config->bonds.size());
    EXPECT_EQ("vehicle", config->bonds[0].name);
    // The bond signs its internet-facing link, and only that one.
    EXPECT_EQ(std::vector<std::string>{"lte"}, config->bonds[0].signing.links);
    EXPECT_TRUE(config->endpoints[2].signing.by_bond);
    EXPECT_FALSE(config->endpoints[1].signing.enabled);
    ASSERT_EQ(3u, config->filters.size());
    EXPECT_EQ("dedup", config->filters[0].plugin);
    EXPECT_EQ("linkswitch", config->filters[1].plugin);
    EXPECT_EQ("stats", config->filters[2].plugin);
}

TEST(ShippedConfig, GroundSide) {
    TempKey key;
    auto config = load_shipped(source_root() + "/conf/examples/ground-side.yaml", key);
    ASSERT_TRUE(config.has_value()) << config.error().message;
    // The LTE port (open to the internet) is signed by the bond; every other listener is on
    // loopback.
    for (const auto& ep : config->endpoints) {
        if (ep.name == "lte") {
            EXPECT_TRUE(ep.signing.by_bond);
        } else if (ep.schema->mode && std::string_view(ep.schema->mode) == "server") {
            EXPECT_EQ("127.0.0.1", ep.options.text("address")) << ep.name;
        }
    }
    int members = 0;
    bool udp_server_14550 = false;
    bool tcp_server_5760 = false;
    for (const auto& ep : config->endpoints) {
        members += ep.bond == "vehicle";
        udp_server_14550 |= std::string_view(ep.schema->type) == "udp" && std::string_view(ep.schema->mode) == "server" &&
                            ep.options.port("address") == 14550;
        tcp_server_5760 |= std::string_view(ep.schema->type) == "tcp" && std::string_view(ep.schema->mode) == "server" &&
                           ep.options.port("address") == 5760;
    }
    EXPECT_EQ(2, members);
    EXPECT_TRUE(udp_server_14550);
    EXPECT_TRUE(tcp_server_5760);
}

// --- valid configs ---------------------------------------------------------------------------

TEST(ConfigParse, DefaultsWithMinimalEndpoint) {
    auto config = parse(R"(
endpoints:
  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:14550}
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_EQ("t.yaml", config->path);
    EXPECT_EQ(LogLevel::Info, config->log_level);
    EXPECT_EQ(UnknownIdPolicy::Forward, config->unknown_messages);
    EXPECT_EQ(seconds(30), config->route_timeout);
    EXPECT_EQ(seconds(10), config->report_interval);
    EXPECT_EQ("", config->plugin_dir);
    EXPECT_EQ("", config->status_socket);
    ASSERT_EQ(1u, config->endpoints.size());
    const auto& ep = config->endpoints[0];
    EXPECT_EQ(seconds(30), ep.options.duration("peer_timeout"));
    EXPECT_EQ(16384u, ep.tx_queue_bytes);
    EXPECT_TRUE(ep.filter_in.allow.empty());
    EXPECT_TRUE(ep.filter_out.block.empty());
    EXPECT_EQ("", ep.bond);
    EXPECT_EQ("t.yaml", ep.mark.file);
    EXPECT_EQ(2, ep.mark.line);
    EXPECT_EQ(5, ep.mark.column);
}

TEST(ConfigParse, EveryKey) {
    auto config = parse(R"(
filters:                     # before endpoints: key order is free
  - plugin: dedup
    enabled: false
    bonds: [vehicle]
    endpoints: [radio, lte]
    window: 500ms
    hash: [a, b]
  - plugin: stats
log_level: debug
unknown_messages: drop
route_timeout: 1m
report_interval: 1.5s
plugin_dir: /opt/plugins
status_socket: /run/mavbond/status.sock
endpoints:
  - name: fc
    type: uart
    device: /dev/ttyAMA0
    baud: 1500000
    flow_control: true
    reconnect_min: 250ms
    reconnect_max: 2s
    tx_queue: 16KiB
    allow_in: [HEARTBEAT, 33, 16777215]
    block_in: [ATTITUDE]
    allow_out: []
    block_out: [0]
  - name: radio
    type: tcp
    mode: client
    address: localhost:5760
    reconnect_min: 100us
    reconnect_max: 100us
    tx_queue: 280
    bond: vehicle
  - name: lte
    type: udp
    mode: client
    address: 192.0.2.10:14560
    tx_queue: 1k
    bond: vehicle
  - name: gcs.1-x_Y
    type: tcp
    mode: server
    address: 127.0.0.1:65535
bonds:
  - name: vehicle
    tx: active
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_EQ(LogLevel::Debug, config->log_level);
    EXPECT_EQ(UnknownIdPolicy::Drop, config->unknown_messages);
    EXPECT_EQ(minutes(1), config->route_timeout);
    EXPECT_EQ(milliseconds(1500), config->report_interval);
    EXPECT_EQ("/opt/plugins", config->plugin_dir);
    EXPECT_EQ("/run/mavbond/status.sock", config->status_socket);

    ASSERT_EQ(4u, config->endpoints.size());
    const auto& fc = config->endpoints[0];
    EXPECT_EQ("fc", fc.name);
    EXPECT_STREQ("uart", fc.schema->type);
    EXPECT_EQ("/dev/ttyAMA0", fc.options.text("device"));
    EXPECT_EQ(1500000u, fc.options.number("baud"));
    EXPECT_TRUE(fc.options.flag("flow_control"));
    EXPECT_EQ(milliseconds(250), fc.options.duration("reconnect_min"));
    EXPECT_EQ(seconds(2), fc.options.duration("reconnect_max"));
    EXPECT_EQ(16384u, fc.tx_queue_bytes);
    EXPECT_EQ((std::vector<uint32_t>{0, 33, 16777215}), fc.filter_in.allow);
    EXPECT_EQ((std::vector<uint32_t>{30}), fc.filter_in.block);
    EXPECT_TRUE(fc.filter_out.allow.empty());
    EXPECT_EQ((std::vector<uint32_t>{0}), fc.filter_out.block);
    EXPECT_EQ(16, fc.mark.line);
    EXPECT_EQ(5, fc.mark.column);

    const auto& radio = config->endpoints[1];
    EXPECT_STREQ("tcp", radio.schema->type);
    EXPECT_STREQ("client", radio.schema->mode);
    EXPECT_EQ("127.0.0.1", radio.options.text("address"));  // localhost is stored as the loopback address
    EXPECT_EQ(5760, radio.options.port("address"));
    EXPECT_EQ(microseconds(100), radio.options.duration("reconnect_min"));
    EXPECT_EQ(microseconds(100), radio.options.duration("reconnect_max"));
    EXPECT_EQ(280u, radio.tx_queue_bytes);
    EXPECT_EQ("vehicle", radio.bond);

    const auto& lte = config->endpoints[2];
    EXPECT_STREQ("udp", lte.schema->type);
    EXPECT_STREQ("client", lte.schema->mode);
    EXPECT_EQ("192.0.2.10", lte.options.text("address"));
    EXPECT_EQ(14560, lte.options.port("address"));
    EXPECT_EQ(1024u, lte.tx_queue_bytes);

    const auto& gcs = config->endpoints[3];
    EXPECT_EQ("gcs.1-x_Y", gcs.name);
    EXPECT_STREQ("server", gcs.schema->mode);
    EXPECT_EQ(65535, gcs.options.port("address"));
    EXPECT_FALSE(gcs.options.has("baud"));  // a UART's option: a UDP endpoint has none

    ASSERT_EQ(1u, config->bonds.size());
    EXPECT_EQ("vehicle", config->bonds[0].name);
    EXPECT_EQ(BondConfig::Tx::Active, config->bonds[0].tx);
    EXPECT_EQ(47, config->bonds[0].mark.line);
    EXPECT_EQ(5, config->bonds[0].mark.column);

    ASSERT_EQ(2u, config->filters.size());
    const auto& dedup = config->filters[0];
    EXPECT_EQ("dedup", dedup.plugin);
    EXPECT_FALSE(dedup.enabled);
    EXPECT_EQ((std::vector<std::string>{"vehicle"}), dedup.bonds);
    EXPECT_EQ((std::vector<std::string>{"radio", "lte"}), dedup.endpoints);
    EXPECT_EQ(2, dedup.mark.line);
    EXPECT_EQ(5, dedup.mark.column);
    ASSERT_EQ(2u, dedup.options.size());
    EXPECT_EQ("window", dedup.options[0].key);
    EXPECT_EQ("500ms", dedup.options[0].value);
    EXPECT_FALSE(dedup.options[0].is_sequence);
    EXPECT_EQ("t.yaml", dedup.options[0].mark.file);
    EXPECT_EQ(6, dedup.options[0].mark.line);
    EXPECT_EQ(5, dedup.options[0].mark.column);
    EXPECT_EQ(6, dedup.options[0].value_mark.line);
    EXPECT_EQ(13, dedup.options[0].value_mark.column);
    EXPECT_EQ("hash", dedup.options[1].key);
    EXPECT_TRUE(dedup.options[1].is_sequence);
    EXPECT_EQ("[a, b]", dedup.options[1].value);
    EXPECT_EQ((std::vector<std::string>{"a", "b"}), dedup.options[1].items);

    const auto& stats = config->filters[1];
    EXPECT_TRUE(stats.enabled);
    EXPECT_TRUE(stats.bonds.empty());
    EXPECT_TRUE(stats.endpoints.empty());
    EXPECT_TRUE(stats.options.empty());
}

TEST(ConfigParse, Tlog) {
    auto config = parse(R"(
endpoints:
  - name: flightlog
    type: tlog
    directory: /var/log/mavbond
    max_size: 64MiB
    block_out: [HEARTBEAT]
  - {name: small, type: tlog, directory: logs, max_size: 1G}
  - {name: unlimited, type: tlog, directory: logs}
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    const EndpointConfig& log = config->endpoints[0];
    EXPECT_STREQ("tlog", log.schema->type);
    EXPECT_EQ("/var/log/mavbond", log.options.text("directory"));
    EXPECT_EQ(64u << 20, log.options.number("max_size"));
    EXPECT_EQ(std::vector<uint32_t>{0}, log.filter_out.block);
    EXPECT_EQ(1ull << 30, config->endpoints[1].options.number("max_size"));
    EXPECT_EQ(0u, config->endpoints[2].options.number("max_size"));
}

TEST(ConfigParse, EmptyOptionalSections) {
    auto config = parse(R"(
endpoints:
  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:14550, allow_in: }
bonds:
filters: []
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_TRUE(config->bonds.empty());
    EXPECT_TRUE(config->filters.empty());
}

TEST(ConfigParse, GarbageNeverThrows) {
    const std::string inputs[] = {
        "\t",
        "{{{{",
        std::string(5000, '['),          // yaml-cpp's depth guard throws
        "\xff\xfe\x00\x01",
        "*undefined_alias\n",
        "endpoints: &a [*a]\n",
        "endpoints:\n  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:14550}\n---\n",
        "endpoints:\n  - !!binary name: x\n",
        std::string("endpoints:\n  - name: \0\n", 24),
    };
    for (const auto& text : inputs) {
        Result<Config> config = make_error("not run");
        EXPECT_NO_THROW(config = parse_config(text, "t.yaml", endpoint_schemas())) << text.substr(0, 40);
        EXPECT_FALSE(config.has_value()) << text.substr(0, 40);
        if (!config.has_value()) {
            EXPECT_EQ(0u, config.error().message.rfind("t.yaml:", 0)) << config.error().message;
        }
    }
}

// --- parse_duration --------------------------------------------------------------------------

TEST(ListenAddresses, OverlapOnlyWhereTheKernelWouldRefuseTheSecondBind) {
    EXPECT_TRUE(listen_addresses_overlap("127.0.0.1", 14550, "127.0.0.1", 14550));
    EXPECT_FALSE(listen_addresses_overlap("127.0.0.1", 14550, "127.0.0.1", 14551));
    EXPECT_FALSE(listen_addresses_overlap("127.0.0.1", 14550, "127.0.0.2", 14550));
    EXPECT_TRUE(listen_addresses_overlap("0.0.0.0", 14550, "192.0.2.1", 14550));
    EXPECT_TRUE(listen_addresses_overlap("192.0.2.1", 14550, "0.0.0.0", 14550));
    EXPECT_FALSE(listen_addresses_overlap("0.0.0.0", 14550, "::1", 14550)) << "IPv4 only";
    EXPECT_TRUE(listen_addresses_overlap("::", 14550, "127.0.0.1", 14550)) << "dual stack";
    EXPECT_TRUE(listen_addresses_overlap("0.0.0.0", 14550, "::", 14550));
    EXPECT_FALSE(listen_addresses_overlap("::1", 14550, "127.0.0.1", 14550));
    EXPECT_TRUE(listen_addresses_overlap("::1", 14550, "0:0:0:0:0:0:0:1", 14550)) << "one address";
    EXPECT_TRUE(listen_addresses_overlap("gs.example", 5760, "gs.example", 5760));
    EXPECT_FALSE(listen_addresses_overlap("gs.example", 5760, "127.0.0.1", 5760))
        << "a name resolves at start only (a taken port fails the bind there)";
}

TEST(ListenAddresses, OneProtocolsServersOnlyAndClientsNever) {
    auto ok = parse(R"(
endpoints:
  - {name: a, type: udp, mode: server, address: 0.0.0.0:14550}
  - {name: b, type: tcp, mode: server, address: 0.0.0.0:14550}
  - {name: c, type: udp, mode: client, address: 127.0.0.1:14550}
  - {name: d, type: udp, mode: server, address: "[::1]:14551"}
  - {name: e, type: udp, mode: server, address: 127.0.0.1:14551}
)");
    EXPECT_TRUE(ok.has_value()) << ok.error().message;
    auto taken = parse(R"(
endpoints:
  - {name: a, type: tcp, mode: server, address: "[::]:5760"}
  - {name: b, type: udp, mode: server, address: 127.0.0.1:5760}
  - {name: c, type: tcp, mode: server, address: localhost:5760}
)");
    ASSERT_FALSE(taken.has_value());
    EXPECT_EQ("t.yaml:4:49: endpoint 'c': tcp address 127.0.0.1:5760 is taken by endpoint 'a' "
              "([::]:5760, declared at t.yaml:2:5): two servers cannot listen on one address",
              taken.error().message);
}

TEST(ParseDuration, Units) {
    EXPECT_EQ(nanoseconds(5), parse_duration("5ns"));
    EXPECT_EQ(microseconds(7), parse_duration("7us"));
    EXPECT_EQ(milliseconds(250), parse_duration("250ms"));
    EXPECT_EQ(seconds(2), parse_duration("2s"));
    EXPECT_EQ(milliseconds(1500), parse_duration("1.5s"));
    EXPECT_EQ(minutes(1), parse_duration("1m"));
    EXPECT_EQ(seconds(90), parse_duration("1.5m"));
    EXPECT_EQ(microseconds(2500), parse_duration("2.5ms"));
    EXPECT_EQ(nanoseconds(1), parse_duration("0.000000001s"));
    EXPECT_EQ(nanoseconds(0), parse_duration("0s"));
}

TEST(ParseDuration, Rejects) {
    for (const char* text : {"", "30", "s", "1.s", ".5s", "1.5", "-1s", "+1s", "1 s", "1sec",
                             "1h", "1.5ns", "0.0000000001s", "1e3ms", "99999999999999999999s",
                             "9999999999m", " 1s", "1s "}) {
        EXPECT_FALSE(parse_duration(text).has_value()) << "'" << text << "'";
    }
}

// --- load_config -----------------------------------------------------------------------------

TEST(LoadConfig, MissingFile) {
    auto config = load_config("/nonexistent/mavbond.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("/nonexistent/mavbond.yaml: cannot open: No such file or directory",
              config.error().message);
}

TEST(LoadConfig, Directory) {
    auto config = load_config("/", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("/: cannot read: Is a directory", config.error().message);
}

TEST(LoadConfig, ErrorNamesTheFile) {
    char path[] = "/tmp/mavbond-config-test-XXXXXX";
    int fd = mkstemp(path);
    ASSERT_GE(fd, 0);
    const std::string text = "endpoints:\n  - {name: gcs, type: udp, mode: server, adress: x}\n";
    ASSERT_EQ(static_cast<ssize_t>(text.size()), write(fd, text.data(), text.size()));
    close(fd);
    auto config = load_config(path, endpoint_schemas());
    unlink(path);
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ(std::string(path) + ":2:42: endpoint 'gcs': unknown key 'adress' (did you mean "
              "'address'? a udp server endpoint takes: address, allow_in, allow_out, block_in, block_out, bond, cost, mode, name, peer_timeout, radio_status, rx_buffer, signing, standby_carries, tx_queue, tx_rate, type)",
              config.error().message);
}

// --- malformed configs: each with its exact message -------------------------------------------

struct BadCase {
    const char* label;  // test name suffix
    const char* yaml;
    const char* error;
};

// Prefix of a valid first endpoint, for cases about later keys.
#define GCS                                                                    \
    "endpoints:\n"                                                             \
    "  - name: gcs\n"                                                          \
    "    type: udp\n"                                                          \
    "    mode: server\n"                                                       \
    "    address: 0.0.0.0:14550\n"

const BadCase kBadCases[] = {
    // --- file level
    {"SyntaxError", "endpoints: [a, b\nlog_level: info\n",
     "t.yaml:2:10: a '[' before this has no closing ']' (YAML: end of sequence flow not found)"},
    {"SyntaxBadIndent", "log_level: info\n  endpoints: []\n",
     "t.yaml:2:12: this line's key (column 3) is indented deeper than the key above it (column 1), "
     "which has its value already: the keys of one map start in the same column (YAML: illegal "
     "map value)"},
    {"EmptyFile", "", "t.yaml:1:1: the file is empty (it needs at least an 'endpoints:' list)"},
    {"OnlyComments", "# nothing here\n",
     "t.yaml:1:1: the file is empty (it needs at least an 'endpoints:' list)"},
    {"TopLevelSequence", "- name: gcs\n",
     "t.yaml:1:1: the top level must be a map of keys, not a sequence"},
    {"TopLevelScalar", "hello\n", "t.yaml:1:1: the top level must be a map of keys, not a scalar"},
    {"TwoDocuments", GCS "---\nlog_level: info\n",
     "t.yaml:7:1: only one YAML document is allowed (found a second one after '---')"},
    {"UnknownTopKey", GCS "log_levle: info\n",
     "t.yaml:6:1: unknown key 'log_levle' (did you mean 'log_level'? it takes: bonds, endpoints, "
     "filters, identity, link_events, log_level, metrics, plugin_dir, report_interval, "
     "route_timeout, status_socket, tx_classes, unknown_messages)"},
    {"DuplicateTopKey", "log_level: info\n" GCS "log_level: debug\n",
     "t.yaml:7:1: duplicate key 'log_level'"},
    {"ComplexKey", GCS "? [a]\n: 1\n", "t.yaml:6:3: a key must be a plain word, not a sequence"},
    {"MissingEndpoints", "log_level: info\n", "t.yaml:1:1: missing required key 'endpoints'"},
    {"EmptyEndpoints", "endpoints: []\n",
     "t.yaml:1:12: 'endpoints' must be a non-empty sequence of endpoints"},
    {"EndpointsIsMap", "endpoints:\n  gcs: {type: udp}\n",
     "t.yaml:2:3: 'endpoints' must be a non-empty sequence of endpoints"},
    {"EndpointsNull", "endpoints:\n",
     "t.yaml:1:1: 'endpoints' must be a non-empty sequence of endpoints"},

    // --- top-level values
    {"BadLogLevel", GCS "log_level: verbose\n",
     "t.yaml:6:12: invalid log_level 'verbose' (allowed: error, warning, notice, info, debug, "
     "trace)"},
    {"LogLevelSequence", GCS "log_level: [info]\n",
     "t.yaml:6:12: 'log_level' must be a single value, not a sequence"},
    {"BadUnknownMessages", GCS "unknown_messages: keep\n",
     "t.yaml:6:19: invalid unknown_messages 'keep' (allowed: forward, drop)"},
    {"DurationWithoutUnit", GCS "route_timeout: 30\n",
     "t.yaml:6:16: 'route_timeout': duration '30' needs a unit (ns, us, ms, s, m)"},
    {"BadDuration", GCS "route_timeout: 30 sec\n",
     "t.yaml:6:16: 'route_timeout': invalid duration '30 sec' (e.g. 250ms, 2s, 1.5s, 1m)"},
    {"ZeroReportInterval", GCS "report_interval: 0s\n",
     "t.yaml:6:18: 'report_interval': duration must be greater than 0"},
    {"PluginDirNull", GCS "plugin_dir:\n", "t.yaml:6:1: 'plugin_dir' needs a value"},
    {"BondsIsMap", GCS "bonds: {name: vehicle}\n",
     "t.yaml:6:8: 'bonds' must be a sequence, not a map"},

    // --- endpoint structure
    {"EndpointNotMap", "endpoints:\n  - gcs\n",
     "t.yaml:2:5: endpoint #1: must be a map of keys, not a scalar"},
    {"EndpointMissingName", "endpoints:\n  - type: udp\n    mode: server\n",
     "t.yaml:2:5: endpoint #1: missing required key 'name'"},
    {"EndpointNameNull", "endpoints:\n  - name:\n    type: udp\n",
     "t.yaml:2:5: endpoint #1: 'name' needs a value"},
    {"EndpointBadName", "endpoints:\n  - name: my gcs\n",
     "t.yaml:2:11: endpoint #1: invalid name 'my gcs' (allowed characters: A-Z a-z 0-9 _ . -)"},
    {"UnknownEndpointKey", GCS "    adress: 0.0.0.0:14550\n",
     "t.yaml:6:5: endpoint 'gcs': unknown key 'adress' (did you mean 'address'? a udp server "
     "endpoint takes: address, allow_in, allow_out, block_in, block_out, bond, cost, mode, name, peer_timeout, radio_status, rx_buffer, signing, standby_carries, tx_queue, tx_rate, type)"},
    {"DuplicateEndpointKey", GCS "    mode: client\n",
     "t.yaml:6:5: endpoint 'gcs': duplicate key 'mode'"},
    {"DuplicateEndpointName", GCS "  - {name: gcs, type: udp, mode: client, address: 1.2.3.4:5}\n",
     "t.yaml:6:12: duplicate endpoint name 'gcs' (first declared at line 2)"},
    {"MissingType", "endpoints:\n  - name: gcs\n    mode: server\n",
     "t.yaml:2:5: endpoint 'gcs': missing required key 'type' (udp, tcp, uart or tlog)"},
    {"BadType", "endpoints:\n  - name: fc\n    type: serial\n",
     "t.yaml:3:11: endpoint 'fc': invalid type 'serial' (allowed: udp, tcp, uart, tlog)"},
    {"MissingMode", "endpoints:\n  - {name: gcs, type: udp, address: 0.0.0.0:14550}\n",
     "t.yaml:2:5: endpoint 'gcs': missing required key 'mode' (server or client)"},
    {"BadMode", "endpoints:\n  - {name: gcs, type: tcp, mode: listen}\n",
     "t.yaml:2:34: endpoint 'gcs': invalid mode 'listen' (allowed: server, client)"},
    {"ModeOnUart", "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, mode: server}\n",
     "t.yaml:2:48: endpoint 'fc': key 'mode' does not apply to a uart endpoint"},
    {"DeviceOnUdp", GCS "    device: /dev/ttyS0\n",
     "t.yaml:6:5: endpoint 'gcs': key 'device' does not apply to a udp endpoint"},
    {"PeerTimeoutOnUdpClient",
     "endpoints:\n  - {name: lte, type: udp, mode: client, address: 1.2.3.4:5, peer_timeout: 5s}\n",
     "t.yaml:2:62: endpoint 'lte': key 'peer_timeout' does not apply to a udp client endpoint"},
    {"ReconnectOnTcpServer",
     "endpoints:\n  - {name: mp, type: tcp, mode: server, address: 0.0.0.0:5760, "
     "reconnect_min: 1s}\n",
     "t.yaml:2:64: endpoint 'mp': key 'reconnect_min' does not apply to a tcp server endpoint"},

    // --- endpoint values
    {"MissingAddress", "endpoints:\n  - {name: gcs, type: udp, mode: server}\n",
     "t.yaml:2:5: endpoint 'gcs': missing required key 'address' (host:port)"},
    {"AddressWithoutPort",
     "endpoints:\n  - {name: gcs, type: udp, mode: server, address: 0.0.0.0}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': '0.0.0.0' needs host:port (e.g. 0.0.0.0:14550, "
     "[::1]:14550, lte.example.net:14550)"},
    {"PortZero", "endpoints:\n  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:0}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': port '0' is not in 1..65535"},
    {"PortTooBig", "endpoints:\n  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:65536}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': port '65536' is not in 1..65535"},
    {"PortText", "endpoints:\n  - {name: gcs, type: udp, mode: server, address: '0.0.0.0:gcs'}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': port 'gcs' is not in 1..65535"},
    {"BadHost", "endpoints:\n  - {name: gcs, type: udp, mode: server, address: 300.1.2.3:14550}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': host '300.1.2.3' is not an IPv4 address (a.b.c.d), "
     "an IPv6 address in brackets or a host name"},
    {"BadHostName", "endpoints:\n  - {name: gcs, type: tcp, mode: client, address: gcs_lan:5760}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': host 'gcs_lan' is not an IPv4 address (a.b.c.d), "
     "an IPv6 address in brackets or a host name"},
    {"BareIpv6", "endpoints:\n  - {name: gcs, type: udp, mode: client, address: '::1:14550'}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': host '::1': an IPv6 address is written in brackets "
     "([::1]:port)"},
    {"BadIpv6", "endpoints:\n  - {name: gcs, type: udp, mode: client, address: '[::g]:14550'}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': '[::g]' is not an IPv6 address"},
    {"Ipv6Unquoted", "endpoints:\n  - name: gcs\n    type: udp\n    mode: server\n    address: [::1]:14550\n",
     "t.yaml:5:19: an IPv6 address in brackets is quoted in YAML: address: \"[::1]:14550\" "
     "(YAML: end of map not found)"},
    {"Ipv6NoPort", "endpoints:\n  - {name: gcs, type: udp, mode: client, address: '[::1]'}\n",
     "t.yaml:2:51: endpoint 'gcs': 'address': '[::1]' needs a port after the brackets "
     "([::1]:14550)"},
    {"MissingDevice", "endpoints:\n  - name: fc\n    type: uart\n    baud: 57600\n",
     "t.yaml:2:5: endpoint 'fc': missing required key 'device'"},
    {"BaudZero", "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, baud: 0}\n",
     "t.yaml:2:54: endpoint 'fc': 'baud': '0' is not a positive integer"},
    {"BaudNegative", "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, baud: -9600}\n",
     "t.yaml:2:54: endpoint 'fc': 'baud': '-9600' is not a positive integer"},
    {"BaudText", "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, baud: fast}\n",
     "t.yaml:2:54: endpoint 'fc': 'baud': 'fast' is not a positive integer"},
    {"BadFlowControl",
     "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, flow_control: maybe}\n",
     "t.yaml:2:62: endpoint 'fc': 'flow_control' must be true or false, not 'maybe'"},
    {"ReconnectMaxBelowMin",
     "endpoints:\n  - name: fc\n    type: uart\n    device: /dev/ttyS0\n"
     "    reconnect_max: 1s\n    reconnect_min: 2s\n",
     "t.yaml:5:20: endpoint 'fc': 'reconnect_max' (1s) must not be below 'reconnect_min' (2s)"},
    {"ReconnectMinAboveDefaultMax",
     "endpoints:\n  - {name: fc, type: uart, device: /dev/ttyS0, reconnect_min: 10s}\n",
     "t.yaml:2:63: endpoint 'fc': 'reconnect_max' (5s) must not be below 'reconnect_min' (10s)"},
    {"PeerTimeoutNoUnit", GCS "    peer_timeout: 30\n",
     "t.yaml:6:19: endpoint 'gcs': 'peer_timeout': duration '30' needs a unit (ns, us, ms, s, m)"},
    {"TxQueueTooSmall", GCS "    tx_queue: 100\n",
     "t.yaml:6:15: endpoint 'gcs': 'tx_queue': 100 is below the minimum of 280 bytes (one "
     "largest frame)"},
    {"TxQueueBadSuffix", GCS "    tx_queue: 16kb\n",
     "t.yaml:6:15: endpoint 'gcs': 'tx_queue': '16kb' is not a size in bytes (e.g. 16384, 16k, "
     "16KiB; at most 64MiB)"},
    {"UnknownMessageName", GCS "    allow_in: [HEARTBEAT, HEARTBEET]\n",
     "t.yaml:6:27: endpoint 'gcs': 'allow_in': unknown message 'HEARTBEET'"},
    {"MessageIdOutOfRange", GCS "    block_in: [16777216]\n",
     "t.yaml:6:16: endpoint 'gcs': 'block_in': message id '16777216' out of range 0..16777215"},
    {"NegativeMessageId", GCS "    allow_out:\n      - -1\n",
     "t.yaml:7:9: endpoint 'gcs': 'allow_out': message id '-1' out of range 0..16777215"},
    {"MessageListNotSequence", GCS "    block_out: HEARTBEAT\n",
     "t.yaml:6:16: endpoint 'gcs': 'block_out' must be a sequence, not a scalar"},
    {"MessageListNested", GCS "    block_out: [[0]]\n",
     "t.yaml:6:17: endpoint 'gcs': 'block_out': a message must be an id or a name, not a "
     "sequence"},

    // --- bonds
    {"UndeclaredBond", GCS "    bond: vehicle\n",
     "t.yaml:6:11: endpoint 'gcs': bond 'vehicle' is not declared under 'bonds:'"},
    {"BondWithoutMembers", GCS "bonds:\n  - name: vehicle\n",
     "t.yaml:7:11: bond 'vehicle' has no member endpoint (set 'bond: vehicle' on at least one "
     "endpoint)"},
    {"DuplicateBond", GCS "    bond: v\nbonds:\n  - name: v\n  - name: v\n",
     "t.yaml:9:11: duplicate bond name 'v' (first declared at line 8)"},
    {"BadBondTx", GCS "    bond: v\nbonds:\n  - {name: v, tx: all}\n",
     "t.yaml:8:19: bond 'v': invalid tx 'all' (allowed: broadcast, active)"},
    {"UnknownBondKey", GCS "    bond: v\nbonds:\n  - {name: v, mode: active}\n",
     "t.yaml:8:15: bond 'v': unknown key 'mode' (it takes: failback_after, failback_loss, "
     "failover_loss, name, renumber, resend, signing, tx)"},
    {"BondMissingName", GCS "bonds:\n  - tx: active\n",
     "t.yaml:7:5: bond #1: missing required key 'name'"},

    // --- filters
    {"FilterMissingPlugin", GCS "filters:\n  - window: 500ms\n",
     "t.yaml:7:5: filter #1: missing required key 'plugin'"},
    {"FilterBadPlugin", GCS "filters:\n  - plugin: Dedup\n",
     "t.yaml:7:13: filter #1: invalid plugin name 'Dedup' (allowed characters: a-z 0-9 _)"},
    {"FilterUnknownBond", GCS "filters:\n  - plugin: stats\n  - {plugin: dedup, bonds: [air]}\n",
     "t.yaml:8:29: filter #2 'dedup': 'bonds': unknown bond 'air'"},
    {"FilterUnknownEndpoint", GCS "filters:\n  - plugin: dedup\n    endpoints: [gcs, radio]\n",
     "t.yaml:8:22: filter #1 'dedup': 'endpoints': unknown endpoint 'radio'"},
    {"FilterBadEnabled", GCS "filters:\n  - {plugin: dedup, enabled: yes please}\n",
     "t.yaml:7:30: filter #1 'dedup': 'enabled' must be true or false, not 'yes please'"},
    {"FilterDuplicateOption", GCS "filters:\n  - plugin: dedup\n    window: 1s\n    window: 2s\n",
     "t.yaml:9:5: filter #1 'dedup': duplicate key 'window'"},
    {"FilterOptionMap", GCS "filters:\n  - plugin: dedup\n    window: {a: 1}\n",
     "t.yaml:8:13: filter #1 'dedup': option 'window' must be a value or a sequence of values, "
     "not a map"},
    {"FilterOptionNull", GCS "filters:\n  - plugin: dedup\n    window:\n",
     "t.yaml:8:5: filter #1 'dedup': option 'window' needs a value"},
    {"FilterNotMap", GCS "filters:\n  - dedup\n",
     "t.yaml:7:5: filter #1: must be a map of keys, not a scalar"},
    // --- identity, link_events, renumber
    {"IdentitySysidZero", GCS "identity:\n  sysid: 0\n",
     "t.yaml:7:10: identity: 'sysid': '0' is not a MAVLink id (1..255)"},
    {"IdentityCompidTooBig", GCS "identity: {compid: 256}\n",
     "t.yaml:6:20: identity: 'compid': '256' is not a MAVLink id (1..255)"},
    {"IdentityUnknownKey", GCS "identity: {sysid: 1, hartbeat: 1s}\n",
     "t.yaml:6:22: identity: unknown key 'hartbeat' (did you mean 'heartbeat'? it takes: compid, "
     "heartbeat, sysid)"},
    {"LinkEventsNotMap", GCS "link_events: yes\n",
     "t.yaml:6:14: link_events: must be a map of keys, not a scalar"},
    {"LinkEventsZeroSilence", GCS "link_events:\n  silent_after: 0s\n",
     "t.yaml:7:17: link_events: 'silent_after': duration must be greater than 0"},
    // --- tlog
    {"TlogWithoutDirectory", "endpoints:\n  - {name: log, type: tlog}\n",
     "t.yaml:2:5: endpoint 'log': missing required key 'directory'"},
    {"TlogMaxSizeTooSmall", "endpoints:\n  - {name: log, type: tlog, directory: /l, max_size: 1k}\n",
     "t.yaml:2:54: endpoint 'log': 'max_size': 1k is below the minimum of 4096 bytes"},
    {"TlogMaxSizeNotSize", "endpoints:\n  - {name: log, type: tlog, directory: /l, max_size: 64MB}\n",
     "t.yaml:2:54: endpoint 'log': 'max_size': '64MB' is not a size in bytes (e.g. 64MiB, 1GiB)"},
    {"TlogInBond", "endpoints:\n  - {name: log, type: tlog, directory: /l, bond: b}\n",
     "t.yaml:2:44: endpoint 'log': key 'bond' does not apply to a tlog endpoint"},
    {"TlogAllowIn", "endpoints:\n  - {name: log, type: tlog, directory: /l, allow_in: [0]}\n",
     "t.yaml:2:44: endpoint 'log': key 'allow_in' does not apply to a tlog endpoint"},
    {"DirectoryOnUdp", GCS "    directory: /l\n",
     "t.yaml:6:5: endpoint 'gcs': key 'directory' does not apply to a udp endpoint"},
    // --- budgets and classes
    {"TxRateNoUnit", GCS "    tx_rate: 5000\n",
     "t.yaml:6:14: endpoint 'gcs': 'tx_rate': '5000' is not a rate (e.g. 5kB/s, 5760B/s, "
     "57600baud, or baud for a UART's own)"},
    {"TxRateBitsPerSecond", GCS "    tx_rate: 5kb/s\n",
     "t.yaml:6:14: endpoint 'gcs': 'tx_rate': '5kb/s' is not a rate (e.g. 5kB/s, 5760B/s, "
     "57600baud, or baud for a UART's own)"},
    {"TxRateTooLow", GCS "    tx_rate: 50B/s\n",
     "t.yaml:6:14: endpoint 'gcs': 'tx_rate': 50B/s is outside 100 B/s (one largest frame "
     "in 3 s) to 1GB/s"},
    {"TxRateBaudOnUdp", GCS "    tx_rate: baud\n",
     "t.yaml:6:14: endpoint 'gcs': 'tx_rate': 'baud' takes a UART's own baudrate; give a "
     "udp server endpoint a rate such as 5kB/s or 57600baud"},
    {"RadioStatusUnknown", GCS "    radio_status: 3dr\n",
     "t.yaml:6:19: endpoint 'gcs': 'radio_status': '3dr' is not a radio mavbond knows (sik: a "
     "SiK radio such as 3DR or RFD900, reporting as system 51, component 68)"},
    {"RadioStatusOnServer", GCS "    radio_status: sik\n",
     "t.yaml:6:19: endpoint 'gcs': 'radio_status' does not apply to a udp server endpoint "
     "(each peer is a link of its own): give it to a UART or a client"},
    {"RadioStatusUdpNoRate",
     "endpoints:\n  - {name: r, type: udp, mode: client, address: 127.0.0.1:5, radio_status: sik}\n",
     "t.yaml:2:76: endpoint 'r': 'radio_status' on a udp client endpoint needs 'tx_rate' "
     "(the radio's rate, e.g. 57600baud)"},
    {"RadioStatusNoBond",
     "endpoints:\n  - {name: r, type: uart, device: /dev/ttyS0, radio_status: sik}\n",
     "t.yaml:2:61: endpoint 'r': 'radio_status' needs the endpoint in a bond (the bond "
     "reports to its local side; a bond of one link will do)"},
    {"TxRateOnTlog", "endpoints:\n  - {name: log, type: tlog, directory: /l, tx_rate: 5kB/s}\n",
     "t.yaml:2:44: endpoint 'log': key 'tx_rate' does not apply to a tlog endpoint"},
    {"TxClassesUnknownKey", GCS "tx_classes: {controll: [HEARTBEAT]}\n",
     "t.yaml:6:14: tx_classes: unknown key 'controll' (did you mean 'control'? it takes: bulk, "
     "caps, control)"},
    {"TxClassesUnknownMessage", GCS "tx_classes: {bulk: [FTP]}\n",
     "t.yaml:6:21: tx_classes: 'bulk': unknown message 'FTP'"},
    {"TxClassesBoth", GCS "tx_classes: {bulk: [HEARTBEAT]}\n",
     "t.yaml:6:20: tx_classes: message HEARTBEAT (0) is in both control and bulk (a list "
     "not given is the default one, mavbond.yaml(5))"},
    {"TxClassesCapOnControl", GCS "tx_classes:\n  caps: {COMMAND_LONG: 1Hz}\n",
     "t.yaml:7:10: tx_classes: caps: 'COMMAND_LONG': a cap thins telemetry; this message "
     "is control"},
    {"TxClassesCapNotHz", GCS "tx_classes:\n  caps: {ATTITUDE: 100ms}\n",
     "t.yaml:7:20: tx_classes: caps: 'ATTITUDE': '100ms' is not a rate in Hz greater than "
     "0 and at most 1000 (e.g. 10Hz, 0.5Hz)"},
    {"TxClassesCapsNotMap", GCS "tx_classes:\n  caps: [ATTITUDE]\n",
     "t.yaml:7:9: tx_classes: 'caps' must be a map of message: rate (e.g. ATTITUDE: 10Hz), "
     "not a sequence"},
};

TEST(ConfigParse, IdentityLinkEventsAndRenumber) {
    auto config = parse(R"(
endpoints:
  - {name: lte, type: udp, mode: server, address: 0.0.0.0:14551, bond: telemetry}
bonds:
  - {name: telemetry, renumber: true}
filters:
  - {plugin: dedup, bonds: [telemetry], key: content}
identity: {sysid: 7, compid: 68, heartbeat: 500ms}
link_events: {silent_after: 1.5s, min_interval: 3s}
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_EQ(std::optional<bool>(true), config->bonds[0].renumber);
    EXPECT_EQ(7, config->identity.sysid);
    EXPECT_EQ(68, config->identity.compid);
    EXPECT_EQ(milliseconds(500), config->identity.heartbeat);
    EXPECT_TRUE(config->link_events.enabled);
    EXPECT_FALSE(config->link_events.statustext.has_value()) << "derived once the section is there";
    EXPECT_EQ(milliseconds(1500), config->link_events.silent_after);
    EXPECT_EQ(seconds(3), config->link_events.min_interval);
}

TEST(ConfigParse, BudgetsAndTheirClasses) {
    auto config = parse(R"(
endpoints:
  - {name: radio, type: uart, device: /dev/ttyUSB0, baud: 57600, tx_rate: baud}
  - {name: lte, type: udp, mode: client, address: 127.0.0.1:14551, tx_rate: 2KiB/s}
  - {name: sik, type: udp, mode: client, address: 127.0.0.1:14552, tx_rate: 57600baud}
  - {name: gcs, type: udp, mode: server, address: 0.0.0.0:14550}
tx_classes:
  bulk: [FILE_TRANSFER_PROTOCOL, 120]
  caps: {ATTITUDE: 10Hz, GLOBAL_POSITION_INT: 0.5Hz}
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    const auto& eps = config->endpoints;
    EXPECT_TRUE(eps[0].tx_budget.uart_baud);
    EXPECT_EQ(2048u, eps[1].tx_budget.bytes_per_s);
    EXPECT_EQ(5760u, eps[2].tx_budget.bytes_per_s);
    EXPECT_TRUE(eps[2].tx_budget.serial) << "a rate in baud charges no datagram headers";
    EXPECT_FALSE(eps[1].tx_budget.serial);
    EXPECT_FALSE(eps[3].tx_budget.enabled());
    EXPECT_TRUE(eps[3].tx_budget.classes.control.empty()) << "no budget, no classes";
    const TxClassesConfig& c = eps[1].tx_budget.classes;
    EXPECT_EQ(eps[0].tx_budget.classes, c);
    EXPECT_EQ((std::vector<uint32_t>{110, 120}), c.bulk);
    // Control kept its defaults: commands, their acks, HEARTBEAT.
    for (uint32_t id : {0u, 76u, 77u})
        EXPECT_TRUE(std::binary_search(c.control.begin(), c.control.end(), id)) << id;
    // Sorted and each once: the budget bisects it (a name the dialect lacked once came out
    // as a second COMMAND_ACK).
    EXPECT_TRUE(std::adjacent_find(c.control.begin(), c.control.end(),
                                   std::greater_equal<uint32_t>()) == c.control.end());
    EXPECT_EQ(36u, c.control.size()) << "every default control message is in the dialect";
    ASSERT_EQ(2u, c.caps.size());
    EXPECT_EQ(std::make_pair(30u, Duration(milliseconds(100))), c.caps[0]);
    EXPECT_EQ(std::make_pair(33u, Duration(seconds(2))), c.caps[1]);
}

TEST(ConfigParse, ARadiosReportsMakeABudget) {
    auto config = parse(R"(
endpoints:
  - {name: radio, type: uart, device: /dev/ttyUSB0, baud: 57600, radio_status: sik, bond: v}
  - {name: rfd, type: uart, device: /dev/ttyUSB1, baud: 57600, tx_rate: 4kB/s,
     radio_status: sik, bond: v}
  - {name: net, type: udp, mode: client, address: 127.0.0.1:14552, tx_rate: 57600baud,
     radio_status: sik, bond: v}
bonds:
  - {name: v}
)");
    ASSERT_TRUE(config.has_value()) << config.error().message;
    const auto& eps = config->endpoints;
    for (const auto& ep : eps) {
        EXPECT_EQ(RadioStatusSource::Sik, ep.tx_budget.radio_status) << ep.name;
        EXPECT_TRUE(ep.tx_budget.enabled()) << ep.name;
        EXPECT_FALSE(ep.tx_budget.classes.control.empty()) << ep.name << ": a budget's classes";
    }
    EXPECT_TRUE(eps[0].tx_budget.uart_baud) << "a UART without tx_rate: its baud is the ceiling";
    EXPECT_FALSE(eps[1].tx_budget.uart_baud);
    EXPECT_EQ(4000u, eps[1].tx_budget.bytes_per_s);
    EXPECT_EQ(5760u, eps[2].tx_budget.bytes_per_s);
    // A reload that changes only radio_status retunes the endpoint in place.
    EndpointConfig plain = eps[1];
    plain.tx_budget.radio_status = RadioStatusSource::None;
    EXPECT_TRUE(same_but_budget(plain, eps[1]));
    EXPECT_FALSE(same_settings(plain, eps[1]));
}

TEST(ConfigParse, WithoutTheSectionsMavbondSaysNothingOfItsOwn) {
    auto config = parse(GCS);
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_FALSE(config->link_events.enabled);
    EXPECT_FALSE(config->bonds.empty() ? false : config->bonds[0].renumber.has_value())
        << "absent: derived by the filter chain";
    EXPECT_EQ(Duration::zero(), config->identity.heartbeat);
    EXPECT_EQ(1, config->identity.sysid);
    EXPECT_EQ(191, config->identity.compid);
}

class BadConfig : public testing::TestWithParam<BadCase> {};

TEST_P(BadConfig, FailsWithExactMessage) {
    auto config = parse_config(GetParam().yaml, "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value()) << GetParam().yaml;
    EXPECT_EQ(GetParam().error, config.error().message) << GetParam().yaml;
}

INSTANTIATE_TEST_SUITE_P(Cases, BadConfig, testing::ValuesIn(kBadCases),
                         [](const testing::TestParamInfo<BadCase>& param_info) {
                             return std::string(param_info.param.label);
                         });

// What a reload compares: the meaning of a declaration, not where in the file it was written.
TEST(SameSettings, IgnoresWhereButNotWhat) {
    // One config three ways: as written, shifted by a comment and extra spaces, and changed.
    auto config = [](const char* head, const char* address, const char* bond, const char* window) {
        return parse((std::string(head) + "endpoints:\n"
                      "  -   {name: a, type: udp, mode: server, address: " + address +
                      ", bond: b}\n"
                      "  - {name: l2, type: udp, mode: server, address: 127.0.0.1:9, bond: b}\n"
                      "bonds:\n  - {name: b" + bond + "}\n"
                      "filters:\n  -  {plugin: dedup,  window: " + window + "}\n").c_str());
    };
    auto a = config("", "127.0.0.1:1", "", "2s");
    auto moved = config("# a comment moves everything down a line\n", "127.0.0.1:1", "", "2s");
    auto changed = config("", "127.0.0.1:2", ", tx: active", "3s");
    for (auto* r : {&a, &moved, &changed})
        EXPECT_TRUE(*r) << (*r ? "" : r->error().message);
    ASSERT_TRUE(a && moved && changed);
    ASSERT_NE(a->endpoints[0].mark, moved->endpoints[0].mark);
    EXPECT_TRUE(same_settings(a->endpoints[0], moved->endpoints[0]));
    EXPECT_TRUE(same_settings(a->bonds, moved->bonds));
    EXPECT_TRUE(same_settings(a->filters, moved->filters));
    EXPECT_FALSE(same_settings(a->endpoints[0], changed->endpoints[0]));
    EXPECT_FALSE(same_settings(a->bonds, changed->bonds));
    EXPECT_FALSE(same_settings(a->filters, changed->filters));
    EXPECT_FALSE(same_settings(a->filters, {}));
    // A budget alone is what a running endpoint takes on in place.
    EndpointConfig budgeted = a->endpoints[0];
    budgeted.tx_budget.bytes_per_s = 5000;
    EXPECT_FALSE(same_settings(a->endpoints[0], budgeted));
    EXPECT_TRUE(same_but_budget(a->endpoints[0], budgeted));
    EXPECT_TRUE(same_but_budget(moved->endpoints[0], budgeted));
    EXPECT_FALSE(same_but_budget(changed->endpoints[0], budgeted));
}

// --- metrics: ------------------------------------------------------------------------------

TEST(MetricsConfig, OffUnlessGivenAndLoopbackForAPort) {
    auto none = parse("endpoints: [{name: a, type: udp, mode: server, address: 127.0.0.1:1}]\n");
    ASSERT_TRUE(none.has_value()) << none.error().message;
    EXPECT_FALSE(none.value().metrics.enabled);
    auto port = parse("metrics: {listen: 9273}\n"
                      "endpoints: [{name: a, type: udp, mode: server, address: 127.0.0.1:1}]\n");
    ASSERT_TRUE(port.has_value()) << port.error().message;
    const MetricsConfig& m = port.value().metrics;
    EXPECT_TRUE(m.enabled);
    EXPECT_EQ("127.0.0.1", m.host);
    EXPECT_EQ(9273, m.port);
    EXPECT_EQ(Duration(seconds(5)), m.timeout);
    EXPECT_EQ(8u, m.max_connections);
    auto all = parse(R"(
metrics:
  listen: 0.0.0.0:9100
  timeout: 250ms
  max_connections: 2
endpoints: [{name: a, type: udp, mode: server, address: 127.0.0.1:1}]
)");
    ASSERT_TRUE(all.has_value()) << all.error().message;
    EXPECT_EQ("0.0.0.0", all.value().metrics.host);
    EXPECT_EQ(9100, all.value().metrics.port);
    EXPECT_EQ(Duration(milliseconds(250)), all.value().metrics.timeout);
    EXPECT_EQ(2u, all.value().metrics.max_connections);
}

TEST(MetricsConfig, ErrorsNameTheirPlace) {
    auto error_of = [](const std::string& metrics) {
        auto c = parse_config("metrics:\n" + metrics +
                              "endpoints: [{name: a, type: udp, mode: server, address: 127.0.0.1:1}]\n",
                              "t.yaml", endpoint_schemas());
        return c ? std::string("(loaded)") : c.error().message;
    };
    EXPECT_EQ("t.yaml:2:11: metrics: 'listen': port '0' is not in 1..65535",
              error_of("  listen: 0\n"));
    EXPECT_EQ("t.yaml:2:11: metrics: 'listen': host 'gcs.local' is not an IPv4 address (a.b.c.d) "
              "or 'localhost'",
              error_of("  listen: gcs.local:9273\n"));
    EXPECT_EQ("t.yaml:3:3: metrics: unknown key 'path' (it takes: listen, max_connections, timeout)",
              error_of("  listen: 1\n  path: /m\n"));
    EXPECT_EQ("t.yaml:2:3: metrics: missing required key 'listen' (e.g. 127.0.0.1:9273)",
              error_of("  timeout: 1s\n"));
    EXPECT_EQ("t.yaml:3:20: metrics: 'max_connections': '0' is not in 1..1024",
              error_of("  listen: 1\n  max_connections: 0\n"));
    EXPECT_EQ(0u, error_of("  listen: 1\n  timeout: 0s\n").find("t.yaml:3:12: metrics: "));
}

}  // namespace
}  // namespace mavbond

// YAML allows no control character but tab and line breaks; yaml-cpp would misplace the error
// (past the end of the line) and put the NUL in the message. Found by tests/fuzz/fuzz_config.
namespace mavbond {
TEST(ConfigParse, ControlCharacterRefusedWhereItIs) {
    const std::string nul("log_level: info\nend\0points: []\n", 31);
    auto config = parse_config(nul, "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("t.yaml:2:4: control character 0x00 is not allowed in YAML", config.error().message);
    config = parse_config("log_level: info\x1b\n", "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("t.yaml:1:16: control character 0x1B is not allowed in YAML", config.error().message);
    // Tab and CR are allowed: a CRLF file with a tab in a value loads.
    config = parse_config("endpoints:\r\n  - {name: a, type: uart, device: \"/dev/a\tb\"}\r\n",
                          "t.yaml", endpoint_schemas());
    ASSERT_TRUE(config.has_value()) << config.error().message;
    EXPECT_EQ("/dev/a\tb", config->endpoints[0].options.text("device"));
}

// yaml-cpp's LoadAll() looped forever, allocating, on a stray ','. Found by tests/fuzz/fuzz_config.
TEST(ConfigParse, StrayTokenRefused) {
    auto config = parse_config(",", "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("t.yaml:1:1: unexpected ','", config.error().message);
    config = parse_config("- name: gcs\n,\n", "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("t.yaml:2:1: unexpected ','", config.error().message);
    config = parse_config("log_level: info\n---\n,\n", "t.yaml", endpoint_schemas());
    ASSERT_FALSE(config.has_value());
    EXPECT_EQ("t.yaml:3:1: only one YAML document is allowed (found a second one after '---')",
              config.error().message);
}
}  // namespace mavbond

namespace mavbond {
namespace {

TEST(HostPort, ReadsEveryFormAnAddressIsWrittenIn) {
    struct Case {
        const char* text;
        const char* host;
        uint16_t port;
    };
    const Case cases[] = {
        {"192.0.2.1:14550", "192.0.2.1", 14550},
        {"0.0.0.0:1", "0.0.0.0", 1},
        {"localhost:5760", "127.0.0.1", 5760},
        {"[::1]:14550", "::1", 14550},
        {"[::]:14550", "::", 14550},
        {"[2001:db8::5]:65535", "2001:db8::5", 65535},
        {"[::ffff:192.0.2.1]:9", "::ffff:192.0.2.1", 9},
        {"lte.example.net:14550", "lte.example.net", 14550},
        {"lte.example.net.:14550", "lte.example.net.", 14550},
        {"ip6-localhost:1", "ip6-localhost", 1},
        {"a1-b2.c3:2", "a1-b2.c3", 2},
    };
    for (const Case& c : cases) {
        HostPort hp = parse_host_port(c.text);
        EXPECT_EQ("", hp.error) << c.text;
        EXPECT_EQ(c.host, hp.host) << c.text;
        EXPECT_EQ(c.port, hp.port) << c.text;
    }
}

TEST(HostPort, RefusesWhatNoResolverTakes) {
    const char* bad[] = {"",         ":14550",        "[::1]",        "[::1]14550", "[::1:14550",
                         "::1:14550", "[fe80::zz]:1", "1.2.3:14550",  "1.2.3.4.5:1", "-a.net:1",
                         "a-.net:1",  "a..net:1",     "a_b.net:1",    "a.net:0",     "a.net:65536",
                         "a.net:x",   "a.net:-1",     "[a.net]:1"};
    for (const char* text : bad)
        EXPECT_NE("", parse_host_port(text).error) << "'" << text << "'";
}

// --- a bond's signing -----------------------------------------------------------------------

class BondSigning : public testing::Test {
protected:
    Result<Config> parse_signed(const std::string& bond_signing, const std::string& extra = "") {
        std::string text =
            "endpoints:\n"
            "  - {name: radio, type: udp, mode: client, address: 127.0.0.1:1, bond: vehicle}\n"
            "  - {name: lte, type: udp, mode: client, address: 127.0.0.1:2, bond: vehicle" +
            extra + "}\n"
            "  - {name: gcs, type: udp, mode: server, address: 127.0.0.1:3}\n"
            "bonds:\n"
            "  - {name: vehicle, signing: " + bond_signing + "}\n";
        return parse_config(text, "t.yaml", endpoint_schemas());
    }
    TempKey key_;
};

TEST_F(BondSigning, SignsEveryMemberByDefaultAndTheLinksGivenOtherwise) {
    auto all = parse_signed("{key_file: " + key_.path() + "}");
    ASSERT_TRUE(all.has_value()) << all.error().message;
    EXPECT_EQ((std::vector<std::string>{"radio", "lte"}), all->bonds[0].signing.links);
    for (size_t i = 0; i < 2; i++) {
        const SigningConfig& s = all->endpoints[i].signing;
        EXPECT_TRUE(s.enabled && s.require && s.by_bond) << all->endpoints[i].name;
        EXPECT_EQ(all->bonds[0].signing.key, s.key);
    }
    EXPECT_FALSE(all->endpoints[2].signing.enabled) << "not a member";
    auto lte = parse_signed("{key_file: " + key_.path() + ", links: [lte]}");
    ASSERT_TRUE(lte.has_value()) << lte.error().message;
    EXPECT_EQ(std::vector<std::string>{"lte"}, lte->bonds[0].signing.links);
    EXPECT_FALSE(lte->endpoints[0].signing.enabled);
    EXPECT_TRUE(lte->endpoints[1].signing.by_bond);
    EXPECT_FALSE(same_settings(all->endpoints[0], lte->endpoints[0]))
        << "a link signed or not is another declaration: a reload restarts it";
}

TEST_F(BondSigning, MistakesNameTheirPlace) {
    const std::string k = key_.path();
    struct Case {
        std::string signing, extra, error;
    };
    const Case cases[] = {
        {"{key_file: " + k + ", links: [gcs]}", "",
         "t.yaml:6:" + std::to_string(51 + k.size()) + ": bond 'vehicle': 'signing': 'links': "
         "'gcs' is not a member of the bond "
         "(a member has 'bond: vehicle')"},
        {"{key_file: " + k + ", links: [lte, lte]}", "",
         "t.yaml:6:" + std::to_string(56 + k.size()) + ": bond 'vehicle': 'signing': 'links': 'lte' is "
         "listed twice"},
        {"{key_file: " + k + ", links: []}", "",
         "t.yaml:6:" + std::to_string(50 + k.size()) + ": bond 'vehicle': 'signing': 'links' "
         "must name at least one member (leave it out to sign every member)"},
        {"{links: [lte]}", "", "t.yaml:6:30: bond 'vehicle': 'signing': missing required key "
                               "'key_file'"},
        {"{key_file: " + k + ", require: false}", "",
         "t.yaml:6:" + std::to_string(43 + k.size()) + ": bond 'vehicle': 'signing': unknown "
         "key 'require' (it takes: key_file, links)"},
        {"on", "", "t.yaml:6:30: bond 'vehicle': 'signing': must be a map (key_file, links), "
                   "not a scalar"},
        {"{key_file: " + k + "}", ", signing: {key_file: " + k + "}",
         "t.yaml:3:79: endpoint 'lte': 'signing' on a bond member: sign the bond instead "
         "(bonds: - {name: vehicle, signing: {key_file: ...}}), which signs what it sends on "
         "its links and verifies what they bring"},
        {"{key_file: " + k + ".missing}", "",
         "t.yaml:6:41: bond 'vehicle': 'signing': key file " + k + ".missing: cannot open: No "
         "such file or directory (make one with: mavbondctl keygen " + k + ".missing; then copy "
         "the same file to the other side)"},
    };
    for (const Case& c : cases) {
        auto config = parse_signed(c.signing, c.extra);
        ASSERT_FALSE(config.has_value()) << c.signing;
        EXPECT_EQ(c.error, config.error().message) << c.signing;
    }
}

}  // namespace
}  // namespace mavbond
