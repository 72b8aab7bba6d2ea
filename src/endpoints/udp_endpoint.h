// UDP endpoints. A server binds an address and learns its peers from what they send: each
// peer is a route target of its own, forgotten after peer_timeout of silence. A client sends
// to a fixed address and accepts replies from it only (a connected socket).
#pragma once

#include <sys/socket.h>
#include <netinet/in.h>

#include <array>
#include <memory>
#include <utility>
#include <vector>

#include "core/event_loop.h"
#include "endpoints/endpoint.h"
#include "endpoints/net.h"
#include "endpoints/stream_endpoint.h"

namespace mavbond {

extern const EndpointSchema kUdpServerType;
extern const EndpointSchema kUdpClientType;

/// A batch of datagrams received with one recvmmsg, each with the time the kernel received it
/// (SO_TIMESTAMPNS). Every slot takes the largest
/// datagram UDP can carry (a bridge may pack many frames into one), yet costs memory only for
/// what is written: the arena is never initialised, so untouched pages are never made resident.
class DatagramBatch {
public:
    static constexpr size_t kCount = 32;
    static constexpr size_t kSize = 65536;
    DatagramBatch();
    /// Receives up to kCount datagrams; returns how many, 0 when none, -errno on error.
    int receive(int fd, const EventLoop& loop);
    std::span<const uint8_t> data(size_t i) const { return {slot(i), msgs_[i].msg_len}; }
    const SocketAddress& from(size_t i) const { return addrs_[i]; }
    /// When datagram i arrived (the kernel's receive time, on the monotonic clock).
    TimePoint arrival(size_t i) const { return arrival_[i]; }
    /// What the last receive() tells the sink: the time up to which the socket is read (the
    /// last datagram's arrival; when it came back short of a full batch, the socket was
    /// empty then: the round's start too).
    TimePoint read_until() const {
        return std::max(count_ ? arrival_[count_ - 1] : TimePoint{}, drained_at_);
    }
    /// When the first datagram of the last receive() arrived (zero when there was none).
    TimePoint first_arrival() const { return count_ ? arrival_[0] : TimePoint{}; }

private:
    // Room for a timestamp.
    static constexpr size_t kControl = CMSG_SPACE(sizeof(timespec));
    uint8_t* slot(size_t i) const { return arena_.get() + i * kSize; }
    void read_control(size_t i, int64_t wall_minus_monotonic_ns);
    std::unique_ptr<uint8_t[]> arena_;
    std::array<mmsghdr, kCount> msgs_{};
    std::array<iovec, kCount> iovs_{};
    std::array<SocketAddress, kCount> addrs_{};
    std::array<std::array<uint8_t, kControl>, kCount> control_{};
    std::array<TimePoint, kCount> arrival_{};
    size_t count_ = 0;
    TimePoint drained_at_{};    // the round's start, when the last receive found the socket empty
    TimePoint last_arrival_{};  // arrivals never go back (a stepped wall clock)
};

class UdpServer;

class UdpPeer : public Endpoint {
public:
    UdpPeer(UdpServer& server, const SocketAddress& addr, TimePoint now);
    const char* kind() const override { return "udp-peer"; }
    /// Not once its sender went on from another address (what is routed to it is dropped,
    /// counted, until it is forgotten at the round's end).
    bool ready() const override { return !rebound_; }
    void mark_rebound() { rebound_ = true; }
    bool rebound() const { return rebound_; }
    const SocketAddress& address() const { return addr_; }
    TimePoint last_heard() const { return last_heard_; }
    void heard(TimePoint now) { last_heard_ = now; }
    /// The last frame of each of the last few components it carried (a vehicle's autopilot,
    /// camera, ...): what a rebinding is recognised by.
    static constexpr size_t kRecentOrigins = 4;
    const std::array<FrameOrigin, kRecentOrigins>& recent_origins() const { return recent_; }
    void heard_from(const FrameOrigin& origin);

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    UdpServer& server_;
    SocketAddress addr_;
    TimePoint last_heard_;
    std::array<FrameOrigin, kRecentOrigins> recent_{};
    size_t next_recent_ = 0;  // the slot a new component takes (round robin)
    bool rebound_ = false;
};

class UdpServer : public Endpoint {
public:
    static Result<std::unique_ptr<UdpServer>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~UdpServer() override;
    const char* kind() const override { return "udp-server"; }
    LinkCounters total_counters() const override;
    void finish(TimePoint deadline) override;
    void retune(const TxBudgetConfig& budget) override;
    int fd() const { return fd_.get(); }
    /// Watches for EPOLLOUT while some peer has a backlog.
    void update_write_interest();

private:
    UdpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              UniqueFd fd);
    void on_events(uint32_t events);
    /// The peer `addr` is, learned now when new (`is_new` says so); null past kMaxPeers.
    UdpPeer* peer_for(const SocketAddress& addr, TimePoint now, bool& is_new);
    /// A new peer whose first frames carry on an old peer's stream (the same system and
    /// component, the sequence a little further): the old peer's NAT mapping was replaced.
    /// Returns the old peer, or null.
    UdpPeer* rebound_from(const UdpPeer& fresh) const;
    /// Forgets a peer: detached, what waits for it dropped and counted, counters kept.
    void forget(UdpPeer& peer, TimePoint now);
    void forget_silent_peers();

    static constexpr size_t kMaxPeers = 64;
    FrameSink& sink_;
    UnknownIdPolicy policy_;
    UniqueFd fd_;
    EventLoop::Watch watch_;
    Input input_{config().bond, watch_};  // for the arrival order of its bond's links
    EventLoop::Timer expiry_timer_;
    DatagramBatch datagrams_;
    ReceivedBatch frames_{sink_, &input_};
    std::vector<std::unique_ptr<UdpPeer>> peers_;
    UdpPeer* last_peer_ = nullptr;  // the peer the last datagram came from
    // Addresses forgotten as rebound: one that sends again was a second live path of one
    // system (two modems to one port), not a NAT rebinding, and the detection stops.
    std::array<SocketAddress, 4> rebound_from_{};
    size_t next_rebound_ = 0;
    bool detect_rebinding_ = true;
    LinkCounters retired_;      // counters of forgotten peers, so totals never go back
    uint64_t refused_peers_ = 0;
};

class UdpClient : public Endpoint {
public:
    static Result<std::unique_ptr<UdpClient>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~UdpClient() override;
    const char* kind() const override { return "udp-client"; }
    /// Not before its host name resolved once.
    bool ready() const override { return static_cast<bool>(fd_); }
    LinkCounters total_counters() const override;

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    UdpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy);
    void on_events(uint32_t events);
    /// Sends to `addr` from now on: the same socket (the same source port) when it can.
    Result<void> use_address(const SocketAddress& addr);
    void on_resolved(Result<SocketAddress> result);
    /// A send failed: the address may have moved. Looks the name up again, no sooner than
    /// reconnect_min after the last lookup that a failure started.
    void failed_to_send();

    FrameSink& sink_;
    UnknownIdPolicy policy_;
    SocketAddress addr_;   // empty until a name resolves
    UniqueFd fd_;          // connected to addr_
    EventLoop::Watch watch_;
    std::unique_ptr<NameResolver> resolver_;  // null for an address literal
    Backoff backoff_;      // lookups that fail
    EventLoop::Timer resolve_retry_;  // after a failed lookup, with backoff
    TimePoint next_failure_lookup_{};
    bool failing_logged_ = false;
    uint64_t old_socket_drops_ = 0;  // of sockets replaced (another address family)
    Input input_{config().bond, watch_};  // for the arrival order of its bond's links
    DatagramBatch datagrams_;
    ReceivedBatch frames_{sink_, &input_};
};

/// sendmmsg of one datagram per iovec (to `to`, or to the connected peer when null).
int send_datagrams(int fd, const iovec* frames, size_t count, const SocketAddress* to);


}  // namespace mavbond
