// The running gateway: the config, the router, the filter chain, the endpoints and the
// daemon's own services (status socket, problem reports), on one event loop. SIGHUP reloads
// the config: what did not change keeps running, untouched.
#pragma once

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "config/config.h"
#include "core/event_loop.h"
#include "daemon/metrics_http.h"
#include "daemon/radio_report.h"
#include "daemon/status.h"
#include "daemon/status_socket.h"
#include "daemon/systemd_notify.h"
#include "endpoints/endpoint.h"
#include "routing/filter_chain.h"
#include "routing/identity.h"
#include "routing/link_events.h"
#include "routing/local_source.h"
#include "routing/router.h"
#include "routing/standby.h"

namespace mavbond {

constexpr int kExitSoftware = 70;  // EX_SOFTWARE
constexpr int kExitOsError = 71;   // EX_OSERR: a socket that cannot be bound, ...

/// What the command line says on top of the config file.
struct DaemonOptions {
    std::string config_path;
    std::string log_level;   // "" = the config's
    std::string plugin_dir;  // "" = the config's, else the compiled-in default
    bool check_config = false;  // only validate: warnings and errors, no progress lines
};

class Daemon {
public:
    /// A failure to start, with the exit code it means.
    struct StartError {
        int exit_code;
        std::string message;
    };

    /// Loads the config, applies the command line and validates everything, plugins included.
    /// Nothing is opened yet: --check-config stops here.
    static std::variant<std::unique_ptr<Daemon>, StartError> prepare(const DaemonOptions& opts,
                                                                    EventLoop& loop);
    ~Daemon();

    const Config& config() const { return *config_; }
    size_t filter_count() const { return chain_->size(); }
    /// The plugin files the filters were loaded from.
    std::vector<std::string> plugin_paths() const { return chain_->plugin_paths(); }

    /// Opens the endpoints and the daemon's services and installs the signal handlers.
    std::optional<StartError> start();
    /// Runs the loop until SIGINT/SIGTERM; returns the exit code.
    int run();
    /// SIGINT/SIGTERM: tells systemd (STOPPING=1) and ends the loop.
    void stop(int signo);

    /// Re-reads the config file and applies what changed (SIGHUP). A config that does not load,
    /// or whose filters cannot be created, is refused and the running one kept. Returns whether
    /// the new config was applied. systemd hears RELOADING=1 before and READY=1 after, either way.
    bool reload();

    /// What `systemctl status` shows (STATUS=): each bond's links up (heard within link
    /// events' silent_after, 3 s without link events) and its delivered loss as the stats
    /// filter counts it; the endpoints and frames routed.
    std::string service_status() const;

    /// Every endpoint's counters, the bonds, the router's totals and each filter's report,
    /// now: what the status socket, /metrics and the log lines show.
    Status status() const;

private:
    Daemon(const DaemonOptions& opts, EventLoop& loop, std::unique_ptr<Config> config);
    /// Loads the file and applies the command line's overrides.
    static Result<std::unique_ptr<Config>> load(const DaemonOptions& opts);
    /// Puts a filter chain on the router's path, in place of the one before it, and the bonds
    /// of `config` (their renumbering starts afresh with them).
    void install_filters(std::unique_ptr<FilterChain> chain, const Config& config);
    /// One log line per renumbering bond: what it did.
    void log_renumbering() const;
    // The steps of reload(), in order: the endpoints whose declaration changed stop (the
    // others are returned, running); the new config's endpoints start, kept ones in their
    // place (returns how many started, how many could not); the global settings apply.
    std::map<std::string, Endpoint::Ptr> stop_changed_endpoints(const Config& next);
    std::pair<size_t, size_t> start_endpoints(const Config& next,
                                              std::map<std::string, Endpoint::Ptr>& kept);
    bool apply_reload();
    /// Tells systemd, when it started the daemon (Type=notify), that it is ready, and feeds
    /// its watchdog from a timer on this loop.
    void start_systemd_notify();
    void apply_settings(std::unique_ptr<Config> next);
    /// mavbond's own frames (`identity:`) and the link events it tells the GCS through them.
    void start_local_source(bool identity_changed);
    /// Logs what the daemon derived for each bond and its identity, and why (account.h).
    void log_derived_settings() const;
    void open_status_socket();
    void open_metrics();
    void dump_counters() const;

    DaemonOptions opts_;
    EventLoop& loop_;
    std::unique_ptr<Config> config_;
    Router router_;
    std::unique_ptr<FilterChain> chain_;
    std::vector<Endpoint::Ptr> endpoints_;  // config order
    std::unique_ptr<LocalSource> local_source_;
    std::unique_ptr<OwnIdentity> identity_;          // remade with the local source's users
    std::unique_ptr<LinkEventMonitor> link_events_;  // remade on reload: it watches endpoints_
    std::unique_ptr<RadioStatusReporter> radio_report_;  // reads endpoints_ at each report
    std::unique_ptr<StandbyMonitor> standby_;        // remade with it: reports of the bonds
    std::unique_ptr<StatusSocket> status_;
    std::unique_ptr<MetricsHttpServer> metrics_;
    ProblemReport report_;
    EventLoop::Timer report_timer_;
    EventLoop::Timer route_timer_;
    std::unique_ptr<SystemdNotify> systemd_;  // nullptr: not started by systemd
    EventLoop::Timer watchdog_timer_;
    EventLoop::Timer service_status_timer_;
    std::string service_status_sent_;
    TimePoint started_{};
};

}  // namespace mavbond
