// What an endpoint type takes in the config, declared once as a table, the way a plugin declares
// its options: each option's key, kind, default and help. The config loader checks and converts
// an endpoint's keys by its type's table (src/endpoints declares the tables, one per type and
// mode, and hands them to the loader); the manual's option list, the importer and the fuzz
// harness read the same tables.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <utility>

#include "core/clock.h"

namespace mavbond {

/// How an option's text is read (and the messages when it does not fit).
enum class OptionKind {
    Flag,      // true or false
    Count,     // a positive integer up to 2^32 - 1
    Time,      // a duration with a unit, greater than 0: 250ms, 2s
    Size,      // bytes: 16384, 16KiB, 64M, 1GiB; within [min, max] (max 0: no limit)
    Address,   // host:port: an IPv4 address, [an IPv6 address] or a host name
    Text,      // any text but empty (a device, a directory)
};

struct EndpointOption {
    const char* key;
    OptionKind kind;
    const char* default_value;  // nullptr: none; `required` then says whether it must be given
    const char* help;
    bool required = false;
    uint64_t min = 0;  // Size: the least accepted
    uint64_t max = 0;  // Size: the most accepted (0: no limit)
};

/// One option's value as read.
struct OptionValue {
    bool flag = false;
    uint64_t number = 0;  // Count, Size
    Duration duration{};
    std::string text;     // Text; Address: the host, no brackets ("localhost" as 127.0.0.1)
    uint16_t port = 0;    // Address
    bool operator==(const OptionValue&) const = default;
};

/// An endpoint's own options: every key of its type's table, given or defaulted (an option
/// without a default that was not given is absent).
class EndpointOptions {
public:
    bool flag(std::string_view key) const { return at(key).flag; }
    uint64_t number(std::string_view key) const { return at(key).number; }
    Duration duration(std::string_view key) const { return at(key).duration; }
    const std::string& text(std::string_view key) const { return at(key).text; }
    uint16_t port(std::string_view key) const { return at(key).port; }
    bool has(std::string_view key) const { return values_.find(key) != values_.end(); }
    /// Whether the config gave it (rather than its default).
    bool given(std::string_view key) const { return given_.find(key) != given_.end(); }
    void set(std::string key, OptionValue value, bool given = true) {
        if (given)
            given_.insert(key);
        values_[std::move(key)] = std::move(value);
    }
    /// The same values, however they were written (what a reload compares).
    bool operator==(const EndpointOptions& o) const { return values_ == o.values_; }

private:
    /// An absent key reads as a zero value: the type's table says which keys exist.
    const OptionValue& at(std::string_view key) const;
    std::map<std::string, OptionValue, std::less<>> values_;
    std::set<std::string, std::less<>> given_;
};

/// An endpoint type (and mode, where it has modes) as the config sees it.
struct EndpointSchema {
    const char* type;   // the YAML `type:` word
    const char* mode;   // the YAML `mode:` word; nullptr: the type has no modes
    const char* about;  // one line for the manual
    std::span<const EndpointOption> options;
    /// false for an endpoint frames never come from (a flight log): it takes no bond, no
    /// allow_in/block_in and no signing.
    bool receives = true;
    /// A rule between options: the key to blame and why, when broken.
    std::optional<std::pair<const char*, std::string>> (*check)(const EndpointOptions&) = nullptr;
    /// A server: its `address` is where it listens, and no other endpoint of its type may
    /// listen there too (config/listeners.h).
    bool listens = false;

    /// "udp server", "uart".
    std::string title() const { return mode ? std::string(type) + " " + mode : std::string(type); }
    const EndpointOption* find(std::string_view key) const;
};

/// The tables the loader reads endpoints by (src/endpoints: endpoint_schemas()).
using EndpointSchemas = std::span<const EndpointSchema* const>;

/// "250ms", "2s": a duration as the config writes it (for a schema's messages).
std::string format_duration(Duration d);

}  // namespace mavbond
