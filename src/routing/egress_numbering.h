// A bond's numbering of what it sends. A frame routed to a bond goes on some of its links at
// once, waits in a link's budget (endpoints/tx_budget.h) or in standby for a resend
// (routing/standby.h), or goes on none: a budget thins a waiting sample when a newer one comes,
// standby keeps telemetry off a metered link. Numbered as its source numbered it, a frame that
// no link carried would be a gap in the sequence the far side sees, which a ground station
// counts as lost, though nothing was lost: the sender chose not to send it. So a bond numbers
// its frames itself, per source, as they go: a frame takes the next number of its source when
// its first copy goes on a line, and every later copy (another link's, a resend) goes with the
// same one. A frame that never goes takes none. Gaps in the source's own numbering (frames lost
// before they reached mavbond) stay gaps: each is owed and stepped over by the next number
// given, so the far side still counts them.
//
// The frame being routed gets a ticket (issue); a link that sends it at once asks for its
// number then (number), a link that holds it keeps the ticket and asks when the copy goes.
// Tickets live in a ring: one whose frame waited longer than kTickets later routings (far
// longer than any budget or resend holds a frame) has expired, and its frame takes a fresh
// number.
// Frames signed by their source keep their number (the signature covers it): no ticket.
//
// A held copy whose frame's number lies far behind its source's newest is superseded, not
// sent: another link carried the frame long ago (a radio whose queue lags the LTE by a
// parameter download), and the far side unwraps each link's sequence byte into positions, so
// a step back of more than half of 256 would read as a step forward and misplace the link.
// The copy was a spare: its frame went, on the link that gave it its number.
#pragma once

#include <cstdint>
#include <vector>

#include "mavbond/source_table.hpp"
#include "mavlink/frame.h"

namespace mavbond {

class EgressNumbering {
public:
    static constexpr size_t kTickets = 8192;
    static constexpr uint32_t kSourceSlots = 128;
    static constexpr uint32_t kMaxSources = SourceTable<char, kSourceSlots>::kMaxSources;
    // How far behind its source's newest number a held copy may still go: under half of 256
    // (a step back the far side reads as one), with room for the link's own later frames.
    static constexpr uint64_t kMaxLag = 96;

    struct Counters {
        uint64_t numbered = 0;   // frames given their number (their first copy went)
        uint64_t expired = 0;    // asked for after their ticket was reused: a fresh number
        uint64_t untracked = 0;  // frames of sources beyond the table: sent as they came
        uint64_t superseded = 0; // held copies not sent: their number too far behind (above)
    };

    EgressNumbering();

    /// A ticket for `frame`, about to go to the bond's links; 0: it keeps its own number (a
    /// frame signed by its source, one of a source beyond the table).
    uint64_t issue(const Frame& frame);
    /// The number the frame of `ticket` (from sysid, compid) goes out with: the one it took
    /// when its first copy went, or, for that first copy, the next of its source.
    uint8_t number(uint64_t ticket, uint8_t sysid, uint8_t compid);
    /// Whether the held copy of `ticket` is superseded (above): its frame took its number when
    /// another copy went, more than kMaxLag numbers ago. Counted when true.
    bool superseded(uint64_t ticket);

    const Counters& counters() const { return counters_; }

private:
    struct Source {
        bool started = false;
        uint8_t last_seq = 0;  // the source's own number of the last frame issued
        uint8_t next = 0;      // the next number to give
        uint32_t owed = 0;     // the source's own gaps not yet stepped over
        uint64_t given = 0;    // numbers passed so far (given or stepped over): no wrap
    };
    struct Ticket {
        uint64_t id = 0;
        uint16_t source = 0;
        int16_t number = -1;  // -1: not given yet
        uint64_t given_at = 0; // its source's `given` once it took its number
    };

    using Sources = SourceTable<Source, kSourceSlots>;

    Sources sources_;  // a ticket names its source by its slot
    std::vector<Ticket> tickets_;  // a ring by id
    uint64_t next_id_ = 1;
    Counters counters_;
};

}  // namespace mavbond
