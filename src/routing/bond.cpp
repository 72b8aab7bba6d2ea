#include "routing/bond.h"

#include <algorithm>

#include "mavlink/frame_writer.h"

namespace mavbond {

Bond::Bond(const BondConfig& config, const std::vector<EndpointConfig>& endpoints,
           const TxClassesConfig& classes, TimePoint now)
    : name_(config.name), tx_active_(config.tx == BondConfig::Tx::Active) {
    std::vector<const EndpointConfig*> member_configs;
    bool metered = false;
    for (const auto& ep : endpoints) {
        if (ep.bond == name_) {
            members_.push_back(ep.name);
            member_configs.push_back(&ep);
            metered = metered || ep.metered;
        }
    }
    if (metered)
        standby_ = std::make_unique<Standby>(config, member_configs, classes, now);
    last_heard_.assign(members_.size(), TimePoint{});
    if (config.signing.enabled) {
        signing_ = std::make_shared<BondSigning>(config.signing.key);
        signed_links_ = config.signing.links;
        for (const std::string& link : signed_links_)
            signing_->member(link);
    }
}

void Bond::set_renumbering(bool on) {
    if (!on)
        renumberer_.reset();
    else if (!renumberer_)
        renumberer_ = std::make_unique<SeqRenumberer>();
}

bool Bond::continue_from(const Bond& old) {
    numbering_ = old.numbering_;
    if (signing_ && old.signing_ && old.signing_->same_key(*signing_) &&
        old.signing_->has_room_for(signed_links_)) {
        // The endpoints a reload kept verify with the old one: it goes on, with any new links.
        signing_ = old.signing_;
        for (const std::string& link : signed_links_)
            signing_->member(link);
    }
    return standby_ && old.standby_ && standby_->continue_from(*old.standby_);
}

uint32_t Bond::member_index(const std::string& endpoint) const {
    auto it = std::find(members_.begin(), members_.end(), endpoint);
    return it == members_.end() ? kNoMember : static_cast<uint32_t>(it - members_.begin());
}

void Bond::set_active_link(LinkId link) {
    if (active_link_ != link) {
        active_link_ = link;
        switches_++;
    }
}

void Bond::forget_link(LinkId link) {
    if (active_link_ == link)
        active_link_ = kNoLink;
}

void Bond::renumber(Frame& frame, bool delivered, std::optional<int64_t> bond_pos,
                    TimePoint arrival) {
    if (frame.is_signed()) {
        signed_left_alone_++;
        return;
    }
    if (!delivered)
        return;
    const int64_t t_ns = std::chrono::duration_cast<Duration>(arrival.time_since_epoch()).count();
    uint8_t out = bond_pos ? renumberer_->deliver(frame.sysid, frame.compid, frame.seq, *bond_pos, t_ns)
                           : renumberer_->deliver_unplaced(frame.sysid, frame.compid, frame.seq);
    rewrite_seq_in_place(frame, out);
    frame.seq = out;
}

std::vector<std::pair<const char*, uint64_t>> Bond::renumber_counters() const {
    if (!renumberer_)
        return {};
    const SeqRenumberer::Counters& c = renumberer_->counters();
    return {{"renumbered", c.renumbered},   {"gaps", c.gaps},
            {"late_filled", c.late_filled}, {"unplaced", c.unplaced},
            {"untracked", c.untracked},     {"signed_left_alone", signed_left_alone_},
            {"added", c.added}};
}

std::optional<uint8_t> Bond::number_added_frame(uint8_t sysid, uint8_t compid) {
    return renumberer_ ? renumberer_->add(sysid, compid) : std::nullopt;
}

// --- arrival order -------------------------------------------------------------------------

bool Bond::must_wait(TimePoint t, TimePoint polled, bool all_reported) const {
    if (!waiting.empty())
        return true;  // after the ones already waiting
    for (const Input* in : inputs) {
        if (in->read_to(polled, all_reported) < t)
            return true;
    }
    return false;
}

void Bond::wait(const ReceivedFrame& frame, uint64_t order, bool copy) {
    auto offset = static_cast<uint32_t>(arena.size());
    if (copy)
        arena.insert(arena.end(), frame.frame.bytes.begin(), frame.frame.bytes.end());
    waiting.push_back(WaitingFrame{frame, order, offset, copy});
}

size_t Bond::release(TimePoint polled, bool all_reported, bool all) {
    // Every frame up to the time each input is known to be read to.
    held_until = TimePoint::max();
    for (const Input* in : inputs) {
        if (!all)
            held_until = std::min(held_until, in->read_to(polled, all_reported));
    }
    // Each socket's frames came in arrival order: sorting is merging a few runs, which an
    // insertion sort does in one pass.
    auto before = [](const WaitingFrame& a, const WaitingFrame& b) {
        return a.received.arrival != b.received.arrival ? a.received.arrival < b.received.arrival
                                                        : a.order < b.order;
    };
    for (size_t i = 1; i < waiting.size(); i++) {
        if (!before(waiting[i], waiting[i - 1]))
            continue;
        WaitingFrame w = waiting[i];
        size_t j = i;
        for (; j > 0 && before(w, waiting[j - 1]); j--)
            waiting[j] = waiting[j - 1];
        waiting[j] = w;
    }
    size_t n = 0;
    while (n < waiting.size() && waiting[n].received.arrival <= held_until)
        n++;
    return n;
}

/// Points a frame's spans at `base`, where its bytes are now.
static void move_frame(Frame& f, const uint8_t* base) {
    auto payload_at = f.payload.data() - f.bytes.data();
    f.payload = {base + payload_at, f.payload.size()};
    f.bytes = {base, f.bytes.size()};
}

ReceivedFrame& Bond::released(size_t i) {
    WaitingFrame& w = waiting[i];
    if (w.owned)
        move_frame(w.received.frame, arena.data() + w.offset);
    return w.received;
}

size_t Bond::keep_unreleased(size_t count) {
    waiting.erase(waiting.begin(), waiting.begin() + static_cast<ptrdiff_t>(count));
    if (waiting.empty()) {
        arena.clear();
        return 0;
    }
    // What stays moves to the arena's front; what was lent is copied in after it.
    size_t keep_from = arena.size();  // not sorted by offset: find the lowest
    for (const WaitingFrame& w : waiting) {
        if (w.owned)
            keep_from = std::min<size_t>(keep_from, w.offset);
    }
    arena.erase(arena.begin(), arena.begin() + static_cast<ptrdiff_t>(keep_from));
    size_t lent = 0;
    for (WaitingFrame& w : waiting) {
        if (w.owned) {
            w.offset -= static_cast<uint32_t>(keep_from);
            continue;
        }
        const Frame& f = w.received.frame;
        w.offset = static_cast<uint32_t>(arena.size());
        arena.insert(arena.end(), f.bytes.begin(), f.bytes.end());
        w.owned = true;
        lent++;
    }
    return lent;
}

}  // namespace mavbond
