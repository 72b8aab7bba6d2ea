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
#include "mavlink/bond_signing.h"
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
    /// connection) names its `parent` server: they share one signature verifier (or its
    /// bond's signing), so a frame replayed from a new address is still a replay.
    Endpoint(const EndpointConfig& config, std::string name, EventLoop& loop, TxQueue::Mode mode,
             const Endpoint* parent = nullptr, Role role = Role::Link);
    ~Endpoint() override;

    const EndpointConfig& config() const { return config_; }
    /// A short type word for logs: "udp-server", "udp-peer", "tcp", "uart", ...
    virtual const char* kind() const = 0;

    /// True when the endpoint can take frames now (a TCP client that is connected, a UART
    /// that is open). Frames routed to an endpoint that is not ready are dropped and counted.
    virtual bool ready() const { return true; }
    /// Why it is not open ("" when it is): the last failure to open or connect, as logged.
    std::string open_error() const {
        return ready() ? std::string() : open_error_.empty() ? "not open yet" : open_error_;
    }
    /// Calls f for each of its links: itself, or a server's peers or connections.
    virtual void for_each_link(const std::function<void(const Link&)>& f) const { f(*this); }

    /// Accepts a frame for transmission if allow_out/block_out let it through. The frame's
    /// bytes are lent until flush(). Returns true when the endpoint became dirty (needs flush).
    /// With its bond's `copy`: sends the numbered copy at once, or holds the frame with its
    /// ticket (Link::send).
    bool send(const Frame& frame, BondCopy* copy = nullptr) override;
    /// Writes what send() lent and whatever waited; called at the end of each receive batch.
    void flush() override;
    bool has_pending() const { return !tx_.empty(); }

    /// What the endpoint's checks made of a received frame (in this order: valid() is the
    /// last two).
    enum class Received {
        Refused,    // signing refused it (counted): it goes nowhere and proves nothing
        Taken,      // taken by the link itself (a radio's own report, a count marker): never
                    // routed, says nothing of who sends on the link
        Unchecked,  // let in, but its CRC could not be checked (an unknown id): proves nothing
        Valid,      // its CRC checked, and signing (if any) let it in unsigned
        Verified,   // its signature verified (`signing:`)
    };
    /// Whether a frame proves its sender: a valid or verified one.
    static bool valid(Received how) { return how >= Received::Valid; }
    /// Who sent a frame, and its place in the sender's sequence.
    struct FrameOrigin {
        bool known = false;  // false: the datagram held no valid frame
        bool verified = false;  // its signature verified (then link_id is the signature's)
        uint8_t sysid = 0, compid = 0, seq = 0, link_id = 0;
    };
    /// Parses a datagram this link received and puts its frames into `batch` (receive());
    /// returns the origin of its last valid frame.
    FrameOrigin receive_datagram(ReceivedBatch& batch, std::span<const uint8_t> datagram,
                                 TimePoint arrival, UnknownIdPolicy policy) {
        DatagramParser parser(datagram, policy, stats_.rx);
        return receive_frames(batch, parser, arrival, FrameOrigin{});
    }
    /// When the last valid frame came in (epoch: never): what a peer or a connection holds
    /// its place by (garbage, refused and unchecked frames never refresh it).
    TimePoint last_valid() const { return last_valid_; }

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
    /// A link its bond signs (`bonds: signing:`, config().signing.by_bond) verifies every
    /// frame it receives with the bond's signing, as the bond's member `endpoint`, and counts
    /// the frames it sends with the bond's signature; make_endpoint() gives it, before the
    /// first read. False when the bond has no room for another signed link.
    bool sign_with(std::shared_ptr<BondSigning> signing);
    /// The bond's signing when this link's frames go signed, else null. The router signs what
    /// it routes once per frame before the links get it; a frame an endpoint makes itself for
    /// this link (a report of its own) is signed here at write time:
    ///     if (BondSigning* s = bond_signing()) len = s->sign(frame, out);
    BondSigning* bond_signing() const { return bond_signing_.get(); }

    /// Who its count markers come from (mavbond's identity, as it is now: it may be derived
    /// after the start); a child takes its server's, and a server passes it to its children.
    virtual void set_marker_source(uint8_t sysid, uint8_t compid) {
        marker_source_ = FrameSource{sysid, compid, marker_source_.seq};
    }
    /// Its transmit budget (`tx_rate`), or null.
    const TxBudget* budget() const { return budget_.get(); }
    /// What its radio reported and made of the budget (`radio_status`), or null.
    const RadioFlow* radio() const { return radio_.get(); }
    /// What its budget says of the room for the autopilot's stream since the last call
    /// (budget_room, endpoints/radio_flow.h); 100 without a budget. The bond's RADIO_STATUS
    /// asks, once a report.
    uint8_t take_budget_room(TimePoint now);

    /// Counters of this endpoint alone.
    const LinkCounters& counters() const override { return stats_; }
    void route_evicted() override { stats_.routes_evicted++; }
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
    /// signature does not let it in (the one check every received frame passes, the place a
    /// server may learn a peer from); routing only learns from it when allow_in/block_in
    /// refuse it. Only a frame signing lets in makes the link heard (`last_rx`); a radio's
    /// own report and a count marker are taken here. A frame its
    /// bond signed goes on without the signature (BondSigning::verify), its signed identity
    /// in `id` when given.
    Received receive(ReceivedBatch& batch, const Frame& frame, TimePoint arrival,
                     SignedId* id = nullptr);
    /// The frames `parser` still yields, through receive(); returns the origin of the last
    /// valid one (`last` when none is), and counts the datagram as heard (last_valid) when
    /// that is known.
    FrameOrigin receive_frames(ReceivedBatch& batch, DatagramParser& parser, TimePoint arrival,
                               FrameOrigin last) {
        Frame frame;
        while (parser.next(frame)) {
            // A frame signing refuses, or whose CRC could not be checked, says nothing about
            // who sent it (it may be forged, or noise).
            SignedId id;
            Received how = receive(batch, frame, arrival, &id);
            if (valid(how))
                last = origin_of(frame, how, id);
        }
        if (last.known)
            heard_valid(arrival);
        return last;
    }
    /// The checks of receive() without handing the frame on (a server's look at a datagram
    /// from an address that is no peer yet): the signature verdict is counted here, and
    /// recorded (a replay check): a frame is judged once. A frame its bond signed loses the
    /// signature here, its signed identity in `id`.
    Received judge(Frame& frame, SignedId& id);
    /// Hands on a frame judge() let in, as receive() does after its checks: the link's
    /// account counts it, a count marker is taken here (false: it goes no further).
    bool let_in(ReceivedBatch& batch, const Frame& frame, TimePoint arrival, const SignedId& id);
    /// The origin of a frame (as received, before judge()) the checks made `how` of (unknown
    /// unless Valid or Verified). A frame its bond signed counts as verified, for a peer's
    /// rebinding, only when it is the newest of its stream on any link (`id.newest`): a late
    /// copy may be one a stranger captured on another link.
    static FrameOrigin origin_of(const Frame& frame, Received how, const SignedId& id) {
        if (!valid(how))
            return {};
        bool verified = how == Received::Verified && (!id.known || id.newest);
        // A verified frame is signed: the signature block begins with its link id.
        uint8_t link_id = !verified ? 0
                          : id.known ? static_cast<uint8_t>(id.stream & 0xff)
                                     : frame.bytes[frame.bytes.size() - kSignatureLen];
        return FrameOrigin{true, verified, frame.sysid, frame.compid, frame.seq, link_id};
    }
    /// A valid frame came in at `t` (once per datagram or read, not per frame).
    void heard_valid(TimePoint t) { last_valid_ = t; }
    /// Drops everything queued (reconnects start at a frame boundary), counting it.
    void clear_tx();
    /// Runs `fn` after this dispatch round, unless the endpoint is gone by then (a reload may
    /// destroy it in the same round).
    void defer(EventLoop& loop, std::function<void()> fn);

    LinkCounters stats_;
    EventLoop& loop_;
    std::string open_error_;  // what open_error() says while it is not ready

private:
    /// Counts a frame handed to the line that carries its bond's signature (`tx_signed`).
    void count_signed(std::span<const uint8_t> bytes) {
        if (bond_signing_ && BondSigning::signed_by_bond(bytes))
            stats_.tx_signed++;
    }
    /// Sends what the budget lets go now and sets the timer for the rest.
    void release_budgeted();
    /// Writes a frame whose bytes live only during the call (the budget's copies).
    void lend_now(std::span<const uint8_t> frame);
    /// Writes a frame the budget held, numbered now on its bond if it has a `ticket`
    /// (BondCopy), and signed then where the bond signs this link.
    void lend_held(std::span<uint8_t> frame, uint64_t ticket);
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
    /// A bond member: every kCountMarkerEvery, a count marker when frames went out since the
    /// last one (routing/link_account.h).
    void send_count_marker();
    /// Where a count marker's bytes are made, right before each write that may carry it (the
    /// one place: a link that signs what it sends signs it here).
    size_t write_marker(std::span<uint8_t> out, uint64_t frames_before);
    /// The bytes one of its markers takes on the line (signed where its bond signs).
    size_t marker_length() const;

    EndpointConfig config_;  // before the filters, which point into it; only retune() changes it
    TxQueue tx_;
    std::shared_ptr<void> alive_ = std::make_shared<int>(0);  // expires with the endpoint
    MessageFilter filter_in_;
    MessageFilter filter_out_;
    std::shared_ptr<SignatureVerifier> verifier_;  // null unless the config has `signing:`
    std::shared_ptr<BondSigning> bond_signing_;    // null unless its bond signs it
    std::shared_ptr<EgressNumbering> numbering_;   // its bond's, once it held a frame of it
    unsigned bond_member_ = 0;                     // its place in the bond's replay window
    std::unique_ptr<RadioFlow> radio_;  // null unless the config has `radio_status:`
    EventLoop::Timer radio_timer_;      // notices reports that stopped
    uint64_t lost_at_report_ = 0;       // the budget's lost count at the radio's last report
    TxBudget::Load room_seen_;          // the budget's load at the last take_budget_room()
    TimePoint room_at_{};
    std::unique_ptr<TxBudget> budget_;  // null unless the config has `tx_rate:` (or radio_status)
    EventLoop::Timer budget_timer_;     // runs while the budget holds frames
    TimePoint budget_due_ = TimePoint::max();
    TimePoint last_valid_{};
    FrameSource marker_source_{1, 191, 0};  // its seq: this link's markers, one after another
    uint32_t marker_session_ = 0;           // when the link was made, in ms: a new count
    uint64_t marked_ = 0;                    // frames written up to the last marker, itself in
    EventLoop::Timer marker_timer_;          // bond members only
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
