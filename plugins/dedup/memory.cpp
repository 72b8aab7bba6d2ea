// What dedup remembers: the ring of delivered instances in arrival order (expiry pops its
// head), the table of keys over it and the table of bond positions over it. All allocated at
// create; nothing per frame.
#include "dedup.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>

namespace mavbond::dedup {

// --- the key table -------------------------------------------------------------------------

uint32_t Dedup::find(uint32_t bond, Key key) const {
    for (uint32_t i = table_home(key.h1, bond);; i = (i + 1) & table_mask_) {
        if (table_[i] == 0)
            return kNone;
        uint32_t e = table_[i] - 1;
        const Entry& en = entries_[e];
        if (en.h1 == key.h1 && en.h2 == key.h2 && en.bond == bond)
            return e;
    }
}

uint32_t Dedup::insert_entry(uint32_t bond, Key key) {
    uint32_t e = free_count_ ? free_entries_[--free_count_] : fresh_++;
    Entry& en = entries_[e];
    en.h1 = key.h1;
    en.h2 = key.h2;
    en.bond = bond;
    en.count = 0;
    en.home = table_home(key.h1, bond);
    uint32_t i = en.home;
    while (table_[i] != 0)
        i = (i + 1) & table_mask_;
    table_[i] = e + 1;
    return e;
}

void Dedup::erase_entry(uint32_t e) {
    uint32_t i = entries_[e].home;
    while (table_[i] != e + 1)
        i = (i + 1) & table_mask_;
    // Backward-shift deletion: later keys of the probe run move up, so no tombstones pile up
    // and lookups stay O(1) however long the daemon runs.
    for (uint32_t j = (i + 1) & table_mask_; table_[j] != 0; j = (j + 1) & table_mask_) {
        uint32_t home = entries_[table_[j] - 1].home;
        bool stays = i <= j ? (i < home && home <= j) : (i < home || home <= j);
        if (!stays) {
            table_[i] = table_[j];
            i = j;
        }
    }
    table_[i] = 0;
    free_entries_[free_count_++] = e;
}

void Dedup::remove_instance(uint32_t e, uint8_t slot) {
    Entry& en = entries_[e];
    en.rec[slot] = en.rec[en.count - 1];
    ring_[en.rec[slot]].slot = slot;
    en.count--;
    if (en.count == 0)
        erase_entry(e);
}

void Dedup::pop_front(bool early, uint64_t now) {
    Record& r = ring_[ring_head_];
    unplace(ring_head_);
    if (r.pos != kUnknownPos) {
        Stream& s = streams_[r.stream];
        if (s.forgotten_pos == kUnknownPos || r.pos > s.forgotten_pos) {
            s.forgotten_pos = r.pos;
            s.forgotten_t0 = r.t0;
        }
    }
    if (r.entry != kNone)
        remove_instance(r.entry, r.slot);
    if (r.entry != kNone || r.pos != kUnknownPos) {
        if (early) {
            evicted_early_++;
            evicted_since_log_++;
            if (!evict_logged_ || now - last_evict_log_ns_ >= kEvictLogPeriod) {
                char msg[200];
                std::snprintf(msg, sizeof msg,
                              "memory full (max_entries %u): %" PRIu64
                              " frames forgotten before their window ended; their late copies "
                              "pass as duplicates",
                              capacity_, evicted_since_log_);
                api_->log(host_, MAVBOND_LOG_WARNING, msg);
                evict_logged_ = true;
                last_evict_log_ns_ = now;
                evicted_since_log_ = 0;
            }
        }
    }
    ring_head_ = ring_head_ + 1 == capacity_ ? 0 : ring_head_ + 1;
    ring_count_--;
}

bool Dedup::awaited(const Record& r, uint64_t now) const {
    const uint64_t longest = std::max(Window::kMaxWindow, window_.floor());
    if (r.pos == kUnknownPos || now - r.t0 > longest)
        return false;
    const uint32_t bond = static_cast<uint32_t>(streams_[r.stream].key >> 16) - 1;
    for (uint32_t m = 0; m < kMaxMembers; m++) {
        const Member& x = members_[bond * kMaxMembers + m];
        const Lane& lane = lanes_[size_t{r.stream} * kMaxMembers + m];
        if ((r.seen >> m & 1) || x.link_id == kNone || lane.generation != x.generation ||
            !lane.aligned)
            continue;
        if (lane.last_pos < r.pos && now - lane.last_t <= longest)
            return true;
    }
    return false;
}

void Dedup::expire(uint64_t now) {
    // The ring is in arrival order, so expiry stops at the first instance in the window, or
    // one a link behind may still bring a copy of.
    while (ring_count_ > 0) {
        const Record& r = ring_[ring_head_];
        if ((r.entry != kNone || r.pos != kUnknownPos) &&
            (now - r.t0 <= window_.ns() || awaited(r, now)))
            break;
        pop_front(false, now);
    }
}

uint32_t Dedup::add_instance(uint32_t e, const Record& rec) {
    Entry& en = entries_[e];
    uint8_t slot = en.count;
    if (en.count == kInstances) {
        // The key's oldest instance is no longer a candidate for aligning a link; its
        // position still holds it until expiry pops it.
        slot = 0;
        for (uint8_t s = 1; s < kInstances; s++) {
            if (ring_[en.rec[s]].t0 < ring_[en.rec[slot]].t0)
                slot = s;
        }
        ring_[en.rec[slot]].entry = kNone;
    } else {
        en.count++;
    }
    uint32_t at = ring_head_ + ring_count_;
    if (at >= capacity_)
        at -= capacity_;
    ring_count_++;
    ring_[at] = rec;
    ring_[at].entry = e;
    ring_[at].slot = slot;
    en.rec[slot] = at;
    return at;
}

// --- the position table --------------------------------------------------------------------

uint32_t Dedup::pos_home(uint32_t stream, int64_t pos) const {
    uint64_t x = (static_cast<uint64_t>(pos) * 0x9e3779b97f4a7c15ull) ^
                 (uint64_t{stream} * 0xbf58476d1ce4e5b9ull);
    x ^= x >> 31;
    x *= 0x94d049bb133111ebull;
    return static_cast<uint32_t>(x >> (64 - table_bits_));
}

uint32_t Dedup::at(uint32_t stream, int64_t pos) const {
    for (uint32_t i = pos_home(stream, pos);; i = (i + 1) & table_mask_) {
        if (at_pos_[i] == 0)
            return kNone;
        const Record& r = ring_[at_pos_[i] - 1];
        if (r.pos == pos && r.stream == stream)
            return at_pos_[i] - 1;
    }
}

void Dedup::place(uint32_t rec) {
    const Record& r = ring_[rec];
    uint32_t i = pos_home(r.stream, r.pos);
    while (at_pos_[i] != 0)
        i = (i + 1) & table_mask_;
    at_pos_[i] = rec + 1;
}

void Dedup::unplace(uint32_t rec) {
    const Record& r = ring_[rec];
    if (r.pos == kUnknownPos)
        return;
    uint32_t i = pos_home(r.stream, r.pos);
    while (at_pos_[i] != rec + 1)
        i = (i + 1) & table_mask_;
    // Backward-shift deletion, as in the key table.
    for (uint32_t j = (i + 1) & table_mask_; at_pos_[j] != 0; j = (j + 1) & table_mask_) {
        const Record& moved = ring_[at_pos_[j] - 1];
        uint32_t home = pos_home(moved.stream, moved.pos);
        bool stays = i <= j ? (i < home && home <= j) : (i < home || home <= j);
        if (!stays) {
            at_pos_[i] = at_pos_[j];
            i = j;
        }
    }
    at_pos_[i] = 0;
}


void Dedup::remember(const Arrival& a, Key key, int64_t pos, uint32_t e) {
    // At the cap the oldest instance overall is forgotten first, which may be this key's last
    // one: look the key up again after making room.
    if (ring_count_ == capacity_) {
        // Early only if still in its window: one past it, kept for a link behind, would have
        // expired without that.
        pop_front(a.t - ring_[ring_head_].t0 <= window_.ns(), a.t);
        e = find(a.bond, key);
    }
    if (e == kNone)
        e = insert_entry(a.bond, key);
    Record r{};
    r.h1 = key.h1;
    r.h2 = key.h2;
    r.t0 = a.t;
    r.pos = pos != kUnknownPos && at(a.stream, pos) == kNone ? pos : kUnknownPos;
    r.link_pos = a.link_pos;
    r.first_link_id = a.link_id;
    r.stream = a.stream;
    r.first_member = static_cast<uint8_t>(a.member);
    r.seen = static_cast<uint8_t>(1u << a.member);
    r.by_time = lanes_[size_t{a.stream} * kMaxMembers + a.member].tentative;
    uint32_t rec = add_instance(e, r);
    if (r.pos != kUnknownPos)
        place(rec);
}

}  // namespace mavbond::dedup
