#include "routing/egress_numbering.h"

namespace mavbond {

EgressNumbering::EgressNumbering() : tickets_(kTickets) {}

uint64_t EgressNumbering::issue(const Frame& frame) {
    if (frame.is_signed())
        return 0;
    const uint32_t slot = sources_.slot(frame.sysid, frame.compid);
    if (slot == Sources::kFull) {
        counters_.untracked++;
        return 0;
    }
    Source* s = &sources_.at(slot);
    if (!s->started) {
        // The source's first frame: its own number is where the bond's numbering starts.
        s->started = true;
        s->next = frame.seq;
    } else {
        s->owed += static_cast<uint8_t>(frame.seq - s->last_seq - 1);
    }
    s->last_seq = frame.seq;
    const uint64_t id = next_id_++;
    tickets_[id % kTickets] = Ticket{id, static_cast<uint16_t>(slot), -1};
    return id;
}

uint8_t EgressNumbering::number(uint64_t ticket, uint8_t sysid, uint8_t compid) {
    Ticket& t = tickets_[ticket % kTickets];
    Source* s = nullptr;
    if (t.id == ticket) {
        if (t.number >= 0)
            return static_cast<uint8_t>(t.number);
        s = &sources_.at(t.source);
    } else {
        // Reused by a later routing: the frame waited past any budget's or resend's hold. It
        // takes the next number of its source, as a first copy would.
        counters_.expired++;
        s = sources_.find(sysid, compid);  // there: it had a ticket, sources are never forgotten
        if (!s)
            return 0;
    }
    const auto n = static_cast<uint8_t>(s->next + s->owed);
    s->given += s->owed + 1;
    s->owed = 0;
    s->next = static_cast<uint8_t>(n + 1);
    if (t.id == ticket) {
        t.number = n;
        t.given_at = s->given;
    }
    counters_.numbered++;
    return n;
}

bool EgressNumbering::superseded(uint64_t ticket) {
    const Ticket& t = tickets_[ticket % kTickets];
    if (t.id != ticket || t.number < 0)
        return false;
    // How far back the far side must step for it from the source's next frame.
    const Source& s = sources_.at(t.source);
    if (s.given + s.owed - t.given_at < kMaxLag)
        return false;
    counters_.superseded++;
    return true;
}

}  // namespace mavbond
