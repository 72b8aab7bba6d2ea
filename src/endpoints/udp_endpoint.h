// UDP endpoints. A server binds an address and learns its peers from what they send: a
// sender becomes a peer with its first frame that passes the server's checks (a datagram
// alone makes nobody a peer); each peer is a route target of its own, forgotten after
// peer_timeout without a valid frame. A client sends to a fixed address and accepts replies
// from it only (a connected socket).
#pragma once

#include <sys/socket.h>
#include <netinet/in.h>

#include <array>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "core/event_loop.h"
#include "core/log_budget.h"
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

/// A sender a UDP server learned: from its first datagram that brought a frame passing the
/// server's checks (never from a datagram alone).
class UdpPeer : public Endpoint {
public:
    UdpPeer(UdpServer& server, const SocketAddress& addr);
    const char* kind() const override { return "udp-peer"; }
    /// Not once it retires (its sender went on from another address, or it made room for a
    /// newcomer): what is routed to it is dropped, counted, until it is forgotten at the
    /// round's end.
    bool ready() const override { return !retiring_; }
    void retire() { retiring_ = true; }
    bool retiring() const { return retiring_; }
    const SocketAddress& address() const { return addr_; }

    /// Its first datagram, which the server judged up to `first` (a frame judge() let in,
    /// `judged` as judge() left it, `origin` the frame's: a signature is checked once, never
    /// twice): `first`, then what `rest` still yields, as any of its datagrams. The
    /// datagram's parser counters (`parsed`, which `rest` counts into) become its own.
    /// Returns the origin of its last valid frame.
    FrameOrigin receive_first(ReceivedBatch& batch, const Frame& judged, const SignedId& id,
                              const FrameOrigin& origin, DatagramParser& rest,
                              const ParserCounters& parsed, TimePoint arrival);

    /// The last valid frame of each of the last few components it carried (a vehicle's
    /// autopilot, camera, ...): what a rebinding is recognised by.
    static constexpr size_t kRecentOrigins = 4;
    const std::array<FrameOrigin, kRecentOrigins>& recent_origins() const { return recent_; }
    void heard_from(const FrameOrigin& origin);

    /// A newcomer whose unsigned frames carry on the stream of the peer at `of`: it takes
    /// that peer's place only when the peer stays silent while it carries the stream on
    /// (UdpServer::judge_succession).
    struct Succession {
        SocketAddress of;
        TimePoint since;         // its first frame
        uint32_t datagrams = 0;  // of its datagrams that carried the stream on
        uint8_t sysid = 0, compid = 0;
    };
    Succession* succession() { return succession_ ? &*succession_ : nullptr; }
    void start_succession(Succession s) { succession_ = s; }
    void end_succession() { succession_.reset(); }

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    UdpServer& server_;
    SocketAddress addr_;
    std::array<FrameOrigin, kRecentOrigins> recent_{};
    size_t next_recent_ = 0;  // the slot a new component takes (round robin)
    std::optional<Succession> succession_;
    bool retiring_ = false;
};

class UdpServer : public Endpoint {
public:
    static Result<std::unique_ptr<UdpServer>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~UdpServer() override;
    const char* kind() const override { return "udp-server"; }
    LinkCounters total_counters() const override;
    void for_each_link(const std::function<void(const Link&)>& f) const override {
        for (const auto& p : peers_)
            f(*p);
    }
    void finish(TimePoint deadline) override;
    void retune(const TxBudgetConfig& budget) override;
    void set_marker_source(uint8_t sysid, uint8_t compid) override;
    int fd() const { return fd_.get(); }
    /// Watches for EPOLLOUT while some peer has a backlog.
    void update_write_interest();

    /// Peers at most; past it the one whose last valid frame is oldest makes room.
    static constexpr size_t kMaxPeers = 64;
    /// An unsigned rebinding: the newcomer carries the stream on in this many datagrams over
    /// at least kSuccessionQuiet, and the old address stays silent all that while. A stranger
    /// guessing the next sequence number cannot silence the vehicle; a vehicle sends at least
    /// its 1 Hz HEARTBEAT.
    static constexpr uint32_t kSuccessionDatagrams = 3;
    static constexpr Duration kSuccessionQuiet = seconds(2);

private:
    UdpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              UniqueFd fd);
    void on_events(uint32_t events);
    /// The peer at `addr` (one that is not retiring), or null. Datagrams come in runs from
    /// one peer: the last one found is tried first.
    UdpPeer* find_peer(const SocketAddress& addr) {
        if (last_peer_ && same_address(last_peer_->address(), addr))
            return last_peer_;
        return search_peer(addr);
    }
    UdpPeer* search_peer(const SocketAddress& addr);
    /// Datagram i of the batch, from an address that is no peer: its first frame that passes
    /// the checks (CRC; a verified signature with `signing:`) makes its sender a peer; a
    /// datagram without one is counted here and goes nowhere.
    void take_stranger(size_t i);
    /// A new peer at `addr`; with the table full, the least recently valid one retires.
    UdpPeer& learn_peer(const SocketAddress& addr, TimePoint now);
    /// Whether a new peer's first frame carries on a known peer's stream (a NAT rebinding):
    /// verified, it takes that peer's place at once; unsigned, its succession starts.
    void check_rebinding(UdpPeer& fresh, const FrameOrigin& first, TimePoint now);
    /// The peer whose stream `first` (a new peer's first frame) carries on, or null: the same
    /// signed stream (system, component, link id) for a verified frame; for an unsigned one,
    /// the same system and component, the sequence a little further.
    UdpPeer* continued_stream(const UdpPeer& fresh, const FrameOrigin& first) const;
    /// A valid datagram `origin` from a newcomer in succession: it takes the old peer's place
    /// once the rule is met, and is a peer like any other once the old one spoke again.
    void judge_succession(UdpPeer& peer, const FrameOrigin& origin, TimePoint now);
    /// `fresh` takes the place of `old`, whose address is forgotten.
    void rebind(UdpPeer& old, UdpPeer& fresh, TimePoint now);
    /// A peer leaves after this round (a bond may hold its frames): not ready meanwhile.
    void retire(UdpPeer& peer);
    /// Forgets a peer: detached, what waits for it dropped and counted, counters kept.
    void forget(UdpPeer& peer, TimePoint now);
    void forget_retired();
    void forget_silent_peers();

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
    // Addresses left by a rebinding, and when: one that sends again within peer_timeout was a
    // second live path of one system (two modems to one port), not a NAT rebinding.
    struct Rebinding {
        SocketAddress from;
        TimePoint at;
    };
    std::array<Rebinding, 4> rebindings_{};
    size_t next_rebinding_ = 0;
    TimePoint rebinding_paused_until_{};  // after two live paths: for peer_timeout
    LinkCounters retired_;      // counters of forgotten peers, so totals never go back
    LogBudget peer_log_{20, seconds(10)};  // peers learned, forgotten, rebound
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
