// mavbond: the daemon's command line. The gateway itself is Daemon (daemon.h).
#include <getopt.h>

#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "core/event_loop.h"
#include "core/log.h"
#include "core/plural.h"
#include "daemon/daemon.h"
#include "daemon/import_mavlink_router.h"
#include "mavbond_build_config.h"

namespace mavbond {
namespace {

struct Options {
    std::string config_path = MAVBOND_DEFAULT_CONFIG;
    std::string log_level;
    std::string plugin_dir;
    bool check_config = false;
    std::string import_path;  // --import-mavlink-router
};

void print_usage(FILE* out) {
    fprintf(out,
            "Usage: mavbond [-c FILE] [--check-config] [--log-level LEVEL] [--plugin-dir DIR]\n"
            "               [--version] [--help]\n"
            "       mavbond --import-mavlink-router FILE\n"
            "MAVLink gateway that bonds redundant telemetry links into one.\n\n"
            "  -c, --config FILE     configuration file (default %s)\n"
            "      --check-config    validate the configuration and exit (78 when invalid)\n"
            "  -l, --log-level LEVEL error, warning, notice, info, debug or trace\n"
            "      --plugin-dir DIR  where filter plugins are loaded from\n"
            "      --import-mavlink-router FILE\n"
            "                        print mavlink-router's config FILE as mavbond YAML (65 when\n"
            "                        FILE is malformed)\n"
            "  -V, --version         print the version and exit\n"
            "  -h, --help            print this help and exit\n\n"
            "Signals: SIGINT/SIGTERM stop, SIGHUP reloads the configuration, SIGUSR1 logs every\n"
            "endpoint's counters.\n",
            MAVBOND_DEFAULT_CONFIG);
}

/// Returns an exit code when the command line says to stop now, or -1 to go on.
int parse_args(int argc, char** argv, Options& opts) {
    enum { kCheckConfig = 1000, kPluginDir, kImport };
    static const option long_opts[] = {
        {"config", required_argument, nullptr, 'c'},
        {"check-config", no_argument, nullptr, kCheckConfig},
        {"log-level", required_argument, nullptr, 'l'},
        {"plugin-dir", required_argument, nullptr, kPluginDir},
        {"import-mavlink-router", required_argument, nullptr, kImport},
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
        case kImport: opts.import_path = optarg; break;
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

/// --import-mavlink-router: the YAML on stdout, what was not translated on stderr.
int import_config(const std::string& path) {
    auto text = read_text_file(path);
    if (!text) {
        fprintf(stderr, "mavbond: %s\n", text.error().message.c_str());
        return 66;  // EX_NOINPUT
    }
    auto imported = import_mavlink_router(text.value(), path);
    if (!imported) {
        fprintf(stderr, "%s\n", imported.error().message.c_str());
        return kExitDataError;
    }
    for (const auto& w : imported->warnings)
        fprintf(stderr, "mavbond: warning: %s\n", w.c_str());
    fputs(imported->yaml.c_str(), stdout);
    return 0;
}

int run_daemon(const Options& opts) {
    auto loop = EventLoop::create();
    if (!loop) {
        fprintf(stderr, "mavbond: %s\n", loop.error().message.c_str());
        return kExitOsError;
    }
    auto prepared = Daemon::prepare(
        {opts.config_path, opts.log_level, opts.plugin_dir, opts.check_config}, *loop.value());
    if (auto* err = std::get_if<Daemon::StartError>(&prepared)) {
        fprintf(stderr, "%s\n", err->message.c_str());
        return err->exit_code;
    }
    Daemon& daemon = *std::get<std::unique_ptr<Daemon>>(prepared);
    if (opts.check_config) {
        // What of the plugins ran: their files were read, not run, before they were loaded;
        // checking their options takes their own code (create), as a start does.
        for (const std::string& path : daemon.plugin_paths())
            printf("%s: checked as a file (owner, mode, machine, ABI, name), then loaded to check "
                   "its options\n", path.c_str());
        printf("%s: OK (%s, %s, %s)\n", opts.config_path.c_str(),
               plural(daemon.config().endpoints.size(), "endpoint").c_str(),
               plural(daemon.config().bonds.size(), "bond").c_str(),
               plural(daemon.filter_count(), "filter").c_str());
        return 0;
    }
    if (auto err = daemon.start()) {
        log_error("%s", err->message.c_str());
        return err->exit_code;
    }
    return daemon.run();
}

}  // namespace
}  // namespace mavbond

int main(int argc, char** argv) {
    mavbond::Options opts;
    int code = mavbond::parse_args(argc, argv, opts);
    if (code >= 0)
        return code;
    try {
        if (!opts.import_path.empty())
            return mavbond::import_config(opts.import_path);
        return mavbond::run_daemon(opts);
    } catch (const std::exception& e) {
        // Nothing on the data path throws; this is the last line of defence (e.g. bad_alloc).
        fprintf(stderr, "mavbond: fatal: %s\n", e.what());
        return mavbond::kExitSoftware;
    }
}
