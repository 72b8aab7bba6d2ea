#include "routing/renumber_stage.h"

#include <string>

#include "core/log.h"
#include "endpoints/endpoint.h"
#include "mavlink/frame_writer.h"

namespace mavbond {

RenumberStage::RenumberStage(FilterChain& chain, const Router& router,
                             const std::vector<BondConfig>& bonds)
    : chain_(chain), router_(router), bonds_(bonds.size()) {
    for (size_t i = 0; i < bonds.size(); i++) {
        if (bonds[i].renumber) {
            bonds_[i].renumberer = std::make_unique<SeqRenumberer>();
            active_ = true;
        }
    }
}

FrameFilter::Verdict RenumberStage::on_ingress(const Frame& frame, Endpoint& from, TimePoint now) {
    Verdict verdict = chain_.on_ingress(frame, from, now);
    uint32_t bond = router_.bond_of(from);
    if (bond >= bonds_.size() || !bonds_[bond].renumberer)
        return verdict;
    BondState& b = bonds_[bond];
    if (frame.is_signed()) {
        b.signed_left_alone++;
        return verdict;
    }
    if (verdict == Verdict::Drop)
        return verdict;
    // dedup's position for the frame: the same for every link's copy of it.
    const mavbond_frame_notes& notes = chain_.ingress_notes();
    const int64_t t_ns = std::chrono::duration_cast<Duration>(now.time_since_epoch()).count();
    uint8_t out = notes.flags & MAVBOND_NOTE_POSITION
                      ? b.renumberer->deliver(frame.sysid, frame.compid, frame.seq, notes.bond_pos, t_ns)
                      : b.renumberer->deliver_unplaced(frame.sysid, frame.compid, frame.seq);
    rewrite_seq_in_place(frame, out);
    return verdict;
}

FrameFilter::Verdict RenumberStage::on_egress(const Frame& frame, Endpoint& to, TimePoint now) {
    if (frame.seq == wire_seq(frame))
        return chain_.on_egress(frame, to, now);
    // Renumbered on ingress: the egress filters see the number that goes on the wire.
    Frame renumbered = frame;
    renumbered.seq = wire_seq(frame);
    return chain_.on_egress(renumbered, to, now);
}

void RenumberStage::on_endpoint(Endpoint& endpoint, bool added) {
    chain_.on_endpoint(endpoint, added);
}

std::vector<std::pair<const char*, uint64_t>> RenumberStage::counters(size_t bond) const {
    if (bond >= bonds_.size() || !bonds_[bond].renumberer)
        return {};
    const SeqRenumberer::Counters& c = bonds_[bond].renumberer->counters();
    return {{"renumbered", c.renumbered},   {"gaps", c.gaps},
            {"late_filled", c.late_filled}, {"unplaced", c.unplaced},
            {"untracked", c.untracked},     {"signed_left_alone", bonds_[bond].signed_left_alone}};
}

void RenumberStage::log_summary() const {
    for (size_t i = 0; i < bonds_.size(); i++) {
        std::string line;
        for (const auto& [name, value] : counters(i))
            line += std::string(" ") + name + "=" + std::to_string(value);
        if (!line.empty())
            log_notice("renumber bond=%s%s", router_.bonds()[i].name.c_str(), line.c_str());
    }
}

}  // namespace mavbond
