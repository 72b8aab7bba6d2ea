#include "routing/egress_numbering.h"

namespace mavbond {

EgressNumbering::EgressNumbering() : sources_(kMaxSources), tickets_(kTickets) {}

EgressNumbering::Source* EgressNumbering::source(uint8_t sysid, uint8_t compid) {
    uint32_t id = static_cast<uint32_t>(sysid) << 8 | compid;
    uint32_t i = (id * 2654435761u >> 16) % kMaxSources;
    for (uint32_t probes = 0; probes < kMaxSources; probes++, i = (i + 1) % kMaxSources) {
        Source& s = sources_[i];
        if (!s.in_use) {
            s.in_use = true;
            s.sysid = sysid;
            s.compid = compid;
            return &s;
        }
        if (s.sysid == sysid && s.compid == compid)
            return &s;
    }
    return nullptr;
}

uint64_t EgressNumbering::issue(const Frame& frame) {
    if (frame.is_signed())
        return 0;
    Source* s = source(frame.sysid, frame.compid);
    if (!s) {
        counters_.untracked++;
        return 0;
    }
    if (!s->started) {
        // The source's first frame: its own number is where the bond's numbering starts.
        s->started = true;
        s->next = frame.seq;
    } else {
        s->owed += static_cast<uint8_t>(frame.seq - s->last_seq - 1);
    }
    s->last_seq = frame.seq;
    const uint64_t id = next_id_++;
    tickets_[id % kTickets] = Ticket{id, static_cast<uint16_t>(s - sources_.data()), -1};
    return id;
}

uint8_t EgressNumbering::number(uint64_t ticket, uint8_t sysid, uint8_t compid) {
    Ticket& t = tickets_[ticket % kTickets];
    Source* s = nullptr;
    if (t.id == ticket) {
        if (t.number >= 0)
            return static_cast<uint8_t>(t.number);
        s = &sources_[t.source];
    } else {
        // Reused by a later routing: the frame waited past any budget's or resend's hold. It
        // takes the next number of its source, as a first copy would.
        counters_.expired++;
        s = source(sysid, compid);  // there: it had a ticket, and sources are never forgotten
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
    if (sources_[t.source].given + sources_[t.source].owed - t.given_at < kMaxLag)
        return false;
    counters_.superseded++;
    return true;
}

}  // namespace mavbond
