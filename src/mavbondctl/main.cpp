// mavbondctl: reads what a running mavbond publishes on its status socket and prints it.
#include <getopt.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <boost/property_tree/json_parser.hpp>
#include <boost/property_tree/ptree.hpp>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <string>

#include "mavbond_build_config.h"

namespace {

namespace pt = boost::property_tree;
constexpr const char* kDefaultSocket = "/run/mavbond/status.sock";

int usage(FILE* out, int code) {
    fprintf(out,
            "Usage: mavbondctl [-s SOCKET] status [--json]\n"
            "Prints the status of a running mavbond: endpoints, bonds, links and filters.\n\n"
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
        fprintf(stderr, "mavbondctl: cannot connect to %s: %s (is mavbond running with "
                        "status_socket set?)\n", path.c_str(), strerror(errno));
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
    if (auto refused = doc.get("status_refused", 0ull); refused > 0)
        printf("status socket: %llu connections refused (credentials)\n", refused);
    auto bonds = doc.get_child("bonds", {});
    if (!bonds.empty()) {
        printf("\n%-12s %-10s %-20s %8s\n", "BOND", "TX", "ACTIVE LINK", "SWITCHES");
        for (const auto& [_, b] : bonds)
            printf("%-12s %-10s %-20s %8s\n", b.get("name", "").c_str(), b.get("tx", "").c_str(),
                   b.get("active", "").empty() ? "-" : b.get("active", "").c_str(),
                   b.get("switches", "").c_str());
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

}  // namespace

int main(int argc, char** argv) {
    std::string socket_path = kDefaultSocket;
    bool json = false;
    static const option opts[] = {{"socket", required_argument, nullptr, 's'},
                                  {"json", no_argument, nullptr, 'j'},
                                  {"version", no_argument, nullptr, 'V'},
                                  {"help", no_argument, nullptr, 'h'},
                                  {nullptr, 0, nullptr, 0}};
    int c;
    while ((c = getopt_long(argc, argv, "s:Vh", opts, nullptr)) != -1) {
        switch (c) {
        case 's': socket_path = optarg; break;
        case 'j': json = true; break;
        case 'V': printf("mavbondctl %s\n", MAVBOND_VERSION); return 0;
        case 'h': return usage(stdout, 0);
        default: return usage(stderr, 64);
        }
    }
    if (optind >= argc || std::strcmp(argv[optind], "status") != 0)
        return usage(stderr, 64);
    std::string doc = fetch(socket_path);
    if (doc.empty())
        return 69;  // EX_UNAVAILABLE
    if (json) {
        fputs(doc.c_str(), stdout);
        return 0;
    }
    try {
        pt::ptree tree;
        std::istringstream in(doc);
        pt::read_json(in, tree);
        print_table(tree);
    } catch (const pt::ptree_error& e) {
        fprintf(stderr, "mavbondctl: the daemon's status is not valid JSON: %s\n", e.what());
        return 65;  // EX_DATAERR
    }
    return 0;
}
