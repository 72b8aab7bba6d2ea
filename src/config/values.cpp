#include "config/values.h"

#include <arpa/inet.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <utility>

#include "config/config.h"
#include "mavlink/message_table.h"

namespace mavbond {

namespace {

bool all_digits(std::string_view s) {
    if (s.empty())
        return false;
    for (char c : s) {
        if (c < '0' || c > '9')
            return false;
    }
    return true;
}

}  // namespace

/// Parses a string of decimal digits; nullopt on anything else or overflow.
std::optional<uint64_t> parse_u64(std::string_view s) {
    if (!all_digits(s))
        return std::nullopt;
    uint64_t v = 0;
    auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec != std::errc() || ptr != s.data() + s.size())
        return std::nullopt;
    return v;
}

/// "16384", "16k", "16KiB", "64M", "64MiB", "1G", "1GiB" -> bytes; nullopt on anything else or
/// overflow.
std::optional<uint64_t> parse_byte_size(std::string_view text) {
    uint64_t unit = 1;
    for (auto [suffix, mult] : {std::pair<std::string_view, uint64_t>{"KiB", 1024},
                                {"k", 1024},
                                {"MiB", 1024 * 1024},
                                {"M", 1024 * 1024},
                                {"GiB", 1024 * 1024 * 1024},
                                {"G", 1024 * 1024 * 1024}}) {
        if (text.size() > suffix.size() && text.ends_with(suffix)) {
            text.remove_suffix(suffix.size());
            unit = mult;
            break;
        }
    }
    auto n = parse_u64(text);
    if (!n || *n > std::numeric_limits<uint64_t>::max() / unit)
        return std::nullopt;
    return *n * unit;
}

/// "5kB/s", "5760B/s", "64KiB/s", "1MB/s" (frame bytes a second) or "57600baud" (a serial line:
/// 8N1 takes 10 bits a byte) -> bytes a second; nullopt on anything else.
std::optional<uint64_t> parse_tx_rate_text(std::string_view text) {
    if (text.size() > 4 && text.ends_with("baud")) {
        auto baud = parse_u64(text.substr(0, text.size() - 4));
        return baud ? std::optional<uint64_t>(*baud / 10) : std::nullopt;
    }
    if (!text.ends_with("B/s"))
        return std::nullopt;
    text.remove_suffix(3);
    uint64_t unit = 1;
    for (auto [prefix, mult] : {std::pair<std::string_view, uint64_t>{"Ki", 1024},
                                {"k", 1000},
                                {"Mi", 1024 * 1024},
                                {"M", 1000 * 1000}}) {
        if (text.size() > prefix.size() && text.ends_with(prefix)) {
            text.remove_suffix(prefix.size());
            unit = mult;
            break;
        }
    }
    auto n = parse_u64(text);
    if (!n || *n > kMaxTxRate)
        return std::nullopt;
    return *n * unit;
}

/// "10Hz", "0.5Hz" -> the rate, within (0, 1000]; nullopt on anything else.
std::optional<double> parse_hertz(std::string_view text) {
    if (!text.ends_with("Hz"))
        return std::nullopt;
    text.remove_suffix(2);
    double hz = 0;
    auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), hz);
    if (ec != std::errc() || ptr != text.data() + text.size() || text.empty() ||
        !(text[0] >= '0' && text[0] <= '9') || !(hz > 0) || hz > 1000)
        return std::nullopt;
    return hz;
}

/// A message as the config names it: an id ("76") or a name ("COMMAND_LONG").
std::optional<uint32_t> message_id(const std::string& text) {
    if (!text.empty() && ((text[0] >= '0' && text[0] <= '9') || text[0] == '-')) {
        auto id = parse_u64(text);
        if (!id || *id > kMaxMessageId)
            return std::nullopt;
        return static_cast<uint32_t>(*id);
    }
    return find_message_id(text);
}

/// "COMMAND_LONG (76)", or "76" for an id the message table does not know.
std::string message_label(uint32_t id) {
    const MessageInfo* info = find_message(id);
    return info ? std::string(info->name) + " (" + std::to_string(id) + ")" : std::to_string(id);
}

/// "10%" -> 0.10: a percentage from 0 to 100, the % required.
std::optional<double> parse_percent(const std::string& text) {
    if (text.size() < 2 || text.back() != '%')
        return std::nullopt;
    char* end = nullptr;
    double v = strtod(text.c_str(), &end);
    if (end != text.c_str() + text.size() - 1 || !std::isfinite(v) || v < 0 || v > 100)
        return std::nullopt;
    return v / 100.0;
}

/// 65536 -> "64KiB", 1073741824 -> "1GiB": the largest unit that divides it.
std::string format_size(uint64_t n) {
    for (auto [unit, mult] : {std::pair<const char*, uint64_t>{"GiB", 1u << 30},
                              {"MiB", 1u << 20},
                              {"KiB", 1u << 10}}) {
        if (n >= mult && n % mult == 0)
            return std::to_string(n / mult) + unit;
    }
    return std::to_string(n);
}

std::string format_duration(Duration d) {
    auto ns = d.count();
    if (ns % 1'000'000'000 == 0)
        return std::to_string(ns / 1'000'000'000) + "s";
    if (ns % 1'000'000 == 0)
        return std::to_string(ns / 1'000'000) + "ms";
    if (ns % 1'000 == 0)
        return std::to_string(ns / 1'000) + "us";
    return std::to_string(ns) + "ns";
}

namespace {

/// A DNS name as a resolver takes it: dot-separated labels of letters, digits and hyphens
/// (not at a label's ends), each 1 to 63 characters, 253 in all; a final dot allowed.
bool is_host_name(std::string_view name) {
    if (name.ends_with('.'))
        name.remove_suffix(1);
    if (name.empty() || name.size() > 253)
        return false;
    size_t label = 0;
    for (size_t i = 0; i <= name.size(); i++) {
        if (i == name.size() || name[i] == '.') {
            if (label == 0 || label > 63 || name[i - 1] == '-' || name[i - label] == '-')
                return false;
            label = 0;
        } else if (std::isalnum(static_cast<unsigned char>(name[i])) || name[i] == '-') {
            label++;
        } else {
            return false;
        }
    }
    return true;
}

/// A URL's scheme or another tool's endpoint prefix ("udp:", "udpin:", "tcp://"): the
/// endpoint's type and mode say that here. The rest, when it is one, is the address meant.
std::optional<std::string_view> scheme_prefix(std::string_view text) {
    static constexpr std::string_view kSchemes[] = {"udp", "udpin", "udpout", "udpbcast", "tcp",
                                                    "tcpin", "tcpout", "serial", "mavlink"};
    auto colon = text.find(':');
    if (colon == std::string_view::npos)
        return std::nullopt;
    std::string_view scheme = text.substr(0, colon);
    if (std::find(std::begin(kSchemes), std::end(kSchemes), scheme) == std::end(kSchemes) &&
        !text.substr(colon).starts_with("://"))
        return std::nullopt;
    std::string_view rest = text.substr(colon + 1);
    while (rest.starts_with('/'))
        rest.remove_prefix(1);
    return rest;
}

}  // namespace

HostPort parse_host_port(std::string_view text) {
    HostPort out;
    if (auto rest = scheme_prefix(text)) {
        const std::string prefix(text.substr(0, text.size() - rest->size()));
        out.error = "'" + std::string(text) + "': drop the '" + prefix + "' prefix (the " +
                    "endpoint's type and mode say that here): " +
                    (parse_host_port(*rest).error.empty() ? "address: " + std::string(*rest)
                                                          : std::string("address: host:port"));
        return out;
    }
    std::string_view host, port_text;
    if (text.starts_with('[')) {
        auto close = text.find(']');
        if (close == std::string_view::npos) {
            out.error = "'" + std::string(text) + "' has no ']' after the IPv6 address";
            return out;
        }
        host = text.substr(1, close - 1);
        std::string_view rest = text.substr(close + 1);
        if (!rest.starts_with(':')) {
            out.error = "'" + std::string(text) + "' needs a port after the brackets ([::1]:14550)";
            return out;
        }
        port_text = rest.substr(1);
        in6_addr v6{};
        if (inet_pton(AF_INET6, std::string(host).c_str(), &v6) != 1) {
            out.error = "'[" + std::string(host) + "]' is not an IPv6 address";
            return out;
        }
    } else {
        auto colon = text.rfind(':');
        if (colon == std::string_view::npos) {
            out.error = "'" + std::string(text) +
                        "' needs host:port (e.g. 0.0.0.0:14550, [::1]:14550, "
                        "lte.example.net:14550)";
            return out;
        }
        host = text.substr(0, colon);
        port_text = text.substr(colon + 1);
        in_addr v4{};
        std::string h(host);
        if (host.find(':') != std::string_view::npos) {
            out.error = "host '" + h + "': an IPv6 address is written in brackets ([" + h +
                        "]:port)";
            return out;
        }
        bool looks_numeric = !h.empty() && h.find_first_not_of("0123456789.") == std::string::npos;
        if (looks_numeric ? inet_pton(AF_INET, h.c_str(), &v4) != 1 : !is_host_name(h)) {
            out.error = "host '" + h + "' is not an IPv4 address (a.b.c.d), an IPv6 address in " +
                        "brackets or a host name";
            return out;
        }
    }
    auto port = parse_u64(port_text);
    if (!port || *port < 1 || *port > 65535) {
        out.error = "port '" + std::string(port_text) + "' is not in 1..65535";
        return out;
    }
    out.host = host == "localhost" ? "127.0.0.1" : std::string(host);
    out.port = static_cast<uint16_t>(*port);
    return out;
}

std::optional<Duration> parse_duration(std::string_view text) {
    size_t i = 0;
    uint64_t whole = 0;
    size_t whole_digits = 0;
    while (i < text.size() && text[i] >= '0' && text[i] <= '9') {
        if (whole > (std::numeric_limits<uint64_t>::max() - 9) / 10)
            return std::nullopt;
        whole = whole * 10 + static_cast<uint64_t>(text[i] - '0');
        ++i;
        ++whole_digits;
    }
    if (whole_digits == 0)
        return std::nullopt;
    // Up to 9 fraction digits, kept as an exact decimal: 1.5s is 1500000000ns.
    uint64_t frac = 0;
    uint64_t frac_scale = 1;
    if (i < text.size() && text[i] == '.') {
        ++i;
        size_t frac_digits = 0;
        while (i < text.size() && text[i] >= '0' && text[i] <= '9') {
            if (frac_digits == 9)
                return std::nullopt;
            frac = frac * 10 + static_cast<uint64_t>(text[i] - '0');
            frac_scale *= 10;
            ++i;
            ++frac_digits;
        }
        if (frac_digits == 0)
            return std::nullopt;
    }
    std::string_view unit = text.substr(i);
    uint64_t ns_per_unit = 0;
    if (unit == "ns")
        ns_per_unit = 1;
    else if (unit == "us")
        ns_per_unit = 1'000;
    else if (unit == "ms")
        ns_per_unit = 1'000'000;
    else if (unit == "s")
        ns_per_unit = 1'000'000'000;
    else if (unit == "m")
        ns_per_unit = 60'000'000'000;
    else
        return std::nullopt;
    constexpr auto kMax = static_cast<uint64_t>(std::numeric_limits<int64_t>::max());
    if (whole > kMax / ns_per_unit)
        return std::nullopt;
    uint64_t ns = whole * ns_per_unit;
    // frac < frac_scale <= 1e9, and frac_scale divides 1e9: both branches stay in 64 bits.
    uint64_t extra = 0;
    if (ns_per_unit >= 1'000'000'000) {
        extra = frac * (1'000'000'000 / frac_scale) * (ns_per_unit / 1'000'000'000);
    } else {
        if (frac * ns_per_unit % frac_scale != 0)
            return std::nullopt;  // finer than a nanosecond
        extra = frac * ns_per_unit / frac_scale;
    }
    if (ns > kMax - extra)
        return std::nullopt;
    return Duration(static_cast<int64_t>(ns + extra));
}

}  // namespace mavbond
