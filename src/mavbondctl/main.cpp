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
#include <sstream>
#include <string>
#include <thread>

namespace {

namespace pt = boost::property_tree;
constexpr const char* kDefaultSocket = "/run/mavbond/status.sock";

int usage(FILE* out, int code) {
    fprintf(out,
            "Usage: mavbondctl [-s SOCKET] status [--json]\n"
            "       mavbondctl [-s SOCKET] watch [--interval S] [--count N]\n"
            "Prints the status of a running mavbond: endpoints, bonds, links and filters.\n"
            "watch: one line per link (bond, loss, frames/s received, last frame received,\n"
            "* for a bond's active link; under a link with tx_rate, its frames/s per class),\n"
            "refreshed every S seconds (default 1), N times\n"
            "(default: until interrupted); redrawn in place on a terminal, else one block each.\n\n"
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
    printf("%-28s %-11s %-9s %10s %11s %8s %9s %10s %8s\n", "ENDPOINT", "KIND", "BOND", "RX FRAMES",
           "RX BYTES", "CRC ERR", "GARBAGE", "TX FRAMES", "TX DROP");
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        printf("%-28s %-11s %-9s %10s %11s %8s %9s %10s %8s\n", e.get("name", "").c_str(),
               e.get("kind", "").c_str(), e.get("bond", "").c_str(), e.get("rx_frames", "").c_str(),
               e.get("rx_bytes", "").c_str(), e.get("crc_errors", "").c_str(),
               e.get("garbage_bytes", "").c_str(), e.get("tx_frames", "").c_str(),
               e.get("tx_dropped", "").c_str());
    }
    // Signing endpoints: what their check dropped (unsigned frames pass when not required).
    for (const auto& [_, e] : doc.get_child("endpoints", {})) {
        auto unsigned_ = e.get("sig_unsigned", 0ull), bad = e.get("sig_bad", 0ull),
             replay = e.get("sig_replay", 0ull);
        if (unsigned_ + bad + replay > 0)
            printf("signing %s: %llu unsigned, %llu bad signature, %llu replayed or stale\n",
                   e.get("name", "").c_str(), unsigned_, bad, replay);
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
    if (auto refused = doc.get("status_refused", 0ull); refused > 0)
        printf("status socket: %llu connections refused (credentials)\n", refused);
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
            printf("  %-26s %-9s %10s %8s %8s %8s\n", "LINK", "BOND", "FRAMES", "LOST", "LOSS", "CRC ERR");
            for (const auto& [__, l] : *links)
                printf("  %-26s %-9s %10s %8s %8s %8s\n", l.get("name", "").c_str(),
                       l.get("bond", "").c_str(), l.get("frames", "").c_str(), l.get("lost", "").c_str(),
                       fmt_pct(l.get("loss_pct", 0.0)).c_str(), l.get("crc_errors", "").c_str());
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

/// Loss of an endpoint from the stats filter's links: its own entry, or its peers' and
/// connections' ("name@address") together. Negative when no stats filter covers it.
double link_loss_pct(const pt::ptree& doc, const std::string& name) {
    double lost = 0, frames = 0;
    bool found = false;
    // get_child_optional: get_child's default would be a temporary gone before the loop body.
    const auto filters = doc.get_child_optional("filters");
    for (const auto& [_, f] : filters ? *filters : pt::ptree()) {
        const auto links = f.get_child_optional("status.links");
        if (!links)
            continue;
        for (const auto& [__, l] : *links) {
            std::string n = l.get("name", "");
            if (n == name) {
                return l.get("loss_pct", 0.0);
            }
            if (n.rfind(name + "@", 0) == 0) {
                found = true;
                lost += l.get("lost", 0.0);
                frames += l.get("frames", 0.0);
            }
        }
    }
    if (!found)
        return -1;
    return lost + frames > 0 ? 100.0 * lost / (lost + frames) : 0.0;
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
    if (const auto bonds = doc.get_child_optional("bonds")) {
        for (const auto& [_, b] : *bonds)
            active[b.get("name", "")] = b.get("active", "");
    }
    time_t t = time(nullptr);
    char clock[16];
    strftime(clock, sizeof clock, "%H:%M:%S", localtime(&t));
    printf("mavbond %s, up %s s, %s\n", doc.get("version", "?").c_str(),
           doc.get("uptime_s", "?").c_str(), clock);
    printf("  %-24s %-10s %8s %10s %10s\n", "LINK", "BOND", "LOSS", "RX/S", "LAST RX");
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
        double loss = link_loss_pct(doc, name);
        // The active link is the endpoint itself or one of its peers ("name@address").
        const std::string& act = active[bond];
        char marker = !bond.empty() && (act == name || act.rfind(name + "@", 0) == 0) ? '*' : ' ';
        printf("%c %-24s %-10s %8s %10s %10s\n", marker, name.c_str(), bond.empty() ? "-" : bond.c_str(),
               loss < 0 ? "-" : fmt_pct(loss).c_str(), rate.c_str(),
               fmt_ago(e.get<long long>("last_rx_ms_ago", -1)).c_str());
        // A budgeted link: frames/s out per class, and what thinning and overflow took.
        if (auto budget = e.get_child_optional("tx_budget")) {
            printf("    tx %s B/s", budget->get("rate", "").c_str());
            for (const auto& [c, k] : *budget) {  // the classes, in the daemon's order
                if (c == "rate")
                    continue;
                std::string key = name + "/" + c;
                std::string sent = per_second(key, k.get<uint64_t>("frames", 0));
                uint64_t lost = k.get<uint64_t>("thinned", 0) + k.get<uint64_t>("dropped", 0);
                printf("; %s %s/s (%s/s thinned or dropped)", c.c_str(), sent.c_str(),
                       per_second(key + "/lost", lost).c_str());
            }
            printf("\n");
        }
        if (auto radio = e.get_child_optional("radio_status"))
            printf("    radio %s\n", radio_line(*radio).c_str());
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
    static const option opts[] = {{"socket", required_argument, nullptr, 's'},
                                  {"json", no_argument, nullptr, 'j'},
                                  {"interval", required_argument, nullptr, 'i'},
                                  {"count", required_argument, nullptr, 'n'},
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
        case 'V': printf("mavbondctl %s\n", MAVBOND_VERSION); return 0;
        case 'h': return usage(stdout, 0);
        default: return usage(stderr, 64);
        }
    }
    if (optind < argc && std::strcmp(argv[optind], "watch") == 0 && optind + 1 == argc)
        return watch(socket_path, interval, count);
    if (optind >= argc || std::strcmp(argv[optind], "status") != 0)
        return usage(stderr, 64);
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
