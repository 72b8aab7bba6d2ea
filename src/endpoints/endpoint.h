// An endpoint is one place frames come from and go to: a UDP peer, a UDP client, a TCP
// connection, a UART. Servers (UDP, TCP) are endpoints too, but not route targets: they own
// the peers/connections they learn, which are.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "config/config.h"
#include "endpoints/tx_queue.h"
#include "mavlink/frame.h"
#include "mavlink/frame_parser.h"
#include "mavlink/signing.h"

namespace mavbond {

class Router;
class EventLoop;

struct EndpointStats {
    ParserCounters rx;          // frames, bytes, crc_errors, garbage_bytes, unknown_ids, bad_flags
    uint64_t rx_filtered = 0;   // dropped by allow_in/block_in
    uint64_t rx_overflows = 0;  // datagrams the kernel dropped: the receive buffer was full
    uint64_t tx_frames = 0;
    uint64_t tx_bytes = 0;
    uint64_t tx_filtered = 0;   // dropped by allow_out/block_out
    uint64_t tx_dropped = 0;    // transmit queue full, link down, or a write error
    uint64_t tx_errors = 0;     // hard write errors (ICMP unreachable, EIO, ...)
    uint64_t sig_unsigned = 0;  // signing endpoints: unsigned frames (dropped when required)
    uint64_t sig_bad = 0;       // signing endpoints: dropped, signature does not verify
    uint64_t sig_replay = 0;    // signing endpoints: dropped, timestamp replayed or too old
    TimePoint last_rx{};        // when a frame last came in (epoch: never); not a counter

    EndpointStats& operator+=(const EndpointStats& o);
};

/// Calls f(name, value) for every counter, in one order: the stats log lines, the status
/// socket and the tests all name them this way.
template <typename F>
void for_each_counter(const EndpointStats& s, F&& f) {
    f("rx_frames", s.rx.frames);
    f("rx_bytes", s.rx.bytes);
    f("crc_errors", s.rx.crc_errors);
    f("garbage_bytes", s.rx.garbage_bytes);
    f("unknown_ids", s.rx.unknown_ids);
    f("bad_flags", s.rx.bad_flags);
    f("rx_filtered", s.rx_filtered);
    f("rx_overflows", s.rx_overflows);
    f("tx_frames", s.tx_frames);
    f("tx_bytes", s.tx_bytes);
    f("tx_filtered", s.tx_filtered);
    f("tx_dropped", s.tx_dropped);
    f("tx_errors", s.tx_errors);
    f("sig_unsigned", s.sig_unsigned);
    f("sig_bad", s.sig_bad);
    f("sig_replay", s.sig_replay);
}

/// Allow/block lists; an empty allow list allows everything, block wins.
class MessageFilter {
public:
    explicit MessageFilter(const MessageFilterConfig& config) : config_(config) {}
    bool passes(uint32_t msgid) const;
    bool empty() const { return config_.allow.empty() && config_.block.empty(); }

private:
    const MessageFilterConfig& config_;
};

class Endpoint {
public:
    using Ptr = std::unique_ptr<Endpoint>;
    static constexpr uint32_t kNoId = UINT32_MAX;

    /// The endpoint keeps its own copy of `config`: a reload replaces the daemon's Config
    /// while the endpoints it did not change keep running. A child (a UDP peer, a TCP
    /// connection) names its `parent` server: they share one signature verifier, so a frame
    /// replayed from a new address is still a replay.
    Endpoint(const EndpointConfig& config, std::string name, TxQueue::Mode mode,
             const Endpoint* parent = nullptr);
    virtual ~Endpoint();
    Endpoint(const Endpoint&) = delete;
    Endpoint& operator=(const Endpoint&) = delete;

    const std::string& name() const { return name_; }
    const EndpointConfig& config() const { return config_; }
    /// Dense id assigned by the router while registered; kNoId otherwise.
    uint32_t id() const { return id_; }
    void set_id(uint32_t id) { id_ = id; }
    /// A short type word for logs: "udp-server", "udp-peer", "tcp", "uart", ...
    virtual const char* kind() const = 0;

    /// True when the endpoint can take frames now (a TCP client that is connected, a UART
    /// that is open). Frames routed to an endpoint that is not ready are dropped and counted.
    virtual bool ready() const { return true; }
    /// True for a recorder (a flight log): the router sends it every frame it routes, a
    /// targeted frame too, wherever its target was heard.
    virtual bool receives_everything() const { return false; }

    /// Accepts a frame for transmission if allow_out/block_out let it through. The frame's
    /// bytes are lent until flush(). Returns true when the endpoint became dirty (needs flush).
    bool send(const Frame& frame);
    /// Writes what send() lent and whatever waited; called at the end of each receive batch.
    void flush();
    bool has_pending() const { return !tx_.empty(); }

    /// Whether an incoming frame passes allow_in/block_in (counted when it does not).
    bool accept_in(const Frame& frame);
    /// Whether an incoming frame passes the endpoint's `signing:` check (counted when it does
    /// not); true without one. The router asks before the frame can teach a route.
    bool authentic(const Frame& frame) { return !verifier_ || check_signature(frame); }

    /// The endpoint stops (the daemon exits, or a reload removes it): what is queued is written
    /// if the peer takes it now, a frame left half written on a stream is completed (waiting
    /// for the peer until `deadline`), and the rest is counted as dropped, so the final
    /// counters account for every frame.
    virtual void finish(TimePoint deadline);

    /// Counters of this endpoint alone.
    const EndpointStats& stats() const { return stats_; }
    /// Counters of this endpoint and every child (peers, connections), present and past.
    virtual EndpointStats total_stats() const { return stats_; }

protected:
    /// Datagram endpoints: send each iovec as one datagram; return the count sent or -errno.
    virtual int write_datagrams(const iovec* frames, size_t count);
    /// Stream endpoints: write the iovecs; return bytes written or -errno.
    virtual ssize_t write_stream(const iovec* iov, size_t count);
    /// Called after a flush: arm EPOLLOUT while `backlog` is true.
    virtual void on_backlog(bool backlog) { (void)backlog; }
    /// Called when a stream write failed hard (peer gone, device unplugged).
    virtual void on_write_error(int err) { (void)err; }
    /// Stream endpoints: waits a moment for the peer to take more; false once `deadline` passed.
    virtual bool wait_writable(TimePoint deadline) { (void)deadline; return false; }

    /// Drops everything queued (reconnects start at a frame boundary), counting it.
    void clear_tx();
    /// Runs `fn` after this dispatch round, unless the endpoint is gone by then (a reload may
    /// destroy it in the same round).
    void defer(EventLoop& loop, std::function<void()> fn);

    EndpointStats stats_;

private:
    bool check_signature(const Frame& frame);

    const EndpointConfig config_;  // before the filters, which point into it
    std::string name_;
    uint32_t id_ = kNoId;
    TxQueue tx_;
    std::shared_ptr<void> alive_ = std::make_shared<int>(0);  // expires with the endpoint
    MessageFilter filter_in_;
    MessageFilter filter_out_;
    std::shared_ptr<SignatureVerifier> verifier_;  // null unless the config has `signing:`
};

/// Builds one endpoint of `config` (whose global settings it takes).
Result<Endpoint::Ptr> make_endpoint(const EndpointConfig& endpoint, const Config& config,
                                    EventLoop& loop, Router& router);
/// Builds every endpoint the config declares. Servers bind now (a failure is returned);
/// UARTs and TCP clients that cannot open yet retry in the background.
Result<std::vector<Endpoint::Ptr>> make_endpoints(const Config& config, EventLoop& loop,
                                                  Router& router);

}  // namespace mavbond
