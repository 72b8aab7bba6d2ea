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
     "[::1]:14550). A sender becomes a peer with its first frame that passes the checks (its "
     "CRC; with signing, its signature). A peer that goes on from a new address (a NAT "
     "rebinding) takes the old one's place: at once with signing, else once the old address "
     "stayed silent for 2 s while the new one carried the stream on (see ADDRESSES).", true},
    {"peer_timeout", OptionKind::Time, "30s",
     "A peer that sends no valid frame this long is forgotten."},
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
                                       "the valid frames they send (64 at most, the least "
                                       "recently heard making room); each is a link of its own.",
                                       kUdpServerOptions, true, nullptr, true};
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

UdpPeer::UdpPeer(UdpServer& server, const SocketAddress& addr)
    : Endpoint(server.config(), server.name() + "@" + to_string(addr), server.loop(),
               TxQueue::Mode::Datagram, &server),
      server_(server), addr_(addr) {}

int UdpPeer::write_datagrams(const iovec* frames, size_t count) {
    return send_datagrams(server_.fd(), frames, count, &addr_);
}

void UdpPeer::on_backlog(bool) { server_.update_write_interest(); }

Endpoint::FrameOrigin UdpPeer::receive_first(ReceivedBatch& batch, const Frame& judged,
                                             const SignedId& id, const FrameOrigin& origin,
                                             DatagramParser& rest, const ParserCounters& parsed,
                                             TimePoint arrival) {
    let_in(batch, judged, arrival, id);
    FrameOrigin last = receive_frames(batch, rest, arrival, origin);
    stats_.rx += parsed;
    return last;
}

void UdpPeer::heard_from(const FrameOrigin& origin) {
    for (FrameOrigin& o : recent_) {
        if (o.known && o.sysid == origin.sysid && o.compid == origin.compid) {
            o = origin;
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

void UdpServer::set_marker_source(uint8_t sysid, uint8_t compid) {
    Endpoint::set_marker_source(sysid, compid);
    for (auto& peer : peers_)
        peer->set_marker_source(sysid, compid);
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

UdpPeer* UdpServer::search_peer(const SocketAddress& addr) {
    for (auto& peer : peers_) {
        if (!peer->retiring() && same_address(peer->address(), addr))
            return last_peer_ = peer.get();
    }
    return nullptr;
}

void UdpServer::take_stranger(size_t i) {
    const TimePoint arrival = datagrams_.arrival(i);
    ParserCounters parsed;
    DatagramParser parser(datagrams_.data(i), policy_, parsed);
    Frame frame;
    while (parser.next(frame)) {
        Frame judged = frame;
        SignedId id;
        Received how = judge(judged, id);  // a signature refused is counted here
        if (!valid(how))
            continue;
        const FrameOrigin origin = origin_of(frame, how, id);
        UdpPeer& peer = learn_peer(datagrams_.from(i), arrival);
        FrameOrigin last = peer.receive_first(frames_, judged, id, origin, parser, parsed, arrival);
        peer.heard_from(last);
        check_rebinding(peer, origin, arrival);
        return;
    }
    // Noise, an empty datagram, frames signing refused: its sender stays a stranger, sent
    // nothing and given no place.
    stats_.rx += parsed;
    stats_.stranger_datagrams++;
}

UdpPeer& UdpServer::learn_peer(const SocketAddress& addr, TimePoint now) {
    auto live = [](const auto& p) { return !p->retiring(); };
    if (static_cast<size_t>(std::count_if(peers_.begin(), peers_.end(), live)) >= kMaxPeers) {
        // The table is full: whoever sent a valid frame least recently makes room. A vehicle
        // that comes back is never refused; with signing, strangers never take a place.
        UdpPeer* oldest = nullptr;
        for (auto& p : peers_) {
            if (live(p) && (!oldest || p->last_valid() < oldest->last_valid()))
                oldest = p.get();
        }
        stats_.peers_evicted++;
        if (peer_log_.allow(now))
            log_info("[udp:%s] %zu peers: %s (its last valid frame %.1fs ago) makes room for %s%s",
                     name().c_str(), kMaxPeers, to_string(oldest->address()).c_str(),
                     std::chrono::duration<double>(now - oldest->last_valid()).count(),
                     to_string(addr).c_str(), peer_log_.left_out_note().c_str());
        retire(*oldest);
    }
    peers_.push_back(std::make_unique<UdpPeer>(*this, addr));
    UdpPeer& peer = *peers_.back();
    last_peer_ = &peer;
    sink_.attach(peer);
    if (peer_log_.allow(now))
        log_info("[udp:%s] new peer %s%s", name().c_str(), to_string(addr).c_str(),
                 peer_log_.left_out_note().c_str());
    return peer;
}

void UdpServer::check_rebinding(UdpPeer& fresh, const FrameOrigin& first, TimePoint now) {
    const Duration peer_timeout = config().options.duration("peer_timeout");
    for (const Rebinding& r : rebindings_) {
        if (r.at != TimePoint{} && now - r.at <= peer_timeout &&
            same_address(r.from, fresh.address())) {
            // The address a rebinding left sends again: it was alive, a second path of one
            // system (two modems), not a NAT rebinding. Both stay; rebindings wait a while.
            rebinding_paused_until_ = now + peer_timeout;
            log_warning("[udp:%s] peer %s sends again after it was taken as rebound: two live "
                        "paths of one system, not a NAT rebinding; rebinding detection paused for "
                        "%.0fs", name().c_str(), to_string(fresh.address()).c_str(),
                        std::chrono::duration<double>(peer_timeout).count());
            return;
        }
    }
    if (now < rebinding_paused_until_)
        return;
    UdpPeer* old = continued_stream(fresh, first);
    if (!old)
        return;
    if (first.verified) {
        rebind(*old, fresh, now);  // only the key's holder can carry a signed stream on
        return;
    }
    fresh.start_succession({old->address(), now, 1, first.sysid, first.compid});
}

UdpPeer* UdpServer::continued_stream(const UdpPeer& fresh, const FrameOrigin& first) const {
    // A NAT rebinding moves one sender to a new source address mid-stream: its next frames
    // carry on its sequence. Frames lost in flight leave a gap; a window of 64 takes a burst
    // of those. A signed stream is its own proof: the shared verifier took the frame as newer
    // than every frame of its stream, from any address.
    constexpr unsigned kSeqWindow = 64;
    for (const auto& peer : peers_) {
        if (peer.get() == &fresh || peer->retiring())
            continue;
        for (const FrameOrigin& was : peer->recent_origins()) {
            if (!was.known || was.sysid != first.sysid || was.compid != first.compid ||
                was.verified != first.verified)
                continue;
            if (first.verified ? was.link_id == first.link_id
                               : static_cast<uint8_t>(first.seq - was.seq) - 1u < kSeqWindow)
                return peer.get();
        }
    }
    return nullptr;
}

void UdpServer::judge_succession(UdpPeer& peer, const FrameOrigin& origin, TimePoint now) {
    UdpPeer::Succession& s = *peer.succession();
    UdpPeer* old = find_peer(s.of);
    // The old address spoke since the newcomer's first frame: the newcomer is another sender
    // (a second path, or a stranger guessing the sequence), a peer like any other. Or the old
    // peer is gone already.
    if (!old || old->last_valid() >= s.since) {
        peer.end_succession();
        return;
    }
    if (origin.sysid == s.sysid && origin.compid == s.compid)
        s.datagrams++;
    if (s.datagrams >= kSuccessionDatagrams && now - s.since >= kSuccessionQuiet)
        rebind(*old, peer, now);
}

void UdpServer::rebind(UdpPeer& old, UdpPeer& fresh, TimePoint now) {
    if (peer_log_.allow(now))
        log_notice("[udp:%s] peer %s now at %s (a NAT rebinding): the old address is forgotten%s",
                   name().c_str(), to_string(old.address()).c_str(),
                   to_string(fresh.address()).c_str(), peer_log_.left_out_note().c_str());
    stats_.peer_rebinds++;
    fresh.account().continue_from(old.account());  // one link: its count goes on
    rebindings_[next_rebinding_] = {old.address(), now};
    next_rebinding_ = (next_rebinding_ + 1) % rebindings_.size();
    fresh.end_succession();
    retire(old);  // nothing more goes to the old address, from this round on
}

void UdpServer::retire(UdpPeer& peer) {
    peer.retire();
    if (last_peer_ == &peer)
        last_peer_ = nullptr;
    defer(loop_, [this] { forget_retired(); });
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

void UdpServer::forget_retired() {
    TimePoint now = loop_.now();
    for (size_t i = peers_.size(); i-- > 0;) {
        if (peers_[i]->retiring())
            forget(*peers_[i], now);
    }
    update_write_interest();
}

void UdpServer::forget_silent_peers() {
    TimePoint now = loop_.now();
    for (size_t i = peers_.size(); i-- > 0;) {
        UdpPeer& peer = *peers_[i];
        if (now - peer.last_valid() <= config().options.duration("peer_timeout"))
            continue;
        if (peer_log_.allow(now))
            log_info("[udp:%s] peer %s silent for %.1fs: forgotten%s", name().c_str(),
                     to_string(peer.address()).c_str(),
                     std::chrono::duration<double>(now - peer.last_valid()).count(),
                     peer_log_.left_out_note().c_str());
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
        UdpPeer* peer = find_peer(datagrams_.from(idx));
        if (!peer) {
            take_stranger(idx);
            continue;
        }
        TimePoint arrival = datagrams_.arrival(idx);
        FrameOrigin origin = peer->receive_datagram(frames_, datagrams_.data(idx), arrival, policy_);
        if (!origin.known)
            continue;
        peer->heard_from(origin);
        if (peer->succession())
            judge_succession(*peer, origin, arrival);
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
        open_error_ = result.error().message;
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
