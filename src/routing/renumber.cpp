#include "routing/renumber.h"

namespace mavbond {

uint8_t SeqRenumberer::next_number(Source& s) {
    auto out = static_cast<uint8_t>(s.next_out + s.owed);
    counters_.gaps += s.owed;
    s.owed = 0;
    s.next_out = static_cast<uint8_t>(out + 1);
    return out;
}

uint8_t SeqRenumberer::deliver(uint8_t sysid, uint8_t compid, uint8_t seq, int64_t pos,
                               int64_t t_ns) {
    Source* s = sources_.find(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return seq;
    }
    if (!s->holes) {
        s->holes = std::make_unique<StreamHoles>();
        s->next_out = seq;  // the first frame keeps its number
    }
    s->owed += s->holes->expire(t_ns);
    if (s->holes->deliver(pos, t_ns, s->owed) == StreamHoles::Arrival::Filled)
        counters_.late_filled++;
    // Else new (its skipped positions are holes now), or a copy later than its hole waited:
    // delivered, and already counted lost.
    counters_.renumbered++;
    return next_number(*s);
}

uint8_t SeqRenumberer::deliver_unplaced(uint8_t sysid, uint8_t compid, uint8_t seq) {
    Source* s = sources_.find(sysid, compid);
    if (!s) {
        counters_.untracked++;
        return seq;
    }
    counters_.unplaced++;
    if (!s->holes)
        return seq;  // nothing to continue yet: its own number
    counters_.renumbered++;
    return next_number(*s);
}

std::optional<uint8_t> SeqRenumberer::add(uint8_t sysid, uint8_t compid) {
    Source* s = sources_.find(sysid, compid);
    if (!s || !s->holes)
        return std::nullopt;
    counters_.added++;
    return next_number(*s);
}

}  // namespace mavbond
