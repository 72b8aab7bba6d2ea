// mavlink-router's main.conf -> mavbond YAML. The INI dialect (from mavlink-router's
// examples/config.sample): `[Type name]` sections, `Key = Value` lines, `#` comment lines;
// section types, keys and predefined values are case-insensitive; booleans are true/false or
// 1/0; lists are comma separated.
//
// Inside this file a malformed input is thrown as ImportError (private to this file) so each
// check stays one line; import_mavlink_router() returns it as a value.
#include "daemon/import_mavlink_router.h"

#include <algorithm>
#include <charconv>
#include <map>
#include <optional>
#include <set>

#include "config/config.h"

namespace mavbond {
namespace {

constexpr int kDefaultTcpServerPort = 5760;  // mavlink-router listens here unless told 0
constexpr const char* kServiceLogDir = "/var/log/mavbond";  // the unit's LogsDirectory=
// A dedup window that covers a radio running a second or more behind LTE (a saturated radio,
// an LTE handover): what the README's radio + LTE table gives.
constexpr int64_t kRadioLteWindowMs = 2000;
constexpr int kDefaultUdpClientPort = 14550; // its first choice for a Normal endpoint
constexpr uint32_t kDefaultBaud = 115200;
constexpr uint32_t kMaxMessageId = 0xFFFFFF;

struct ImportError {
    std::string message;
};

struct IniKey {
    std::string name;   // as written
    std::string lower;  // for matching
    std::string value;
    int line;
};

struct IniSection {
    std::string type;   // lower case: general, uartendpoint, udpendpoint, tcpendpoint, ...
    std::string type_as_written;
    std::string name;
    int line;
    std::vector<IniKey> keys;
};

std::string lower(std::string_view s) {
    std::string out(s);
    std::transform(out.begin(), out.end(), out.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    return out;
}

std::string_view trim(std::string_view s) {
    while (!s.empty() && (s.front() == ' ' || s.front() == '\t' || s.front() == '\r'))
        s.remove_prefix(1);
    while (!s.empty() && (s.back() == ' ' || s.back() == '\t' || s.back() == '\r'))
        s.remove_suffix(1);
    return s;
}

/// A YAML scalar: plain when it cannot be misread, double-quoted otherwise.
std::string yaml_text(std::string_view s) {
    bool plain = !s.empty();
    for (char c : s) {
        bool safe = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '.' || c == '-' || c == '/' || c == ':' || c == '@' || c == '+';
        plain = plain && safe;
    }
    if (plain && s.front() != '-' && s.front() != ':' && s.back() != ':')
        return std::string(s);
    std::string out = "\"";
    for (char c : s) {
        if (c == '"' || c == '\\')
            out += '\\';
        out += c;
    }
    return out + "\"";
}

class Importer {
public:
    explicit Importer(std::string file) : file_(std::move(file)) {}
    ImportedConfig run(std::string_view text);

private:
    /// One endpoint of the output, written as a block.
    struct Endpoint {
        std::vector<std::string> lines;     // "key: value" (already YAML)
        std::vector<std::string> comments;  // "not translated: ..."
        std::string name;
        std::string header;                 // a comment naming where it came from
    };

    [[noreturn]] void fail(int line, const std::string& what) const {
        throw ImportError{file_ + ":" + std::to_string(line) + ": " + what};
    }
    void warn(int line, const std::string& what, std::vector<std::string>* comments) {
        warnings_.push_back(file_ + ":" + std::to_string(line) + ": " + what);
        if (comments)
            comments->push_back("not translated (line " + std::to_string(line) + "): " + what);
    }
    /// What is translated, but carries a risk the user must see: a warning and a comment.
    /// Line 0: the file as a whole (a default of a section it does not have).
    void risk(int line, const std::string& what, std::vector<std::string>& comments) {
        const std::string at = line > 0 ? ":" + std::to_string(line) : "";
        warnings_.push_back(file_ + at + ": " + what);
        comments.push_back((line > 0 ? "check (line " + std::to_string(line) + "): " : "check: ") +
                           what);
    }

    std::vector<IniSection> parse_ini(std::string_view text) const;
    std::string section_label(const IniSection& s) const {
        return "[" + s.type_as_written + (s.name.empty() ? "" : " " + s.name) + "]";
    }
    bool boolean(const IniKey& k) const;
    /// 64 bits on every target: a 32-bit long cannot hold a baud rate's range (armhf).
    int64_t integer(const IniKey& k, int64_t min, int64_t max) const;
    std::vector<uint32_t> id_list(const IniKey& k) const;
    /// Address and Port as mavbond's `address:` value (an IPv6 address in brackets, quoted
    /// for YAML); empty when Address is no address or name mavbond takes.
    std::string address_value(const IniKey& k, int64_t port) const;
    std::string unique_name(const std::string& wanted, int line);

    void general(const IniSection& s);
    void endpoint(const IniSection& s);
    /// Keys every endpoint type takes (message filters, Group); false if `k` is not one.
    bool common_key(const IniKey& k, Endpoint& ep, const IniSection& s);

    std::string file_;
    std::vector<std::string> warnings_;
    std::vector<std::string> top_comments_;
    std::string log_level_;
    std::vector<Endpoint> endpoints_;
    std::vector<std::string> bonds_;
    std::set<std::string> names_;
    int64_t dedup_ms_ = 0;
    int dedup_line_ = 0;
    bool report_stats_ = false;
};

std::vector<IniSection> Importer::parse_ini(std::string_view text) const {
    std::vector<IniSection> sections;
    std::map<std::string, int> seen;  // "type name" -> line
    int line_no = 0;
    while (!text.empty()) {
        size_t eol = text.find('\n');
        std::string_view raw = text.substr(0, eol);
        text = eol == std::string_view::npos ? std::string_view() : text.substr(eol + 1);
        line_no++;
        std::string_view line = trim(raw);
        if (line.empty() || line.front() == '#' || line.front() == ';')
            continue;
        if (line.front() == '[') {
            if (line.back() != ']')
                fail(line_no, "section header without its closing ']': " + std::string(line));
            std::string_view inner = trim(line.substr(1, line.size() - 2));
            size_t space = inner.find_first_of(" \t");
            IniSection s;
            s.type_as_written = std::string(inner.substr(0, space));
            s.type = lower(s.type_as_written);
            s.name = space == std::string_view::npos ? "" : std::string(trim(inner.substr(space)));
            s.line = line_no;
            if (s.type.empty())
                fail(line_no, "empty section header");
            if (s.name.find_first_of(" \t") != std::string::npos)
                fail(line_no, "section name '" + s.name + "' contains blanks");
            auto [it, inserted] = seen.emplace(s.type + " " + lower(s.name), line_no);
            if (!inserted)
                fail(line_no, "section " + section_label(s) + " repeated (first at line " +
                                  std::to_string(it->second) + ")");
            sections.push_back(std::move(s));
            continue;
        }
        size_t eq = line.find('=');
        if (eq == std::string_view::npos)
            fail(line_no, "expected 'Key = Value', '[Section]' or a '#' comment, got '" +
                              std::string(line) + "'");
        if (sections.empty())
            fail(line_no, "'" + std::string(trim(line.substr(0, eq))) +
                              "' comes before any [section]");
        std::string_view key = trim(line.substr(0, eq));
        if (key.empty())
            fail(line_no, "a key is missing before '='");
        sections.back().keys.push_back(IniKey{std::string(key), lower(key),
                                              std::string(trim(line.substr(eq + 1))), line_no});
    }
    return sections;
}

bool Importer::boolean(const IniKey& k) const {
    std::string v = lower(k.value);
    if (v == "true" || v == "1")
        return true;
    if (v == "false" || v == "0")
        return false;
    fail(k.line, k.name + ": '" + k.value + "' is not a boolean (true, false, 1 or 0)");
}

int64_t Importer::integer(const IniKey& k, int64_t min, int64_t max) const {
    int64_t v = 0;
    const char* end = k.value.data() + k.value.size();
    auto [ptr, ec] = std::from_chars(k.value.data(), end, v);
    if (k.value.empty() || ec != std::errc() || ptr != end || v < min || v > max)
        fail(k.line, k.name + ": '" + k.value + "' is not an integer in " + std::to_string(min) +
                         ".." + std::to_string(max));
    return v;
}

std::vector<uint32_t> Importer::id_list(const IniKey& k) const {
    std::vector<uint32_t> ids;
    std::string_view rest = k.value;
    while (!trim(rest).empty()) {
        size_t comma = rest.find(',');
        IniKey item{k.name, k.lower, std::string(trim(rest.substr(0, comma))), k.line};
        ids.push_back(static_cast<uint32_t>(integer(item, 0, kMaxMessageId)));
        rest = comma == std::string_view::npos ? std::string_view() : rest.substr(comma + 1);
    }
    return ids;
}

std::string Importer::address_value(const IniKey& k, int64_t port) const {
    // mavlink-router writes an IPv6 address with or without brackets.
    std::string host = k.value;
    if (host.size() > 2 && host.front() == '[' && host.back() == ']')
        host = host.substr(1, host.size() - 2);
    bool v6 = host.find(':') != std::string::npos;
    std::string text = (v6 ? "[" + host + "]" : host) + ":" + std::to_string(port);
    if (!parse_host_port(text).error.empty())
        return "";
    return v6 ? "\"" + text + "\"" : text;
}

std::string Importer::unique_name(const std::string& wanted, int line) {
    std::string name;
    for (char c : wanted) {
        bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                  c == '_' || c == '.' || c == '-';
        name += ok ? c : '_';
    }
    if (name.empty())
        name = "endpoint";
    std::string unique = name;
    for (int i = 2; !names_.insert(unique).second; i++)
        unique = name + "-" + std::to_string(i);
    if (unique != wanted)
        warn(line, "endpoint '" + wanted + "' is named '" + unique +
                       "' (mavbond names are unique and use A-Z a-z 0-9 _ . -)", nullptr);
    return unique;
}

void Importer::general(const IniSection& s) {
    std::optional<int64_t> tcp_port;
    int tcp_line = s.line;
    std::string log_dir;
    int log_line = 0;
    for (const IniKey& k : s.keys) {
        if (k.lower == "tcpserverport") {
            tcp_port = integer(k, 0, 65535);
            tcp_line = k.line;
        } else if (k.lower == "reportstats") {
            report_stats_ = boolean(k);
        } else if (k.lower == "debugloglevel") {
            std::string v = lower(k.value);
            if (v != "error" && v != "warning" && v != "info" && v != "debug")
                fail(k.line, "DebugLogLevel: '" + k.value +
                                 "' is not one of error, warning, info, debug");
            log_level_ = v;
        } else if (k.lower == "deduplicationperiod") {
            dedup_ms_ = integer(k, 0, 1000L * 3600);
            dedup_line_ = k.line;
        } else if (k.lower == "log") {
            log_dir = k.value;
            log_line = k.line;
        } else if (k.lower == "logmode") {
            if (lower(k.value) != "always")
                warn(k.line, "LogMode = " + k.value + ": mavbond's tlog endpoint logs always",
                     &top_comments_);
        } else if (k.lower == "logtelemetry") {
            boolean(k);  // validated; mavbond's log is the telemetry tlog either way
        } else if (k.lower == "mavlinkdialect" || k.lower == "logsystemid" ||
                   k.lower == "minfreespace" || k.lower == "maxlogfiles") {
            warn(k.line, k.name + " = " + k.value + ": no mavbond equivalent (the tlog endpoint "
                                                    "records every frame, rotates by max_size, "
                                                    "deletes nothing)",
                 &top_comments_);
        } else if (k.lower == "sniffersysid") {
            warn(k.line, k.name + " = " + k.value +
                             ": no mavbond equivalent (a tlog endpoint receives every frame)",
                 &top_comments_);
        } else {
            warn(k.line, "unknown key " + k.name + " in [General]", &top_comments_);
        }
    }
    int64_t port = tcp_port.value_or(kDefaultTcpServerPort);
    if (port != 0) {
        Endpoint ep;
        ep.name = unique_name("tcp-server", tcp_line);
        ep.header = tcp_port ? "[General] TcpServerPort (line " + std::to_string(tcp_line) + ")"
                             : "[General]: mavlink-router's default TCP server, port 5760 "
                               "(TcpServerPort = 0 disables it)";
        ep.lines = {"type: tcp", "mode: server", "address: 0.0.0.0:" + std::to_string(port)};
        // mavlink-router binds its TCP server to every address (0.0.0.0, or [::] in its
        // later versions), not loopback: kept so, and said, since anyone who reaches the
        // machine reaches the vehicle through it.
        risk(tcp_line,
             std::string(tcp_port ? "TcpServerPort = " + std::to_string(port)
                                  : "no TcpServerPort: mavlink-router's default TCP server") +
                 " listens on every address, kept as 0.0.0.0:" + std::to_string(port) +
                 ": anyone who can reach this machine may connect and command the vehicle; "
                 "use 127.0.0.1:" + std::to_string(port) + " if only programs on this machine "
                 "connect, or drop the endpoint",
             ep.comments);
        endpoints_.push_back(std::move(ep));
    }
    if (!log_dir.empty()) {
        Endpoint ep;
        ep.name = unique_name("flightlog", log_line);
        ep.header = "[General] Log (line " + std::to_string(log_line) +
                    "): mavlink-router logged the flight stack there; mavbond logs every routed "
                    "frame as .tlog";
        // The service may write nowhere else (ProtectSystem=strict, LogsDirectory=mavbond).
        std::string dir = log_dir;
        if (dir != kServiceLogDir && !dir.starts_with(std::string(kServiceLogDir) + "/")) {
            dir = kServiceLogDir;
            risk(log_line,
                 "Log = " + log_dir + ": mavbond.service may write only under " +
                     kServiceLogDir + ", so the flight logs go there; to keep " + log_dir +
                     ", give the service ReadWritePaths=" + log_dir +
                     " in a drop-in (systemctl edit mavbond) and set the directory back",
                 ep.comments);
        }
        ep.lines = {"type: tlog", "directory: " + yaml_text(dir)};
        endpoints_.push_back(std::move(ep));
    }
}

bool Importer::common_key(const IniKey& k, Endpoint& ep, const IniSection& s) {
    static const std::map<std::string, std::string> kFilters = {
        {"allowmsgidout", "allow_out"}, {"blockmsgidout", "block_out"},
        {"allowmsgidin", "allow_in"},   {"blockmsgidin", "block_in"}};
    if (auto it = kFilters.find(k.lower); it != kFilters.end()) {
        std::vector<uint32_t> ids = id_list(k);
        if (ids.empty())
            return true;  // an empty list filters nothing, as in mavlink-router
        std::string list;
        for (uint32_t id : ids)
            list += (list.empty() ? "" : ", ") + std::to_string(id);
        ep.lines.push_back(it->second + ": [" + list + "]");
        return true;
    }
    static const std::set<std::string> kSourceFilters = {
        "allowsrccompout", "blocksrccompout", "allowsrcsysout", "blocksrcsysout",
        "allowsrccompin",  "blocksrccompin",  "allowsrcsysin",  "blocksrcsysin"};
    if (kSourceFilters.count(k.lower)) {
        if (!trim(k.value).empty())
            warn(k.line, section_label(s) + " " + k.name + " = " + k.value +
                             ": mavbond filters by message id only",
                 &ep.comments);
        return true;
    }
    if (k.lower == "group") {
        if (k.value.empty())
            return true;
        std::string bond = k.value;
        for (char& c : bond) {
            bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') ||
                      (c >= '0' && c <= '9') || c == '_' || c == '.' || c == '-';
            c = ok ? c : '_';
        }
        if (std::find(bonds_.begin(), bonds_.end(), bond) == bonds_.end()) {
            bonds_.push_back(bond);
            if (bond != k.value)
                warn(k.line, "Group '" + k.value + "' is the bond '" + bond +
                                 "' (mavbond names use A-Z a-z 0-9 _ . -)", nullptr);
        }
        ep.lines.push_back("bond: " + bond);
        return true;
    }
    return false;
}

void Importer::endpoint(const IniSection& s) {
    if (s.name.empty())
        fail(s.line, section_label(s) + " needs a name ([" + s.type_as_written + " name])");
    Endpoint ep;
    ep.header = section_label(s) + " (line " + std::to_string(s.line) + ")";
    std::map<std::string, const IniKey*> keys;
    for (const IniKey& k : s.keys) {
        if (keys.count(k.lower))
            warn(k.line, section_label(s) + " " + k.name + " given twice: the last one counts",
                 nullptr);
        keys[k.lower] = &k;
    }
    auto take = [&keys](const char* name) -> const IniKey* {
        auto it = keys.find(name);
        if (it == keys.end())
            return nullptr;
        const IniKey* k = it->second;
        keys.erase(it);
        return k;
    };
    auto require = [&](const char* name, const char* as_written) -> const IniKey& {
        const IniKey* k = take(name);
        if (!k || k->value.empty())
            fail(s.line, section_label(s) + ": missing " + as_written);
        return *k;
    };
    bool translatable = true;
    if (s.type == "uartendpoint") {
        ep.lines = {"type: uart", "device: " + yaml_text(require("device", "Device").value)};
        uint32_t baud = kDefaultBaud;
        if (const IniKey* k = take("baud")) {
            std::vector<uint32_t> rates;
            std::string_view rest = k->value;
            while (!trim(rest).empty()) {
                size_t comma = rest.find(',');
                IniKey item{k->name, k->lower, std::string(trim(rest.substr(0, comma))), k->line};
                rates.push_back(static_cast<uint32_t>(integer(item, 1, UINT32_MAX)));
                rest = comma == std::string_view::npos ? std::string_view() : rest.substr(comma + 1);
            }
            if (!rates.empty())
                baud = rates.front();
            if (rates.size() > 1)
                warn(k->line, "Baud = " + k->value + ": mavlink-router tried each rate in turn; "
                                                     "mavbond uses the first, " +
                                  std::to_string(baud),
                     &ep.comments);
        }
        ep.lines.push_back("baud: " + std::to_string(baud));
        if (const IniKey* k = take("flowcontrol"); k && boolean(*k))
            ep.lines.push_back("flow_control: true");
    } else if (s.type == "udpendpoint") {
        const IniKey& mode_key = require("mode", "Mode");
        std::string mode = lower(mode_key.value);
        bool server = mode == "server" || mode == "eavesdropping";
        if (!server && mode != "normal" && mode != "client")
            fail(mode_key.line, "Mode: '" + mode_key.value + "' is not Normal or Server");
        const IniKey& addr_key = require("address", "Address");
        int64_t port = kDefaultUdpClientPort;
        if (const IniKey* k = take("port"))
            port = integer(*k, 1, 65535);
        else if (server)
            fail(s.line, section_label(s) + ": missing Port (mandatory in Server mode)");
        else
            warn(s.line, section_label(s) + " has no Port: mavlink-router picked a free one from "
                                            "14550; mavbond sends to 14550",
                 &ep.comments);
        std::string address = address_value(addr_key, port);
        if (address.empty()) {
            translatable = false;
            warn(addr_key.line, section_label(s) + " Address = " + addr_key.value +
                                    ": not an IPv4 or IPv6 address or a host name",
                 &ep.comments);
        }
        ep.lines = {"type: udp", std::string("mode: ") + (server ? "server" : "client"),
                    "address: " + address};
    } else {  // tcpendpoint
        const IniKey& addr_key = require("address", "Address");
        int64_t port = integer(require("port", "Port"), 1, 65535);
        std::string address = address_value(addr_key, port);
        if (address.empty()) {
            translatable = false;
            warn(addr_key.line, section_label(s) + " Address = " + addr_key.value +
                                    ": not an IPv4 or IPv6 address or a host name",
                 &ep.comments);
        }
        ep.lines = {"type: tcp", "mode: client", "address: " + address};
        if (const IniKey* k = take("retrytimeout")) {
            int64_t secs = integer(*k, 0, 86400);
            if (secs == 0)
                warn(k->line, "RetryTimeout = 0: mavbond always reconnects (with backoff)",
                     &ep.comments);
            else  // mavbond backs off from reconnect_min up to this
                ep.lines.push_back("reconnect_max: " + std::to_string(secs) + "s");
        }
    }
    for (auto& [name, k] : keys) {
        if (!common_key(*k, ep, s))
            warn(k->line, "unknown key " + k->name + " in " + section_label(s), &ep.comments);
    }
    ep.name = unique_name(s.name, s.line);
    if (!translatable) {
        // Kept as a comment: the user sees what was there.
        ep.comments.insert(ep.comments.begin(), "this endpoint is left out");
        ep.lines.clear();
    }
    endpoints_.push_back(std::move(ep));
}

ImportedConfig Importer::run(std::string_view text) {
    std::vector<IniSection> sections = parse_ini(text);
    bool has_general = false;
    for (const IniSection& s : sections) {
        if (s.type == "general") {
            has_general = true;
            general(s);
        } else if (s.type == "uartendpoint" || s.type == "udpendpoint" ||
                   s.type == "tcpendpoint") {
            endpoint(s);
        } else {
            warn(s.line, "unknown section " + section_label(s) + " (skipped with its keys)",
                 &top_comments_);
        }
    }
    if (!has_general)
        general(IniSection{"general", "General", "", 0, {}});  // the TCP server is on by default

    std::string y = "# Imported from mavlink-router's " + file_ +
                    " by mavbond --import-mavlink-router.\n"
                    "# Check it with: mavbond --check-config -c FILE\n";
    for (const auto& c : top_comments_)
        y += "# " + c + "\n";
    if (!log_level_.empty())
        y += "log_level: " + log_level_ + "\n";
    y += "endpoints:\n";
    size_t active = 0;
    for (const Endpoint& ep : endpoints_) {
        y += "  # " + ep.header + "\n";
        if (!ep.lines.empty()) {
            active++;
            y += "  - name: " + ep.name + "\n";
            for (const auto& l : ep.lines)
                y += "    " + l + "\n";
        }
        for (const auto& c : ep.comments)
            y += (ep.lines.empty() ? "  # " : "    # ") + c + "\n";
    }
    if (active == 0)
        warnings_.push_back(file_ + ": no endpoint could be translated; the result needs one");
    if (!bonds_.empty()) {
        y += "# mavlink-router's Groups: links that carry the same vehicle\nbonds:\n";
        for (const auto& b : bonds_)
            y += "  - name: " + b + "\n";
    }
    if (dedup_ms_ > 0 && bonds_.empty())
        warnings_.push_back(file_ + ": DeDuplicationPeriod: mavbond's dedup removes the copies "
                                    "that arrive over the links of a bond (a Group); with no "
                                    "Group it has nothing to do");
    if (dedup_ms_ > 0 || report_stats_) {
        y += "filters:\n";
        if (dedup_ms_ > 0) {
            y += "  # DeDuplicationPeriod: a frame that arrives again over another link of its bond\n"
                 "  # within the window is dropped (a repeat on one link, or outside a bond, passes)\n";
            if (dedup_ms_ < kRadioLteWindowMs) {
                std::vector<std::string> comments;
                risk(dedup_line_,
                     "DeDuplicationPeriod = " + std::to_string(dedup_ms_) + ", kept as window: " +
                         std::to_string(dedup_ms_) + "ms: a copy that comes later than that over "
                         "another link is delivered twice, and a radio beside LTE runs a second "
                         "or more behind it (saturated, or at an LTE handover); dedup matches "
                         "copies by identity, so a longer window costs only memory: use window: "
                         "2s for radio + LTE",
                     comments);
                for (const auto& c : comments)
                    y += "  # " + c + "\n";
            }
            y += "  - plugin: dedup\n    window: " + std::to_string(dedup_ms_) + "ms\n";
        }
        if (report_stats_)
            y += "  # ReportStats: a line of per-link figures each interval\n"
                 "  - plugin: stats\n";
    }
    return ImportedConfig{std::move(y), std::move(warnings_)};
}

}  // namespace

Result<ImportedConfig> import_mavlink_router(std::string_view text, const std::string& file) {
    try {
        Importer importer(file);
        return importer.run(text);
    } catch (const ImportError& e) {
        return make_error(e.message);
    }
}

}  // namespace mavbond
