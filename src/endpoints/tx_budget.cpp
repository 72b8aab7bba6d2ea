#include "endpoints/tx_budget.h"

#include <algorithm>
#include <cstring>

#include "mavlink/message_table.h"

namespace mavbond {
namespace {

// Held telemetry is one slot per message and source; a stream with more than this many at
// once (a swarm behind one slow link) drops the excess as it comes (counted).
constexpr size_t kMaxSlots = 256;
// When telemetry and bulk both wait, bulk gets this share of the budget.
constexpr double kBulkShare = 0.25;
constexpr size_t kRecordHeader = 2;  // a bulk record's u16 length

}  // namespace

TxBudget::TxBudget(uint64_t bytes_per_s, uint32_t overhead, const TxClassesConfig& classes,
                   size_t bulk_capacity, std::array<TxClassCounters, kTxClassCount>& counters)
    : rate_(bytes_per_s), overhead_(overhead), burst_(burst_for(bytes_per_s, overhead)),
      classes_(classes), tokens_(burst_),
      ring_(std::max(bulk_capacity, kMaxFrameLen + kRecordHeader)), counters_(counters) {
    slots_.reserve(32);
}

double TxBudget::burst_for(uint64_t bytes_per_s, uint32_t overhead) {
    return std::max(static_cast<double>(kMaxFrameLen + overhead),
                    static_cast<double>(bytes_per_s) * 0.02);
}

void TxBudget::set_rate(uint64_t bytes_per_s, TimePoint now) {
    refill(now);  // what accrued so far, at the old rate
    rate_ = std::max<uint64_t>(bytes_per_s, 1);
    burst_ = burst_for(rate_, overhead_);
    tokens_ = std::min(tokens_, burst_);
}

void TxBudget::refill(TimePoint now) {
    if (!started_) {
        started_ = true;
        refilled_ = now;
        return;
    }
    if (now <= refilled_)
        return;
    double dt = std::chrono::duration<double>(now - refilled_).count();
    tokens_ = std::min(burst_, tokens_ + dt * static_cast<double>(rate_));
    refilled_ = now;
}

void TxBudget::charge(TxClass c, size_t len, bool waited) {
    TxClassCounters& k = counters_[static_cast<size_t>(c)];
    k.frames++;
    k.bytes += cost(len);
    k.waited += waited;
    tokens_ -= static_cast<double>(cost(len));
    double weighted = static_cast<double>(cost(len));
    if (c == TxClass::Telemetry)
        telemetry_turn_ += weighted / (1 - kBulkShare);
    else if (c == TxClass::Bulk)
        bulk_turn_ += weighted / kBulkShare;
}

/// A telemetry sample's message, source and instance (its low 24 bits: an ICAO address fits).
uint64_t TxBudget::slot_key(const Frame& frame) {
    uint32_t instance = 0;
    if (frame.info && frame.info->instance_size != 0) {
        // Little-endian on the wire; a v2 payload may end early (its zeros trimmed).
        for (size_t i = frame.info->instance_size; i-- > 0;) {
            size_t at = static_cast<size_t>(frame.info->instance_ofs) + i;
            instance = instance << 8 | (at < frame.payload.size() ? frame.payload[at] : 0);
        }
    }
    return static_cast<uint64_t>(frame.msgid) << 40 | static_cast<uint64_t>(frame.sysid) << 32 |
           static_cast<uint64_t>(frame.compid) << 24 | (instance & 0xFFFFFF);
}

TxBudget::Slot* TxBudget::slot_for(const Frame& frame) {
    const uint64_t key = slot_key(frame);
    for (Slot& s : slots_) {
        if (s.key == key)
            return &s;
    }
    Slot* s = nullptr;
    if (slots_.size() < kMaxSlots) {
        s = &slots_.emplace_back();
    } else {
        // Reuse the one that went longest ago among those not holding a frame.
        for (Slot& old : slots_) {
            if (!old.held && (!s || old.last_sent < s->last_sent))
                s = &old;
        }
        if (!s)
            return nullptr;  // every slot holds a frame
        *s = Slot{};
    }
    s->key = key;
    auto cap = std::lower_bound(classes_.caps.begin(), classes_.caps.end(),
                                std::pair<uint32_t, Duration>(frame.msgid, Duration::min()));
    if (cap != classes_.caps.end() && cap->first == frame.msgid)
        s->cap = cap->second;
    return s;
}

bool TxBudget::offer(const Frame& frame, TimePoint now) {
    refill(now);
    const size_t len = frame.bytes.size();
    const TxClass c = classes_.class_of(frame.msgid);
    if (c == TxClass::Control) {
        charge(c, len, false);
        return true;
    }
    // Nothing passes what waits for the budget (only what a cap holds may be passed).
    bool queue_ahead = pick(now, false).kind != Pick::None ||
                       tokens_ < static_cast<double>(cost(len));
    if (c == TxClass::Bulk) {
        if (!queue_ahead) {
            charge(c, len, false);
            return true;
        }
        bulk_push(frame.bytes);
        return false;
    }
    Slot* slot = slot_for(frame);
    if (!slot) {
        counters_[static_cast<size_t>(c)].dropped++;
        return false;
    }
    Slot& s = *slot;
    if (!s.held && !queue_ahead && telemetry_ready(s, now)) {
        charge(c, len, false);
        s.last_sent = now;
        return true;
    }
    if (s.held) {
        counters_[static_cast<size_t>(c)].thinned++;
    } else {
        s.held = true;
        s.order = next_order_++;
        held_telemetry_++;
    }
    std::memcpy(s.bytes.data(), frame.bytes.data(), len);
    s.len = static_cast<uint16_t>(len);
    return false;
}

TxBudget::Pick TxBudget::pick(TimePoint now, bool affordable) const {
    Pick p;
    // The telemetry that waited longest of what its cap lets go now; else when a cap opens.
    const Slot* first = nullptr;
    for (size_t i = 0; i < slots_.size() && held_telemetry_ != 0; i++) {
        const Slot& s = slots_[i];
        if (!s.held)
            continue;
        if (telemetry_ready(s, now)) {
            if (!first || s.order < first->order) {
                first = &s;
                p.slot = i;
            }
        } else {
            p.due = std::min(p.due, s.last_sent + s.cap);
        }
    }
    size_t len = 0;
    if (first && (bulk_frames_ == 0 || telemetry_turn_ <= bulk_turn_)) {
        p.kind = Pick::Telemetry;
        len = first->len;
    } else if (bulk_frames_ != 0) {
        p.kind = Pick::Bulk;
        len = bulk_front_len();
    }
    if (p.kind == Pick::None || !affordable)
        return p;
    double missing = static_cast<double>(cost(len)) - tokens_;
    if (missing > 0) {
        auto wait = Duration(static_cast<int64_t>(missing * 1e9 / static_cast<double>(rate_)) + 1);
        p.due = std::min(p.due, refilled_ + wait);
        p.kind = Pick::None;
    }
    return p;
}

std::span<const uint8_t> TxBudget::take(const Pick& p, TimePoint now) {
    if (p.kind == Pick::Telemetry) {
        Slot& s = slots_[p.slot];
        s.held = false;
        s.last_sent = now;
        held_telemetry_--;
        charge(TxClass::Telemetry, s.len, true);
        return {s.bytes.data(), s.len};
    }
    size_t len = bulk_front_len();
    bulk_pop(bulk_out_.data());
    charge(TxClass::Bulk, len, true);
    return {bulk_out_.data(), len};
}

uint64_t TxBudget::clear() {
    uint64_t held = held_telemetry_ + bulk_frames_;
    for (Slot& s : slots_)
        s.held = false;
    held_telemetry_ = 0;
    ring_head_ = ring_used_ = bulk_frames_ = 0;
    return held;
}

// --- the bulk queue ----------------------------------------------------------------------------

void TxBudget::ring_read(size_t at, uint8_t* into, size_t n) const {
    at %= ring_.size();
    size_t first = std::min(n, ring_.size() - at);
    std::memcpy(into, ring_.data() + at, first);
    std::memcpy(into + first, ring_.data(), n - first);
}

void TxBudget::ring_write(size_t at, const uint8_t* from, size_t n) {
    at %= ring_.size();
    size_t first = std::min(n, ring_.size() - at);
    std::memcpy(ring_.data() + at, from, first);
    std::memcpy(ring_.data(), from + first, n - first);
}

size_t TxBudget::bulk_front_len() const {
    uint8_t h[kRecordHeader];
    ring_read(ring_head_, h, kRecordHeader);
    return static_cast<size_t>(h[0]) | static_cast<size_t>(h[1]) << 8;
}

void TxBudget::bulk_pop(uint8_t* into) {
    size_t len = bulk_front_len();
    if (into)
        ring_read(ring_head_ + kRecordHeader, into, len);
    ring_head_ = (ring_head_ + kRecordHeader + len) % ring_.size();
    ring_used_ -= kRecordHeader + len;
    bulk_frames_--;
}

void TxBudget::bulk_push(std::span<const uint8_t> frame) {
    const size_t need = kRecordHeader + frame.size();
    while (ring_.size() - ring_used_ < need) {
        bulk_pop(nullptr);
        counters_[static_cast<size_t>(TxClass::Bulk)].dropped++;
    }
    if (bulk_frames_ == 0)  // a class that starts to wait takes its turn from now, not before
        bulk_turn_ = std::max(bulk_turn_, telemetry_turn_);
    uint8_t h[kRecordHeader] = {static_cast<uint8_t>(frame.size()),
                                static_cast<uint8_t>(frame.size() >> 8)};
    size_t tail = ring_head_ + ring_used_;
    ring_write(tail, h, kRecordHeader);
    ring_write(tail + kRecordHeader, frame.data(), frame.size());
    ring_used_ += need;
    bulk_frames_++;
}

}  // namespace mavbond
