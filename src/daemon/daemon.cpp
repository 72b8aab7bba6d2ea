#include "daemon/daemon.h"

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <tuple>

#include "core/log.h"
#include "core/plural.h"
#include "mavbond_build_config.h"
#include "daemon/account.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {
namespace {

// How long an endpoint that stops may wait for its peer to take a frame it half wrote: at
// exit, and (shorter: the loop keeps routing) when a reload removes or changes it.
constexpr Duration kExitFinishBound = milliseconds(500);
constexpr Duration kReloadFinishBound = milliseconds(50);
// systemd's STATUS= line: refreshed this often (sent only when it changed); a link is up if
// heard within this, when link events (which say it otherwise) are off.
constexpr Duration kServiceStatusPeriod = seconds(5);
constexpr Duration kUpWithoutLinkEvents = seconds(3);

/// Each bonded endpoint's (name, bond, standby), in config order: the filters number a bond's
/// links by this order, so a change in it restarts them; a bond is rebuilt with them, so a
/// change in a member's cost or standby classes (or in the classes) rebuilds it too.
std::vector<std::tuple<std::string, std::string, bool, uint8_t>> bond_members(const Config& c) {
    std::vector<std::tuple<std::string, std::string, bool, uint8_t>> out;
    for (const auto& ep : c.endpoints) {
        if (!ep.bond.empty())
            out.emplace_back(ep.name, ep.bond, ep.metered, ep.standby_classes);
    }
    return out;
}

/// Whether the filters must restart: anything they depend on changed (their entries, the
/// bonds, the order of the bonds' links, the plugin directory).
bool filters_must_restart(const Config& old, const Config& next) {
    return !same_settings(old.bonds, next.bonds) || !same_settings(old.filters, next.filters) ||
           bond_members(old) != bond_members(next) || old.plugin_dir != next.plugin_dir ||
           !(old.tx_classes == next.tx_classes);
}

/// This process's peak resident set (VmHWM), in KiB; -1 when /proc does not say. Not
/// ru_maxrss: Linux carries that over from the parent across exec, so a daemon started from a
/// big process would report the parent's peak.
long peak_rss_kib() {
    FILE* f = fopen("/proc/self/status", "r");
    if (!f)
        return -1;
    char line[256];
    long kib = -1;
    while (fgets(line, sizeof line, f)) {
        if (sscanf(line, "VmHWM: %ld kB", &kib) == 1)
            break;
    }
    fclose(f);
    return kib;
}

const EndpointConfig* find_endpoint(const Config& c, const std::string& name) {
    for (const auto& ep : c.endpoints) {
        if (ep.name == name)
            return &ep;
    }
    return nullptr;
}

/// Whether a listener's host takes only this machine's connections: 127.0.0.0/8 or ::1 (a
/// name, even "localhost" spelled otherwise, may resolve anywhere).
bool loopback_host(const std::string& host) {
    return host.rfind("127.", 0) == 0 || host == "::1";
}

/// A listener anyone on a network can reach, with nothing to tell their frames from the
/// vehicle's or the GCS's: said once, with what to do.
void warn_if_open(const EndpointConfig& ep) {
    if (!ep.schema || !ep.schema->mode || std::string_view(ep.schema->mode) != "server" ||
        !ep.options.has("address"))
        return;
    const std::string& host = ep.options.text("address");
    if (loopback_host(host) || (ep.signing.enabled && ep.signing.require))
        return;
    std::string where = host.find(':') != std::string::npos ? "[" + host + "]" : host;
    log_warning("endpoint '%s' listens on %s:%u without signing: whoever can reach it can send "
                "the vehicle commands; listen on 127.0.0.1 when only this machine connects, or "
                "sign it (a bond's links: bonds: signing:; man mavbond.yaml, SIGNING)",
                ep.name.c_str(), where.c_str(), static_cast<unsigned>(ep.options.port("address")));
}

}  // namespace

Daemon::Daemon(const DaemonOptions& opts, EventLoop& loop, std::unique_ptr<Config> config)
    : opts_(opts), loop_(loop), config_(std::move(config)),
      router_(loop, config_->route_timeout) {}

Daemon::~Daemon() {
    link_events_.reset();
    identity_.reset();
    radio_report_.reset();
    standby_.reset();
    // Endpoints go away because the daemon stops, not because links fail: the filters must
    // not take it for an outage (a link switch logged at every shutdown).
    router_.set_filter(nullptr);
    endpoints_.clear();
}

Result<std::unique_ptr<Config>> Daemon::load(const DaemonOptions& opts) {
    auto config = load_config(opts.config_path, endpoint_schemas());
    if (!config)
        return config.error();
    auto c = std::make_unique<Config>(std::move(config.value()));
    if (!opts.log_level.empty())
        c->log_level = *parse_log_level(opts.log_level);  // checked in prepare()
    if (!opts.plugin_dir.empty())
        c->plugin_dir = opts.plugin_dir;
    if (c->plugin_dir.empty())
        c->plugin_dir = MAVBOND_PLUGIN_DIR;
    return c;
}

std::variant<std::unique_ptr<Daemon>, Daemon::StartError> Daemon::prepare(
    const DaemonOptions& opts, EventLoop& loop) {
    if (!opts.log_level.empty() && !parse_log_level(opts.log_level))
        return StartError{64, "mavbond: unknown log level '" + opts.log_level + "'"};
    auto config = load(opts);
    if (!config)
        return StartError{kExitConfig, config.error().message};
    std::unique_ptr<Daemon> d(new Daemon(opts, loop, std::move(config.value())));
    log_set_level(opts.check_config ? LogLevel::Warning : d->config_->log_level);
    for (const EndpointConfig& ep : d->config_->endpoints)
        warn_if_open(ep);
    // The chain comes before the endpoints (it hears of each one as it registers) and goes
    // after them. --check-config builds it too: plugin options are part of the config.
    auto chain = FilterChain::create(*d->config_, d->config_->plugin_dir, loop, d->router_);
    if (!chain)
        return StartError{kExitConfig, chain.error().message};
    d->install_filters(std::move(chain.value()), *d->config_);
    return d;
}

void Daemon::start_local_source(bool identity_changed) {
    link_events_.reset();
    standby_.reset();
    identity_.reset();
    if (identity_changed || !local_source_)
        local_source_ = std::make_unique<LocalSource>(config_->identity, loop_, router_);
    identity_ = std::make_unique<OwnIdentity>(config_->identity, router_, loop_, *local_source_,
                                              [this](uint8_t sysid, uint8_t compid) {
                                                  for (const auto& e : endpoints_)
                                                      e->set_marker_source(sysid, compid);
                                              });
    standby_ = std::make_unique<StandbyMonitor>(router_, loop_, *local_source_);
    if (config_->link_events.enabled)
        link_events_ = std::make_unique<LinkEventMonitor>(config_->link_events, router_, loop_,
                                                          *local_source_);
}

std::optional<Daemon::StartError> Daemon::start() {
    signal(SIGPIPE, SIG_IGN);  // a vanished TCP peer is an error code, not a death
    auto signals = {
        std::pair<int, EventLoop::SignalHandler>{SIGINT, [this](int signo) { stop(signo); }},
        {SIGTERM, [this](int signo) { stop(signo); }},
        {SIGHUP, [this](int) { reload(); }},
        {SIGUSR1, [this](int) { dump_counters(); }},
    };
    for (const auto& [sig, handler] : signals) {
        if (auto r = loop_.on_signal(sig, handler); !r)
            return StartError{kExitOsError, r.error().message};
    }
    // Another daemon with this status socket is most likely this one started twice: it would
    // share its ports too. Refused before anything is opened.
    if (!config_->status_socket.empty()) {
        if (auto pid = StatusSocket::answered_by(config_->status_socket))
            return StartError{kExitOsError, StatusSocket::in_use_message(config_->status_socket, *pid)};
    }
    auto endpoints = make_endpoints(*config_, loop_, router_);
    if (!endpoints)
        return StartError{kExitOsError, endpoints.error().message};
    endpoints_ = std::move(endpoints.value());
    started_ = loop_.now();
    start_local_source(true);
    radio_report_ = std::make_unique<RadioStatusReporter>(loop_, router_, endpoints_);
    open_status_socket();
    open_metrics();
    // The timers read the current config each time, so a reload changes their periods.
    report_timer_ = loop_.schedule(config_->report_interval, [this] {
        report_.run(status(), config_->report_interval);
        return config_->report_interval;
    });
    route_timer_ = loop_.schedule(seconds(1), [this] {
        router_.expire_routes(loop_.now());
        return Duration(seconds(1));
    });
    // The frames of a round that waited for earlier arrivals, before the timers see the time.
    loop_.add_after_io_hook([this] { router_.merge_round(); });
    // Anything still queued (a backlog waiting for EPOLLOUT is flushed by its own watch).
    loop_.add_round_hook([this] { router_.end_batch(); });
    log_notice("mavbond %s running with %s from %s", MAVBOND_VERSION,
               plural(endpoints_.size(), "endpoint").c_str(), opts_.config_path.c_str());
    log_derived_settings();
    start_systemd_notify();
    return std::nullopt;
}

void Daemon::stop(int signo) {
    log_notice("%s: stopping", strsignal(signo));
    if (systemd_)
        systemd_->stopping();
    loop_.request_exit(0);
}

void Daemon::start_systemd_notify() {
    auto notify = SystemdNotify::from_environment();
    if (!notify) {
        log_error("%s: systemd will not hear that mavbond is ready", notify.error().message.c_str());
        return;
    }
    systemd_ = std::move(notify.value());
    if (!systemd_)
        return;
    // Every endpoint is open (a device that is missing is retried: that is its state).
    service_status_sent_ = service_status();
    systemd_->ready(service_status_sent_);
    // On the loop itself: a loop that hangs, or a daemon frozen, stops feeding it.
    if (const Duration period = systemd_->watchdog_period(); period > Duration::zero()) {
        watchdog_timer_ = loop_.schedule(period, [this, period] {
            systemd_->watchdog();
            return period;
        });
        log_info("systemd watchdog: fed every %s", format_duration(period).c_str());
    }
    service_status_timer_ = loop_.schedule(kServiceStatusPeriod, [this] {
        if (std::string line = service_status(); line != service_status_sent_) {
            systemd_->status(line);
            service_status_sent_ = std::move(line);
        }
        return kServiceStatusPeriod;
    });
}

std::string Daemon::service_status() const {
    const Status s = status();
    // Up: heard within link events' silence, or within 3 s when they are off.
    const Duration window = config_->link_events.enabled ? config_->link_events.silent_after
                                                         : kUpWithoutLinkEvents;
    std::string line;
    for (const Status::Bond& bond : s.bonds) {
        unsigned members = 0, up = 0;
        for (const Status::Endpoint& e : s.endpoints) {
            if (e.bond != bond.name)
                continue;
            members++;
            const TimePoint last = e.counters.last_rx;
            up += last != TimePoint{} && s.taken - last <= window ? 1 : 0;
        }
        line += (line.empty() ? "" : "; ") + std::string("bond ") + bond.name + ": " +
                std::to_string(up) + " of " + std::to_string(members) +
                (members == 1 ? " link up" : " links up");
        // The stats filter's own figure, as /metrics serves it.
        const std::pair<std::string, std::string> label("bond", bond.name);
        for (const FilterReport& f : s.filters) {
            for (const MetricSample& m : f.samples) {
                if (m.name == "mavbond_stats_bond_delivered_loss_ratio" &&
                    std::find(m.labels.begin(), m.labels.end(), label) != m.labels.end()) {
                    char loss[48];
                    snprintf(loss, sizeof loss, ", delivered loss %.2f%%", m.value * 100);
                    line += loss;
                }
            }
        }
    }
    return line + (line.empty() ? "" : "; ") + plural(s.endpoints.size(), "endpoint") + ", " +
           plural(s.frames_routed, "frame") + " routed";
}

int Daemon::run() {
    int code = loop_.run();
    router_.set_filter(nullptr);  // see ~Daemon
    // What is still queued goes out if the peers take it now, a frame half written on a
    // stream is completed, the rest is counted as dropped: the final counters account for
    // every frame. Bounded: a stalled peer cannot hold the stop (its stream ends cut, logged).
    TimePoint finish_by = Clock::now() + kExitFinishBound;
    for (const auto& e : endpoints_)
        e->finish(finish_by);
    dump_counters();
    log_renumbering();
    log_notice("exit: routed %s, %llu without a destination, %llu held back for arrival "
               "order; peak RSS %ld KiB",
               plural(router_.frames_routed(), "frame").c_str(),
               (unsigned long long)router_.frames_without_destination(),
               (unsigned long long)router_.frames_held_back(), peak_rss_kib());
    return code;
}

void Daemon::open_status_socket() {
    status_.reset();
    if (config_->status_socket.empty())
        return;
    auto st = StatusSocket::open(config_->status_socket, loop_,
                                 [this] { return status_json(status()); });
    // Telemetry matters more than the status: without its socket the daemon still routes.
    if (st)
        status_ = std::move(st.value());
    else
        log_warning("%s: mavbondctl cannot reach this daemon", st.error().message.c_str());
}

void Daemon::open_metrics() {
    metrics_.reset();
    if (!config_->metrics.enabled)
        return;
    const MetricsConfig& mc = config_->metrics;
    auto m = MetricsHttpServer::open(mc.host, mc.port, {8192, mc.max_connections, mc.timeout},
                                     loop_, [this] { return status_metrics(status()); });
    // As with the status socket: without its metrics the daemon still routes.
    if (m)
        metrics_ = std::move(m.value());
    else
        log_warning("%s: Prometheus cannot scrape this daemon", m.error().message.c_str());
}

void Daemon::dump_counters() const {
    for (const Status::Endpoint& e : status().endpoints)
        log_notice("%s", counters_line(e).c_str());
}

bool Daemon::reload() {
    if (systemd_)
        systemd_->reloading();
    const bool applied = apply_reload();
    if (systemd_) {
        service_status_sent_ = service_status();
        systemd_->ready(service_status_sent_);
    }
    return applied;
}

bool Daemon::apply_reload() {
    log_notice("SIGHUP: reloading %s", opts_.config_path.c_str());
    auto loaded = load(opts_);
    if (!loaded) {
        log_error("reload refused, the running configuration stays: %s",
                  loaded.error().message.c_str());
        return false;
    }
    std::unique_ptr<Config> next = std::move(loaded.value());

    // The new chain is built before anything is touched, so a plugin that will not load
    // refuses the whole reload.
    const bool filters_restart = filters_must_restart(*config_, *next);
    std::unique_ptr<FilterChain> next_chain;
    if (filters_restart) {
        auto chain = FilterChain::create(*next, next->plugin_dir, loop_, router_);
        if (!chain) {
            log_error("reload refused, the running configuration stays: %s",
                      chain.error().message.c_str());
            return false;
        }
        next_chain = std::move(chain.value());
    }

    link_events_.reset();  // it watches the endpoints about to change
    // The frames this round read are lent from the endpoints' buffers: routed before any of
    // them stops.
    router_.merge_round(true);
    const size_t running = endpoints_.size();
    std::map<std::string, Endpoint::Ptr> kept = stop_changed_endpoints(*next);
    const size_t kept_count = kept.size();
    if (next_chain)
        install_filters(std::move(next_chain), *next);  // hears of every link kept
    router_.set_route_timeout(next->route_timeout);
    const auto [started, failed] = start_endpoints(*next, kept);
    apply_settings(std::move(next));
    log_notice("reloaded: %s kept, %zu stopped, %zu started%s; filters %s",
               plural(kept_count, "endpoint").c_str(), running - kept_count, started,
               failed ? (", " + std::to_string(failed) + " failed").c_str() : "",
               filters_restart ? "restarted" : "kept");
    log_derived_settings();
    return true;
}

void Daemon::log_derived_settings() const {
    // One block, so the account reads as one: its lines follow the header at once.
    log_notice("derived settings (what mavbond chose where settings depend on each other, and "
               "what may make it wrong):");
    for (const std::string& line : derived_settings(*config_, router_, *chain_))
        log_notice("  %s", line.c_str());
}

void Daemon::install_filters(std::unique_ptr<FilterChain> chain, const Config& config) {
    router_.set_filter(nullptr);
    log_renumbering();
    chain_ = std::move(chain);
    router_.replace_bonds(config);
    for (const BondConfig& b : config.bonds)
        router_.bond(router_.bond_index(b.name)).set_renumbering(chain_->renumbers(b));
    router_.mark_radio_status_bonds(config);
    router_.set_filter(chain_.get());
}

void Daemon::log_renumbering() const {
    for (const Bond& bond : router_.bonds()) {
        std::string line;
        for (const auto& [name, value] : bond.renumber_counters())
            line += std::string(" ") + name + "=" + std::to_string(value);
        if (!line.empty())
            log_notice("renumber bond=%s%s", bond.name().c_str(), line.c_str());
    }
}

std::map<std::string, Endpoint::Ptr> Daemon::stop_changed_endpoints(const Config& next) {
    // An endpoint keeps running when its declaration means the same as before. One that
    // stops writes its queue if its peer takes it at once (a frame half written on a stream
    // is completed, within a bound), the rest is counted as dropped, and its last counters
    // are logged: no frame leaves unaccounted.
    const TimePoint finish_by = Clock::now() + kReloadFinishBound;
    std::map<std::string, Endpoint::Ptr> kept;
    for (auto& e : endpoints_) {
        const EndpointConfig* now = find_endpoint(next, e->config().name);
        const bool same_policy = config_->unknown_messages == next.unknown_messages;
        if (now && same_policy && same_but_budget(*now, e->config())) {
            if (!(now->tx_budget == e->config().tx_budget)) {
                // A budget changes in place: a restart would reopen a UART.
                e->retune(now->tx_budget);
                std::string rate = e->budget()
                                       ? std::to_string(e->budget()->bytes_per_s()) + " B/s"
                                       : "none";
                log_notice("reload: [%s] transmit budget now %s", e->name().c_str(), rate.c_str());
            }
            kept[e->config().name] = std::move(e);
            continue;
        }
        e->finish(finish_by);
        log_notice("reload: %s",
                   counters_line(endpoint_status(*e, loop_.now(), config_->link_events.silent_after),
                                 "stopped")
                       .c_str());
        report_.forget(e->name());
        e.reset();  // closes its sockets before a replacement binds the same address
    }
    endpoints_.clear();
    return kept;
}

std::pair<size_t, size_t> Daemon::start_endpoints(const Config& next,
                                                  std::map<std::string, Endpoint::Ptr>& kept) {
    size_t started = 0, failed = 0;
    for (const auto& ep : next.endpoints) {
        if (auto k = kept.find(ep.name); k != kept.end()) {
            endpoints_.push_back(std::move(k->second));
            continue;
        }
        warn_if_open(ep);
        auto e = make_endpoint(ep, next, loop_, router_);
        if (!e) {
            // The rest of the new config stands; this endpoint is reported and left out.
            log_error("reload: endpoint '%s': %s", ep.name.c_str(), e.error().message.c_str());
            failed++;
            continue;
        }
        endpoints_.push_back(std::move(e.value()));
        started++;
    }
    return {started, failed};
}

void Daemon::apply_settings(std::unique_ptr<Config> next) {
    const bool status_moved = config_->status_socket != next->status_socket;
    const bool metrics_moved = !(config_->metrics == next->metrics);
    const bool identity_changed = !(config_->identity == next->identity);
    config_ = std::move(next);
    router_.mark_radio_status_bonds(*config_);
    log_set_level(config_->log_level);
    start_local_source(identity_changed);
    // Markers from the identity as it is (a derived one kept across the reload), new
    // endpoints' too.
    for (const auto& e : endpoints_)
        e->set_marker_source(local_source_->sysid(), local_source_->compid());
    if (status_moved)
        open_status_socket();
    if (metrics_moved)
        open_metrics();
}

Status Daemon::status() const {
    Status s;
    s.taken = loop_.now();
    s.uptime = s.taken - started_;
    s.status_refused = status_ ? status_->refused() : 0;
    s.stalls = loop_.stalls();
    for (const auto& e : endpoints_)
        s.endpoints.push_back(endpoint_status(*e, s.taken, config_->link_events.silent_after));
    for (uint32_t b = 0; b < router_.bonds().size(); b++) {
        const Bond& bond = router_.bonds()[b];
        Status::Bond& out = s.bonds.emplace_back();
        out.name = bond.name();
        out.tx_active = bond.tx_active();
        const Link* active = router_.link(bond.active_link());
        out.active = active ? active->name() : "";
        out.switches = bond.switches();
        for (LinkId id = 0; id < router_.link_id_bound(); id++) {
            const Link* link = router_.link(id);
            if (!link || router_.bond_of(*link) != b)
                continue;
            // By endpoint: a server's peers are one member (no address in a metric label).
            auto it = std::find_if(out.links.begin(), out.links.end(), [&](const Status::BondLink& l) {
                return l.name == link->endpoint_name();
            });
            if (it == out.links.end())
                it = out.links.insert(out.links.end(), {link->endpoint_name(), false});
            it->active = it->active || id == bond.active_link();
        }
        out.renumber = bond.renumber_counters();
        out.numbering = bond.numbering()->counters();
        out.reports_radio_status = bond.reports_radio_status;
        out.foreign_radio_status = bond.foreign_radio_status;
        if (const auto* r = radio_report_ ? radio_report_->find(bond.name()) : nullptr) {
            out.radio_status_sent = r->sent;
            out.radio_status_last = r->last;
        }
        if (const auto& signing = bond.signing()) {
            out.signed_links = bond.signed_links();
            out.signing = signing->counters();
        }
        if (const Standby* standby = bond.standby()) {
            out.has_standby = true;
            out.standby_active = standby->active();
            out.standby = standby->counters();
            for (const Standby::PeerLink& l : standby->peer_links())
                out.peer_loss.emplace_back(l.name, l.permille);
            for (LinkId id = 0; id < router_.link_id_bound(); id++) {
                const Link* link = router_.link(id);
                if (link && router_.bond_of(*link) == b && router_.member_of(*link) != Bond::kNoMember &&
                    standby->metered(router_.member_of(*link)))
                    out.metered_tx_bytes += link->counters().tx_bytes;
            }
        }
    }
    s.frames_routed = router_.frames_routed();
    s.frames_without_destination = router_.frames_without_destination();
    s.frames_held_back = router_.frames_held_back();
    s.standby_reports_dropped = router_.standby_reports_dropped();
    s.filters = chain_->report();
    return s;
}

}  // namespace mavbond
