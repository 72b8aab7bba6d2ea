#include "endpoints/radio_flow.h"

#include <algorithm>

namespace mavbond {
namespace {

constexpr uint8_t kVeryLow = 20;   // txbuf below: halve
constexpr uint8_t kLow = 50;       // txbuf below: lose a quarter
constexpr uint8_t kPlenty = 90;    // txbuf above: gain a tenth of the ceiling
constexpr uint64_t kFloorShare = 16;
constexpr uint64_t kIncreaseShare = 10;
constexpr uint64_t kMinFloor = 100;  // B/s: the least tx_rate takes

uint16_t saturating_add(uint16_t a, uint16_t b) {
    return static_cast<uint16_t>(std::min<uint32_t>(uint32_t{a} + b, UINT16_MAX));
}

}  // namespace

bool is_radio_report(const Frame& frame, RadioStatusSource source) {
    return source == RadioStatusSource::Sik && is_radio_status(frame.msgid) &&
           frame.sysid == kSikSysid && frame.compid == kSikCompid;
}

RadioFlow::RadioFlow(uint64_t ceiling, TimePoint started)
    : ceiling_(ceiling), rate_(std::max(ceiling / 2, floor())), last_at_(started) {}

uint64_t RadioFlow::floor() const {
    return std::min(ceiling_, std::max(ceiling_ / kFloorShare, kMinFloor));
}

void RadioFlow::set_ceiling(uint64_t ceiling) {
    ceiling_ = ceiling;
    rate_ = std::clamp(rate_, floor(), ceiling_);
}

uint64_t RadioFlow::report(const RadioReport& r, TimePoint now, bool rate_was_limit) {
    counters_.reports++;
    last_ = r;
    last_at_ = now;
    stale_ = false;
    const uint64_t before = rate_;
    if (r.txbuf < kVeryLow)
        rate_ = std::max(rate_ / 2, floor());
    else if (r.txbuf < kLow)
        rate_ = std::max(rate_ - rate_ / 4, floor());
    else if (r.txbuf > kPlenty && rate_was_limit)
        rate_ = std::min(rate_ + std::max<uint64_t>(ceiling_ / kIncreaseShare, 1), ceiling_);
    counters_.decreases += rate_ < before;
    counters_.increases += rate_ > before;
    return rate_;
}

uint64_t RadioFlow::check(TimePoint now) {
    if (!stale_ && now - last_at_ >= kStale) {
        stale_ = true;
        counters_.stale += counters_.reports != 0;  // a radio that never spoke: no report stopped
        rate_ = ceiling_;
    }
    return rate_;
}

uint8_t budget_room(uint64_t offered_frames, uint64_t offered_bytes, uint64_t lost, uint64_t rate,
                    double span_s) {
    if (lost != 0)
        return lost * 10 > offered_frames ? 10 : 40;
    if (span_s <= 0)
        return 100;  // nothing measured yet
    const double carried = static_cast<double>(rate) * span_s;
    const auto offered = static_cast<double>(offered_bytes);
    if (offered >= 0.85 * carried)
        return 70;
    return offered >= 0.70 * carried ? 92 : 100;
}

std::optional<RadioReport> bond_report(std::span<const RadioVote> members) {
    std::optional<uint8_t> txbuf;
    const RadioReport* best = nullptr;
    uint16_t rxerrors = 0, fixed = 0;
    for (const RadioVote& m : members) {
        if (!m.reports) {
            if (m.alive && !m.standby)
                txbuf = std::max<uint8_t>(txbuf.value_or(0), m.room);
            continue;
        }
        if (!m.fresh)
            continue;
        const RadioReport& r = m.last;
        txbuf = std::max<uint8_t>(txbuf.value_or(0), std::min<uint8_t>({r.txbuf, m.room, 100}));
        rxerrors = saturating_add(rxerrors, r.rxerrors);
        fixed = saturating_add(fixed, r.fixed);
        // 255 is "unknown": weaker than any measured rssi.
        auto strength = [](const RadioReport& x) { return x.rssi == 255 ? -1 : int{x.rssi}; };
        if (!best || r.txbuf > best->txbuf ||
            (r.txbuf == best->txbuf && strength(r) > strength(*best)))
            best = &r;
    }
    if (!txbuf)
        return std::nullopt;
    RadioReport out = best ? *best : RadioReport{};
    out.txbuf = *txbuf;
    out.rxerrors = rxerrors;
    out.fixed = fixed;
    return out;
}

}  // namespace mavbond
