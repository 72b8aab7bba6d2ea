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

}  // namespace

TxBudget::TxBudget(uint64_t bytes_per_s, uint32_t overhead, const TxClassesConfig& classes,
                   size_t bulk_capacity, std::array<TxClassCounters, kTxClassCount>& counters)
    : rate_(bytes_per_s), overhead_(overhead), burst_(burst_for(bytes_per_s, overhead)),
      classes_(classes), tokens_(burst_), control_(bulk_capacity), bulk_(bulk_capacity),
      counters_(counters) {
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
    load_.waited += waited;
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

bool TxBudget::offer(const Frame& frame, TimePoint now, uint64_t ticket, uint8_t extra) {
    refill(now);
    const size_t len = frame.bytes.size() + extra;  // what it takes on the line
    const TxClass c = classes_.class_of(frame.msgid);
    load_.offered_frames++;
    load_.offered_bytes += cost(len);
    if (c == TxClass::Control) {
        // In order: nothing passes control that waits.
        if (control_.empty() && tokens_ - static_cast<double>(cost(len)) >= -control_debt()) {
            charge(c, len, false);
            return true;
        }
        enqueue(control_, c, frame, now, ticket, extra);
        return false;
    }
    // Nothing passes what waits for the budget (only what a cap holds may be passed).
    bool queue_ahead = pick(now, false).kind != Pick::None ||
                       tokens_ < static_cast<double>(cost(len));
    if (c == TxClass::Bulk) {
        if (!queue_ahead) {
            charge(c, len, false);
            return true;
        }
        enqueue(bulk_, c, frame, now, ticket, extra);
        return false;
    }
    Slot* slot = slot_for(frame);
    if (!slot) {
        lose(c, &TxClassCounters::dropped);
        return false;
    }
    Slot& s = *slot;
    if (!s.held && !queue_ahead && telemetry_ready(s, now)) {
        charge(c, len, false);
        s.last_sent = now;
        return true;
    }
    if (s.held) {
        lose(c, &TxClassCounters::thinned);
    } else {
        s.held = true;
        s.order = next_order_++;
        held_telemetry_++;
    }
    std::memcpy(s.bytes.data(), frame.bytes.data(), frame.bytes.size());
    s.len = static_cast<uint16_t>(frame.bytes.size());
    s.extra = extra;
    s.ticket = ticket;
    return false;
}

void TxBudget::enqueue(FrameRing& ring, TxClass c, const Frame& frame, TimePoint now,
                       uint64_t ticket, uint8_t extra) {
    while (!ring.fits(frame.bytes.size())) {
        ring.pop(nullptr);
        lose(c, &TxClassCounters::dropped);
    }
    if (&ring == &bulk_ && bulk_.empty())  // a class that starts to wait takes its turn from now
        bulk_turn_ = std::max(bulk_turn_, telemetry_turn_);
    ring.push(frame.bytes, now, ticket, extra);
}

void TxBudget::expire_control(TimePoint now) {
    while (!control_.empty() && now - control_.front().at >= kControlMaxWait) {
        control_.pop(nullptr);
        lose(TxClass::Control, &TxClassCounters::dropped);
    }
}

TxBudget::Pick TxBudget::pick(TimePoint now, bool affordable) const {
    Pick p;
    size_t len = 0;
    double allowed_debt = 0;
    if (!control_.empty()) {
        p.kind = Pick::Control;
        const FrameRing::Record r = control_.front();
        len = r.len + r.extra;
        allowed_debt = control_debt();
    } else {
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
        if (first && (bulk_.empty() || telemetry_turn_ <= bulk_turn_)) {
            p.kind = Pick::Telemetry;
            len = first->len + first->extra;
        } else if (!bulk_.empty()) {
            p.kind = Pick::Bulk;
            const FrameRing::Record r = bulk_.front();
            len = r.len + r.extra;
        }
    }
    if (p.kind == Pick::None || !affordable)
        return p;
    double missing = static_cast<double>(cost(len)) - allowed_debt - tokens_;
    if (missing > 0) {
        auto wait = Duration(static_cast<int64_t>(missing * 1e9 / static_cast<double>(rate_)) + 1);
        p.due = std::min(p.due, refilled_ + wait);
        p.kind = Pick::None;
    }
    return p;
}

TxBudget::Taken TxBudget::take(const Pick& p, TimePoint now) {
    if (p.kind == Pick::Telemetry) {
        Slot& s = slots_[p.slot];
        s.held = false;
        s.last_sent = now;
        held_telemetry_--;
        charge(TxClass::Telemetry, s.len + s.extra, true);
        return {{s.bytes.data(), s.len}, s.ticket};
    }
    FrameRing& ring = p.kind == Pick::Control ? control_ : bulk_;
    const FrameRing::Record r = ring.front();
    ring.pop(queued_out_.data());
    charge(p.kind == Pick::Control ? TxClass::Control : TxClass::Bulk, r.len + r.extra, true);
    return {{queued_out_.data(), r.len}, r.ticket};
}

uint64_t TxBudget::clear() {
    uint64_t held = held_telemetry_ + bulk_.frames() + control_.frames();
    for (Slot& s : slots_)
        s.held = false;
    held_telemetry_ = 0;
    bulk_.clear();
    control_.clear();
    return held;
}

}  // namespace mavbond
