// An endpoint is what the config declares: a UDP client, a UART, a flight log, each a link
// (routing/link.h) it attaches to the frame sink it is handed; or a server (UDP, TCP), which
// is no route target itself but owns the links it learns (UDP peers, TCP connections).
// Endpoints decide what they can about a received frame before handing it over (its
// signature, allow_in/block_in), so routing never asks them anything per frame.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/event_loop.h"
#include "endpoints/radio_flow.h"
#include "endpoints/tx_budget.h"
#include "endpoints/tx_queue.h"
#include "mavlink/frame.h"
#include "mavlink/frame_parser.h"
#include "mavlink/signing.h"
#include "routing/frame_sink.h"
#include "routing/link.h"

namespace mavbond {

class EventLoop;

/// Allow/block lists; an empty allow list allows everything, block wins.
class MessageFilter {
public:
    explicit MessageFilter(const MessageFilterConfig& config) : config_(config) {}
    bool passes(uint32_t msgid) const;
    bool empty() const { return config_.allow.empty() && config_.block.empty(); }

private:
    const MessageFilterConfig& config_;
};

class Endpoint : public Link {
public:
    using Ptr = std::unique_ptr<Endpoint>;
    /// A flight log's role: it gets every frame routed, targeted ones too.
    enum class Role { Link, Recorder };

    /// The endpoint keeps its own copy of `config`: a reload replaces the daemon's Config
    /// while the endpoints it did not change keep running. A child (a UDP peer, a TCP
    /// connection) names its `parent` server: they share one signature verifier, so a frame
    /// replayed from a new address is still a replay.
    Endpoint(const EndpointConfig& config, std::string name, EventLoop& loop, TxQueue::Mode mode,
             const Endpoint* parent = nullptr, Role role = Role::Link);
    ~Endpoint() override;

    const EndpointConfig& config() const { return config_; }
    /// A short type word for logs: "udp-server", "udp-peer", "tcp", "uart", ...
    virtual const char* kind() const = 0;

    /// True when the endpoint can take frames now (a TCP client that is connected, a UART
    /// that is open). Frames routed to an endpoint that is not ready are dropped and counted.
    virtual bool ready() const { return true; }

    /// Accepts a frame for transmission if allow_out/block_out let it through. The frame's
    /// bytes are lent until flush(). Returns true when the endpoint became dirty (needs flush).
    bool send(const Frame& frame) override;
    /// Writes what send() lent and whatever waited; called at the end of each receive batch.
    void flush() override;
    bool has_pending() const { return !tx_.empty(); }

    /// Who sent a frame, and its place in the sender's sequence.
    struct FrameOrigin {
        bool known = false;  // false: the datagram held no frame
        uint8_t sysid = 0, compid = 0, seq = 0;
    };
    /// Parses a datagram this link received and puts its frames into `batch` (receive());
    /// returns the origin of its last frame that signing let in.
    FrameOrigin receive_datagram(ReceivedBatch& batch, std::span<const uint8_t> datagram,
                                 TimePoint arrival, UnknownIdPolicy policy);

    /// The endpoint stops (the daemon exits, or a reload removes it): what is queued is written
    /// if the peer takes it now, a frame left half written on a stream is completed (waiting
    /// for the peer until `deadline`), and the rest is counted as dropped, so the final
    /// counters account for every frame.
    virtual void finish(TimePoint deadline);

    /// Takes on a new transmit budget (a reload), with no restart: what the old one held goes
    /// now, its counters go on. A server passes it to its peers or connections.
    virtual void retune(const TxBudgetConfig& budget);

    /// The loop it runs on (its children run on it too).
    EventLoop& loop() const { return loop_; }
    /// Its transmit budget (`tx_rate`), or null.
    const TxBudget* budget() const { return budget_.get(); }
    /// What its radio reported and made of the budget (`radio_status`), or null.
    const RadioFlow* radio() const { return radio_.get(); }

    /// Counters of this endpoint alone.
    const LinkCounters& counters() const override { return stats_; }
    /// Counters of this endpoint and every child (peers, connections), present and past.
    virtual LinkCounters total_counters() const { return stats_; }

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

    /// A frame this link received, on its way into `batch`: dropped here (counted) when its
    /// signature does not let it in; routing only learns from it when allow_in/block_in
    /// refuse it. False when signing refused it.
    bool receive(ReceivedBatch& batch, const Frame& frame, TimePoint arrival);
    /// Drops everything queued (reconnects start at a frame boundary), counting it.
    void clear_tx();
    /// Runs `fn` after this dispatch round, unless the endpoint is gone by then (a reload may
    /// destroy it in the same round).
    void defer(EventLoop& loop, std::function<void()> fn);

    LinkCounters stats_;
    EventLoop& loop_;

private:
    /// Whether the frame passes the `signing:` check (counted when it does not).
    bool authentic(const Frame& frame);
    /// Sends what the budget lets go now and sets the timer for the rest.
    void release_budgeted();
    /// Writes a frame whose bytes live only during the call (the budget's copies).
    void lend_now(std::span<const uint8_t> frame);
    /// The budget config_ asks for (null for none); with `radio_status`, at the rate the radio's
    /// reports made it so far.
    std::unique_ptr<TxBudget> make_budget();
    /// Keeps radio_ in step with config_ (made, its ceiling moved, or dropped with no
    /// `radio_status` or no budget, `ceiling` 0); returns the rate a budget starts at.
    uint64_t follow_radio(uint64_t ceiling);
    /// A report of the radio on this link: the budget follows it.
    void take_radio_report(const Frame& frame, TimePoint arrival);
    /// The budget at the radio's rate now; what it holds goes when the new rate lets it.
    void apply_radio_rate(uint64_t rate);

    EndpointConfig config_;  // before the filters, which point into it; only retune() changes it
    TxQueue tx_;
    std::shared_ptr<void> alive_ = std::make_shared<int>(0);  // expires with the endpoint
    MessageFilter filter_in_;
    MessageFilter filter_out_;
    std::shared_ptr<SignatureVerifier> verifier_;  // null unless the config has `signing:`
    std::unique_ptr<RadioFlow> radio_;  // null unless the config has `radio_status:`
    EventLoop::Timer radio_timer_;      // notices reports that stopped
    std::unique_ptr<TxBudget> budget_;  // null unless the config has `tx_rate:` (or radio_status)
    EventLoop::Timer budget_timer_;     // runs while the budget holds frames
    TimePoint budget_due_ = TimePoint::max();
};

/// Builds one endpoint of `config` (whose global settings it takes), its links attached to
/// `sink`.
Result<Endpoint::Ptr> make_endpoint(const EndpointConfig& endpoint, const Config& config,
                                    EventLoop& loop, FrameSink& sink);
/// Builds every endpoint the config declares. Servers bind now (a failure is returned);
/// UARTs and TCP clients that cannot open yet retry in the background.
Result<std::vector<Endpoint::Ptr>> make_endpoints(const Config& config, EventLoop& loop,
                                                  FrameSink& sink);

}  // namespace mavbond
