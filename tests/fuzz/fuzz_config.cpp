// Fuzz target: the config loader, parse_config() on any text. It never throws or crashes and
// either
//  - returns an error "fuzz.yaml:LINE:COLUMN: message" whose position lies in the text (a line
//    of it, a column on that line or just past its end), or
//  - returns a Config that keeps every promise config.h makes to the daemon: names valid and
//    unique, addresses and ports usable, durations positive, sizes in range, every bond and
//    filter scope resolved, every mark in the text.
// Loading the same text twice gives the same answer.
#include <arpa/inet.h>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <set>
#include <string>
#include <string_view>
#include <vector>

#include "config/config.h"
#include "fuzz_check.h"
#include "mavlink/frame.h"
#include "endpoints/endpoint_types.h"

namespace mavbond::fuzz {
namespace {

constexpr const char* kName = "fuzz.yaml";

/// The length of each line. Only \n ends a line, for yaml-cpp as for the loader: a \r is a
/// character of its line.
std::vector<size_t> line_lengths(std::string_view text) {
    std::vector<size_t> lines;
    size_t start = 0;
    for (size_t i = 0; i < text.size(); ++i) {
        if (text[i] == '\n') {
            lines.push_back(i - start);
            start = i + 1;
        }
    }
    lines.push_back(text.size() - start);
    return lines;
}

class ConfigChecker {
public:
    explicit ConfigChecker(std::string_view text) : lines_(line_lengths(text)) {}

    void check_position(long line, long column, const char* what) const {
        FUZZ_CHECK(line >= 1 && static_cast<size_t>(line) <= lines_.size(),
                   "%s: line %ld of %zu", what, line, lines_.size());
        const size_t length = lines_[static_cast<size_t>(line) - 1];
        FUZZ_CHECK(column >= 1 && static_cast<size_t>(column) <= length + 1,
                   "%s: line %ld column %ld, the line has %zu characters", what, line, column,
                   length);
    }

    void check_error(const std::string& message) const {
        const std::string prefix = std::string(kName) + ":";
        FUZZ_CHECK(message.rfind(prefix, 0) == 0, "error without the file name: %s",
                   message.c_str());
        // LINE:COLUMN: what
        const char* p = message.c_str() + prefix.size();
        char* end = nullptr;
        const long line = std::strtol(p, &end, 10);
        FUZZ_CHECK(end != p && *end == ':', "error without a line: %s", message.c_str());
        p = end + 1;
        const long column = std::strtol(p, &end, 10);
        FUZZ_CHECK(end != p && end[0] == ':' && end[1] == ' ' && end[2] != '\0',
                   "error without a column and a message: %s", message.c_str());
        check_position(line, column, message.c_str());
    }

    void check_mark(const SourceMark& mark, const std::string& what) const {
        FUZZ_CHECK(mark.file == kName, "%s: marked in '%s'", what.c_str(), mark.file.c_str());
        check_position(mark.line, mark.column, what.c_str());
    }

    void check_config(const Config& config) const {
        FUZZ_CHECK(config.path == kName, "path '%s'", config.path.c_str());
        FUZZ_CHECK(!config.endpoints.empty(), "a config without endpoints");
        FUZZ_CHECK(config.route_timeout.count() >= 0 && config.report_interval.count() > 0,
                   "negative route_timeout or report_interval not positive");
        std::set<std::string> endpoints;
        std::set<std::string> bonds;
        for (const BondConfig& b : config.bonds) {
            check_name(b.name, "bond");
            FUZZ_CHECK(bonds.insert(b.name).second, "bond '%s' twice", b.name.c_str());
            check_mark(b.mark, "bond " + b.name);
        }
        std::set<std::string> bonds_with_members;
        for (const EndpointConfig& ep : config.endpoints) {
            check_endpoint(ep);
            FUZZ_CHECK(endpoints.insert(ep.name).second, "endpoint '%s' twice", ep.name.c_str());
            FUZZ_CHECK(ep.bond.empty() || bonds.count(ep.bond) != 0,
                       "endpoint '%s' in undeclared bond '%s'", ep.name.c_str(), ep.bond.c_str());
            bonds_with_members.insert(ep.bond);
        }
        for (const BondConfig& b : config.bonds)
            FUZZ_CHECK(bonds_with_members.count(b.name) != 0, "bond '%s' without members",
                       b.name.c_str());
        for (const FilterConfig& filter : config.filters)
            check_filter(filter, endpoints, bonds);
    }

private:
    static void check_name(const std::string& name, const char* what) {
        FUZZ_CHECK(!name.empty(), "an empty %s name", what);
        for (char ch : name) {
            const bool ok = (ch >= 'A' && ch <= 'Z') || (ch >= 'a' && ch <= 'z') ||
                            (ch >= '0' && ch <= '9') || ch == '_' || ch == '.' || ch == '-';
            FUZZ_CHECK(ok, "%s name '%s'", what, name.c_str());
        }
    }

    static void check_ids(const MessageFilterConfig& filter, const std::string& name) {
        for (const auto* list : {&filter.allow, &filter.block}) {
            for (uint32_t id : *list)
                FUZZ_CHECK(id <= 0xFFFFFF, "endpoint '%s': message id %u", name.c_str(), id);
        }
    }

    void check_endpoint(const EndpointConfig& ep) const {
        check_name(ep.name, "endpoint");
        check_mark(ep.mark, "endpoint " + ep.name);
        const char* name = ep.name.c_str();
        // Every option of its type's table as its kind promises it; an option with neither
        // a default nor a value must have been optional.
        FUZZ_CHECK(ep.schema != nullptr, "endpoint '%s' without a type", name);
        for (const EndpointOption& o : ep.schema->options) {
            if (!ep.options.has(o.key)) {
                FUZZ_CHECK(!o.required && !o.default_value, "endpoint '%s': '%s' missing", name,
                           o.key);
                continue;
            }
            switch (o.kind) {
            case OptionKind::Address: {
                // What was read reads again as itself: a literal or a host name, a port.
                const std::string& host = ep.options.text(o.key);
                std::string again = (host.find(':') != std::string::npos ? "[" + host + "]" : host) +
                                    ":" + std::to_string(ep.options.port(o.key));
                HostPort reread = parse_host_port(again);
                FUZZ_CHECK(reread.error.empty() && reread.host == host &&
                               ep.options.port(o.key) != 0,
                           "endpoint '%s': address '%s' port %u", name,
                           ep.options.text(o.key).c_str(), ep.options.port(o.key));
                break;
            }
            case OptionKind::Time:
                FUZZ_CHECK(ep.options.duration(o.key).count() > 0, "endpoint '%s': '%s' <= 0",
                           name, o.key);
                break;
            case OptionKind::Count:
                FUZZ_CHECK(ep.options.number(o.key) > 0 && ep.options.number(o.key) <= UINT32_MAX,
                           "endpoint '%s': '%s' %llu", name, o.key,
                           static_cast<unsigned long long>(ep.options.number(o.key)));
                break;
            case OptionKind::Size: {
                uint64_t n = ep.options.number(o.key);
                bool is_default = o.default_value && n == 0;
                FUZZ_CHECK(is_default || (n >= o.min && (o.max == 0 || n <= o.max)),
                           "endpoint '%s': '%s' %llu", name, o.key, static_cast<unsigned long long>(n));
                break;
            }
            case OptionKind::Text:
                FUZZ_CHECK(!ep.options.text(o.key).empty(), "endpoint '%s': '%s' empty", name,
                           o.key);
                break;
            case OptionKind::Flag:
                break;
            }
        }
        FUZZ_CHECK(!ep.schema->check || !ep.schema->check(ep.options),
                   "endpoint '%s': its type's rule is broken", name);
        FUZZ_CHECK(ep.tx_queue_bytes >= kMaxFrameLen && ep.tx_queue_bytes <= 64u * 1024 * 1024,
                   "endpoint '%s': tx_queue %zu", name, ep.tx_queue_bytes);
        check_ids(ep.filter_in, ep.name);
        check_ids(ep.filter_out, ep.name);
        check_budget(ep);
    }

    /// A budget within its bounds, a UART's own rate only on a UART, and classes that are
    /// sorted, apart, and capped only where telemetry is; no classes without a budget; a
    /// radio's reports only on a bond member with a budget for them to set.
    static void check_budget(const EndpointConfig& ep) {
        const char* name = ep.name.c_str();
        const TxBudgetConfig& b = ep.tx_budget;
        FUZZ_CHECK(b.radio_status == RadioStatusSource::None || (b.enabled() && !ep.bond.empty()),
                   "endpoint '%s': radio_status without a budget or a bond", name);
        if (!b.enabled()) {
            FUZZ_CHECK(b.classes == TxClassesConfig{}, "endpoint '%s': classes, no budget", name);
            return;
        }
        FUZZ_CHECK(ep.schema->receives, "endpoint '%s': a budget on a recorder", name);
        if (b.uart_baud)
            FUZZ_CHECK(std::string_view(ep.schema->type) == "uart" && b.serial,
                       "endpoint '%s': tx_rate baud on a %s", name, ep.schema->type);
        else
            FUZZ_CHECK(b.bytes_per_s >= 100 && b.bytes_per_s <= 1000000000ull,
                       "endpoint '%s': tx_rate %llu B/s", name,
                       static_cast<unsigned long long>(b.bytes_per_s));
        const TxClassesConfig& c = b.classes;
        for (const auto* list : {&c.control, &c.bulk}) {
            for (size_t i = 0; i < list->size(); i++) {
                FUZZ_CHECK((*list)[i] <= 0xFFFFFF && (i == 0 || (*list)[i - 1] < (*list)[i]),
                           "endpoint '%s': a class list not sorted or out of range", name);
            }
        }
        for (uint32_t id : c.control)
            FUZZ_CHECK(!std::binary_search(c.bulk.begin(), c.bulk.end(), id),
                       "endpoint '%s': message %u both control and bulk", name, id);
        for (size_t i = 0; i < c.caps.size(); i++) {
            const auto& [id, interval] = c.caps[i];
            FUZZ_CHECK(interval.count() > 0 && (i == 0 || c.caps[i - 1].first <= id),
                       "endpoint '%s': cap of %u", name, id);
            FUZZ_CHECK(!std::binary_search(c.control.begin(), c.control.end(), id) &&
                           !std::binary_search(c.bulk.begin(), c.bulk.end(), id),
                       "endpoint '%s': a cap on %u, not telemetry", name, id);
        }
    }

    void check_filter(const FilterConfig& filter, const std::set<std::string>& endpoints,
                      const std::set<std::string>& bonds) const {
        const char* plugin = filter.plugin.c_str();
        FUZZ_CHECK(!filter.plugin.empty(), "a filter without a plugin name");
        for (char ch : filter.plugin)
            FUZZ_CHECK((ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9') || ch == '_',
                       "plugin name '%s'", plugin);
        check_mark(filter.mark, "filter " + filter.plugin);
        for (const std::string& b : filter.bonds)
            FUZZ_CHECK(bonds.count(b) != 0, "filter '%s' scoped to unknown bond '%s'", plugin,
                       b.c_str());
        for (const std::string& e : filter.endpoints)
            FUZZ_CHECK(endpoints.count(e) != 0, "filter '%s' scoped to unknown endpoint '%s'",
                       plugin, e.c_str());
        std::set<std::string> keys;
        for (const FilterConfig::Option& o : filter.options) {
            FUZZ_CHECK(o.key != "plugin" && o.key != "enabled" && o.key != "bonds" &&
                           o.key != "endpoints",
                       "filter '%s': '%s' kept as a plugin option", plugin, o.key.c_str());
            FUZZ_CHECK(keys.insert(o.key).second, "filter '%s': option '%s' twice", plugin,
                       o.key.c_str());
            FUZZ_CHECK(o.is_sequence || o.items.empty(), "filter '%s': option '%s' items",
                       plugin, o.key.c_str());
            check_mark(o.mark, "option " + o.key);
            check_mark(o.value_mark, "value of option " + o.key);
        }
    }

    std::vector<size_t> lines_;
};

}  // namespace
}  // namespace mavbond::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    using namespace mavbond;
    using namespace mavbond::fuzz;
    const std::string text(reinterpret_cast<const char*>(data), size);
    const ConfigChecker checker(text);

    const Result<Config> config = parse_config(text, kName, endpoint_schemas());
    const Result<Config> again = parse_config(text, kName, endpoint_schemas());
    FUZZ_CHECK(config.has_value() == again.has_value(), "loaded twice, one failed");
    if (!config.has_value()) {
        checker.check_error(config.error().message);
        FUZZ_CHECK(config.error().message == again.error().message,
                   "loaded twice, two errors: '%s', '%s'", config.error().message.c_str(),
                   again.error().message.c_str());
        return 0;
    }
    checker.check_config(config.value());
    return 0;
}
