// The anti-replay window of one signed stream (sysid, compid, link id), kept as IPsec keeps
// one for a security association (RFC 4303 3.4.3) and PRP its duplicate discard: a signed
// frame's 48-bit timestamp is its identity, so the window remembers the timestamps it let in,
// not the order they came in.
//
// A frame is let in once per link that brings it: a bond's links each carry their copy, and
// a late copy on the slow link is no replay (the filters' dedup then delivers one of them; or
// it is the only copy, the fast link having lost it). Refused: a timestamp the same link
// brought already (a replay), one more than kSpan behind the newest, and one older than any
// the window had to forget to stay within kCapacity. So a link's frames may come in any order
// within the window (a budget that sends commands before the telemetry it holds, a network
// that reorders), which a strictly increasing check would refuse.
//
// The window also remembers which timestamps were delivered (first_delivery): a copy another
// link brings once dedup has forgotten the frame (its window is shorter than kSpan) is a copy
// all the same, and is not delivered twice.
//
// Memory: kCapacity timestamps in one ring kept in ascending order (a frame newer than all
// goes at the end, a late one is found or placed by binary search), allocated with the
// stream's first frame and reused for the next stream in its place; nothing per frame.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>

namespace mavbond {

class ReplayWindow {
public:
    /// Timestamps remembered: 8 KiB. At 124 frames a second (ArduPilot's streams at 4 Hz)
    /// 8 s of one source; a faster source's window is shorter than kSpan.
    static constexpr size_t kCapacity = 1024;
    /// How far behind the stream's newest timestamp a frame may come: 10 s, in the signing
    /// clock's 10 us units (a saturated radio lags LTE by about a second).
    static constexpr uint64_t kSpan = 1'000'000;
    /// Links that may share one window (a bit each per timestamp).
    static constexpr unsigned kMaxLinks = 8;

    /// Lets the frame with timestamp `ts` in from link `link` (< kMaxLinks) if that link has
    /// not brought it and it is within the window; remembers it. No allocation but the first
    /// call's (the ring).
    bool admit(uint64_t ts, unsigned link);
    /// Whether the frame with timestamp `ts` is delivered for the first time now (and marks
    /// it delivered); false when a copy of it was delivered before. A timestamp the window
    /// does not hold (never let in, or forgotten) counts as the first.
    bool first_delivery(uint64_t ts);
    /// Forgets everything (the stream's place goes to another); keeps the ring.
    void clear();

    uint64_t newest() const { return newest_; }
    size_t size() const { return count_; }

private:
    static constexpr size_t kMask = kCapacity - 1;
    static_assert((kCapacity & kMask) == 0, "a power of two");
    uint64_t& at(size_t i) { return ring_[(head_ + i) & kMask]; }
    static uint64_t ts_of(uint64_t entry) { return entry >> 9; }
    /// The place of `ts` among the entries: its own, or where it would go.
    size_t lower_bound(uint64_t ts);
    void forget_oldest();
    static constexpr uint64_t kDelivered = uint64_t{1} << kMaxLinks;

    // Each entry: timestamp << 9 | delivered << 8 | a bit per link that brought it (48-bit
    // timestamps).
    std::unique_ptr<uint64_t[]> ring_;
    size_t head_ = 0, count_ = 0;
    uint64_t newest_ = 0;
    uint64_t floor_ = 0;  // what is older was forgotten: refused
};

}  // namespace mavbond
