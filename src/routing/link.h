// A link is a route target: a place frames come from and go to (a UDP peer or client, a TCP
// connection, a UART, a flight log). Endpoints (src/endpoints) are links; routing knows them
// only through this class and never includes an endpoint's header.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>

#include "config/config.h"
#include "core/clock.h"
#include "mavlink/frame.h"
#include "mavlink/frame_parser.h"
#include "routing/link_account.h"

namespace mavbond {

/// What a link with a transmit budget (`tx_rate`) did with one class of frames
/// (src/endpoints/tx_budget.h): control, telemetry, bulk.
struct TxClassCounters {
    uint64_t frames = 0;   // handed to the line
    uint64_t bytes = 0;    // of them, with the link's framing charged
    uint64_t waited = 0;   // of them, held for the budget (or a cap) first
    uint64_t thinned = 0;  // replaced, while held, by a newer sample of the same message
    uint64_t dropped = 0;  // bulk: the oldest when the queue was full; telemetry: no slot left

    TxClassCounters& operator+=(const TxClassCounters& o);
};

/// Calls f(name, value) for each of a class's counters, in one order.
template <typename F>
void for_each_counter(const TxClassCounters& c, F&& f) {
    f("frames", c.frames);
    f("bytes", c.bytes);
    f("waited", c.waited);
    f("thinned", c.thinned);
    f("dropped", c.dropped);
}

/// A link's counters (and an endpoint's, summed over its links): what the status socket,
/// /metrics, the log lines and the plugins' link_counters show.
struct LinkCounters {
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
    uint64_t tx_signed = 0;     // handed to the line with its bond's signature (13 bytes more)
    uint64_t resolve_failures = 0;  // clients of a name: lookups that failed
    uint64_t address_changes = 0;   // clients of a name: a lookup gave a new address
    uint64_t peer_rebinds = 0;      // UDP servers: a peer went on from a new address (NAT)
    uint64_t stranger_datagrams = 0;  // UDP servers: from no peer, with no frame that passed
    uint64_t peers_evicted = 0;     // UDP servers: forgotten to make room (a full peer table)
    uint64_t clients_refused = 0;   // TCP servers: connections refused (a cap reached)
    uint64_t clients_idle_closed = 0;  // TCP servers: closed, no valid frame for idle_timeout
    uint64_t routes_evicted = 0;    // routes learned on it forgotten for the per-link cap
    uint64_t markers_foreign = 0;   // count markers naming another link: not counted
    TimePoint last_rx{};        // when a frame last came in (epoch: never); not a counter
    std::array<TxClassCounters, kTxClassCount> tx_class{};  // with a budget only (see above)

    LinkCounters& operator+=(const LinkCounters& o);
};

/// Calls f(name, value) for every counter, in one order: the log lines, the status socket,
/// /metrics and the tests all name them this way.
template <typename F>
void for_each_counter(const LinkCounters& s, F&& f) {
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
    f("tx_signed", s.tx_signed);
    f("resolve_failures", s.resolve_failures);
    f("address_changes", s.address_changes);
    f("peer_rebinds", s.peer_rebinds);
    f("stranger_datagrams", s.stranger_datagrams);
    f("peers_evicted", s.peers_evicted);
    f("clients_refused", s.clients_refused);
    f("clients_idle_closed", s.clients_idle_closed);
    f("routes_evicted", s.routes_evicted);
    f("markers_foreign", s.markers_foreign);
}

class EgressNumbering;

/// A frame a bond numbers as it goes (routing/egress_numbering.h), as the router hands it to
/// one of the bond's links: a link that sends it at once sends now(); one that holds it (a
/// budget) keeps the frame as routed with `ticket` and, when its copy goes, numbers it with
/// `numbering` (and signs it, where the bond signs the link).
class BondCopy {
public:
    std::shared_ptr<EgressNumbering> numbering;
    uint64_t ticket = 0;
    /// The frame with its number, signed for a link the bond signs: made once per routing,
    /// for whichever link sends it first; null when it cannot go (MAVLink 1 on a signed link).
    virtual const Frame* now(bool signed_link) = 0;

protected:
    ~BondCopy() = default;
};

/// Dense id of an attached link (reused after it detaches).
using LinkId = uint32_t;
constexpr LinkId kNoLink = UINT32_MAX;

class Link {
public:
    /// `endpoint`: the configured endpoint it belongs to (a UDP peer's or TCP connection's
    /// server): its place in a bond and in a filter's scope. `bond`: "" when not in one.
    Link(std::string name, std::string endpoint, std::string bond, bool records_everything)
        : name_(std::move(name)), endpoint_(std::move(endpoint)), bond_(std::move(bond)),
          records_everything_(records_everything) {}
    virtual ~Link() = default;
    Link(const Link&) = delete;
    Link& operator=(const Link&) = delete;

    /// "radio", or "gcs@127.0.0.1:5555" for a learned UDP peer.
    const std::string& name() const { return name_; }
    const std::string& endpoint_name() const { return endpoint_; }
    const std::string& bond() const { return bond_; }
    /// A recorder (a flight log) gets every frame routed, targeted ones too, and sends none.
    bool records_everything() const { return records_everything_; }
    /// Its id while attached to a sink, kNoLink otherwise.
    LinkId id() const { return id_; }

    /// Takes a frame to send; its bytes are lent until flush(). Returns true when the link
    /// has something to flush that it had not before (the sink flushes it at the batch's end).
    /// `copy`: what its bond sends of the frame (a member link), else null: the frame goes
    /// as it is.
    virtual bool send(const Frame& frame, BondCopy* copy = nullptr) = 0;
    /// Writes what send() lent and whatever waited.
    virtual void flush() = 0;
    /// This link's own counters.
    virtual const LinkCounters& counters() const = 0;
    /// Routing forgot a route learned on this link to make room for another (its per-link
    /// cap): counted with the link's counters (routes_evicted).
    virtual void route_evicted() = 0;
    /// What the far side wrote on this link against what arrived (routing/link_account.h):
    /// the endpoint keeps it, routing and the status read it.
    const LinkAccount& account() const { return account_; }
    LinkAccount& account() { return account_; }
    /// Whether its bond keeps it in standby (a metered member while the free ones are
    /// healthy: routing/standby.h); the router keeps it current, its count markers say it.
    bool standby() const { return standby_; }
    void set_standby(bool standby) { standby_ = standby; }

private:
    friend class Router;  // assigns the id at attach
    std::string name_;
    std::string endpoint_;
    std::string bond_;
    bool records_everything_;
    LinkId id_ = kNoLink;
    LinkAccount account_;
    bool standby_ = false;
};

}  // namespace mavbond
