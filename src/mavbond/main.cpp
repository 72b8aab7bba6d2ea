// mavbond: the daemon. Parses the command line, loads the config, builds the loop, the router
// and the endpoints, and runs until SIGINT/SIGTERM.
#include <getopt.h>
#include <sys/resource.h>

#include <csignal>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/event_loop.h"
#include "core/log.h"
#include "core/router.h"
#include "core/status_socket.h"
#include "endpoints/endpoint.h"
#include "filters/filter_chain.h"
#include "mavbond_build_config.h"

namespace mavbond {
namespace {

constexpr int kExitSoftware = 70;  // EX_SOFTWARE
constexpr int kExitOsError = 71;   // EX_OSERR: a socket that cannot be bound, ...

struct Options {
    std::string config_path = MAVBOND_DEFAULT_CONFIG;
    std::string log_level;
    std::string plugin_dir;
    bool check_config = false;
};

void print_usage(FILE* out) {
    fprintf(out,
            "Usage: mavbond [-c FILE] [--check-config] [--log-level LEVEL] [--plugin-dir DIR]\n"
            "               [--version] [--help]\n"
            "MAVLink gateway that bonds redundant telemetry links into one.\n\n"
            "  -c, --config FILE     configuration file (default %s)\n"
            "      --check-config    validate the configuration and exit (78 when invalid)\n"
            "  -l, --log-level LEVEL error, warning, notice, info, debug or trace\n"
            "      --plugin-dir DIR  where filter plugins are loaded from\n"
            "  -V, --version         print the version and exit\n"
            "  -h, --help            print this help and exit\n\n"
            "Signals: SIGINT/SIGTERM stop, SIGUSR1 logs every endpoint's counters.\n",
            MAVBOND_DEFAULT_CONFIG);
}

/// Returns an exit code when the command line says to stop now, or -1 to go on.
int parse_args(int argc, char** argv, Options& opts) {
    enum { kCheckConfig = 1000, kPluginDir };
    static const option long_opts[] = {
        {"config", required_argument, nullptr, 'c'},
        {"check-config", no_argument, nullptr, kCheckConfig},
        {"log-level", required_argument, nullptr, 'l'},
        {"plugin-dir", required_argument, nullptr, kPluginDir},
        {"version", no_argument, nullptr, 'V'},
        {"help", no_argument, nullptr, 'h'},
        {nullptr, 0, nullptr, 0},
    };
    int c;
    while ((c = getopt_long(argc, argv, "c:l:Vh", long_opts, nullptr)) != -1) {
        switch (c) {
        case 'c': opts.config_path = optarg; break;
        case 'l': opts.log_level = optarg; break;
        case kCheckConfig: opts.check_config = true; break;
        case kPluginDir: opts.plugin_dir = optarg; break;
        case 'V': printf("mavbond %s\n", MAVBOND_VERSION); return 0;
        case 'h': print_usage(stdout); return 0;
        default: print_usage(stderr); return 64;  // EX_USAGE
        }
    }
    if (optind < argc) {
        fprintf(stderr, "mavbond: unexpected argument '%s'\n", argv[optind]);
        print_usage(stderr);
        return 64;
    }
    return -1;
}

std::string counters_line(const Endpoint& e) {
    std::string line = "stats endpoint=" + e.name() + " kind=" + e.kind();
    for_each_counter(e.total_stats(), [&line](const char* name, uint64_t value) {
        line += std::string(" ") + name + "=" + std::to_string(value);
    });
    return line;
}

/// The status socket's document: every endpoint's counters, the bonds, and each filter's own
/// status (the stats plugin's per-link and per-bond figures among them).
std::string status_document(const std::vector<Endpoint::Ptr>& endpoints, const Router& router,
                            const FilterChain& chain, TimePoint started, TimePoint now) {
    std::string out = "{\"version\":\"" MAVBOND_VERSION "\",\"uptime_s\":" +
                      std::to_string(std::chrono::duration_cast<seconds>(now - started).count()) +
                      ",\"endpoints\":[";
    for (size_t i = 0; i < endpoints.size(); i++) {
        const Endpoint& e = *endpoints[i];
        out += std::string(i ? "," : "") + "{\"name\":\"" + e.name() + "\",\"kind\":\"" + e.kind() +
               "\",\"bond\":\"" + e.config().bond + "\"";
        for_each_counter(e.total_stats(), [&out](const char* name, uint64_t value) {
            out += std::string(",\"") + name + "\":" + std::to_string(value);
        });
        out += "}";
    }
    out += "],\"bonds\":[";
    for (size_t i = 0; i < router.bonds().size(); i++) {
        const Router::Bond& b = router.bonds()[i];
        const Endpoint* active = b.active_link < router.endpoints().size()
                                     ? router.endpoints()[b.active_link] : nullptr;
        out += std::string(i ? "," : "") + "{\"name\":\"" + b.name + "\",\"tx\":\"" +
               (b.tx_active ? "active" : "broadcast") + "\",\"active\":\"" +
               (active ? active->name() : "") + "\",\"switches\":" + std::to_string(b.switches) + "}";
    }
    return out + "],\"filters\":" + chain.status_json() + "}";
}

/// Per-frame problems are never logged one by one: every report_interval, one line per
/// endpoint that had any says how many of each.
class ProblemReport {
public:
    explicit ProblemReport(const std::vector<Endpoint::Ptr>& endpoints)
        : endpoints_(endpoints), last_(endpoints.size()) {}

    void run(Duration interval) {
        double secs = std::chrono::duration<double>(interval).count();
        for (size_t i = 0; i < endpoints_.size(); i++) {
            EndpointStats now = endpoints_[i]->total_stats();
            const EndpointStats& was = last_[i];
            std::string what;
            auto add = [&what](uint64_t delta, const char* label) {
                if (delta == 0)
                    return;
                if (!what.empty())
                    what += ", ";
                what += std::to_string(delta) + " " + label;
            };
            add(now.rx.crc_errors - was.rx.crc_errors, "CRC errors");
            add(now.rx.garbage_bytes - was.rx.garbage_bytes, "garbage bytes");
            add(now.rx.unknown_ids - was.rx.unknown_ids, "unknown message ids");
            add(now.rx.bad_flags - was.rx.bad_flags, "frames with unknown incompat flags");
            add(now.tx_dropped - was.tx_dropped, "frames dropped on transmit");
            add(now.tx_errors - was.tx_errors, "write errors");
            if (!what.empty())
                log_notice("[%s] %s in the last %.0fs", endpoints_[i]->name().c_str(), what.c_str(),
                           secs);
            last_[i] = now;
        }
    }

private:
    const std::vector<Endpoint::Ptr>& endpoints_;
    std::vector<EndpointStats> last_;
};

int run_daemon(const Options& opts) {
    auto config = load_config(opts.config_path);
    if (!config) {
        fprintf(stderr, "%s\n", config.error().message.c_str());
        return kExitConfig;
    }
    if (!opts.log_level.empty()) {
        auto level = parse_log_level(opts.log_level);
        if (!level) {
            fprintf(stderr, "mavbond: unknown log level '%s'\n", opts.log_level.c_str());
            return 64;
        }
        config->log_level = *level;
    }
    if (!opts.plugin_dir.empty())
        config->plugin_dir = opts.plugin_dir;
    if (config->plugin_dir.empty())
        config->plugin_dir = MAVBOND_PLUGIN_DIR;
    // --check-config answers with one line (or the error): no progress lines around it.
    log_set_level(opts.check_config ? LogLevel::Warning : config->log_level);

    auto loop = EventLoop::create();
    if (!loop) {
        log_error("%s", loop.error().message.c_str());
        return kExitOsError;
    }
    EventLoop& ev = *loop.value();
    // The chain comes before the endpoints (it hears of each one as it registers) and goes
    // after them. --check-config builds it too: plugin options are part of the config.
    Router router(config->route_timeout, config->bonds);
    auto chain = FilterChain::create(*config, config->plugin_dir, ev, router);
    if (!chain) {
        fprintf(stderr, "%s\n", chain.error().message.c_str());
        return kExitConfig;
    }
    router.set_filter(chain.value().get());
    if (opts.check_config) {
        printf("%s: OK (%zu endpoints, %zu bonds, %zu filters)\n", opts.config_path.c_str(),
               config->endpoints.size(), config->bonds.size(), chain.value()->size());
        return 0;
    }
    signal(SIGPIPE, SIG_IGN);  // a vanished TCP peer is an error code, not a death
    for (int sig : {SIGINT, SIGTERM}) {
        auto r = ev.on_signal(sig, [&ev](int signo) {
            log_notice("%s: stopping", strsignal(signo));
            ev.request_exit(0);
        });
        if (!r) {
            log_error("%s", r.error().message.c_str());
            return kExitOsError;
        }
    }

    auto endpoints = make_endpoints(*config, ev, router);
    if (!endpoints) {
        log_error("%s", endpoints.error().message.c_str());
        return kExitOsError;
    }
    auto dump_counters = [&] {
        for (const auto& e : *endpoints)
            log_notice("%s", counters_line(*e).c_str());
    };
    if (auto r = ev.on_signal(SIGUSR1, [&](int) { dump_counters(); }); !r) {
        log_error("%s", r.error().message.c_str());
        return kExitOsError;
    }
    TimePoint started = ev.now();
    std::unique_ptr<StatusSocket> status;
    if (!config->status_socket.empty()) {
        auto st = StatusSocket::open(config->status_socket, ev, [&] {
            return status_document(*endpoints, router, *chain.value(), started, ev.now());
        });
        // Telemetry matters more than the status: without its socket the daemon still routes.
        if (st)
            status = std::move(st.value());
        else
            log_warning("%s: mavbondctl cannot reach this daemon", st.error().message.c_str());
    }
    ProblemReport report(*endpoints);
    auto report_timer = ev.schedule(config->report_interval, [&] {
        report.run(config->report_interval);
        return config->report_interval;
    });
    auto route_timer = ev.schedule(seconds(1), [&] {
        router.expire_routes(ev.now());
        return Duration(seconds(1));
    });
    // Anything still queued (a backlog waiting for EPOLLOUT is flushed by its own watch).
    ev.add_round_hook([&router] { router.end_batch(); });

    log_notice("mavbond %s running with %zu endpoints from %s", MAVBOND_VERSION,
               endpoints->size(), opts.config_path.c_str());
    int code = ev.run();
    // From here endpoints go away because the daemon stops, not because links fail: the
    // filters must not take it for an outage (a link switch logged at every shutdown).
    router.set_filter(nullptr);
    // What is still queued goes out if the peers take it now, a frame half written on a
    // stream is completed (a peer never sees half a frame), the rest is counted as dropped:
    // the final counters account for every frame. Bounded: a stalled peer cannot hold the stop.
    TimePoint finish_by = Clock::now() + milliseconds(500);
    for (const auto& e : *endpoints)
        e->finish(finish_by);
    dump_counters();
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    log_notice("exit: routed %llu frames, %llu without a destination; peak RSS %ld KiB",
               (unsigned long long)router.frames_routed(),
               (unsigned long long)router.frames_without_destination(), ru.ru_maxrss);
    return code;
}

}  // namespace
}  // namespace mavbond

int main(int argc, char** argv) {
    mavbond::Options opts;
    int code = mavbond::parse_args(argc, argv, opts);
    if (code >= 0)
        return code;
    try {
        return mavbond::run_daemon(opts);
    } catch (const std::exception& e) {
        // Nothing on the data path throws; this is the last line of defence (e.g. bad_alloc).
        fprintf(stderr, "mavbond: fatal: %s\n", e.what());
        return mavbond::kExitSoftware;
    }
}
