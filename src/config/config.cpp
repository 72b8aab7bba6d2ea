// YAML config -> typed structs. yaml-cpp throws; its exceptions are caught here and nowhere
// else, and turned into "file:line:column: message" errors.
//
// Inside this file a validation failure is thrown as ConfigError (private to this file) so the
// many small checks stay one line each; parse_config() catches it and returns it as a value.
// Nothing is thrown out of load_config()/parse_config(). The value syntax (numbers, sizes,
// durations, addresses) is values.h's; the YAML text and its syntax errors, yaml_text.h's.
#include "config/config.h"
#include "config/values.h"
#include "config/yaml_text.h"

#include <arpa/inet.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <utility>

#include "config/listeners.h"
#include "mavlink/frame.h"
#include "mavlink/message_table.h"
#include "mavlink/bond_signing.h"
#include "mavlink/signing.h"

namespace mavbond {
namespace {

constexpr size_t kMinTxQueueBytes = kMaxFrameLen;      // one largest frame (280 bytes)
constexpr size_t kMaxTxQueueBytes = 64u * 1024 * 1024; // a typo guard, far above any real need
constexpr std::string_view kDurationExamples = "e.g. 250ms, 2s, 1.5s, 1m";

struct ConfigError {
    std::string message;
};

bool is_name_char(char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
           c == '_' || c == '.' || c == '-';
}

bool is_plugin_char(char c) {
    return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
}

/// What a link with a budget spends it on first, when the file has no `tx_classes:`
/// (mavbond.yaml(5) lists them). Control: what a pilot or a protocol waits for; bulk: what
/// comes in long runs and is retried when lost. Everything else is telemetry.
TxClassesConfig default_tx_classes() {
    static const char* const kControl[] = {
        "HEARTBEAT", "SET_MODE", "PING", "COMMAND_INT", "COMMAND_LONG", "COMMAND_ACK",
        "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_VALUE",
        "PARAM_SET", "PARAM_EXT_REQUEST_READ", "PARAM_EXT_REQUEST_LIST", "PARAM_EXT_VALUE",
        "PARAM_EXT_SET", "PARAM_EXT_ACK", "MISSION_ITEM", "MISSION_REQUEST",
        "MISSION_SET_CURRENT", "MISSION_REQUEST_LIST", "MISSION_COUNT", "MISSION_CLEAR_ALL",
        "MISSION_ITEM_REACHED", "MISSION_ACK", "MISSION_REQUEST_INT", "MISSION_ITEM_INT",
        "MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE", "SET_ATTITUDE_TARGET",
        "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT", "SET_HOME_POSITION",
        "LOG_REQUEST_LIST", "LOG_REQUEST_DATA", "LOG_ERASE", "LOG_REQUEST_END", "STATUSTEXT"};
    static const char* const kBulk[] = {
        "FILE_TRANSFER_PROTOCOL", "LOG_ENTRY", "LOG_DATA", "DATA_TRANSMISSION_HANDSHAKE",
        "ENCAPSULATED_DATA", "REMOTE_LOG_DATA_BLOCK", "REMOTE_LOG_BLOCK_STATUS", "GPS_RTCM_DATA",
        "GPS_INJECT_DATA", "SERIAL_CONTROL", "LOGGING_DATA", "LOGGING_DATA_ACKED", "LOGGING_ACK"};
    // The dialect is generated from the pymavlink at hand (all.xml): a name it lacks (a message
    // still in development.xml) can never be sent, so it is left out, not looked up blindly.
    TxClassesConfig classes;
    for (const char* name : kControl) {
        if (auto id = find_message_id(name))
            classes.control.push_back(*id);
    }
    for (const char* name : kBulk) {
        if (auto id = find_message_id(name))
            classes.bulk.push_back(*id);
    }
    std::sort(classes.control.begin(), classes.control.end());
    std::sort(classes.bulk.begin(), classes.bulk.end());
    return classes;
}


const char* kind_name(const YAML::Node& node) {
    switch (node.Type()) {
    case YAML::NodeType::Null: return "nothing";
    case YAML::NodeType::Scalar: return "a scalar";
    case YAML::NodeType::Sequence: return "a sequence";
    case YAML::NodeType::Map: return "a map";
    case YAML::NodeType::Undefined: return "nothing";
    }
    return "?";
}

/// Edits (insert, delete, replace, swap two neighbours) that make `a` into `b`.
size_t edit_distance(std::string_view a, std::string_view b) {
    std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
    for (size_t i = 0; i <= a.size(); i++)
        d[i][0] = i;
    for (size_t j = 0; j <= b.size(); j++)
        d[0][j] = j;
    for (size_t i = 1; i <= a.size(); i++) {
        for (size_t j = 1; j <= b.size(); j++) {
            d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1,
                                d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
            if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
                d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
        }
    }
    return d[a.size()][b.size()];
}

/// "did you mean 'baud'? a uart endpoint takes: baud, bond, ...": the keys `taker` takes,
/// and first the one `key` is most likely a typo of (at most 2 edits, fewer than half of it).
std::string known_keys_hint(std::string_view key, const std::set<std::string_view>& keys,
                            const std::string& taker) {
    std::string_view nearest;
    size_t best = std::min<size_t>(3, (key.size() + 1) / 2);
    std::string list;
    for (std::string_view k : keys) {
        list += (list.empty() ? "" : ", ") + std::string(k);
        if (size_t d = edit_distance(key, k); d < best) {
            best = d;
            nearest = k;
        }
    }
    return (nearest.empty() ? "" : "did you mean '" + std::string(nearest) + "'? ") + taker +
           " takes: " + list;
}

/// One key/value pair of a YAML map, in document order.
struct Entry {
    YAML::Node key;
    YAML::Node value;
    std::string name;  // the key's text ("" if the key is not a scalar)
};

/// The pairs of a map. yaml-cpp keeps duplicate keys as separate pairs, so iterating is the
/// only way to see them; find() returns the first.
struct MapView {
    std::vector<Entry> entries;

    const Entry* find(std::string_view name) const {
        for (const auto& e : entries) {
            if (e.key.IsScalar() && e.name == name)
                return &e;
        }
        return nullptr;
    }
};

MapView make_view(const YAML::Node& map) {
    MapView view;
    for (auto it = map.begin(); it != map.end(); ++it) {
        Entry e{it->first, it->second, it->first.IsScalar() ? it->first.Scalar() : ""};
        view.entries.push_back(std::move(e));
    }
    return view;
}

class Parser {
public:
    Parser(std::string name, EndpointSchemas types) : name_(std::move(name)), types_(types) {}

    Config parse(const YAML::Node& root);

private:
    struct BondRef {
        size_t endpoint;   // index into config_.endpoints
        YAML::Mark mark;   // the bond value
    };
    struct ScopeRef {
        std::string filter_ctx;
        std::string key;   // "bonds" or "endpoints"
        std::string name;
        YAML::Mark mark;
    };

    [[noreturn]] void fail(const YAML::Mark& mark, const std::string& message) const {
        throw ConfigError{format_at(name_, mark, message)};
    }

    SourceMark source_mark(const YAML::Mark& mark) const {
        return SourceMark{name_, mark.is_null() ? 1 : mark.line + 1,
                          mark.is_null() ? 1 : mark.column + 1};
    }

    /// A value's mark; a missing value (`key:` then newline) has a mark pointing past it, so
    /// the key's mark is used instead.
    static YAML::Mark value_mark(const Entry& e) {
        return e.value.IsNull() || e.value.Mark().is_null() ? e.key.Mark() : e.value.Mark();
    }

    /// Keys are plain words, each once, and (with `allowed`) known: an unknown one is named
    /// with the keys `listed` (by default the allowed ones), those `taker` (by default "it")
    /// takes, and the nearest of them when it looks like a typo of it.
    void check_keys(const MapView& view, const std::string& ctx,
                    const std::set<std::string_view>* allowed,
                    const std::set<std::string_view>* listed = nullptr,
                    const std::string& taker = "it") const;
    /// A top-level section's map (`identity:`, `link_events:`, ...), its keys checked.
    MapView section_view(const Entry& section, const std::string& ctx,
                         const std::set<std::string_view>& keys) const;
    const std::string& scalar(const Entry& e, const std::string& ctx) const;
    std::string required_scalar(const MapView& view, const YAML::Node& map,
                                std::string_view key, const std::string& ctx) const;
    Duration duration(const Entry& e, const std::string& ctx, bool positive) const;
    bool boolean(const Entry& e, const std::string& ctx) const;
    std::vector<uint32_t> message_ids(const Entry& e, const std::string& ctx) const;
    std::vector<std::pair<std::string, YAML::Mark>> name_list(const Entry& e,
                                                              const std::string& ctx) const;
    template <typename T>
    T choice(const Entry& e, const std::string& ctx,
             std::initializer_list<std::pair<std::string_view, T>> allowed) const;
    const YAML::Node& sequence(const Entry& e, const std::string& ctx, bool required) const;

    void parse_endpoint(const YAML::Node& node, size_t index);
    /// The endpoint type (and mode) of an entry, by its `type:` and `mode:`.
    /// The endpoint's type and mode, if they name one (nullptr: parse_endpoint_type says why).
    const EndpointSchema* endpoint_type_named(const MapView& view) const;
    /// Every key an endpoint of this type and mode takes.
    std::set<std::string_view> endpoint_keys(const EndpointSchema& type) const;
    const EndpointSchema& parse_endpoint_type(const MapView& view, const YAML::Node& node,
                                              const std::string& ctx) const;
    /// One option of an endpoint's type, as its kind reads it.
    /// One option of an endpoint's type, as its kind reads it (`given`: not its default).
    OptionValue endpoint_option(const EndpointOption& option, const Entry& e,
                                const std::string& ctx, bool given) const;
    OptionValue parse_address(const Entry& e, const std::string& ctx) const;
    void parse_signing(const Entry& e, const std::string& ctx, SigningConfig& signing) const;
    /// A signing block's `key_file`: its path, resolved from the config file's directory, and
    /// the key it holds.
    std::pair<std::string, std::array<uint8_t, 32>> key_file(const MapView& view,
                                                              const YAML::Node& map,
                                                              const std::string& where) const;
    void parse_bond_signing(const Entry& e, const std::string& ctx, BondConfig& bond);
    /// Checks the bonds' signed links and gives each its bond's key (SigningConfig::by_bond).
    void sign_bond_links();
    /// After parse_tx_rate: `radio_status` (a UART without `tx_rate` takes its baud).
    void parse_radio_status(const Entry& e, const std::string& ctx, const EndpointSchema& type,
                            TxBudgetConfig& budget) const;
    void parse_tx_rate(const Entry& e, const std::string& ctx, const EndpointSchema& type,
                       TxBudgetConfig& budget) const;
    void parse_tx_classes(const Entry& section, TxClassesConfig& classes) const;
    double percent(const Entry& e, const std::string& ctx) const;
    void parse_bond(const YAML::Node& node, size_t index);
    void parse_filter(const YAML::Node& node, size_t index);
    void parse_identity(const Entry& section);
    void parse_link_events(const Entry& section);
    uint8_t mavlink_id(const Entry& e, const std::string& ctx) const;
    void parse_metrics(const Entry& e);
    void cross_check();

    std::string name_;
    EndpointSchemas types_;
    Config config_;
    std::map<std::string, YAML::Mark> endpoint_names_;
    std::map<std::string, YAML::Mark> bond_names_;
    std::vector<BondRef> bond_refs_;
    std::vector<BondRef> radio_refs_;  // endpoints with `radio_status`: each must be in a bond
    std::vector<BondRef> listener_refs_;  // servers, at their address: one address each
    struct StandbyRef {
        std::string bond;
        std::string key;
        YAML::Mark mark;
    };
    std::vector<StandbyRef> standby_refs_;  // standby keys given: their bond needs a metered member
    std::vector<BondRef> signing_refs_;  // endpoints with their own `signing:`
    struct SignedLinkRef {
        size_t bond;       // index into config_.bonds
        std::string name;
        YAML::Mark mark;   // the item in `links`
    };
    std::vector<SignedLinkRef> signed_link_refs_;
    std::map<std::string, YAML::Mark> bond_signing_marks_;  // bonds with `signing:`, the key's mark
    std::vector<ScopeRef> scope_refs_;
};

void Parser::check_keys(const MapView& view, const std::string& ctx,
                        const std::set<std::string_view>* allowed,
                        const std::set<std::string_view>* listed, const std::string& taker) const {
    std::set<std::string_view> seen;
    for (const auto& e : view.entries) {
        if (!e.key.IsScalar())
            fail(e.key.Mark(), ctx + "a key must be a plain word, not " + kind_name(e.key));
        if (!seen.insert(e.name).second)
            fail(e.key.Mark(), ctx + "duplicate key '" + e.name + "'");
        if (allowed && !allowed->count(e.name))
            fail(e.key.Mark(), ctx + "unknown key '" + e.name + "' (" +
                                   known_keys_hint(e.name, listed ? *listed : *allowed, taker) +
                                   ")");
    }
}

MapView Parser::section_view(const Entry& section, const std::string& ctx,
                             const std::set<std::string_view>& keys) const {
    if (!section.value.IsMap())
        fail(value_mark(section), ctx + "must be a map of keys, not " + kind_name(section.value));
    MapView view = make_view(section.value);
    check_keys(view, ctx, &keys);
    return view;
}

const std::string& Parser::scalar(const Entry& e, const std::string& ctx) const {
    if (e.value.IsNull())
        fail(value_mark(e), ctx + "'" + e.name + "' needs a value");
    if (!e.value.IsScalar())
        fail(value_mark(e), ctx + "'" + e.name + "' must be a single value, not " +
                                kind_name(e.value));
    return e.value.Scalar();
}

std::string Parser::required_scalar(const MapView& view, const YAML::Node& map,
                                    std::string_view key, const std::string& ctx) const {
    const Entry* e = view.find(key);
    if (!e)
        fail(map.Mark(), ctx + "missing required key '" + std::string(key) + "'");
    std::string text = scalar(*e, ctx);
    if (text.empty())
        fail(value_mark(*e), ctx + "'" + e->name + "' must not be empty");
    return text;
}

Duration Parser::duration(const Entry& e, const std::string& ctx, bool positive) const {
    const std::string& text = scalar(e, ctx);
    std::string where = ctx + "'" + e.name + "': ";
    bool bare_number = !text.empty();
    for (char c : text) {
        if (!((c >= '0' && c <= '9') || c == '.'))
            bare_number = false;
    }
    if (bare_number)
        fail(value_mark(e), where + "duration '" + text + "' needs a unit (ns, us, ms, s, m)");
    auto d = parse_duration(text);
    if (!d)
        fail(value_mark(e), where + "invalid duration '" + text + "' (" +
                                std::string(kDurationExamples) + ")");
    if (positive && d->count() <= 0)
        fail(value_mark(e), where + "duration must be greater than 0");
    return *d;
}

bool Parser::boolean(const Entry& e, const std::string& ctx) const {
    const std::string& text = scalar(e, ctx);
    if (text == "true" || text == "True" || text == "TRUE")
        return true;
    if (text == "false" || text == "False" || text == "FALSE")
        return false;
    fail(value_mark(e), ctx + "'" + e.name + "' must be true or false, not '" + text + "'");
}

template <typename T>
T Parser::choice(const Entry& e, const std::string& ctx,
                 std::initializer_list<std::pair<std::string_view, T>> allowed) const {
    const std::string& text = scalar(e, ctx);
    std::string list;
    for (const auto& [word, value] : allowed) {
        if (text == word)
            return value;
        list += (list.empty() ? "" : ", ") + std::string(word);
    }
    fail(value_mark(e), ctx + "invalid " + e.name + " '" + text + "' (allowed: " + list + ")");
}

const YAML::Node& Parser::sequence(const Entry& e, const std::string& ctx, bool required) const {
    if (e.value.IsNull() && !required)
        return e.value;
    if (!e.value.IsSequence())
        fail(value_mark(e), ctx + "'" + e.name + "' must be a sequence, not " +
                                kind_name(e.value));
    return e.value;
}

std::vector<uint32_t> Parser::message_ids(const Entry& e, const std::string& ctx) const {
    std::vector<uint32_t> ids;
    const YAML::Node& seq = sequence(e, ctx, false);
    std::string where = ctx + "'" + e.name + "': ";
    for (const auto& item : seq) {
        if (!item.IsScalar())
            fail(item.Mark(), where + "a message must be an id or a name, not " +
                                  kind_name(item));
        const std::string& text = item.Scalar();
        auto id = message_id(text);
        if (!id && !text.empty() && ((text[0] >= '0' && text[0] <= '9') || text[0] == '-'))
            fail(item.Mark(), where + "message id '" + text + "' out of range 0.." +
                                  std::to_string(kMaxMessageId));
        if (!id)
            fail(item.Mark(), where + "unknown message '" + text + "'");
        ids.push_back(*id);
    }
    return ids;
}

std::vector<std::pair<std::string, YAML::Mark>> Parser::name_list(const Entry& e,
                                                                  const std::string& ctx) const {
    std::vector<std::pair<std::string, YAML::Mark>> names;
    const YAML::Node& seq = sequence(e, ctx, false);
    for (const auto& item : seq) {
        if (!item.IsScalar() || item.Scalar().empty())
            fail(item.Mark(), ctx + "'" + e.name + "': each item must be a name");
        names.emplace_back(item.Scalar(), item.Mark());
    }
    return names;
}

Config Parser::parse(const YAML::Node& root) {
    config_.path = name_;
    if (root.IsNull())
        fail(root.Mark(), "the file is empty (it needs at least an 'endpoints:' list)");
    if (!root.IsMap())
        fail(root.Mark(), std::string("the top level must be a map of keys, not ") +
                              kind_name(root));

    static const std::set<std::string_view> kTopKeys = {
        "log_level", "unknown_messages", "route_timeout", "report_interval", "plugin_dir",
        "status_socket", "endpoints", "bonds", "filters", "identity", "link_events", "metrics",
        "tx_classes"};
    MapView view = make_view(root);
    check_keys(view, "", &kTopKeys);

    if (const Entry* e = view.find("log_level")) {
        const std::string& text = scalar(*e, "");
        auto level = parse_log_level(text);
        if (!level)
            fail(value_mark(*e), "invalid log_level '" + text +
                                     "' (allowed: error, warning, notice, info, debug, trace)");
        config_.log_level = *level;
    }
    if (const Entry* e = view.find("unknown_messages")) {
        config_.unknown_messages = choice<UnknownIdPolicy>(
            *e, "", {{"forward", UnknownIdPolicy::Forward}, {"drop", UnknownIdPolicy::Drop}});
    }
    if (const Entry* e = view.find("route_timeout"))
        config_.route_timeout = duration(*e, "", false);
    if (const Entry* e = view.find("report_interval"))
        config_.report_interval = duration(*e, "", true);
    if (const Entry* e = view.find("plugin_dir"))
        config_.plugin_dir = scalar(*e, "");
    if (const Entry* e = view.find("status_socket"))
        config_.status_socket = scalar(*e, "");
    if (const Entry* e = view.find("metrics"))
        parse_metrics(*e);

    const Entry* endpoints = view.find("endpoints");
    if (!endpoints)
        fail(root.Mark(), "missing required key 'endpoints'");
    if (!endpoints->value.IsSequence() || endpoints->value.size() == 0)
        fail(value_mark(*endpoints), "'endpoints' must be a non-empty sequence of endpoints");
    size_t index = 0;
    for (const auto& node : endpoints->value)
        parse_endpoint(node, ++index);

    if (const Entry* e = view.find("bonds")) {
        index = 0;
        for (const auto& node : sequence(*e, "", false))
            parse_bond(node, ++index);
    }
    if (const Entry* e = view.find("filters")) {
        index = 0;
        for (const auto& node : sequence(*e, "", false))
            parse_filter(node, ++index);
    }
    if (const Entry* e = view.find("identity"))
        parse_identity(*e);
    if (const Entry* e = view.find("link_events"))
        parse_link_events(*e);
    TxClassesConfig classes = default_tx_classes();
    if (const Entry* e = view.find("tx_classes"))
        parse_tx_classes(*e, classes);
    for (EndpointConfig& ep : config_.endpoints) {
        if (ep.tx_budget.enabled())
            ep.tx_budget.classes = classes;
    }
    config_.tx_classes = std::move(classes);
    cross_check();
    return std::move(config_);
}

const EndpointSchema& Parser::parse_endpoint_type(const MapView& view, const YAML::Node& node,
                                            const std::string& ctx) const {
    // The words `type:` and `mode:` take, once each, in table order.
    auto words = [](const std::vector<std::string>& w, const char* last) {
        std::string out;
        for (size_t i = 0; i < w.size(); i++)
            out += (i == 0 ? "" : i + 1 == w.size() ? last : ", ") + w[i];
        return out;
    };
    std::vector<std::string> types;
    for (const EndpointSchema* t : types_) {
        if (std::find(types.begin(), types.end(), t->type) == types.end())
            types.emplace_back(t->type);
    }
    const Entry* type = view.find("type");
    if (!type)
        fail(node.Mark(), ctx + "missing required key 'type' (" + words(types, " or ") + ")");
    const std::string& word = scalar(*type, ctx);
    std::vector<const EndpointSchema*> modes;
    std::vector<std::string> mode_words;
    for (const EndpointSchema* t : types_) {
        if (word == t->type) {
            modes.push_back(t);
            if (t->mode)
                mode_words.emplace_back(t->mode);
        }
    }
    if (modes.empty())
        fail(value_mark(*type), ctx + "invalid type '" + word + "' (allowed: " +
                                    words(types, ", ") + ")");
    if (mode_words.empty())
        return *modes.front();
    const Entry* mode = view.find("mode");
    if (!mode)
        fail(node.Mark(), ctx + "missing required key 'mode' (" + words(mode_words, " or ") + ")");
    const std::string& mode_word = scalar(*mode, ctx);
    for (const EndpointSchema* t : modes) {
        if (mode_word == t->mode)
            return *t;
    }
    fail(value_mark(*mode), ctx + "invalid mode '" + mode_word + "' (allowed: " +
                                words(mode_words, ", ") + ")");
}

const EndpointSchema* Parser::endpoint_type_named(const MapView& view) const {
    const Entry* type = view.find("type");
    const Entry* mode = view.find("mode");
    if (!type || !type->value.IsScalar())
        return nullptr;
    for (const EndpointSchema* t : types_) {
        if (type->value.Scalar() != t->type)
            continue;
        if (!t->mode || (mode && mode->value.IsScalar() && mode->value.Scalar() == t->mode))
            return t;
    }
    return nullptr;
}

std::set<std::string_view> Parser::endpoint_keys(const EndpointSchema& type) const {
    // The keys every endpoint takes, and those only an endpoint frames come from takes; the
    // rest are its type's (its table).
    static const std::set<std::string_view> kCommonKeys = {"name", "type", "tx_queue",
                                                           "allow_out", "block_out"};
    // A recorder (a flight log) takes none of these: nothing comes from it, and it has no line.
    static const std::set<std::string_view> kReceiverKeys = {
        "allow_in", "block_in", "bond", "signing", "tx_rate", "radio_status", "cost",
        "standby_carries"};
    std::set<std::string_view> keys(kCommonKeys.begin(), kCommonKeys.end());
    if (type.receives)
        keys.insert(kReceiverKeys.begin(), kReceiverKeys.end());
    if (type.mode)
        keys.insert("mode");
    for (const EndpointOption& o : type.options)
        keys.insert(o.key);
    return keys;
}

void Parser::parse_endpoint(const YAML::Node& node, size_t index) {
    std::string ctx = "endpoint #" + std::to_string(index) + ": ";
    if (!node.IsMap())
        fail(node.Mark(), ctx + "must be a map of keys, not " + kind_name(node));
    MapView view = make_view(node);

    EndpointConfig ep;
    ep.mark = source_mark(node.Mark());
    ep.name = required_scalar(view, node, "name", ctx);
    const Entry& name_entry = *view.find("name");
    for (char c : ep.name) {
        if (!is_name_char(c))
            fail(value_mark(name_entry), ctx + "invalid name '" + ep.name +
                                             "' (allowed characters: A-Z a-z 0-9 _ . -)");
    }
    ctx = "endpoint '" + ep.name + "': ";

    // Every key some endpoint takes; any other is unknown, and named with the keys its type
    // takes when the type is clear already (else with every endpoint key).
    std::set<std::string_view> known;
    for (const EndpointSchema* t : types_)
        known.merge(endpoint_keys(*t));
    if (const EndpointSchema* t = endpoint_type_named(view)) {
        const std::set<std::string_view> own = endpoint_keys(*t);
        check_keys(view, ctx, &known, &own, "a " + t->title() + " endpoint");
    } else {
        check_keys(view, ctx, &known, nullptr, "an endpoint");
    }

    if (auto [it, inserted] = endpoint_names_.emplace(ep.name, name_entry.value.Mark());
        !inserted) {
        fail(value_mark(name_entry), "duplicate endpoint name '" + ep.name +
                                         "' (first declared at line " +
                                         std::to_string(it->second.line + 1) + ")");
    }

    const EndpointSchema& type = parse_endpoint_type(view, node, ctx);
    ep.schema = &type;
    // The keys this type and mode takes; those its type takes in another mode are named so.
    const std::set<std::string_view> own = endpoint_keys(type);
    std::set<std::string_view> other_modes;
    for (const EndpointSchema* t : types_) {
        if (std::string_view(t->type) == type.type && t != &type) {
            for (const EndpointOption& o : t->options)
                other_modes.insert(o.key);
        }
    }
    for (const auto& e : view.entries) {
        if (own.count(e.name))
            continue;
        std::string what = other_modes.count(e.name) ? type.title() : std::string(type.type);
        fail(e.key.Mark(), ctx + "key '" + e.name + "' does not apply to a " + what + " endpoint");
    }

    for (const EndpointOption& option : type.options) {
        if (const Entry* e = view.find(option.key)) {
            ep.options.set(option.key, endpoint_option(option, *e, ctx, true));
        } else if (option.default_value) {
            Entry fallback{YAML::Node(option.key), YAML::Node(option.default_value), option.key};
            ep.options.set(option.key, endpoint_option(option, fallback, ctx, false), false);
        } else if (option.required) {
            fail(node.Mark(), ctx + "missing required key '" + option.key + "'" +
                                  (option.kind == OptionKind::Address ? " (host:port)" : ""));
        }
    }
    if (type.listens)
        listener_refs_.push_back(BondRef{config_.endpoints.size(), value_mark(*view.find("address"))});
    if (type.check) {
        if (auto broken = type.check(ep.options)) {
            const Entry* e = view.find(broken->first);
            fail(e ? value_mark(*e) : node.Mark(), ctx + broken->second);
        }
    }

    if (const Entry* e = view.find("tx_queue")) {
        const std::string& text = scalar(*e, ctx);
        auto n = parse_byte_size(text);
        if (!n || *n > kMaxTxQueueBytes)
            fail(value_mark(*e), ctx + "'tx_queue': '" + text +
                                     "' is not a size in bytes (e.g. 16384, 16k, 16KiB; at most "
                                     "64MiB)");
        if (*n < kMinTxQueueBytes)
            fail(value_mark(*e), ctx + "'tx_queue': " + text + " is below the minimum of " +
                                     std::to_string(kMinTxQueueBytes) +
                                     " bytes (one largest frame)");
        ep.tx_queue_bytes = static_cast<size_t>(*n);
    }
    if (const Entry* e = view.find("allow_in"))
        ep.filter_in.allow = message_ids(*e, ctx);
    if (const Entry* e = view.find("block_in"))
        ep.filter_in.block = message_ids(*e, ctx);
    if (const Entry* e = view.find("allow_out"))
        ep.filter_out.allow = message_ids(*e, ctx);
    if (const Entry* e = view.find("block_out"))
        ep.filter_out.block = message_ids(*e, ctx);
    if (const Entry* e = view.find("bond")) {
        ep.bond = scalar(*e, ctx);
        if (ep.bond.empty())
            fail(value_mark(*e), ctx + "'bond' must not be empty");
        bond_refs_.push_back(BondRef{config_.endpoints.size(), value_mark(*e)});
    }
    if (const Entry* e = view.find("signing")) {
        parse_signing(*e, ctx, ep.signing);
        signing_refs_.push_back(BondRef{config_.endpoints.size(), e->key.Mark()});
    }
    if (const Entry* e = view.find("tx_rate"))
        parse_tx_rate(*e, ctx, type, ep.tx_budget);
    if (const Entry* e = view.find("radio_status")) {
        parse_radio_status(*e, ctx, type, ep.tx_budget);
        radio_refs_.push_back(BondRef{config_.endpoints.size(), value_mark(*e)});
    }
    // Standby: cost and standby_carries.
    const Entry* cost = view.find("cost");
    if (cost)
        ep.metered = choice<bool>(*cost, ctx, {{"free", false}, {"metered", true}});
    const Entry* carries = view.find("standby_carries");
    if (carries) {
        ep.standby_classes = 0;
        for (const auto& [word, mark] : name_list(*carries, ctx)) {
            size_t c = 0;
            while (c < kTxClassCount && word != kTxClassNames[c])
                c++;
            if (c == kTxClassCount)
                fail(mark, ctx + "'standby_carries': unknown class '" + word +
                               "' (allowed: control, telemetry, bulk)");
            ep.standby_classes |= static_cast<uint8_t>(1u << c);
        }
        if (ep.standby_classes == 0)
            fail(value_mark(*carries), ctx + "'standby_carries' must name at least one class");
    }
    // Standby is a bond's way of using a member: outside a bond there is nothing to stand by for.
    const Entry* stray = ep.metered ? cost : carries;
    if (stray && ep.bond.empty())
        fail(stray->key.Mark(), ctx + "'" + stray->name + "' needs 'bond': standby applies to a "
                                      "bond member");
    if (carries && !ep.metered)
        fail(carries->key.Mark(), ctx + "'standby_carries' applies only with 'cost: metered'");
    config_.endpoints.push_back(std::move(ep));
}

OptionValue Parser::endpoint_option(const EndpointOption& option, const Entry& e,
                                    const std::string& ctx, bool given) const {
    OptionValue v;
    const std::string key = "'" + std::string(option.key) + "'";
    switch (option.kind) {
    case OptionKind::Flag:
        v.flag = boolean(e, ctx);
        break;
    case OptionKind::Time:
        v.duration = duration(e, ctx, true);
        break;
    case OptionKind::Address:
        v = parse_address(e, ctx);
        break;
    case OptionKind::Text:
        v.text = scalar(e, ctx);
        if (v.text.empty())
            fail(value_mark(e), ctx + key + " must not be empty");
        break;
    case OptionKind::Count: {
        const std::string& text = scalar(e, ctx);
        auto n = parse_u64(text);
        if (!n || *n == 0 || *n > std::numeric_limits<uint32_t>::max())
            fail(value_mark(e), ctx + key + ": '" + text + "' is not a positive integer");
        v.number = *n;
        break;
    }
    case OptionKind::Size: {
        const std::string& text = scalar(e, ctx);
        auto n = parse_byte_size(text);
        if (option.max) {
            // A bounded size: one message for what is not one, or out of bounds.
            if (!n || *n < option.min || *n > option.max)
                fail(value_mark(e), ctx + key + ": '" + text + "' is not a size between " +
                                        format_size(option.min) + " and " + format_size(option.max) +
                                        " (e.g. " + option.default_value + ")");
        } else {
            if (!n)
                fail(value_mark(e), ctx + key + ": '" + text +
                                        "' is not a size in bytes (e.g. 64MiB, 1GiB)");
            // A default below the minimum means "no limit".
            if (*n < option.min && given)
                fail(value_mark(e), ctx + key + ": " + text + " is below the minimum of " +
                                        std::to_string(option.min) + " bytes");
        }
        v.number = *n;
        break;
    }
    }
    return v;
}

OptionValue Parser::parse_address(const Entry& e, const std::string& ctx) const {
    if (e.value.IsSequence())
        fail(value_mark(e), ctx + "'address' is a list: an IPv6 address in brackets is quoted in "
                                  "YAML (address: \"[::1]:14550\")");
    HostPort hp = parse_host_port(scalar(e, ctx));
    if (!hp.error.empty())
        fail(value_mark(e), ctx + "'address': " + hp.error);
    OptionValue v;
    v.text = std::move(hp.host);
    v.port = hp.port;
    return v;
}

std::pair<std::string, std::array<uint8_t, 32>> Parser::key_file(const MapView& view,
                                                                  const YAML::Node& map,
                                                                  const std::string& where) const {
    std::string file = required_scalar(view, map, "key_file", where);
    // A relative path is read from the config file's directory, wherever the daemon runs.
    auto slash = name_.rfind('/');
    if (file[0] != '/' && slash != std::string::npos)
        file = name_.substr(0, slash + 1) + file;
    auto key = load_signing_key(file);
    if (!key)
        fail(value_mark(*view.find("key_file")), where + key.error().message);
    return {file, key.value()};
}

void Parser::parse_signing(const Entry& e, const std::string& ctx, SigningConfig& signing) const {
    std::string where = ctx + "'signing': ";
    if (!e.value.IsMap())
        fail(value_mark(e), where + "must be a map (key_file, require), not " + kind_name(e.value));
    MapView view = make_view(e.value);
    static const std::set<std::string_view> kKeys = {"key_file", "require"};
    check_keys(view, where, &kKeys);
    signing.enabled = true;
    std::tie(signing.key_file, signing.key) = key_file(view, e.value, where);
    if (const Entry* r = view.find("require"))
        signing.require = boolean(*r, where);
}

void Parser::parse_bond_signing(const Entry& e, const std::string& ctx, BondConfig& bond) {
    std::string where = ctx + "'signing': ";
    if (!e.value.IsMap())
        fail(value_mark(e), where + "must be a map (key_file, links), not " + kind_name(e.value));
    MapView view = make_view(e.value);
    static const std::set<std::string_view> kKeys = {"key_file", "links"};
    check_keys(view, where, &kKeys);
    bond.signing.enabled = true;
    std::tie(bond.signing.key_file, bond.signing.key) = key_file(view, e.value, where);
    bond_signing_marks_.emplace(bond.name, e.key.Mark());
    if (const Entry* links = view.find("links")) {
        auto names = name_list(*links, where);
        if (names.empty())
            fail(value_mark(*links), where + "'links' must name at least one member (leave it "
                                             "out to sign every member)");
        for (const auto& [name, mark] : names) {
            for (const auto& ref : signed_link_refs_) {
                if (ref.bond == config_.bonds.size() && ref.name == name)
                    fail(mark, where + "'links': '" + name + "' is listed twice");
            }
            signed_link_refs_.push_back(SignedLinkRef{config_.bonds.size(), name, mark});
        }
    }
}

void Parser::parse_bond(const YAML::Node& node, size_t index) {
    std::string ctx = "bond #" + std::to_string(index) + ": ";
    if (!node.IsMap())
        fail(node.Mark(), ctx + "must be a map of keys, not " + kind_name(node));
    MapView view = make_view(node);
    BondConfig bond;
    bond.mark = source_mark(node.Mark());
    bond.name = required_scalar(view, node, "name", ctx);
    const Entry& name_entry = *view.find("name");
    for (char c : bond.name) {
        if (!is_name_char(c))
            fail(value_mark(name_entry), ctx + "invalid name '" + bond.name +
                                             "' (allowed characters: A-Z a-z 0-9 _ . -)");
    }
    ctx = "bond '" + bond.name + "': ";
    static const std::set<std::string_view> kKeys = {
        "name", "tx", "renumber", "failover_loss", "failback_loss", "failback_after", "resend",
        "signing"};
    check_keys(view, ctx, &kKeys);
    if (auto [it, inserted] = bond_names_.emplace(bond.name, name_entry.value.Mark());
        !inserted) {
        fail(value_mark(name_entry), "duplicate bond name '" + bond.name +
                                         "' (first declared at line " +
                                         std::to_string(it->second.line + 1) + ")");
    }
    if (const Entry* e = view.find("tx")) {
        bond.tx = choice<BondConfig::Tx>(*e, ctx,
                                         {{"broadcast", BondConfig::Tx::Broadcast},
                                          {"active", BondConfig::Tx::Active}});
        bond.tx_mark = source_mark(value_mark(*e));
    }
    if (const Entry* e = view.find("renumber")) {
        bond.renumber = boolean(*e, ctx);
        bond.renumber_mark = source_mark(value_mark(*e));
    }
    // Standby: when a metered member leaves it and comes back.
    if (const Entry* e = view.find("failover_loss"))
        bond.failover_loss = percent(*e, ctx);
    if (const Entry* e = view.find("failback_after"))
        bond.failback_after = duration(*e, ctx, false);
    if (const Entry* e = view.find("resend")) {
        bond.resend = duration(*e, ctx, false);
        if (bond.resend > seconds(10))
            fail(value_mark(*e), ctx + "'resend': at most 10s (what standby held back is kept "
                                       "that long)");
    }
    if (const Entry* e = view.find("failback_loss")) {
        bond.failback_loss = percent(*e, ctx);
        if (bond.failback_loss >= bond.failover_loss)
            fail(value_mark(*e), ctx + "'failback_loss' must be below 'failover_loss' (" +
                                     std::to_string(static_cast<int>(bond.failover_loss * 100 + 0.5)) +
                                     "%): the gap between them keeps standby from flapping");
    }
    if (const Entry* e = view.find("signing"))
        parse_bond_signing(*e, ctx, bond);
    for (const char* key : {"failover_loss", "failback_loss", "failback_after", "resend"}) {
        if (const Entry* e = view.find(key))
            standby_refs_.push_back(StandbyRef{bond.name, key, e->key.Mark()});
    }
    config_.bonds.push_back(std::move(bond));
}

double Parser::percent(const Entry& e, const std::string& ctx) const {
    const std::string& text = scalar(e, ctx);
    auto v = parse_percent(text);
    if (!v)
        fail(value_mark(e), ctx + "'" + e.name + "': '" + text +
                                "' is not a percentage from 0% to 100% (e.g. 10%)");
    return *v;
}



void Parser::parse_metrics(const Entry& entry) {
    const std::string ctx = "metrics: ";
    if (!entry.value.IsMap())
        fail(value_mark(entry), std::string("'metrics' must be a map of keys (listen, timeout, "
                                            "max_connections), not ") + kind_name(entry.value));
    MapView view = make_view(entry.value);
    static const std::set<std::string_view> kKeys = {"listen", "timeout", "max_connections"};
    check_keys(view, ctx, &kKeys);
    MetricsConfig& m = config_.metrics;
    const Entry* listen = view.find("listen");
    if (!listen)
        fail(value_mark(entry), ctx + "missing required key 'listen' (e.g. 127.0.0.1:9273)");
    const std::string& text = scalar(*listen, ctx);
    auto colon = text.rfind(':');
    std::string port_text = colon == std::string::npos ? text : text.substr(colon + 1);
    if (colon != std::string::npos) {
        m.host = text.substr(0, colon);
        in_addr addr{};
        if (m.host == "localhost")
            m.host = "127.0.0.1";
        else if (inet_pton(AF_INET, m.host.c_str(), &addr) != 1)
            fail(value_mark(*listen), ctx + "'listen': host '" + m.host +
                                          "' is not an IPv4 address (a.b.c.d) or 'localhost'");
    }
    auto port = parse_u64(port_text);
    if (!port || *port < 1 || *port > 65535)
        fail(value_mark(*listen), ctx + "'listen': port '" + port_text + "' is not in 1..65535");
    m.port = static_cast<uint16_t>(*port);
    m.enabled = true;
    if (const Entry* e = view.find("timeout"))
        m.timeout = duration(*e, ctx, true);
    if (const Entry* e = view.find("max_connections")) {
        const std::string& n_text = scalar(*e, ctx);
        auto n = parse_u64(n_text);
        if (!n || *n < 1 || *n > 1024)
            fail(value_mark(*e), ctx + "'max_connections': '" + n_text + "' is not in 1..1024");
        m.max_connections = static_cast<uint32_t>(*n);
    }
}

void Parser::parse_filter(const YAML::Node& node, size_t index) {
    std::string ctx = "filter #" + std::to_string(index) + ": ";
    if (!node.IsMap())
        fail(node.Mark(), ctx + "must be a map of keys, not " + kind_name(node));
    MapView view = make_view(node);
    FilterConfig filter;
    filter.mark = source_mark(node.Mark());
    filter.plugin = required_scalar(view, node, "plugin", ctx);
    for (char c : filter.plugin) {
        if (!is_plugin_char(c))
            fail(value_mark(*view.find("plugin")),
                 ctx + "invalid plugin name '" + filter.plugin +
                     "' (allowed characters: a-z 0-9 _)");
    }
    ctx = "filter #" + std::to_string(index) + " '" + filter.plugin + "': ";
    // Any key is allowed: the plugin's own options are checked by the plugin loader.
    check_keys(view, ctx, nullptr);

    for (const auto& e : view.entries) {
        if (e.name == "plugin") {
            continue;
        } else if (e.name == "enabled") {
            filter.enabled = boolean(e, ctx);
        } else if (e.name == "bonds" || e.name == "endpoints") {
            for (auto& [name, mark] : name_list(e, ctx)) {
                scope_refs_.push_back(ScopeRef{ctx, e.name, name, mark});
                (e.name == "bonds" ? filter.bonds : filter.endpoints).push_back(name);
            }
        } else {
            FilterConfig::Option option;
            option.key = e.name;
            option.mark = source_mark(e.key.Mark());
            option.value_mark = source_mark(value_mark(e));
            if (e.value.IsScalar()) {
                option.value = e.value.Scalar();
            } else if (e.value.IsSequence()) {
                option.is_sequence = true;
                for (const auto& item : e.value) {
                    if (!item.IsScalar())
                        fail(item.Mark(), ctx + "option '" + e.name +
                                              "': items must be single values, not " +
                                              kind_name(item));
                    option.items.push_back(item.Scalar());
                    option.item_marks.push_back(source_mark(item.Mark()));
                }
                option.value = "[";
                for (size_t i = 0; i < option.items.size(); ++i)
                    option.value += (i ? ", " : "") + option.items[i];
                option.value += "]";
            } else if (e.value.IsNull()) {
                fail(value_mark(e), ctx + "option '" + e.name + "' needs a value");
            } else {
                fail(value_mark(e), ctx + "option '" + e.name +
                                        "' must be a value or a sequence of values, not " +
                                        kind_name(e.value));
            }
            filter.options.push_back(std::move(option));
        }
    }
    config_.filters.push_back(std::move(filter));
}

uint8_t Parser::mavlink_id(const Entry& e, const std::string& ctx) const {
    const std::string& text = scalar(e, ctx);
    auto id = parse_u64(text);
    if (!id || *id < 1 || *id > 255)
        fail(value_mark(e), ctx + "'" + e.name + "': '" + text + "' is not a MAVLink id (1..255)");
    return static_cast<uint8_t>(*id);
}

void Parser::parse_identity(const Entry& section) {
    const std::string ctx = "identity: ";
    static const std::set<std::string_view> kKeys = {"sysid", "compid", "heartbeat"};
    MapView view = section_view(section, ctx, kKeys);
    IdentityConfig& id = config_.identity;
    if (const Entry* e = view.find("sysid"))
        id.sysid = mavlink_id(*e, ctx);
    if (const Entry* e = view.find("compid")) {
        id.compid = mavlink_id(*e, ctx);
        id.compid_given = true;
    }
    if (const Entry* e = view.find("heartbeat"))
        id.heartbeat = duration(*e, ctx, true);
}

void Parser::parse_tx_rate(const Entry& e, const std::string& ctx, const EndpointSchema& type,
                           TxBudgetConfig& budget) const {
    const std::string& text = scalar(e, ctx);
    const std::string what = ctx + "'tx_rate': ";
    if (text == "baud") {
        if (std::string_view(type.type) != "uart")
            fail(value_mark(e), what + "'baud' takes a UART's own baudrate; give a " +
                                    type.title() + " endpoint a rate such as 5kB/s or 57600baud");
        budget.uart_baud = budget.serial = true;
        return;
    }
    auto rate = parse_tx_rate_text(text);
    if (!rate)
        fail(value_mark(e), what + "'" + text + "' is not a rate (e.g. 5kB/s, 5760B/s, " +
                                "57600baud, or baud for a UART's own)");
    if (*rate < kMinTxRate || *rate > kMaxTxRate)
        fail(value_mark(e), what + text + " is outside " + std::to_string(kMinTxRate) +
                                " B/s (one largest frame in 3 s) to 1GB/s");
    budget.bytes_per_s = *rate;
    budget.serial = text.ends_with("baud");
}

void Parser::parse_radio_status(const Entry& e, const std::string& ctx,
                                const EndpointSchema& type, TxBudgetConfig& budget) const {
    const std::string& text = scalar(e, ctx);
    if (text != "sik")
        fail(value_mark(e), ctx + "'radio_status': '" + text +
                                "' is not a radio mavbond knows (sik: a SiK radio such as 3DR "
                                "or RFD900, reporting as system 51, component 68)");
    // One radio, one link: a server's peers or connections are links of their own.
    if (type.mode && std::string_view(type.mode) == "server")
        fail(value_mark(e), ctx + "'radio_status' does not apply to a " + type.title() +
                                " endpoint (each peer is a link of its own): give it to a "
                                "UART or a client");
    budget.radio_status = RadioStatusSource::Sik;
    if (budget.enabled())
        return;
    // The ceiling the reports lower the budget from: a UART's line, else it must be said.
    if (std::string_view(type.type) != "uart")
        fail(value_mark(e), ctx + "'radio_status' on a " + type.title() +
                                " endpoint needs 'tx_rate' (the radio's rate, e.g. 57600baud)");
    budget.uart_baud = budget.serial = true;
}

void Parser::parse_tx_classes(const Entry& section, TxClassesConfig& classes) const {
    const std::string ctx = "tx_classes: ";
    static const std::set<std::string_view> kKeys = {"control", "bulk", "caps"};
    MapView view = section_view(section, ctx, kKeys);
    auto sorted = [](std::vector<uint32_t> ids) {
        std::sort(ids.begin(), ids.end());
        ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
        return ids;
    };
    if (const Entry* e = view.find("control"))
        classes.control = sorted(message_ids(*e, ctx));
    if (const Entry* e = view.find("bulk"))
        classes.bulk = sorted(message_ids(*e, ctx));
    for (const char* key : {"control", "bulk"}) {
        const Entry* e = view.find(key);
        if (!e)
            continue;
        const auto& other = std::string_view(key) == "control" ? classes.bulk : classes.control;
        for (uint32_t id : message_ids(*e, ctx)) {
            if (std::binary_search(other.begin(), other.end(), id))
                fail(value_mark(*e), ctx + "message " + message_label(id) +
                                         " is in both control and bulk (a list not given is "
                                         "the default one, mavbond.yaml(5))");
        }
    }
    if (const Entry* e = view.find("caps")) {
        if (!e->value.IsMap())
            fail(value_mark(*e), ctx + "'caps' must be a map of message: rate (e.g. "
                                       "ATTITUDE: 10Hz), not " + kind_name(e->value));
        classes.caps.clear();
        MapView caps = make_view(e->value);
        check_keys(caps, ctx + "caps: ", nullptr);
        for (const Entry& cap : caps.entries) {
            std::string where = ctx + "caps: '" + cap.name + "': ";
            auto id = message_id(cap.name);
            if (!id)
                fail(cap.key.Mark(), where + "unknown message");
            for (const auto* list : {&classes.control, &classes.bulk}) {
                if (std::binary_search(list->begin(), list->end(), *id))
                    fail(cap.key.Mark(), where + "a cap thins telemetry; this message is " +
                                                 (list == &classes.control ? "control" : "bulk"));
            }
            const std::string& text = scalar(cap, where);
            auto hz = parse_hertz(text);
            if (!hz)
                fail(value_mark(cap), where + "'" + text + "' is not a rate in Hz greater than "
                                              "0 and at most 1000 (e.g. 10Hz, 0.5Hz)");
            classes.caps.emplace_back(*id, Duration(static_cast<int64_t>(1e9 / *hz)));
        }
        std::sort(classes.caps.begin(), classes.caps.end());
    }
}

void Parser::parse_link_events(const Entry& section) {
    const std::string ctx = "link_events: ";
    static const std::set<std::string_view> kKeys = {"statustext", "silent_after", "min_interval"};
    MapView view = section_view(section, ctx, kKeys);
    LinkEventsConfig& ev = config_.link_events;
    ev.enabled = true;
    if (const Entry* e = view.find("statustext"))
        ev.statustext = boolean(*e, ctx);
    if (const Entry* e = view.find("silent_after"))
        ev.silent_after = duration(*e, ctx, true);
    if (const Entry* e = view.find("min_interval"))
        ev.min_interval = duration(*e, ctx, false);
}

void Parser::cross_check() {
    for (const auto& ref : bond_refs_) {
        const auto& ep = config_.endpoints[ref.endpoint];
        if (!bond_names_.count(ep.bond))
            fail(ref.mark, "endpoint '" + ep.name + "': bond '" + ep.bond +
                               "' is not declared under 'bonds:'");
    }
    for (size_t j = 0; j < listener_refs_.size(); j++) {
        const auto& b = config_.endpoints[listener_refs_[j].endpoint];
        for (size_t i = 0; i < j; i++) {
            const auto& a = config_.endpoints[listener_refs_[i].endpoint];
            if (std::string_view(a.schema->type) != b.schema->type ||
                !listen_addresses_overlap(a.options.text("address"), a.options.port("address"),
                                          b.options.text("address"), b.options.port("address")))
                continue;
            auto shown = [](const EndpointConfig& e) {
                const std::string& host = e.options.text("address");
                return (host.find(':') != std::string::npos ? "[" + host + "]" : host) + ":" +
                       std::to_string(e.options.port("address"));
            };
            fail(listener_refs_[j].mark,
                 "endpoint '" + b.name + "': " + b.schema->type + " address " + shown(b) +
                     " is taken by endpoint '" + a.name + "' (" + shown(a) + ", declared at " +
                     a.mark.file + ":" + std::to_string(a.mark.line) + ":" +
                     std::to_string(a.mark.column) + "): two servers cannot listen on one address");
        }
    }
    for (const auto& ref : radio_refs_) {
        const auto& ep = config_.endpoints[ref.endpoint];
        if (ep.bond.empty())
            fail(ref.mark, "endpoint '" + ep.name + "': 'radio_status' needs the endpoint in a "
                           "bond (the bond reports to its local side; a bond of one link will "
                           "do)");
    }
    for (const auto& bond : config_.bonds) {
        bool has_member = false;
        for (const auto& ep : config_.endpoints)
            has_member = has_member || ep.bond == bond.name;
        if (!has_member)
            fail(bond_names_.at(bond.name),
                 "bond '" + bond.name + "' has no member endpoint (set 'bond: " + bond.name +
                     "' on at least one endpoint)");
    }
    for (const auto& bond : config_.bonds) {
        bool metered = false, free = false;
        for (const auto& ep : config_.endpoints) {
            if (ep.bond == bond.name)
                (ep.metered ? metered : free) = true;
        }
        for (const auto& ref : standby_refs_) {
            if (ref.bond == bond.name && !metered)
                fail(ref.mark, "bond '" + bond.name + "': '" + ref.key +
                                   "' applies only to a bond with a 'cost: metered' member");
        }
        if (metered && !free)
            fail(bond_names_.at(bond.name),
                 "bond '" + bond.name + "': every member is 'cost: metered'; standby needs a "
                 "free member to stand by for");
    }
    sign_bond_links();
    for (const auto& ref : scope_refs_) {
        bool known = ref.key == "bonds" ? bond_names_.count(ref.name) > 0
                                        : endpoint_names_.count(ref.name) > 0;
        if (!known)
            fail(ref.mark, ref.filter_ctx + "'" + ref.key + "': unknown " +
                               (ref.key == "bonds" ? "bond" : "endpoint") + " '" + ref.name +
                               "'");
    }
}

void Parser::sign_bond_links() {
    for (const auto& ref : signed_link_refs_) {
        const BondConfig& bond = config_.bonds[ref.bond];
        auto ep = std::find_if(config_.endpoints.begin(), config_.endpoints.end(),
                               [&](const EndpointConfig& e) { return e.name == ref.name; });
        if (ep == config_.endpoints.end() || ep->bond != bond.name)
            fail(ref.mark, "bond '" + bond.name + "': 'signing': 'links': '" + ref.name +
                               "' is not a member of the bond (a member has 'bond: " +
                               bond.name + "')");
    }
    for (size_t b = 0; b < config_.bonds.size(); b++) {
        BondConfig& bond = config_.bonds[b];
        if (!bond.signing.enabled)
            continue;
        // The links in config order: those `links` names, or every member.
        auto listed = [&](const std::string* name) {
            return std::any_of(signed_link_refs_.begin(), signed_link_refs_.end(),
                               [&](const SignedLinkRef& r) {
                                   return r.bond == b && (!name || r.name == *name);
                               });
        };
        const bool all = !listed(nullptr);
        for (const EndpointConfig& ep : config_.endpoints) {
            if (ep.bond == bond.name && (all || listed(&ep.name)))
                bond.signing.links.push_back(ep.name);
        }
        if (bond.signing.links.size() > BondSigning::kMaxMembers)
            fail(bond_signing_marks_.at(bond.name),
                 "bond '" + bond.name + "': 'signing': at most " +
                     std::to_string(BondSigning::kMaxMembers) + " signed links (it has " +
                     std::to_string(bond.signing.links.size()) + ")");
    }
    // An endpoint in a bond is signed by its bond or not at all: its own `signing:` would
    // check frames the bond signs, and let unsigned ones steer the bond with `require: false`.
    for (const auto& ref : signing_refs_) {
        const EndpointConfig& ep = config_.endpoints[ref.endpoint];
        if (!ep.bond.empty())
            fail(ref.mark, "endpoint '" + ep.name + "': 'signing' on a bond member: sign the "
                           "bond instead (bonds: - {name: " + ep.bond +
                           ", signing: {key_file: ...}}), which signs what it sends on its links "
                           "and verifies what they bring");
    }
    for (const BondConfig& bond : config_.bonds) {
        for (const std::string& link : bond.signing.links) {
            for (EndpointConfig& ep : config_.endpoints) {
                if (ep.name != link)
                    continue;
                ep.signing.enabled = true;
                ep.signing.require = true;
                ep.signing.by_bond = true;
                ep.signing.key_file = bond.signing.key_file;
                ep.signing.key = bond.signing.key;
            }
        }
    }
}

}  // namespace

const EndpointOption* EndpointSchema::find(std::string_view key) const {
    for (const EndpointOption& o : options) {
        if (key == o.key)
            return &o;
    }
    return nullptr;
}

const OptionValue& EndpointOptions::at(std::string_view key) const {
    static const OptionValue kAbsent;
    auto it = values_.find(key);
    return it == values_.end() ? kAbsent : it->second;
}

Result<Config> parse_config(const std::string& text, const std::string& name,
                            EndpointSchemas types) {
    if (auto error = control_character_error(text, name))
        return make_error(*error);
    try {
        if (auto error = document_error(text, name))
            return make_error(*error);
        Parser parser(name, types);
        return parser.parse(YAML::Load(text));
    } catch (const ConfigError& e) {
        return make_error(e.message);
    } catch (const YAML::Exception& e) {
        return make_error(yaml_syntax_error(text, name, e.mark, e.msg));
    } catch (const std::exception& e) {
        return make_error(format_at(name, YAML::Mark::null_mark(), e.what()));
    }
}

Result<std::string> read_text_file(const std::string& path) {
    FILE* f = std::fopen(path.c_str(), "rb");
    if (!f)
        return make_error(path + ": cannot open: " + std::strerror(errno));
    std::string text;
    char buf[8192];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0)
        text.append(buf, n);
    int read_errno = std::ferror(f) ? errno : 0;
    std::fclose(f);
    if (read_errno != 0)
        return make_error(path + ": cannot read: " + std::strerror(read_errno));
    return text;
}

Result<Config> load_config(const std::string& path, EndpointSchemas types) {
    auto text = read_text_file(path);
    if (!text)
        return text.error();
    return parse_config(text.value(), path, types);
}

namespace {

/// Text for a roff paragraph: a hyphen written as \- (it may be a path's or an option's).
std::string roff(std::string_view text) {
    std::string out;
    for (char c : text)
        out += c == '-' ? std::string("\\-") : std::string(1, c);
    return out;
}

}  // namespace

std::string endpoint_options_manual(EndpointSchemas types) {
    static const char* const kKinds[] = {"true or false", "a positive integer",
                                         "a duration such as 250ms or 2s",
                                         "a size in bytes such as 16KiB or 64MiB",
                                         ("host:port, the host an IPv4 address, an IPv6 address in "
                                          "brackets ([::1]:14550) or a host name"),
                                         "a text"};
    std::string out;
    for (const EndpointSchema* t : types) {
        out += ".SS \"type: " + std::string(t->type) +
               (t->mode ? ", mode: " + std::string(t->mode) : "") + "\"\n" + roff(t->about) + "\n";
        for (const EndpointOption& o : t->options) {
            // .BR: the key bold, then in roman what it takes.
            out += ".TP\n.BR " + std::string(o.key) + " \" (" + kKinds[static_cast<int>(o.kind)];
            if (o.default_value)
                out += std::string("; default ") + o.default_value;
            else if (o.required)
                out += "; required";
            out += ")\"\n" + roff(o.help) + "\n";
        }
    }
    return out;
}

namespace {

// Copies with every SourceMark cleared: a declaration moved to another line is the same one.
EndpointConfig unmarked(EndpointConfig c) {
    c.mark = {};
    return c;
}
BondConfig unmarked(BondConfig c) {
    c.mark = c.renumber_mark = c.tx_mark = {};
    return c;
}
FilterConfig unmarked(FilterConfig c) {
    c.mark = {};
    for (auto& o : c.options)
        o.mark = o.value_mark = {};
    return c;
}
template <typename T>
bool same_unmarked(const std::vector<T>& a, const std::vector<T>& b) {
    return std::equal(a.begin(), a.end(), b.begin(), b.end(),
                      [](const T& x, const T& y) { return unmarked(x) == unmarked(y); });
}

}  // namespace

bool same_settings(const EndpointConfig& a, const EndpointConfig& b) {
    return unmarked(a) == unmarked(b);
}
bool same_but_budget(const EndpointConfig& a, const EndpointConfig& b) {
    EndpointConfig x = unmarked(a), y = unmarked(b);
    x.tx_budget = y.tx_budget = {};
    return x == y;
}
bool same_settings(const std::vector<BondConfig>& a, const std::vector<BondConfig>& b) {
    return same_unmarked(a, b);
}
bool same_settings(const std::vector<FilterConfig>& a, const std::vector<FilterConfig>& b) {
    return same_unmarked(a, b);
}

TxClass TxClassesConfig::class_of(uint32_t msgid) const {
    if (std::binary_search(control.begin(), control.end(), msgid))
        return TxClass::Control;
    if (std::binary_search(bulk.begin(), bulk.end(), msgid))
        return TxClass::Bulk;
    return TxClass::Telemetry;
}

}  // namespace mavbond
