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
     "Where to listen (0.0.0.0:14550, 127.0.0.1:14550, localhost:14550).", true},
    {"peer_timeout", OptionKind::Time, "30s", "A peer silent this long is forgotten."},
    kRxBuffer,
};

constexpr EndpointOption kUdpClientOptions[] = {
    {"address", OptionKind::Address, nullptr,
     "Where to send (192.0.2.10:14550); replies are taken from there only.", true},
    kRxBuffer,
};

}  // namespace

const EndpointSchema kUdpServerType = {"udp", "server",
                                       "A UDP socket bound to an address. Peers are learned from "
                                       "what they send; each is a link of its own.",
                                       kUdpServerOptions};
const EndpointSchema kUdpClientType = {"udp", "client", "A UDP socket sending to one address.",
                                       kUdpClientOptions};

// --- DatagramBatch -------------------------------------------------------------------------

DatagramBatch::DatagramBatch() : arena_(std::make_unique_for_overwrite<uint8_t[]>(kCount * kSize)) {
    for (size_t i = 0; i < kCount; i++) {
        iovs_[i] = iovec{slot(i), kSize};
        msgs_[i].msg_hdr.msg_iov = &iovs_[i];
        msgs_[i].msg_hdr.msg_iovlen = 1;
        msgs_[i].msg_hdr.msg_name = &addrs_[i];
        msgs_[i].msg_hdr.msg_control = control_[i].data();
        msgs_[i].msg_hdr.msg_controllen = kControl;
        msgs_[i].msg_hdr.msg_namelen = sizeof(sockaddr_in);
    }
}

int DatagramBatch::receive(int fd, const EventLoop& loop) {
    // The kernel changed only the headers of the datagrams it gave last time.
    for (size_t i = 0; i < count_; i++) {
        msgs_[i].msg_hdr.msg_namelen = sizeof(sockaddr_in);
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
        for (size_t i = 0; i < count_; i++)
            read_control(i, wall_minus_monotonic);
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

int send_datagrams(int fd, const iovec* frames, size_t count, const sockaddr_in* to) {
    // Only the headers in use are filled: zeroing all 64 cost more than the rest of the send.
    std::array<mmsghdr, 64> msgs;
    count = std::min(count, msgs.size());
    for (size_t i = 0; i < count; i++) {
        msghdr& h = msgs[i].msg_hdr;
        h = msghdr{};
        h.msg_iov = const_cast<iovec*>(&frames[i]);
        h.msg_iovlen = 1;
        if (to) {
            h.msg_name = const_cast<sockaddr_in*>(to);
            h.msg_namelen = sizeof(sockaddr_in);
        }
    }
    int n = sendmmsg(fd, msgs.data(), static_cast<unsigned>(count), MSG_DONTWAIT | MSG_NOSIGNAL);
    return n < 0 ? -errno : n;
}

// --- UdpPeer -------------------------------------------------------------------------------

UdpPeer::UdpPeer(UdpServer& server, const sockaddr_in& addr, TimePoint now)
    : Endpoint(server.config(), server.name() + "@" + to_string(addr), server.loop(),
               TxQueue::Mode::Datagram, &server),
      server_(server), addr_(addr), last_heard_(now) {}

int UdpPeer::write_datagrams(const iovec* frames, size_t count) {
    return send_datagrams(server_.fd(), frames, count, &addr_);
}

void UdpPeer::on_backlog(bool) { server_.update_write_interest(); }

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

UdpPeer* UdpServer::peer_for(const sockaddr_in& addr, TimePoint now) {
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
    last_peer_ = peers_.back().get();
    sink_.attach(*peers_.back());
    log_info("[udp:%s] new peer %s", name().c_str(), to_string(addr).c_str());
    return peers_.back().get();
}

void UdpServer::forget_silent_peers() {
    TimePoint now = loop_.now();
    auto silent = [&](const std::unique_ptr<UdpPeer>& peer) {
        if (now - peer->last_heard() <= config().options.duration("peer_timeout"))
            return false;
        log_info("[udp:%s] peer %s silent for %.1fs: forgotten", name().c_str(),
                 to_string(peer->address()).c_str(),
                 std::chrono::duration<double>(now - peer->last_heard()).count());
        sink_.detach(*peer);
        peer->finish(now);  // what waits for it goes now (a datagram never waits), counted
        retired_ += peer->counters();
        if (last_peer_ == peer.get())
            last_peer_ = nullptr;
        return true;
    };
    peers_.erase(std::remove_if(peers_.begin(), peers_.end(), silent), peers_.end());
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
        UdpPeer* peer = peer_for(datagrams_.from(idx), arrival);
        if (!peer) {
            stats_.rx.garbage_bytes += datagrams_.data(idx).size();
            continue;
        }
        peer->heard(arrival);
        peer->receive_datagram(frames_, datagrams_.data(idx), arrival, policy_);
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
    auto addr = resolve_ipv4(o.text("address"), o.port("address"));
    if (!addr)
        return addr.error();
    auto fd = make_socket(SOCK_DGRAM, o.number("rx_buffer"), config.name);
    if (!fd)
        return fd.error();
    // Connected: the kernel delivers only the peer's replies, and send needs no address.
    if (connect(fd->get(), reinterpret_cast<const sockaddr*>(&*addr), sizeof(sockaddr_in)) < 0)
        return make_error("cannot connect to " + to_string(*addr) + ": " + errno_text(errno));
    std::unique_ptr<UdpClient> client(
        new UdpClient(config, loop, sink, policy, std::move(fd.value())));
    auto w = loop.watch(client->fd_.get(), EPOLLIN,
                        [c = client.get()](uint32_t events) { c->on_events(events); });
    if (!w)
        return w.error();
    client->watch_ = std::move(w.value());
    sink.attach(client->input_);
    sink.attach(*client);
    log_info("[udp:%s] sending to %s", config.name.c_str(), to_string(*addr).c_str());
    return client;
}

UdpClient::UdpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                     UnknownIdPolicy policy, UniqueFd fd)
    : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram), sink_(sink),
      policy_(policy), fd_(std::move(fd)) {}

UdpClient::~UdpClient() {
    sink_.detach(*this);
    sink_.detach(input_);
}

LinkCounters UdpClient::total_counters() const {
    LinkCounters total = stats_;
    total.rx_overflows = socket_drops(fd_.get());
    return total;
}

int UdpClient::write_datagrams(const iovec* frames, size_t count) {
    return send_datagrams(fd_.get(), frames, count, nullptr);
}

void UdpClient::on_backlog(bool backlog) { watch_.set_events(backlog ? EPOLLIN | EPOLLOUT : EPOLLIN); }

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
        if (n == -ECONNREFUSED)
            stats_.tx_errors++;
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
