#include "endpoints/udp_endpoint.h"

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "core/log.h"
#include "endpoints/net.h"

namespace mavbond {

namespace {

// A UDP socket's receive buffer, in the bytes the kernel counts: what a link's backlog may fill
// while the daemon does not read (a stalled companion computer). The kernel counts about 830
// bytes per small datagram and 1,280 per largest frame (measured on loopback), so a 1 s stall
// at 10,000 datagrams/s takes 8.3 to 12.8 MB; 16 MiB holds it. It costs memory only while full.
constexpr EndpointOption kRxBuffer = {
    "rx_buffer", OptionKind::Size, "16MiB",
    "The socket's receive buffer, in the bytes the kernel counts (about 830 per small "
    "datagram): what a link's backlog may fill while the daemon does not read. The default "
    "holds a 1 s stall at 10,000 datagrams/s. Above net.core.rmem_max it needs root or the "
    "package's sysctl setting (a warning says when the kernel gives less). Datagrams the "
    "kernel drops anyway are counted per endpoint (rx_overflows).",
    false, 64u << 10, 1u << 30};

constexpr EndpointOption kUdpServerOptions[] = {
    {"address", OptionKind::Address, nullptr,
     "Where to listen (0.0.0.0:14550, 127.0.0.1:14550, [::]:14550 for IPv6 and IPv4, "
     "[::1]:14550). A peer that goes on from a new address (a NAT rebinding) takes the old "
     "one's place at once.", true},
    {"peer_timeout", OptionKind::Time, "30s", "A peer silent this long is forgotten."},
    kRxBuffer,
};

constexpr EndpointOption kUdpClientOptions[] = {
    {"address", OptionKind::Address, nullptr,
     "Where to send (192.0.2.10:14550, [2001:db8::5]:14550, lte.example.net:14550); replies "
     "are taken from there only. A host name is looked up off the event loop, again every "
     "resolve_interval and after a send fails.", true},
    kRxBuffer,
    kResolveInterval,
    kReconnectMin,
    kReconnectMax,
};

}  // namespace

const EndpointSchema kUdpServerType = {"udp", "server",
                                       "A UDP socket bound to an address. Peers are learned from "
                                       "what they send; each is a link of its own.",
                                       kUdpServerOptions};
const EndpointSchema kUdpClientType = {"udp", "client", "A UDP socket sending to one address.",
                                       kUdpClientOptions, true, reconnect_bounds};

// --- DatagramBatch -------------------------------------------------------------------------

DatagramBatch::DatagramBatch() : arena_(std::make_unique_for_overwrite<uint8_t[]>(kCount * kSize)) {
    for (size_t i = 0; i < kCount; i++) {
        iovs_[i] = iovec{slot(i), kSize};
        msgs_[i].msg_hdr.msg_iov = &iovs_[i];
        msgs_[i].msg_hdr.msg_iovlen = 1;
        msgs_[i].msg_hdr.msg_name = addrs_[i].buffer();
        msgs_[i].msg_hdr.msg_control = control_[i].data();
        msgs_[i].msg_hdr.msg_controllen = kControl;
        msgs_[i].msg_hdr.msg_namelen = SocketAddress::capacity();
    }
}

int DatagramBatch::receive(int fd, const EventLoop& loop) {
    // The kernel changed only the headers of the datagrams it gave last time.
    for (size_t i = 0; i < count_; i++) {
        msgs_[i].msg_hdr.msg_namelen = SocketAddress::capacity();
        msgs_[i].msg_hdr.msg_controllen = kControl;
        msgs_[i].msg_hdr.msg_flags = 0;
    }
    int n = recvmmsg(fd, msgs_.data(), kCount, MSG_DONTWAIT, nullptr);
    count_ = n > 0 ? static_cast<size_t>(n) : 0;
    // Found the socket empty (or short of a full batch): everything that arrived before the
    // read was read, so before the round began too.
    drained_at_ = count_ < kCount ? loop.now() : TimePoint{};
    if (count_ > 0) {
        int64_t wall_minus_monotonic = loop.wall_minus_monotonic_ns();
        for (size_t i = 0; i < count_; i++) {
            addrs_[i].set_size(msgs_[i].msg_hdr.msg_namelen);
            read_control(i, wall_minus_monotonic);
        }
    }
    if (n < 0)
        return errno == EAGAIN || errno == EWOULDBLOCK ? 0 : -errno;
    return n;
}

void DatagramBatch::read_control(size_t i, int64_t wall_minus_monotonic) {
    TimePoint t = last_arrival_;  // no timestamp: no later than what came before it
    msghdr& h = msgs_[i].msg_hdr;
    for (cmsghdr* c = CMSG_FIRSTHDR(&h); c; c = CMSG_NXTHDR(&h, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS) {
            // The kernel stamps arrivals on the wall clock; every timeout uses the monotonic.
            timespec ts;
            std::memcpy(&ts, CMSG_DATA(c), sizeof ts);
            t = TimePoint(Duration(ts.tv_sec * 1'000'000'000LL + ts.tv_nsec - wall_minus_monotonic));
        }
    }
    // A wall clock stepped back between two arrivals must not make the later one earlier.
    last_arrival_ = std::max(last_arrival_, t);
    arrival_[i] = last_arrival_;
}

int send_datagrams(int fd, const iovec* frames, size_t count, const SocketAddress* to) {
    // Only the headers in use are filled: zeroing all 64 cost more than the rest of the send.
    std::array<mmsghdr, 64> msgs;
    count = std::min(count, msgs.size());
    for (size_t i = 0; i < count; i++) {
        msghdr& h = msgs[i].msg_hdr;
        h = msghdr{};
        h.msg_iov = const_cast<iovec*>(&frames[i]);
        h.msg_iovlen = 1;
        if (to) {
            h.msg_name = const_cast<sockaddr*>(to->get());
            h.msg_namelen = to->size();
        }
    }
    int n = sendmmsg(fd, msgs.data(), static_cast<unsigned>(count), MSG_DONTWAIT | MSG_NOSIGNAL);
    return n < 0 ? -errno : n;
}

// --- UdpPeer -------------------------------------------------------------------------------

UdpPeer::UdpPeer(UdpServer& server, const SocketAddress& addr, TimePoint now)
    : Endpoint(server.config(), server.name() + "@" + to_string(addr), server.loop(),
               TxQueue::Mode::Datagram, &server),
      server_(server), addr_(addr), last_heard_(now) {}

int UdpPeer::write_datagrams(const iovec* frames, size_t count) {
    return send_datagrams(server_.fd(), frames, count, &addr_);
}

void UdpPeer::on_backlog(bool) { server_.update_write_interest(); }

void UdpPeer::heard_from(const FrameOrigin& origin) {
    if (!origin.known)
        return;
    for (FrameOrigin& o : recent_) {
        if (o.known && o.sysid == origin.sysid && o.compid == origin.compid) {
            o.seq = origin.seq;
            return;
        }
    }
    recent_[next_recent_] = origin;
    next_recent_ = (next_recent_ + 1) % kRecentOrigins;
}

// --- UdpServer -----------------------------------------------------------------------------

Result<std::unique_ptr<UdpServer>> UdpServer::open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy) {
    const EndpointOptions& o = config.options;
    auto bound = bind_socket(SOCK_DGRAM, o.text("address"), o.port("address"),
                             o.number("rx_buffer"), config.name);
    if (!bound)
        return bound.error();
    std::unique_ptr<UdpServer> server(
        new UdpServer(config, loop, sink, policy, std::move(bound->fd)));
    auto w = loop.watch(server->fd_.get(), EPOLLIN,
                        [s = server.get()](uint32_t events) { s->on_events(events); });
    if (!w)
        return w.error();
    server->watch_ = std::move(w.value());
    sink.attach(server->input_);
    auto period = std::clamp<Duration>(o.duration("peer_timeout") / 4, milliseconds(100), seconds(5));
    server->expiry_timer_ = loop.schedule(period, [s = server.get(), period] {
        s->forget_silent_peers();
        return period;
    });
    log_info("[udp:%s] listening on %s", config.name.c_str(), to_string(bound->addr).c_str());
    return server;
}

UdpServer::UdpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                     UnknownIdPolicy policy, UniqueFd fd)
    : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram), sink_(sink),
      policy_(policy), fd_(std::move(fd)) {}

UdpServer::~UdpServer() {
    for (auto& peer : peers_)
        sink_.detach(*peer);
    sink_.detach(input_);
}

LinkCounters UdpServer::total_counters() const {
    LinkCounters total = stats_;
    total.rx_overflows = socket_drops(fd_.get());
    total += retired_;
    for (const auto& peer : peers_)
        total += peer->counters();
    return total;
}

void UdpServer::retune(const TxBudgetConfig& budget) {
    Endpoint::retune(budget);
    for (auto& peer : peers_)
        peer->retune(budget);
}

void UdpServer::finish(TimePoint deadline) {
    for (auto& peer : peers_)
        peer->finish(deadline);
}

UdpPeer* UdpServer::peer_for(const SocketAddress& addr, TimePoint now, bool& is_new) {
    is_new = false;
    // Datagrams come in runs from one peer: the last one found is tried first.
    if (last_peer_ && same_address(last_peer_->address(), addr))
        return last_peer_;
    for (auto& peer : peers_) {
        if (same_address(peer->address(), addr))
            return last_peer_ = peer.get();
    }
    if (peers_.size() >= kMaxPeers) {
        if (refused_peers_++ == 0)
            log_warning("[udp:%s] %zu peers already: ignoring new peer %s", name().c_str(),
                        kMaxPeers, to_string(addr).c_str());
        return nullptr;
    }
    peers_.push_back(std::make_unique<UdpPeer>(*this, addr, now));
    is_new = true;
    last_peer_ = peers_.back().get();
    sink_.attach(*peers_.back());
    log_info("[udp:%s] new peer %s", name().c_str(), to_string(addr).c_str());
    return peers_.back().get();
}

UdpPeer* UdpServer::rebound_from(const UdpPeer& fresh) const {
    // A NAT rebinding moves one sender to a new source address mid-stream: its next frames
    // carry on its sequence. Frames lost in flight leave a gap; a window of 64 takes a burst
    // of those, and two senders of one system and component (a misconfiguration) rarely
    // line up within it.
    constexpr unsigned kSeqWindow = 64;
    const FrameOrigin& now = fresh.recent_origins()[0];  // what its first datagram ended with
    if (!now.known)
        return nullptr;
    for (const auto& peer : peers_) {
        if (peer.get() == &fresh || peer->rebound())
            continue;
        for (const FrameOrigin& was : peer->recent_origins()) {
            if (!was.known || was.sysid != now.sysid || was.compid != now.compid)
                continue;
            unsigned ahead = static_cast<uint8_t>(now.seq - was.seq);
            if (ahead >= 1 && ahead <= kSeqWindow)
                return peer.get();
        }
    }
    return nullptr;
}

void UdpServer::forget(UdpPeer& peer, TimePoint now) {
    auto it = std::find_if(peers_.begin(), peers_.end(),
                           [&](const auto& p) { return p.get() == &peer; });
    if (it == peers_.end())
        return;  // forgotten already
    sink_.detach(peer);
    peer.finish(now);  // what waits for it goes now (a datagram never waits), counted
    retired_ += peer.counters();
    if (last_peer_ == &peer)
        last_peer_ = nullptr;
    peers_.erase(it);
}

void UdpServer::forget_silent_peers() {
    TimePoint now = loop_.now();
    for (size_t i = peers_.size(); i-- > 0;) {
        UdpPeer& peer = *peers_[i];
        if (now - peer.last_heard() <= config().options.duration("peer_timeout"))
            continue;
        log_info("[udp:%s] peer %s silent for %.1fs: forgotten", name().c_str(),
                 to_string(peer.address()).c_str(),
                 std::chrono::duration<double>(now - peer.last_heard()).count());
        forget(peer, now);
    }
    update_write_interest();
}

void UdpServer::update_write_interest() {
    bool pending = std::any_of(peers_.begin(), peers_.end(),
                               [](const auto& p) { return p->has_pending(); });
    watch_.set_events(pending ? EPOLLIN | EPOLLOUT : EPOLLIN);
}

void UdpServer::on_events(uint32_t events) {
    if (events & EPOLLOUT) {
        for (auto& peer : peers_)
            peer->flush();
    }
    if (!(events & (EPOLLIN | EPOLLERR)))
        return;
    int n = datagrams_.receive(fd_.get(), loop_);
    if (n < 0) {
        // ICMP errors surface here for a peer that went away: nothing to do but go on.
        log_debug("[udp:%s] recvmmsg: %s", name().c_str(), errno_text(-n).c_str());
        return;
    }
    // A socket epoll reported readable held its first datagram when epoll looked.
    input_.read(datagrams_.read_until(), events & EPOLLIN ? datagrams_.first_arrival() : TimePoint{});
    for (int i = 0; i < n; i++) {
        auto idx = static_cast<size_t>(i);
        TimePoint arrival = datagrams_.arrival(idx);
        bool is_new = false;
        UdpPeer* peer = peer_for(datagrams_.from(idx), arrival, is_new);
        if (!peer) {
            stats_.rx.garbage_bytes += datagrams_.data(idx).size();
            continue;
        }
        peer->heard(arrival);
        peer->heard_from(peer->receive_datagram(frames_, datagrams_.data(idx), arrival, policy_));
        if (is_new && detect_rebinding_) {
            if (std::any_of(rebound_from_.begin(), rebound_from_.end(),
                            [&](const SocketAddress& a) { return same_address(a, peer->address()); })) {
                log_warning("[udp:%s] peer %s sends again after it was taken as rebound: two live "
                            "paths of one system, not a NAT rebinding; rebinding detection is off "
                            "for this endpoint", name().c_str(), to_string(peer->address()).c_str());
                detect_rebinding_ = false;
            } else if (UdpPeer* old = rebound_from(*peer)) {
                log_notice("[udp:%s] peer %s now at %s (a NAT rebinding): the old address is "
                           "forgotten", name().c_str(), to_string(old->address()).c_str(),
                           to_string(peer->address()).c_str());
                stats_.peer_rebinds++;
                rebound_from_[next_rebound_] = old->address();
                next_rebound_ = (next_rebound_ + 1) % rebound_from_.size();
                // Nothing more goes to the old address, from this round on. It is forgotten
                // once the round has routed what it received (a bond may hold its frames).
                old->mark_rebound();
                defer(loop_, [this, old] {
                    forget(*old, loop_.now());
                    update_write_interest();
                });
            }
        }
    }
    // The frames stay lent in datagrams_ until the round ends (its next read is in a later
    // round): no end_batch() here, the round's end sends what they gave the links.
    if (n > 0)
        frames_.submit();
}

// --- UdpClient -----------------------------------------------------------------------------

Result<std::unique_ptr<UdpClient>> UdpClient::open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy) {
    const EndpointOptions& o = config.options;
    const std::string& host = o.text("address");
    uint16_t port = o.port("address");
    std::unique_ptr<UdpClient> client(new UdpClient(config, loop, sink, policy));
    sink.attach(client->input_);
    sink.attach(*client);
    if (is_numeric_host(host)) {
        if (auto r = client->use_address(SocketAddress::numeric(host, port)); !r)
            return r.error();
        log_info("[udp:%s] sending to %s", config.name.c_str(), to_string(client->addr_).c_str());
        return client;
    }
    // A name: looked up off the loop, now and every resolve_interval. Until it resolves the
    // link is not ready (what is routed to it is dropped and counted), as a UART not there yet.
    client->resolver_ = std::make_unique<NameResolver>(
        loop, host, port, SOCK_DGRAM,
        [c = client.get()](Result<SocketAddress> r) { c->on_resolved(std::move(r)); });
    if (auto r = client->resolver_->start_every(o.duration("resolve_interval")); !r)
        return r.error();
    return client;
}

UdpClient::UdpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                     UnknownIdPolicy policy)
    : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram), sink_(sink),
      policy_(policy), backoff_(reconnect_backoff(config)) {}

UdpClient::~UdpClient() {
    sink_.detach(*this);
    sink_.detach(input_);
}

LinkCounters UdpClient::total_counters() const {
    LinkCounters total = stats_;
    total.rx_overflows = old_socket_drops_ + socket_drops(fd_.get());
    return total;
}

Result<void> UdpClient::use_address(const SocketAddress& addr) {
    // Connected: the kernel delivers only the peer's replies, and send needs no address.
    // Connecting again keeps the source port (the NAT mapping); another family needs
    // another socket.
    if (fd_ && addr.family() == addr_.family() && connect(fd_.get(), addr.get(), addr.size()) == 0) {
        addr_ = addr;
        return {};
    }
    auto fd = make_socket(addr.family(), SOCK_DGRAM, config().options.number("rx_buffer"), name());
    if (!fd)
        return fd.error();
    if (connect(fd->get(), addr.get(), addr.size()) < 0)
        return make_error("cannot connect to " + addr.to_string() + ": " + errno_text(errno));
    auto w = loop_.watch(fd->get(), has_pending() ? EPOLLIN | EPOLLOUT : EPOLLIN,
                         [this](uint32_t events) { on_events(events); });
    if (!w)
        return w.error();
    old_socket_drops_ += socket_drops(fd_.get());
    watch_ = std::move(w.value());
    fd_ = std::move(fd.value());
    addr_ = addr;
    return {};
}

void UdpClient::on_resolved(Result<SocketAddress> result) {
    const std::string& host = resolver_->host();
    if (!result) {
        stats_.resolve_failures++;
        Duration delay = backoff_.next();
        // One line per state change, not one per attempt.
        if (!failing_logged_) {
            log_warning("[udp:%s] %s%s; retrying with backoff up to %.1fs", name().c_str(),
                        result.error().message.c_str(),
                        addr_.empty() ? "" : (" (still sending to " + addr_.to_string() + ")").c_str(),
                        std::chrono::duration<double>(backoff_.max()).count());
            failing_logged_ = true;
        }
        resolve_retry_ = loop_.schedule(delay, [this] {
            (void)resolver_->start();
            return Duration::zero();
        });
        return;
    }
    backoff_.reset();
    resolve_retry_ = {};
    if (failing_logged_)
        log_notice("[udp:%s] %s resolves again", name().c_str(), host.c_str());
    failing_logged_ = false;
    if (!addr_.empty() && same_address(addr_, *result))
        return;
    bool first = addr_.empty();
    if (auto r = use_address(*result); !r) {
        log_warning("[udp:%s] %s: %s", name().c_str(), host.c_str(), r.error().message.c_str());
        return;
    }
    if (first) {
        log_info("[udp:%s] sending to %s (%s)", name().c_str(), addr_.to_string().c_str(),
                 host.c_str());
    } else {
        stats_.address_changes++;
        log_notice("[udp:%s] %s now %s", name().c_str(), host.c_str(), addr_.to_string().c_str());
    }
}

void UdpClient::failed_to_send() {
    if (!resolver_ || resolver_->running() || loop_.now() < next_failure_lookup_)
        return;
    next_failure_lookup_ = loop_.now() + config().options.duration("reconnect_min");
    (void)resolver_->start();
}

int UdpClient::write_datagrams(const iovec* frames, size_t count) {
    int n = send_datagrams(fd_.get(), frames, count, nullptr);
    if (n == -ECONNREFUSED || n == -ENETUNREACH || n == -EHOSTUNREACH || n == -EADDRNOTAVAIL)
        failed_to_send();
    return n;
}

void UdpClient::on_backlog(bool backlog) {
    if (fd_)
        watch_.set_events(backlog ? EPOLLIN | EPOLLOUT : EPOLLIN);
}

void UdpClient::on_events(uint32_t events) {
    if (events & EPOLLOUT)
        flush();
    if (!(events & (EPOLLIN | EPOLLERR)))
        return;
    int n = datagrams_.receive(fd_.get(), loop_);
    if (n < 0) {
        // ECONNREFUSED: the peer's port is closed (ICMP port unreachable). Keep going. The
        // kernel reports the ICMP on whichever call comes first, usually this read rather than
        // the next send: it is still a datagram we sent that was lost, so a transmit error.
        if (n == -ECONNREFUSED) {
            stats_.tx_errors++;
            failed_to_send();
        }
        log_debug("[udp:%s] recvmmsg: %s", name().c_str(), errno_text(-n).c_str());
        return;
    }
    // A socket epoll reported readable held its first datagram when epoll looked.
    input_.read(datagrams_.read_until(), events & EPOLLIN ? datagrams_.first_arrival() : TimePoint{});
    for (int i = 0; i < n; i++) {
        auto idx = static_cast<size_t>(i);
        receive_datagram(frames_, datagrams_.data(idx), datagrams_.arrival(idx), policy_);
    }
    if (n > 0)
        frames_.submit();
}

}  // namespace mavbond
