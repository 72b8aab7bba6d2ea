// mavbondctl: reads what a running mavbond publishes on its status socket and prints it.
#include <getopt.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <boost/property_tree/json_parser.hpp>
#include <boost/property_tree/ptree.hpp>
#include <cerrno>
#include <cstdio>
#include <chrono>
#include <cstring>
#include <ctime>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "keygen.h"

namespace {

namespace pt = boost::property_tree;
constexpr const char* kDefaultSocket = "/run/mavbond/status.sock";

int usage(FILE* out, int code) {
    fprintf(out,
            "Usage: mavbondctl [-s SOCKET] status [--json]\n"
            "       mavbondctl [-s SOCKET] watch [--interval S] [--count N]\n"
            "       mavbondctl keygen [--owner USER] PATH\n"
            "Prints the status of a running mavbond: endpoints, bonds, links and filters.\n"
            "watch: one line per link (bond, state, loss and what it is read from, frames/s\n"
            "received, last frame received, * for a bond's active link; under a link with\n"
            "tx_rate, its frames/s per class), one per bond (delivered loss, standby),\n"
            "refreshed every S seconds (default 1), N times\n"
            "(default: until interrupted); redrawn in place on a terminal, else one block each.\n"
            "keygen: a new signing key for a bond in PATH (mode 0600, owner USER, default\n"
            "mavbond when that user exists), never over an existing file; copy the same file\n"
            "to the other gateway.\n\n"
            "  -s, --socket PATH  the daemon's status_socket (default %s)\n"
            "      --json         print the daemon's JSON document as it is (for scripts)\n"
            "  -V, --version      print the version\n",
            kDefaultSocket);
    return code;
}

/// Reads the whole document; empty with a message on stderr when the daemon is not there.
std::string fetch(const std::string& path) {
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    if (path.size() >= sizeof addr.sun_path) {
        fprintf(stderr, "mavbondctl: socket path too long: %s\n", path.c_str());
        return "";
    }
    std::memcpy(addr.sun_path, path.c_str(), path.size() + 1);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0 || connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) < 0) {
        int err = errno;
        const char* hint = err == EACCES
            ? "the socket's group may read it: as installed, group mavbond; sudo adduser $USER "
              "mavbond, then log in again"
            : "is mavbond running with status_socket set?";
        fprintf(stderr, "mavbondctl: cannot connect to %s: %s (%s)\n", path.c_str(), strerror(err),
                hint);
        if (fd >= 0)
            close(fd);
        return "";
    }
    timeval tv{2, 0};
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    std::string doc;
    char buf[8192];
    ssize_t n;
    while ((n = read(fd, buf, sizeof buf)) > 0)
        doc.append(buf, static_cast<size_t>(n));
    close(fd);
    return doc;
}

std::string fmt_pct(double v) {
    char b[32];
    snprintf(b, sizeof b, "%.2f%%", v);
    return b;
}

constexpr size_t kWidth = 80;  // watch and status lines wrap before this column

/// Prints `head` then `parts` joined by `sep`, wrapped between parts (never inside one) so no
/// line passes kWidth; a line that goes on ends with the separator's mark (";" of "; "), the
/// next starts with `indent` spaces.
void print_wrapped(std::string line, const std::vector<std::string>& parts, const std::string& sep,
                   size_t indent) {
    std::string mark = sep;
    while (!mark.empty() && mark.back() == ' ')
        mark.pop_back();
    for (size_t i = 0; i < parts.size(); i++) {
        if (i == 0) {
            line += parts[i];
        } else if (line.size() + sep.size() + parts[i].size() > kWidth) {
            printf("%s%s\n", line.c_str(), mark.c_str());
            line = std::string(indent, ' ') + parts[i];
        } else {
            line += sep + parts[i];
        }
    }
    printf("%s\n", line.c_str());
}

/// Splits `text` at every `sep`.
std::vector<std::string> split(const std::string& text, const std::string& sep) {
    std::vector<std::string> out;
    size_t from = 0;
    for (size_t at; (at = text.find(sep, from)) != std::string::npos; from = at + sep.size())
        out.push_back(text.substr(from, at - from));
    out.push_back(text.substr(from));
    return out;
}

/// A radio link's `radio_status` object in one line: its last report, the budget it set.
std::string radio_line(const pt::ptree& r) {
    char b[256];
    if (r.get("reports", 0ull) == 0) {
        snprintf(b, sizeof b, "no report yet; budget %s B/s", r.get("rate", "").c_str());
        return b;
    }
    snprintf(b, sizeof b,
             "txbuf %s%%, rssi %s/%s, noise %s/%s, rxerrors %s (%s reports, last %.1f s ago); "
             "budget %s of %s B/s",
             r.get("last.txbuf", "").c_str(), r.get("last.rssi", "").c_str(),
             r.get("last.remrssi", "").c_str(), r.get("last.noise", "").c_str(),
             r.get("last.remnoise", "").c_str(), r.get("last.rxerrors", "").c_str(),
             r.get("reports", "").c_str(), r.get("age_ms", 0ll) / 1000.0,
             r.get("rate", "").c_str(), r.get("ceiling", "").c_str());
    return b;
}

void print_table(const pt::ptree& doc) {
    printf("mavbond %s, up %s s\n\n", doc.get("version", "?").c_str(), doc.get("uptime_s", "?").c_str());
    printf("%-28s %-11s %-9s %-7s %10s %11s %8s %9s %10s %8s\n", "ENDPOINT", "KIND", "BOND",
           "STATE", "RX FRAMES", "RX BYTES", "CRC ERR", "GARBAGE", "TX FRAMES", "TX DROP");
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        printf("%-28s %-11s %-9s %-7s %10s %11s %8s %9s %10s %8s\n", e.get("name", "").c_str(),
               e.get("kind", "").c_str(), e.get("bond", "").c_str(), e.get("state", "").c_str(),
               e.get("rx_frames", "").c_str(),
               e.get("rx_bytes", "").c_str(), e.get("crc_errors", "").c_str(),
               e.get("garbage_bytes", "").c_str(), e.get("tx_frames", "").c_str(),
               e.get("tx_dropped", "").c_str());
    }
    // Endpoints not open, and why (a missing device, a permission).
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        if (auto why = e.get_optional<std::string>("open_error"))
            printf("closed %s: %s\n", e.get("name", "").c_str(), why->c_str());
    }
    // Signing endpoints: what their check dropped (unsigned frames pass when not required),
    // and what a signed bond's links sent with its signature.
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        auto unsigned_ = e.get("sig_unsigned", 0ull), bad = e.get("sig_bad", 0ull),
             replay = e.get("sig_replay", 0ull), sent = e.get("tx_signed", 0ull);
        if (unsigned_ + bad + replay + sent > 0)
            printf("signing %s: %llu unsigned, %llu bad signature, %llu replayed or stale "
                   "dropped; %llu sent signed (+%llu bytes)\n",
                   e.get("name", "").c_str(), unsigned_, bad, replay, sent, 13 * sent);
    }
    // Budgeted endpoints (tx_rate): what each class sent, waited, lost to thinning or overflow.
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        auto budget = e.get_child_optional("tx_budget");
        if (!budget)
            continue;
        printf("budget %s: %s B/s", e.get("name", "").c_str(), budget->get("rate", "").c_str());
        for (const auto& [c, k] : *budget) {  // the classes, in the daemon's order
            if (c != "rate")
                printf("; %s %s frames (%s waited, %s thinned, %s dropped)", c.c_str(),
                       k.get("frames", "0").c_str(), k.get("waited", "0").c_str(),
                       k.get("thinned", "0").c_str(), k.get("dropped", "0").c_str());
        }
        printf("\n");
    }
    // Radio links (radio_status): what the radio said last, and the budget it set.
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        if (auto radio = e.get_child_optional("radio_status"))
            printf("radio %s: %s\n", e.get("name", "").c_str(), radio_line(*radio).c_str());
    }
    // Stalls of the daemon's own loop (100 ms or more): the machine or a blocking call held
    // every frame that long.
    if (auto late = doc.get("event_loop.late_wakeups", 0ull), rounds = doc.get("event_loop.long_rounds", 0ull);
        late + rounds > 0)
        printf("event loop: woke up to %s ms late (%llu times), longest round %s ms (%llu of 100 ms "
               "or more)\n",
               doc.get("event_loop.latest_wakeup_ms", "0").c_str(), late,
               doc.get("event_loop.longest_round_ms", "0").c_str(), rounds);
    if (auto refused = doc.get("status_refused", 0ull); refused > 0)
        printf("status socket: %llu %s refused (credentials)\n", refused,
               refused == 1 ? "connection" : "connections");
    auto bonds = doc.get_child("bonds", {});
    if (!bonds.empty()) {
        printf("\n%-12s %-10s %-20s %8s\n", "BOND", "TX", "ACTIVE LINK", "SWITCHES");
        for (const auto& [_, b] : bonds)
            printf("%-12s %-10s %-20s %8s\n", b.get("name", "").c_str(), b.get("tx", "").c_str(),
                   b.get("active", "").empty() ? "-" : b.get("active", "").c_str(),
                   b.get("switches", "").c_str());
        for (const auto& [_, b] : bonds) {
            if (auto r = b.get_child_optional("radio_status"))
                printf("radio status %s: %s sent to the local side, last txbuf %s%%; %s from "
                       "others dropped\n",
                       b.get("name", "").c_str(), r->get("sent", "0").c_str(),
                       r->get("last.txbuf", "-").c_str(), r->get("foreign", "0").c_str());
        }
        for (const auto& [_, b] : bonds) {
            if (auto sg = b.get_child_optional("signing")) {
                std::string links;
                for (const auto& [__, l] : sg->get_child("links", {}))
                    links += (links.empty() ? "" : ", ") + l.get_value<std::string>();
                printf("signing %s: links %s; %s frames signed, %s verified, %s copies not "
                       "delivered again, %s MAVLink 1 frames kept off\n",
                       b.get("name", "").c_str(), links.c_str(), sg->get("signed", "0").c_str(),
                       sg->get("verified", "0").c_str(), sg->get("redelivered", "0").c_str(),
                       sg->get("refused_v1", "0").c_str());
            }
            if (auto r = b.get_child_optional("renumber"))
                printf("renumber %s: %s frames renumbered, %s gaps (lost on every link), %s filled "
                       "late, %s signed left alone\n",
                       b.get("name", "").c_str(), r->get("renumbered", "0").c_str(),
                       r->get("gaps", "0").c_str(), r->get("late_filled", "0").c_str(),
                       r->get("signed_left_alone", "0").c_str());
            if (auto sb = b.get_child_optional("standby")) {
                std::string peer;
                for (const auto& [link, permille] : sb->get_child("peer_loss_permille", {}))
                    peer += " " + link + " " + fmt_pct(permille.get_value<double>() / 10.0);
                printf("standby %s: metered links %s, %s bytes sent on them; %s to active, %s back "
                       "to standby; %s frames withheld, %s resent; peer reports%s\n",
                       b.get("name", "").c_str(), sb->get("state", "").c_str(),
                       sb->get("metered_tx_bytes", "0").c_str(), sb->get("to_active", "0").c_str(),
                       sb->get("to_standby", "0").c_str(), sb->get("withheld", "0").c_str(),
                       sb->get("resent", "0").c_str(), peer.empty() ? " none" : peer.c_str());
            }
        }
    }
    for (const auto& [_, f] : doc.get_child("filters", {})) {
        printf("\nfilter %s: %s frames dropped\n", f.get("name", "").c_str(), f.get("dropped", "0").c_str());
        if (f.get("plugin", "") != "stats")
            continue;
        // The stats plugin's figures: per link and per bond.
        if (auto links = f.get_child_optional("status.links")) {
            // LOST and LOSS of EXPECTED: what the far side wrote (BY markers), or what the
            // sequence numbers say (BY sequence).
            printf("  %-26s %-9s %10s %10s %8s %8s %-8s %8s\n", "LINK", "BOND", "FRAMES", "EXPECTED",
                   "LOST", "LOSS", "BY", "CRC ERR");
            for (const auto& [__, l] : *links)
                printf("  %-26s %-9s %10s %10s %8s %8s %-8s %8s\n", l.get("name", "").c_str(),
                       l.get("bond", "").c_str(), l.get("frames", "").c_str(),
                       l.get("expected", "").c_str(), l.get("lost", "").c_str(),
                       fmt_pct(l.get("loss_pct", 0.0)).c_str(), l.get("basis", "").c_str(),
                       l.get("crc_errors", "").c_str());
        }
        if (auto sb = f.get_child_optional("status.bonds")) {
            printf("  %-12s %10s %10s %7s %9s %9s %-12s %8s\n", "BOND", "DELIVERED", "DUPLICATES",
                   "STALE", "LOSS", "SKEW ms", "ACTIVE", "SWITCHES");
            for (const auto& [__, b] : *sb)
                printf("  %-12s %10s %10s %7s %9s %9s %-12s %8s\n", b.get("name", "").c_str(),
                       b.get("delivered", "").c_str(), b.get("duplicates", "").c_str(),
                       b.get("stale", "").c_str(), fmt_pct(b.get("delivered_loss_pct", 0.0)).c_str(),
                       b.get("skew_ms.mean", "-").c_str(),
                       b.get("active", "").empty() ? "-" : b.get("active", "").c_str(),
                       b.get("switches", "").c_str());
        }
    }
}

/// The document as a tree; false (with a message) when it is not JSON.
bool parse_doc(const std::string& doc, pt::ptree& tree) {
    try {
        std::istringstream in(doc);
        pt::read_json(in, tree);
        return true;
    } catch (const pt::ptree_error& e) {
        fprintf(stderr, "mavbondctl: the daemon's status is not valid JSON: %s\n", e.what());
        return false;
    }
}

/// The stats filter's figures (its status), or nullptr when no stats filter runs. Only the
/// stats filter's: other filters list links by the same names (dedup, linkswitch).
const pt::ptree* stats_of(const pt::ptree& doc) {
    const auto filters = doc.get_child_optional("filters");
    if (!filters)
        return nullptr;
    for (const auto& [_, f] : *filters) {  // the document's own nodes: they outlive the call
        if (f.get("plugin", "") == "stats") {
            if (const auto status = f.get_child_optional("status"))
                return &*status;
        }
    }
    return nullptr;
}

/// A configured endpoint's loss as the stats filter counts it, its own link or a server's
/// peers together: by the far side's count markers when any of them has them, else by
/// sequence gaps.
struct LinkLoss {
    bool known = false;  // a stats filter covers it and something was expected
    double pct = 0;
    std::string basis;   // "markers" or "sequence"
};
LinkLoss link_loss(const pt::ptree* stats, const std::string& endpoint) {
    double expected[2] = {0, 0}, lost[2] = {0, 0};  // [sequence, markers]
    bool markers = false;
    const auto links = stats ? stats->get_child_optional("links") : boost::none;
    for (const auto& [_, l] : links ? *links : pt::ptree()) {
        if (l.get("endpoint", "") != endpoint)
            continue;
        const int k = l.get("basis", "") == "markers" ? 1 : 0;
        markers = markers || k == 1;
        expected[k] += l.get("expected", 0.0);
        lost[k] += l.get("lost", 0.0);
    }
    const int k = markers ? 1 : 0;
    if (expected[k] <= 0)
        return {};
    return {true, 100.0 * lost[k] / expected[k], markers ? "markers" : "sequence"};
}

std::string fmt_ago(long long ms) {
    if (ms < 0)
        return "never";
    char b[32];
    if (ms < 60'000)
        snprintf(b, sizeof b, "%.1fs", static_cast<double>(ms) / 1000);
    else
        snprintf(b, sizeof b, "%lldm%02llds", ms / 60'000, ms / 1000 % 60);
    return b;
}

/// One refresh of `watch`. `prev` holds the counters of the refresh before (`dt` seconds ago),
/// by endpoint and counter; the first refresh has no rates yet.
void print_watch_block(const pt::ptree& doc, std::map<std::string, uint64_t>& prev, double dt) {
    std::map<std::string, std::string> active;  // bond -> its active link
    const auto bonds = doc.get_child_optional("bonds");
    for (const auto& [_, b] : bonds ? *bonds : pt::ptree())
        active[b.get("name", "")] = b.get("active", "");
    const pt::ptree* stats = stats_of(doc);
    time_t t = time(nullptr);
    char clock[16];
    strftime(clock, sizeof clock, "%H:%M:%S", localtime(&t));
    printf("mavbond %s, up %s s, %s\n", doc.get("version", "?").c_str(),
           doc.get("uptime_s", "?").c_str(), clock);
    printf("  %-16s %-9s %-7s %7s %-8s %7s %8s\n", "LINK", "BOND", "STATE", "LOSS", "BY", "RX/S",
           "LAST RX");
    std::map<std::string, uint64_t> now;
    // A counter's rate since the refresh before, as text ("-" on the first).
    auto per_second = [&](const std::string& key, uint64_t value) -> std::string {
        now[key] = value;
        auto it = prev.find(key);
        if (it == prev.end() || dt <= 0)
            return "-";
        char b[32];
        snprintf(b, sizeof b, "%.1f", static_cast<double>(value - it->second) / dt);
        return b;
    };
    const auto endpoints = doc.get_child_optional("endpoints");
    for (const auto& [_, e] : endpoints ? *endpoints : pt::ptree()) {
        std::string name = e.get("name", "");
        std::string bond = e.get("bond", "");
        std::string rate = per_second(name + "/rx_frames", e.get<uint64_t>("rx_frames", 0));
        LinkLoss loss = link_loss(stats, name);
        // The active link is the endpoint itself or one of its peers ("name@address").
        const std::string& act = active[bond];
        char marker = !bond.empty() && (act == name || act.rfind(name + "@", 0) == 0) ? '*' : ' ';
        printf("%c %-16s %-9s %-7s %7s %-8s %7s %8s\n", marker, name.c_str(),
               bond.empty() ? "-" : bond.c_str(), e.get("state", "-").c_str(),
               loss.known ? fmt_pct(loss.pct).c_str() : "-", loss.known ? loss.basis.c_str() : "-",
               rate.c_str(), fmt_ago(e.get<long long>("last_rx_ms_ago", -1)).c_str());
        if (auto why = e.get_optional<std::string>("open_error"))
            print_wrapped("    closed: ", split(*why, " "), " ", 6);
        // A budgeted link: frames/s out per class, and what thinning and overflow took.
        if (auto budget = e.get_child_optional("tx_budget")) {
            std::vector<std::string> parts;
            for (const auto& [c, k] : *budget) {  // the classes, in the daemon's order
                if (c == "rate")
                    continue;
                std::string key = name + "/" + c;
                std::string sent = per_second(key, k.get<uint64_t>("frames", 0));
                uint64_t lost = k.get<uint64_t>("thinned", 0) + k.get<uint64_t>("dropped", 0);
                parts.push_back(c + " " + sent + "/s (" + per_second(key + "/lost", lost) +
                                "/s thinned or dropped)");
            }
            print_wrapped("    tx " + budget->get("rate", "") + " B/s; ", parts, "; ", 7);
        }
        if (auto radio = e.get_child_optional("radio_status"))
            print_wrapped("    radio ", split(radio_line(*radio), " "), " ", 10);
    }
    // Each bond: what it delivered, and whether its metered links stand by.
    const auto stats_bonds = stats ? stats->get_child_optional("bonds") : boost::none;
    for (const auto& [_, b] : bonds ? *bonds : pt::ptree()) {
        const std::string name = b.get("name", "");
        std::vector<std::string> parts;
        for (const auto& [__, sb] : stats_bonds ? *stats_bonds : pt::ptree()) {
            if (sb.get("name", "") != name)
                continue;
            const double lost = sb.get("delivered_lost", 0.0);
            char text[128];
            snprintf(text, sizeof text, "delivered loss %s (%.0f of %.0f lost)",
                     fmt_pct(sb.get("delivered_loss_pct", 0.0)).c_str(), lost,
                     lost + sb.get("delivered", 0.0));
            parts.push_back(text);
        }
        if (auto standby = b.get_child_optional("standby"))
            parts.push_back(standby->get("state", "") == "active" ? "metered links active"
                                                                   : "metered links in standby");
        if (b.get("tx", "") == "active") {
            // Its endpoint (a peer's address is in `status`): the row marked * is the link.
            const std::string link = b.get("active", "");
            parts.push_back("active link " + (link.empty() ? "-" : link.substr(0, link.find('@'))));
        }
        if (parts.empty())
            parts.push_back("no figures (no stats filter on it)");
        print_wrapped("  bond " + name + ": ", parts, "; ", 4);
    }
    prev = std::move(now);
}

int watch(const std::string& socket_path, double interval, long count) {
    bool tty = isatty(STDOUT_FILENO) != 0;
    std::map<std::string, uint64_t> prev;
    auto last = std::chrono::steady_clock::now();
    for (long i = 0; count <= 0 || i < count; i++) {
        if (i > 0)
            std::this_thread::sleep_for(std::chrono::duration<double>(interval));
        std::string doc = fetch(socket_path);
        if (doc.empty())
            return 69;  // EX_UNAVAILABLE: the daemon went away
        pt::ptree tree;
        if (!parse_doc(doc, tree))
            return 65;
        auto now = std::chrono::steady_clock::now();
        double dt = std::chrono::duration<double>(now - last).count();
        last = now;
        if (tty)
            fputs("\033[H\033[2J", stdout);  // home and clear: redraw in place
        else if (i > 0)
            fputs("\n", stdout);  // a blank line between blocks
        print_watch_block(tree, prev, dt);
        fflush(stdout);
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    std::string socket_path = kDefaultSocket;
    bool json = false;
    double interval = 1.0;
    long count = 0;
    std::string owner = mavbond::kServiceUser;
    bool owner_given = false;
    static const option opts[] = {{"socket", required_argument, nullptr, 's'},
                                  {"json", no_argument, nullptr, 'j'},
                                  {"interval", required_argument, nullptr, 'i'},
                                  {"count", required_argument, nullptr, 'n'},
                                  {"owner", required_argument, nullptr, 'o'},
                                  {"version", no_argument, nullptr, 'V'},
                                  {"help", no_argument, nullptr, 'h'},
                                  {nullptr, 0, nullptr, 0}};
    int c;
    while ((c = getopt_long(argc, argv, "s:Vh", opts, nullptr)) != -1) {
        switch (c) {
        case 's': socket_path = optarg; break;
        case 'j': json = true; break;
        case 'i': {
            char* end = nullptr;
            interval = strtod(optarg, &end);
            if (*optarg == '\0' || *end != '\0' || !(interval >= 0.1 && interval <= 3600)) {
                fprintf(stderr, "mavbondctl: --interval: '%s' is not a number of seconds in "
                                "0.1..3600\n", optarg);
                return 64;
            }
            break;
        }
        case 'n': {
            char* end = nullptr;
            count = strtol(optarg, &end, 10);
            if (*optarg == '\0' || *end != '\0' || count < 1) {
                fprintf(stderr, "mavbondctl: --count: '%s' is not a positive integer\n", optarg);
                return 64;
            }
            break;
        }
        case 'o': owner = optarg; owner_given = true; break;
        case 'V': printf("mavbondctl %s\n", MAVBOND_VERSION); return 0;
        case 'h': return usage(stdout, 0);
        default: return usage(stderr, 64);
        }
    }
    if (optind < argc && std::strcmp(argv[optind], "keygen") == 0)
        return optind + 2 == argc ? mavbond::keygen(argv[optind + 1], owner, owner_given)
                                  : usage(stderr, 64);
    if (optind < argc && std::strcmp(argv[optind], "watch") == 0 && optind + 1 == argc)
        return watch(socket_path, interval, count);
    if (optind >= argc || std::strcmp(argv[optind], "status") != 0 || optind + 1 != argc) {
        // Say what was wrong before the usage: "stat" is a typo, not a request for help.
        if (optind >= argc)
            fprintf(stderr, "mavbondctl: no command given (status or watch)\n");
        else if (std::strcmp(argv[optind], "status") != 0 && std::strcmp(argv[optind], "watch") != 0)
            fprintf(stderr, "mavbondctl: unknown command '%s' (status or watch)\n", argv[optind]);
        else
            fprintf(stderr, "mavbondctl: unexpected argument '%s' after %s\n", argv[optind + 1],
                    argv[optind]);
        return usage(stderr, 64);
    }
    std::string doc = fetch(socket_path);
    if (doc.empty())
        return 69;  // EX_UNAVAILABLE
    if (json) {
        fputs(doc.c_str(), stdout);
        return 0;
    }
    pt::ptree tree;
    if (!parse_doc(doc, tree))
        return 65;  // EX_DATAERR
    print_table(tree);
    return 0;
}
