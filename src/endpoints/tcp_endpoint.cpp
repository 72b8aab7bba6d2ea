#include "endpoints/tcp_endpoint.h"

#include <netinet/tcp.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>

#include "core/log.h"
#include "endpoints/net.h"

namespace mavbond {
namespace {

constexpr EndpointOption kTcpServerOptions[] = {
    {"address", OptionKind::Address, nullptr,
     "Where to listen (0.0.0.0:5760; [::]:5760 for IPv6 and IPv4). 32 clients at most.", true},
    {"max_clients_per_address", OptionKind::Count, "8",
     "Clients from one address at most; one more is refused (counted as clients_refused, "
     "logged once per report_interval), as is one past 32 in all."},
    {"idle_timeout", OptionKind::Time, "30s",
     "A client that brings no valid frame this long (its CRC checked; with signing, its "
     "signature verified) is closed (clients_idle_closed): a connection held open without "
     "MAVLink keeps no place. A ground station's HEARTBEAT keeps it; a client that only "
     "reads (a logger sending nothing) is closed too, and reconnects: raise it for one."},
};

constexpr EndpointOption kTcpClientOptions[] = {
    {"address", OptionKind::Address, nullptr,
     "Where to connect (127.0.0.1:5760, [2001:db8::5]:5760, lte.example.net:5760). A host name "
     "is looked up off the event loop before each connect that follows a failure, and every "
     "resolve_interval (a connection that works is kept).", true},
    kReconnectMin,
    kReconnectMax,
    kResolveInterval,
};

void set_nodelay(int fd) {
    // Telemetry is latency-bound; frames are coalesced by the transmit queue already.
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
}

}  // namespace

const EndpointSchema kTcpServerType = {"tcp", "server",
                                       "A TCP listener; each client it accepts is a link of its "
                                       "own.",
                                       kTcpServerOptions, true, nullptr, true};
const EndpointSchema kTcpClientType = {"tcp", "client",
                                       "A TCP connection, made again with backoff when it "
                                       "cannot be made or is lost.",
                                       kTcpClientOptions, true, reconnect_bounds};

// --- TcpConnection -------------------------------------------------------------------------

TcpConnection::TcpConnection(TcpServer& server, const SocketAddress& peer, TimePoint now)
    : StreamEndpoint(server.config(), server.name() + "@" + to_string(peer), server.loop(),
                     server.sink_, server.policy_, &server),
      server_(server), peer_(peer), connected_at_(now) {}

TcpConnection::~TcpConnection() { sink_.detach(*this); }

void TcpConnection::on_disconnect(const std::string& reason) {
    if (server_.client_log_.allow(loop_.now()))
        log_info("[tcp:%s] client %s gone: %s%s", server_.name().c_str(), name().c_str(),
                 reason.c_str(), server_.client_log_.left_out_note().c_str());
    server_.drop_client(*this);
}

void TcpConnection::close(const std::string& reason) {
    stop_stream();
    on_disconnect(reason);
}

// --- TcpServer -----------------------------------------------------------------------------

Result<std::unique_ptr<TcpServer>> TcpServer::open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy) {
    auto bound = bind_socket(SOCK_STREAM, config.options.text("address"),
                             config.options.port("address"));
    if (!bound)
        return bound.error();
    if (listen(bound->fd.get(), 16) < 0)
        return make_error("cannot listen on " + to_string(bound->addr) + ": " + errno_text(errno));
    std::unique_ptr<TcpServer> server(
        new TcpServer(config, loop, sink, policy, std::move(bound->fd)));
    auto w = loop.watch(server->fd_.get(), EPOLLIN, [s = server.get()](uint32_t) { s->on_accept(); });
    if (!w)
        return w.error();
    server->watch_ = std::move(w.value());
    Duration idle = config.options.duration("idle_timeout");
    auto period = std::clamp<Duration>(idle / 4, milliseconds(100), seconds(5));
    server->idle_timer_ = loop.schedule(period, [s = server.get(), period] {
        s->close_idle_clients();
        return period;
    });
    log_info("[tcp:%s] listening on %s", config.name.c_str(), to_string(bound->addr).c_str());
    return server;
}

TcpServer::TcpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                     UnknownIdPolicy policy, UniqueFd fd)
    : Endpoint(config, config.name, loop, TxQueue::Mode::Stream), sink_(sink),
      policy_(policy), fd_(std::move(fd)) {}

TcpServer::~TcpServer() = default;

LinkCounters TcpServer::total_counters() const {
    LinkCounters total = stats_;
    total += retired_;
    for (const auto& c : clients_)
        total += c->counters();
    return total;
}

void TcpServer::set_marker_source(uint8_t sysid, uint8_t compid) {
    Endpoint::set_marker_source(sysid, compid);
    for (auto& c : clients_)
        c->set_marker_source(sysid, compid);
}

void TcpServer::retune(const TxBudgetConfig& budget) {
    Endpoint::retune(budget);
    for (auto& c : clients_)
        c->retune(budget);
}

void TcpServer::finish(TimePoint deadline) {
    for (auto& c : clients_)
        c->finish(deadline);
}

void TcpServer::on_accept() {
    for (;;) {
        SocketAddress peer;
        socklen_t len = SocketAddress::capacity();
        UniqueFd fd(accept4(fd_.get(), peer.buffer(), &len, SOCK_NONBLOCK | SOCK_CLOEXEC));
        peer.set_size(len);
        if (!fd) {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)
                log_warning("[tcp:%s] accept: %s", name().c_str(), errno_text(errno).c_str());
            return;
        }
        // Refused (the fd closes here) past a cap: counted, and said once per report_interval
        // with the count (a flood of connections must not flood the log).
        const size_t per_address = config().options.number("max_clients_per_address");
        if (clients_.size() >= kMaxClients ||
            static_cast<size_t>(std::count_if(clients_.begin(), clients_.end(), [&](const auto& c) {
                return same_host(c->peer(), peer);
            })) >= per_address) {
            stats_.clients_refused++;
            continue;
        }
        set_nodelay(fd.get());
        auto client = std::make_unique<TcpConnection>(*this, peer, loop_.now());
        if (auto r = client->start(std::move(fd)); !r) {
            log_warning("[tcp:%s] %s", name().c_str(), r.error().message.c_str());
            continue;
        }
        sink_.attach(*client);
        if (client_log_.allow(loop_.now()))
            log_info("[tcp:%s] client %s connected%s", name().c_str(), to_string(peer).c_str(),
                     client_log_.left_out_note().c_str());
        clients_.push_back(std::move(client));
    }
}

void TcpServer::close_idle_clients() {
    const TimePoint now = loop_.now();
    const Duration idle = config().options.duration("idle_timeout");
    for (auto& c : clients_) {
        if (!c->ready())
            continue;  // closing already
        TimePoint since = std::max(c->connected_at(), c->last_valid());
        if (now - since <= idle)
            continue;
        stats_.clients_idle_closed++;
        char why[64];
        snprintf(why, sizeof why, "no valid frame for %.1fs",
                 std::chrono::duration<double>(now - since).count());
        c->close(why);
    }
}

void TcpServer::drop_client(TcpConnection& client) {
    sink_.detach(client);
    defer(loop_, [this, target = &client] {
        auto it = std::find_if(clients_.begin(), clients_.end(),
                               [target](const auto& c) { return c.get() == target; });
        if (it != clients_.end()) {
            retired_ += (*it)->counters();
            clients_.erase(it);
        }
    });
}

// --- TcpClient -----------------------------------------------------------------------------

Result<std::unique_ptr<TcpClient>> TcpClient::open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy) {
    const EndpointOptions& o = config.options;
    const std::string& host = o.text("address");
    uint16_t port = o.port("address");
    bool literal = is_numeric_host(host);
    std::unique_ptr<TcpClient> client(new TcpClient(
        config, loop, sink, policy, literal ? SocketAddress::numeric(host, port) : SocketAddress()));
    sink.attach(*client);
    if (literal) {
        client->connect_now();
        return client;
    }
    // A name: looked up off the loop, first, after each failure and every resolve_interval;
    // it connects once the first lookup gives an address.
    client->resolver_ = std::make_unique<NameResolver>(
        loop, host, port, SOCK_STREAM,
        [c = client.get()](Result<SocketAddress> r) { c->on_resolved(std::move(r)); });
    if (auto r = client->resolver_->start_every(o.duration("resolve_interval")); !r)
        return r.error();
    return client;
}

TcpClient::TcpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                     UnknownIdPolicy policy, const SocketAddress& addr)
    : StreamEndpoint(config, config.name, loop, sink, policy), addr_(addr),
      backoff_(reconnect_backoff(config)) {}

TcpClient::~TcpClient() { sink_.detach(*this); }

void TcpClient::on_resolved(Result<SocketAddress> result) {
    const std::string& host = resolver_->host();
    bool first = addr_.empty();
    if (!result) {
        stats_.resolve_failures++;
        if (!resolve_failing_logged_)
            log_warning("[tcp:%s] %s%s", name().c_str(), result.error().message.c_str(),
                        first ? "; retrying with backoff" : "; connecting to the last address");
        resolve_failing_logged_ = true;
        // Not resolved yet: the retry looks it up again (retry_later starts a lookup).
        if (first && !retry_timer_.active())
            retry_later(result.error().message);
        return;
    }
    if (resolve_failing_logged_)
        log_notice("[tcp:%s] %s resolves again", name().c_str(), host.c_str());
    resolve_failing_logged_ = false;
    if (!first && same_address(addr_, *result))
        return;
    addr_ = *result;
    if (first) {
        retry_timer_ = {};
        connect_now();
        return;
    }
    // The connection that works is kept: the next connect goes to the new address.
    stats_.address_changes++;
    log_notice("[tcp:%s] %s now %s", name().c_str(), host.c_str(), addr_.to_string().c_str());
}

void TcpClient::connect_now() {
    if (addr_.empty()) {
        retry_later("not resolved yet");
        return;
    }
    auto fd = make_socket(addr_.family(), SOCK_STREAM);
    if (!fd) {
        retry_later(fd.error().message);
        return;
    }
    int rc = connect(fd->get(), addr_.get(), addr_.size());
    if (rc < 0 && errno != EINPROGRESS) {
        retry_later(errno_text(errno));
        return;
    }
    connecting_fd_ = std::move(fd.value());
    // Completion (or failure) of a non-blocking connect shows as writability.
    auto w = loop_.watch(connecting_fd_.get(), EPOLLOUT,
                         [this](uint32_t events) { on_connecting(events); });
    if (!w) {
        connecting_fd_.reset();
        retry_later(w.error().message);
        return;
    }
    connecting_watch_ = std::move(w.value());
}

void TcpClient::on_connecting(uint32_t) {
    int err = 0;
    socklen_t len = sizeof err;
    getsockopt(connecting_fd_.get(), SOL_SOCKET, SO_ERROR, &err, &len);
    connecting_watch_.reset();
    UniqueFd fd = std::move(connecting_fd_);
    if (err != 0) {
        retry_later(errno_text(err));
        return;
    }
    set_nodelay(fd.get());
    if (auto r = start_stream(std::move(fd)); !r) {
        retry_later(r.error().message);
        return;
    }
    backoff_.reset();
    failing_logged_ = false;
    was_connected_ = true;
    log_notice("[tcp:%s] connected to %s", name().c_str(), to_string(addr_).c_str());
}

void TcpClient::retry_later(const std::string& reason) {
    open_error_ = "cannot connect: " + reason;
    Duration delay = backoff_.next();
    // The address may have moved (dynamic DNS): the retry uses what a lookup gives by then.
    if (resolver_)
        (void)resolver_->start();
    // One line per state change, not one per attempt.
    if (!failing_logged_ && !addr_.empty()) {
        log_warning("[tcp:%s] cannot connect to %s: %s; retrying with backoff up to %.1fs",
                    name().c_str(), to_string(addr_).c_str(), reason.c_str(),
                    std::chrono::duration<double>(backoff_.max()).count());
        failing_logged_ = true;
    }
    retry_timer_ = loop_.schedule(delay, [this] {
        connect_now();
        return Duration::zero();
    });
}

void TcpClient::on_disconnect(const std::string& reason) {
    log_warning("[tcp:%s] connection to %s lost: %s", name().c_str(), to_string(addr_).c_str(),
                reason.c_str());
    failing_logged_ = true;
    retry_later(reason);
}

}  // namespace mavbond
