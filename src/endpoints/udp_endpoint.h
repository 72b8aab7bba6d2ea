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
    const sockaddr_in& from(size_t i) const { return addrs_[i]; }
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
    std::array<sockaddr_in, kCount> addrs_{};
    std::array<std::array<uint8_t, kControl>, kCount> control_{};
    std::array<TimePoint, kCount> arrival_{};
    size_t count_ = 0;
    TimePoint drained_at_{};    // the round's start, when the last receive found the socket empty
    TimePoint last_arrival_{};  // arrivals never go back (a stepped wall clock)
};

class UdpServer;

class UdpPeer : public Endpoint {
public:
    UdpPeer(UdpServer& server, const sockaddr_in& addr, TimePoint now);
    const char* kind() const override { return "udp-peer"; }
    const sockaddr_in& address() const { return addr_; }
    TimePoint last_heard() const { return last_heard_; }
    void heard(TimePoint now) { last_heard_ = now; }

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    UdpServer& server_;
    sockaddr_in addr_;
    TimePoint last_heard_;
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
    UdpPeer* peer_for(const sockaddr_in& addr, TimePoint now);
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
    LinkCounters retired_;      // counters of forgotten peers, so totals never go back
    uint64_t refused_peers_ = 0;
};

class UdpClient : public Endpoint {
public:
    static Result<std::unique_ptr<UdpClient>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~UdpClient() override;
    const char* kind() const override { return "udp-client"; }
    LinkCounters total_counters() const override;

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    UdpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              UniqueFd fd);
    void on_events(uint32_t events);

    FrameSink& sink_;
    UnknownIdPolicy policy_;
    UniqueFd fd_;  // connected to the peer
    EventLoop::Watch watch_;
    Input input_{config().bond, watch_};  // for the arrival order of its bond's links
    DatagramBatch datagrams_;
    ReceivedBatch frames_{sink_, &input_};
};

/// sendmmsg of one datagram per iovec (to `to`, or to the connected peer when null).
int send_datagrams(int fd, const iovec* frames, size_t count, const sockaddr_in* to);

}  // namespace mavbond
