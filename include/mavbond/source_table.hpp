// Per-source state for a frame path that must not allocate: a fixed open-addressed table keyed
// by (sysid, compid), and the 128-position history a sequence tracker keeps per source. Header
// only, so the host (stream positions) and plugins (linkswitch's delivered history) share it
// without a plugin linking anything.
#ifndef MAVBOND_SOURCE_TABLE_HPP
#define MAVBOND_SOURCE_TABLE_HPP

#include <array>
#include <cstdint>

namespace mavbond {

/// Up to three quarters of Capacity sources, each a Value; find() adds a source the first time
/// it is asked for and returns nullptr once the table is that full (probe runs stay short).
template <class Value, uint32_t Capacity>
class SourceTable {
public:
    static constexpr uint32_t kMaxSources = Capacity * 3 / 4;
    static constexpr uint32_t kFull = UINT32_MAX;

    /// The slot of (sysid, compid), which keeps it for the table's life (a compact reference
    /// to it: at()); added the first time, kFull once the table is full.
    uint32_t slot(uint8_t sysid, uint8_t compid) {
        auto key = static_cast<uint16_t>(sysid << 8 | compid);
        uint32_t i = (key * 40503u >> 4) % Capacity;  // spreads neighbouring compids
        for (uint32_t n = 0; n < Capacity; n++, i = (i + 1) % Capacity) {
            Slot& s = slots_[i];
            if (s.used && s.key == key)
                return i;
            if (!s.used) {
                if (used_ >= kMaxSources)
                    return kFull;
                s.used = true;
                s.key = key;
                used_++;
                return i;
            }
        }
        return kFull;
    }
    Value& at(uint32_t slot) { return slots_[slot].value; }

    Value* find(uint8_t sysid, uint8_t compid) {
        const uint32_t i = slot(sysid, compid);
        return i == kFull ? nullptr : &slots_[i].value;
    }

    /// Calls f(value) for every source in the table.
    template <class F>
    void for_each(F&& f) {
        for (Slot& s : slots_) {
            if (s.used)
                f(s.value);
        }
    }

private:
    struct Slot {
        uint16_t key = 0;
        bool used = false;
        Value value{};
    };
    std::array<Slot, Capacity> slots_{};
    uint32_t used_ = 0;
};

/// 128 positions of one stream, bit i standing for "i positions back from the newest".
class History128 {
public:
    /// The newest moves n positions on: every bit i becomes bit i + n.
    void shift(unsigned n) {
        if (n >= 128) {
            bits_[0] = bits_[1] = 0;
        } else if (n >= 64) {
            bits_[1] = bits_[0] << (n - 64);
            bits_[0] = 0;
        } else if (n > 0) {
            bits_[1] = bits_[1] << n | bits_[0] >> (64 - n);
            bits_[0] <<= n;
        }
    }
    bool has(unsigned i) const { return bits_[i / 64] >> (i % 64) & 1; }
    void set(unsigned i) { bits_[i / 64] |= uint64_t{1} << (i % 64); }
    void fill() { bits_[0] = bits_[1] = ~uint64_t{0}; }
    void reset() { bits_[0] = bits_[1] = 0; }

private:
    uint64_t bits_[2] = {};
};

}  // namespace mavbond

#endif  // MAVBOND_SOURCE_TABLE_HPP
