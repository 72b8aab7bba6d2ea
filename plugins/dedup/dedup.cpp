// dedup: turns the copies of one stream that arrive over a bond's links back into one stream
// (the redundant-telemetry paper's method, made exact).
//
// Each frame from a bonded link is hashed once (MurmurHash3) and remembered as an instance
// for `window`. A frame is a duplicate when an instance with the same key, first seen on
// another link of the same bond, has not been seen on this link yet and its arrival time fits
// the latency offset learned between the two links. Byte-identical frames legitimately recur
// (the sequence byte wraps every 256 frames), so a repeat on the same link is always a new
// instance, and when a link also loses frames the offset model, not arrival counting, decides
// which instance a copy belongs to.
//
// Memory: a ring of instances in arrival order (expiry pops its head: O(1) amortised), a slab
// of entries (one per key, up to kInstances instances each) and an open-addressing table over
// the slab, all allocated in create and sized by max_entries. Nothing is allocated per frame.
#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <cstdlib>
#include <memory>
#include <new>
#include <type_traits>
#include <string>
#include <vector>

#include "mavbond/filter.hpp"
#include "murmur3.h"

namespace mavbond::dedup {
namespace {

constexpr uint64_t kMs = 1'000'000;
constexpr uint64_t kSecond = 1'000 * kMs;
constexpr uint32_t kNone = UINT32_MAX;

// Bond ids and member positions index fixed arrays (per-pair latency models, per-link
// counters). Bonds join a handful of links; a link beyond these passes untouched (logged once).
constexpr uint32_t kMaxBonds = 16;
constexpr uint32_t kMaxMembers = 8;
// Instances remembered per key. Identical bytes recur every 256 frames of a source, or every
// second with key: content (HEARTBEAT): 8 covers a 5 s window at 1 Hz plus the copies in flight.
// When full, the oldest instance of that key is forgotten (its late copy passes: fail open).
constexpr int kInstances = 8;
// A copy fits an instance when its skew is within this of the learned offset, or 4 mean
// absolute deviations when the pair's jitter is larger. The floor covers a UART's byte
// timing, a receive batch and the hiccups of a busy companion computer or an LTE modem (a
// 25 ms floor let such a hiccup through as a duplicate); it only has to stay under half the
// time identical bytes take to recur: 256 frames of one source (128 ms even at 2,000
// frames/s). The cap keeps a confused model from swallowing everything: a copy further off
// than that passes (a duplicate delivered, never a good frame dropped).
constexpr int64_t kMinTolerance = 60 * static_cast<int64_t>(kMs);
constexpr int64_t kMaxTolerance = 250 * static_cast<int64_t>(kMs);
constexpr int64_t kToleranceDeviations = 4;
// The offset starts as the median of the first samples, so a few wrong ones (a link that
// lost the first instance of a recurring frame delivers the next as "the" copy) cannot set
// it; after that an EWMA with gain 1/16 follows it.
constexpr uint32_t kMinSamples = 8;
constexpr int64_t kEwmaGain = 16;
// A timestamp going back by more than this is an autopilot reboot (time_boot_ms restarts),
// not a late copy: a late copy lags by the links' skew, which the window is sized to cover.
constexpr uint64_t kMinRebootJump = 2 * kSecond;
constexpr uint64_t kEvictLogPeriod = 10 * kSecond;
// (bond, sysid, compid, msgid) streams whose newest timestamp is kept (power of two). A
// stream beyond it is not checked for staleness (fail open); real vehicles have a few hundred.
constexpr uint32_t kStreams = 4096;
// Upper bound for max_entries: a typo must not allocate gigabytes at start.
constexpr int64_t kMaxEntriesLimit = int64_t{1} << 24;
constexpr uint32_t kScopeCache = 256;

enum class HashKind { murmur3_128, murmur3_32 };
enum class KeyKind { frame, content };

/// One remembered instance of a key, in the ring in arrival order.
/// A fixed array from calloc: fresh zero pages that only become resident as they are used, so
/// a generous max_entries costs memory only for what the window really holds. T must be
/// trivially copyable with all-zero bytes a valid value.
template <typename T>
class ZeroedArray {
public:
    void allocate(size_t n) {
        static_assert(std::is_trivially_copyable_v<T>);
        data_.reset(static_cast<T*>(std::calloc(n, sizeof(T))));
        if (!data_ && n > 0)
            throw std::bad_alloc();
    }
    T& operator[](size_t i) { return data_.get()[i]; }
    const T& operator[](size_t i) const { return data_.get()[i]; }

private:
    struct Free {
        void operator()(T* p) const { std::free(p); }
    };
    std::unique_ptr<T, Free> data_;
};

struct Record {
    uint64_t t0;             // arrival of the first copy
    uint32_t entry;          // kNone: forgotten (its slot was reused), skipped by expiry
    uint32_t first_link_id;  // for the notes
    uint8_t slot;            // index in the entry's rec[]
    uint8_t first_member;    // position of the first link in its bond
    uint8_t seen;            // members that have had this instance (bit = member position)
};

/// One key: its hash, its bond and its live instances (ring positions).
struct Entry {
    uint64_t h1, h2;
    uint32_t bond;
    uint32_t home;  // table slot the key hashes to (for backward-shift deletion)
    uint32_t rec[kInstances];
    uint8_t count;
    uint8_t recurred;  // the key has had two instances in the window at once (a HEARTBEAT...)
};

/// The latency offset between two members of a bond: t_hi - t_lo for one instance, signed.
struct PairModel {
    int64_t offset_ns = 0;
    int64_t mad_ns = 0;  // mean absolute deviation of the samples from the offset
    uint32_t samples = 0;
    int64_t first[kMinSamples] = {};  // the samples before the offset is trusted
};

struct Member {
    uint32_t link_id = kNone;
    uint64_t passed = 0, duplicates = 0, stale = 0;
};

struct Stream {
    uint64_t key = UINT64_MAX;  // UINT64_MAX: empty
    uint64_t newest_ns = 0;
};

constexpr const char* kHashNames[] = {"murmur3_128", "murmur3_32"};
constexpr const char* kKeyNames[] = {"frame", "content"};

// Defaults, and why:
// - window 2s: must exceed the largest latency skew between a bond's links. Radio links run at
//   tens of ms; LTE and satellite paths sit hundreds of ms behind and spike past 1 s under load.
//   Exact matching keeps a long window safe, so 2 s leaves a margin; copies later than that
//   pass, and drop_stale still catches late timestamped samples. (The paper used 5 s.)
// - hash murmur3_128: with N keys in the window, a new frame collides with one of them with
//   probability N/2^bits, and a collision drops a good frame. At 1000 frames/s and 2 s that is
//   one lost frame every ~35 minutes with 32 bits, never in practice with 128. The hash is
//   computed once over <= 280 bytes, cheap on a Pi's 64-bit core.
// - key frame: the other gateway fans out one stream, so copies are byte-identical; `content`
//   is for an autopilot feeding two radios with separate sequence counters.
// - drop_stale true: delivering an older position after a newer one makes the vehicle jump
//   back on the map (the paper's "rubberbanding").
// - max_entries 32768: instances remembered (one per unique frame, copies add none). At 2 s
//   that holds 16k unique frames/s, 7x a 921600-baud UART full of small frames; about
//   100 bytes each (3.3 MB), allocated once.
const mavbond_option kOptions[] = {
    {"window", MAVBOND_OPT_DURATION, "2s",
     "how long a frame is remembered; covers the largest latency skew between the bond's links "
     "(0 disables dedup)"},
    {"hash", MAVBOND_OPT_STRING, "murmur3_128",
     "murmur3_128 or murmur3_32 (the paper's; more collisions, each one drops a good frame)"},
    {"key", MAVBOND_OPT_STRING, "frame",
     "frame (every byte) or content (sysid, compid, msgid, payload: copies with their own "
     "sequence counters)"},
    {"drop_stale", MAVBOND_OPT_BOOL, "true",
     "drop a timestamped sample older than the newest delivered of its (sysid, compid, msgid)"},
    {"max_entries", MAVBOND_OPT_INT, "32768",
     "frames remembered at most; beyond it the oldest are forgotten early (their copies pass)"},
    {nullptr, MAVBOND_OPT_BOOL, nullptr, nullptr},
};

uint64_t read_le(const uint8_t* p, uint32_t avail, uint32_t size) {
    uint64_t v = 0;
    for (uint32_t i = 0; i < size; i++)
        v |= uint64_t{i < avail ? p[i] : uint8_t{0}} << (8 * i);
    return v;
}

class Dedup {
public:
    Dedup(const mavbond_host_api* api, mavbond_host* h) : api_(api), host_(h) {}

    /// Reads and checks the options and allocates all memory. Non-zero with err filled on error.
    int init(const mavbond_config* cfg, char* err, size_t err_len);

    mavbond_verdict on_ingress(const mavbond_frame* f, mavbond_frame_notes* notes,
                               const mavbond_link* from);
    void on_link(const mavbond_link* link, mavbond_link_event event);
    std::string status() const;
    void metrics(MetricOut& out) const;
    size_t status_json(char* buf, size_t len) const {
        std::string s = status();
        if (buf && len > 0)
            std::snprintf(buf, len, "%s", s.c_str());
        return s.size();
    }

private:
    struct Key {
        uint64_t h1, h2;
    };
    struct Match {
        bool duplicate = false;
        uint32_t first_link_id = kNone;
        int64_t skew_ns = 0;
    };

    bool in_scope(const mavbond_link* link);
    bool scope_allows(const mavbond_link* link) const;
    Key hash(const mavbond_frame* f) const;
    /// `timestamped`: the message carries time_boot_ms / time_usec, so its bytes never recur.
    Match match(uint32_t bond, uint32_t member, uint32_t link_id, Key key, uint64_t t,
                bool timestamped);
    bool stale(uint32_t bond, const mavbond_frame* f);

    PairModel& pair(uint32_t bond, uint32_t a, uint32_t b) {
        return pairs_[(bond * kMaxMembers + std::min(a, b)) * kMaxMembers + std::max(a, b)];
    }
    /// Expected arrival on `to` minus arrival on `from` for one instance.
    int64_t predicted_skew(const PairModel& p, uint32_t from, uint32_t to) const {
        return from < to ? p.offset_ns : -p.offset_ns;
    }
    static int64_t tolerance(const PairModel& p) {
        return std::clamp(kToleranceDeviations * p.mad_ns, kMinTolerance, kMaxTolerance);
    }
    void learn(PairModel& p, int64_t sample);

    uint32_t table_home(uint64_t h1, uint32_t bond) const {
        uint64_t x = (h1 ^ (uint64_t{bond} * 0x9e3779b97f4a7c15ull)) * 0xbf58476d1ce4e5b9ull;
        return static_cast<uint32_t>(x >> (64 - table_bits_));
    }
    uint32_t find(uint32_t bond, Key key) const;
    uint32_t insert_entry(uint32_t bond, Key key);
    void erase_entry(uint32_t e);
    void add_instance(uint32_t e, uint32_t member, uint32_t link_id, uint64_t t);
    void remove_instance(uint32_t e, uint8_t slot);
    void pop_front(bool early, uint64_t now);
    void expire(uint64_t now);

    const mavbond_host_api* api_;
    mavbond_host* host_;
    const char* const* scope_bonds_ = nullptr;
    const char* const* scope_endpoints_ = nullptr;
    size_t scope_bond_count_ = 0, scope_endpoint_count_ = 0;
    uint8_t scope_cache_[kScopeCache] = {};  // 0 unknown, 1 in scope, 2 not (by link id)

    uint64_t window_ns_ = 0;
    HashKind hash_ = HashKind::murmur3_128;
    KeyKind key_ = KeyKind::frame;
    bool drop_stale_ = true;
    uint64_t reboot_jump_ns_ = kMinRebootJump;

    uint32_t capacity_ = 0;  // max_entries
    ZeroedArray<Record> ring_;
    uint32_t ring_head_ = 0, ring_count_ = 0;
    ZeroedArray<Entry> entries_;
    ZeroedArray<uint32_t> free_entries_;  // entries given back, a stack
    uint32_t free_count_ = 0;
    uint32_t fresh_ = 0;                  // entries never used yet start here
    ZeroedArray<uint32_t> table_;         // entry + 1; 0: an empty slot
    uint32_t table_bits_ = 0, table_mask_ = 0;

    std::vector<PairModel> pairs_;
    std::vector<Member> members_;
    std::vector<Stream> streams_;
    uint32_t streams_used_ = 0;

    uint64_t clock_ns_ = 0;  // newest arrival seen: time never runs backwards here
    uint64_t evicted_early_ = 0, evicted_since_log_ = 0, last_evict_log_ns_ = 0;
    bool evict_logged_ = false, overflow_logged_ = false, streams_full_logged_ = false;
    uint64_t untracked_streams_ = 0;
};

int Dedup::init(const mavbond_config* cfg, char* err, size_t err_len) {
    api_->cfg_duration_ns(cfg, "window", &window_ns_);
    const char* text = nullptr;
    if (api_->cfg_string(cfg, "hash", &text) == 0) {
        if (std::strcmp(text, "murmur3_128") == 0) {
            hash_ = HashKind::murmur3_128;
        } else if (std::strcmp(text, "murmur3_32") == 0) {
            hash_ = HashKind::murmur3_32;
        } else {
            api_->cfg_error(cfg, "hash", "must be murmur3_128 or murmur3_32", err, err_len);
            return -1;
        }
    }
    if (api_->cfg_string(cfg, "key", &text) == 0) {
        if (std::strcmp(text, "frame") == 0) {
            key_ = KeyKind::frame;
        } else if (std::strcmp(text, "content") == 0) {
            key_ = KeyKind::content;
        } else {
            api_->cfg_error(cfg, "key", "must be frame or content", err, err_len);
            return -1;
        }
    }
    int b = 1;
    api_->cfg_bool(cfg, "drop_stale", &b);
    drop_stale_ = b != 0;
    int64_t max_entries = 32768;
    api_->cfg_int(cfg, "max_entries", &max_entries);
    if (max_entries < 1 || max_entries > kMaxEntriesLimit) {
        api_->cfg_error(cfg, "max_entries", "must be between 1 and 16777216", err, err_len);
        return -1;
    }
    api_->scope(cfg, &scope_bonds_, &scope_bond_count_, &scope_endpoints_, &scope_endpoint_count_);
    reboot_jump_ns_ = std::max(kMinRebootJump, 2 * window_ns_);

    capacity_ = static_cast<uint32_t>(max_entries);
    // The table stays at most half full, so probe runs stay short.
    table_bits_ = 1;
    while ((uint64_t{1} << table_bits_) < 2 * uint64_t{capacity_})
        table_bits_++;
    table_mask_ = (1u << table_bits_) - 1;
    ring_.allocate(capacity_);
    entries_.allocate(capacity_);
    free_entries_.allocate(capacity_);
    table_.allocate(size_t{1} << table_bits_);
    pairs_.assign(size_t{kMaxBonds} * kMaxMembers * kMaxMembers, PairModel{});
    members_.assign(size_t{kMaxBonds} * kMaxMembers, Member{});
    streams_.assign(kStreams, Stream{});
    return 0;
}

bool Dedup::scope_allows(const mavbond_link* link) const {
    if (scope_bond_count_ == 0 && scope_endpoint_count_ == 0)
        return true;
    for (size_t i = 0; i < scope_bond_count_; i++) {
        if (link->bond_name && std::strcmp(scope_bonds_[i], link->bond_name) == 0)
            return true;
    }
    for (size_t i = 0; i < scope_endpoint_count_; i++) {
        if (link->name && std::strcmp(scope_endpoints_[i], link->name) == 0)
            return true;
    }
    return false;
}

bool Dedup::in_scope(const mavbond_link* link) {
    if (link->bond_id == MAVBOND_NO_BOND)
        return false;
    if (link->bond_id >= kMaxBonds || link->priority >= kMaxMembers) {
        if (!overflow_logged_) {
            overflow_logged_ = true;
            char msg[160];
            std::snprintf(msg, sizeof msg,
                          "link '%s' is not deduplicated: only %u bonds of %u links each are",
                          link->name ? link->name : "?", kMaxBonds, kMaxMembers);
            api_->log(host_, MAVBOND_LOG_WARNING, msg);
        }
        return false;
    }
    if (link->id >= kScopeCache)
        return scope_allows(link);
    uint8_t& cached = scope_cache_[link->id];
    if (cached == 0)
        cached = scope_allows(link) ? 1 : 2;
    return cached == 1;
}

void Dedup::on_link(const mavbond_link* link, mavbond_link_event) {
    // Ids are reused after a link goes away: its scope is decided again on its next frame.
    if (link && link->id < kScopeCache)
        scope_cache_[link->id] = 0;
}

Dedup::Key Dedup::hash(const mavbond_frame* f) const {
    const uint8_t* data = f->raw;
    size_t len = f->raw_len;
    uint8_t buf[5 + 255];
    if (key_ == KeyKind::content) {
        // The sequence byte differs between two senders of one stream, and v1 / v2 framing
        // and v2's truncation of trailing zeros do not change the message: hash what does.
        uint32_t n = std::min<uint32_t>(f->payload_len, 255);
        while (n > 0 && f->payload[n - 1] == 0)
            n--;
        buf[0] = f->sysid;
        buf[1] = f->compid;
        buf[2] = static_cast<uint8_t>(f->msgid);
        buf[3] = static_cast<uint8_t>(f->msgid >> 8);
        buf[4] = static_cast<uint8_t>(f->msgid >> 16);
        if (n > 0)
            std::memcpy(buf + 5, f->payload, n);
        data = buf;
        len = 5 + n;
    }
    if (hash_ == HashKind::murmur3_32)
        return {murmur3_x86_32(data, len, 0), 0};
    Hash128 h = murmur3_x64_128(data, len, 0);
    return {h.h1, h.h2};
}

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
    en.recurred = 0;
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
    if (r.entry != kNone) {
        remove_instance(r.entry, r.slot);
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

void Dedup::expire(uint64_t now) {
    // The ring is in arrival order, so expiry stops at the first live instance in the window.
    while (ring_count_ > 0) {
        const Record& r = ring_[ring_head_];
        if (r.entry != kNone && now - r.t0 <= window_ns_)
            break;
        pop_front(false, now);
    }
}

void Dedup::add_instance(uint32_t e, uint32_t member, uint32_t link_id, uint64_t t) {
    Entry& en = entries_[e];
    uint8_t slot = en.count;
    if (en.count > 0)
        en.recurred = 1;
    if (en.count == kInstances) {
        // Forget this key's oldest instance; its ring record stays until expiry pops it.
        slot = 0;
        for (uint8_t s = 1; s < kInstances; s++) {
            if (ring_[en.rec[s]].t0 < ring_[en.rec[slot]].t0)
                slot = s;
        }
        ring_[en.rec[slot]].entry = kNone;
    } else {
        en.count++;
    }
    uint32_t pos = ring_head_ + ring_count_;
    if (pos >= capacity_)
        pos -= capacity_;
    ring_count_++;
    ring_[pos] = Record{t, e, link_id, slot, static_cast<uint8_t>(member),
                        static_cast<uint8_t>(1u << member)};
    en.rec[slot] = pos;
}

void Dedup::learn(PairModel& p, int64_t sample) {
    if (p.samples < kMinSamples) {
        p.first[p.samples++] = sample;
        if (p.samples == kMinSamples) {
            int64_t sorted[kMinSamples];
            std::copy(p.first, p.first + kMinSamples, sorted);
            std::sort(sorted, sorted + kMinSamples);
            p.offset_ns = sorted[kMinSamples / 2];
            for (int64_t& x : sorted)
                x = x < p.offset_ns ? p.offset_ns - x : x - p.offset_ns;
            std::sort(sorted, sorted + kMinSamples);
            p.mad_ns = sorted[kMinSamples / 2];
        }
        return;
    }
    // Clamp outliers (a legitimate repeat read as a copy) so one cannot move the offset far;
    // a real change of a link's latency is still followed, because clamped residuals raise
    // the deviation and so the tolerance, within tens of samples.
    int64_t tol = tolerance(p);
    int64_t residual = std::clamp(sample - p.offset_ns, -tol, tol);
    p.offset_ns += residual / kEwmaGain;
    int64_t abs_res = residual < 0 ? -residual : residual;
    p.mad_ns += (abs_res - p.mad_ns) / kEwmaGain;
    if (p.samples < UINT32_MAX)
        p.samples++;
}

Dedup::Match Dedup::match(uint32_t bond, uint32_t member, uint32_t link_id, Key key, uint64_t t,
                          bool timestamped) {
    Match m;
    uint32_t e = find(bond, key);
    if (e != kNone) {
        const Entry& en = entries_[e];
        int best = -1, oldest = -1, unseen = 0;
        int64_t best_err = INT64_MAX;
        uint64_t oldest_t0 = UINT64_MAX;
        for (int s = 0; s < en.count; s++) {
            const Record& r = ring_[en.rec[s]];
            if (r.seen & (1u << member))
                continue;  // this link had that instance: this frame is a later one
            unseen++;
            int64_t skew = static_cast<int64_t>(t - r.t0);
            const PairModel& p = pair(bond, r.first_member, member);
            if (p.samples >= kMinSamples) {
                int64_t err = skew - predicted_skew(p, r.first_member, member);
                err = err < 0 ? -err : err;
                if (err <= tolerance(p) && err < best_err) {
                    best = s;
                    best_err = err;
                }
            } else if (r.t0 < oldest_t0) {
                // No offset yet for this pair: the oldest unseen instance is the likeliest.
                oldest = s;
                oldest_t0 = r.t0;
            }
        }
        int chosen = best >= 0 ? best : oldest;
        if (chosen < 0 && timestamped && en.count == 1 && unseen == 1 && !en.recurred) {
            // A timestamped sample's bytes never recur, so a later copy of its only instance
            // is that instance, however late: a stalled link (a busy modem or CPU), not a new
            // frame. Only later than the offset predicts; an early copy may be a new instance
            // of a key that does recur (a test stream built of repeating cycles).
            const Record& r = ring_[en.rec[0]];
            const PairModel& p = pair(bond, r.first_member, member);
            int64_t late = static_cast<int64_t>(t - r.t0) - predicted_skew(p, r.first_member, member);
            if (p.samples >= kMinSamples && late > tolerance(p))
                chosen = 0;
        }
        if (en.count == 1 && unseen == 1) {
            // One instance in the window and this link has not had it: whichever way the
            // decision goes (even when it does not fit: the latency may have changed), the
            // arrival gap is a clean sample of the pair's offset.
            const Record& r = ring_[en.rec[0]];
            int64_t skew = static_cast<int64_t>(t - r.t0);
            learn(pair(bond, r.first_member, member), r.first_member < member ? skew : -skew);
        }
        if (chosen >= 0) {
            Record& r = ring_[en.rec[chosen]];
            r.seen |= static_cast<uint8_t>(1u << member);
            m.duplicate = true;
            m.first_link_id = r.first_link_id;
            m.skew_ns = static_cast<int64_t>(t - r.t0);
            return m;
        }
    }
    // A new instance. At the cap the oldest instance overall is forgotten first, which may
    // be this key's last one: look the key up again after making room.
    if (ring_count_ == capacity_) {
        pop_front(true, t);
        e = find(bond, key);
    }
    if (e == kNone)
        e = insert_entry(bond, key);
    add_instance(e, member, link_id, t);
    return m;
}

bool Dedup::stale(uint32_t bond, const mavbond_frame* f) {
    if (f->timestamp_offset < 0 || (f->timestamp_size != 4 && f->timestamp_size != 8))
        return false;
    // A v2 payload may be truncated: the bytes cut off were zeros.
    uint32_t off = static_cast<uint32_t>(f->timestamp_offset);
    uint32_t avail = f->payload_len > off ? f->payload_len - off : 0;
    uint64_t raw = read_le(f->payload + std::min(off, f->payload_len), avail, f->timestamp_size);
    uint64_t ts_ns = f->timestamp_us ? raw * 1000 : raw * kMs;
    uint64_t k = uint64_t{bond} << 48 | uint64_t{f->sysid} << 40 | uint64_t{f->compid} << 32 |
                 (f->msgid & 0xffffff);
    uint32_t i = static_cast<uint32_t>((k * 0x9e3779b97f4a7c15ull) >> 52) & (kStreams - 1);
    for (uint32_t probes = 0; streams_[i].key != k; i = (i + 1) & (kStreams - 1)) {
        if (streams_[i].key == UINT64_MAX) {
            if (streams_used_ * 4 >= kStreams * 3) {
                untracked_streams_++;
                if (!streams_full_logged_) {
                    streams_full_logged_ = true;
                    api_->log(host_, MAVBOND_LOG_WARNING,
                              "too many message streams: new ones are not checked for staleness");
                }
                return false;
            }
            streams_[i].key = k;
            streams_[i].newest_ns = ts_ns;
            streams_used_++;
            return false;
        }
        if (++probes == kStreams)
            return false;
    }
    Stream& s = streams_[i];
    if (ts_ns < s.newest_ns && s.newest_ns - ts_ns <= reboot_jump_ns_)
        return true;
    // Newer, equal, or so much older that the source restarted its clock.
    s.newest_ns = ts_ns;
    return false;
}

mavbond_verdict Dedup::on_ingress(const mavbond_frame* f, mavbond_frame_notes* notes,
                                  const mavbond_link* from) {
    // A frame an earlier filter dropped must leave no trace: remembered, it would make its
    // good copy from another link look like a duplicate.
    if (notes && (notes->flags & MAVBOND_NOTE_DROPPED))
        return MAVBOND_PASS;
    if (!from || !in_scope(from))
        return MAVBOND_PASS;
    uint64_t t = f->rx_time_ns ? f->rx_time_ns : api_->now_ns(host_);
    // Links are read in batches, each stamped once: keep time monotonic across them.
    if (t < clock_ns_)
        t = clock_ns_;
    clock_ns_ = t;

    uint32_t bond = from->bond_id;
    uint32_t member = from->priority;
    Member& mem = members_[bond * kMaxMembers + member];
    if (mem.link_id != from->id) {
        // Another link took this place in the bond: its latencies are its own.
        mem = Member{};
        mem.link_id = from->id;
        for (uint32_t other = 0; other < kMaxMembers; other++)
            pair(bond, member, other) = PairModel{};
    }

    if (window_ns_ > 0) {
        Key key = hash(f);
        if (notes) {
            notes->flags |= MAVBOND_NOTE_HASHED;
            notes->hash[0] = key.h1;
            notes->hash[1] = key.h2;
        }
        expire(t);
        Match m = match(bond, member, from->id, key, t, f->timestamp_offset >= 0);
        if (m.duplicate) {
            if (notes) {
                notes->flags |= MAVBOND_NOTE_DUPLICATE;
                notes->first_link_id = m.first_link_id;
                notes->skew_ns = m.skew_ns;
            }
            mem.duplicates++;
            return MAVBOND_DROP;
        }
    }
    if (drop_stale_ && stale(bond, f)) {
        if (notes)
            notes->flags |= MAVBOND_NOTE_STALE;
        mem.stale++;
        return MAVBOND_DROP;
    }
    mem.passed++;
    return MAVBOND_PASS;
}

void append_json_string(std::string& out, const char* s) {
    out += '"';
    for (; s && *s; s++) {
        char c = *s;
        if (c == '"' || c == '\\') {
            out += '\\';
            out += c;
        } else if (static_cast<unsigned char>(c) < 0x20) {
            char esc[8];
            std::snprintf(esc, sizeof esc, "\\u%04x", c);
            out += esc;
        } else {
            out += c;
        }
    }
    out += '"';
}

std::string Dedup::status() const {
    const mavbond_link* links[256];
    size_t n = std::min<size_t>(api_->links(host_, links, 256), 256);
    auto link_of = [&](uint32_t id) -> const mavbond_link* {
        for (size_t i = 0; i < n; i++) {
            if (links[i]->id == id)
                return links[i];
        }
        return nullptr;
    };
    auto name_of = [&](uint32_t id) {
        const mavbond_link* l = link_of(id);
        return l && l->name ? l->name : "?";
    };
    char num[96];
    std::string out = "{";
    std::snprintf(num, sizeof num, "\"window_ms\":%.1f,", static_cast<double>(window_ns_) / kMs);
    out += num;
    out += "\"hash\":\"";
    out += kHashNames[static_cast<int>(hash_)];
    out += "\",\"key\":\"";
    out += kKeyNames[static_cast<int>(key_)];
    out += "\",";
    std::snprintf(num, sizeof num,
                  "\"drop_stale\":%s,\"entries\":%u,\"instances\":%u,\"max_entries\":%u,",
                  drop_stale_ ? "true" : "false", fresh_ - free_count_, ring_count_, capacity_);
    out += num;
    std::snprintf(num, sizeof num, "\"evicted_early\":%" PRIu64 ",\"untracked_streams\":%" PRIu64
                  ",\"links\":[", evicted_early_, untracked_streams_);
    out += num;
    bool first = true;
    for (uint32_t b = 0; b < kMaxBonds; b++) {
        for (uint32_t m = 0; m < kMaxMembers; m++) {
            const Member& mem = members_[b * kMaxMembers + m];
            if (mem.link_id == kNone)
                continue;
            out += first ? "{\"name\":" : ",{\"name\":";
            first = false;
            append_json_string(out, name_of(mem.link_id));
            std::snprintf(num, sizeof num,
                          ",\"passed\":%" PRIu64 ",\"duplicates\":%" PRIu64 ",\"stale\":%" PRIu64
                          "}",
                          mem.passed, mem.duplicates, mem.stale);
            out += num;
        }
    }
    out += "],\"offsets\":[";
    first = true;
    for (uint32_t b = 0; b < kMaxBonds; b++) {
        for (uint32_t lo = 0; lo < kMaxMembers; lo++) {
            for (uint32_t hi = lo + 1; hi < kMaxMembers; hi++) {
                const PairModel& p = pairs_[(b * kMaxMembers + lo) * kMaxMembers + hi];
                const Member& a = members_[b * kMaxMembers + lo];
                const Member& c = members_[b * kMaxMembers + hi];
                if (p.samples == 0 || a.link_id == kNone || c.link_id == kNone)
                    continue;
                // Shown as "to is offset_ms behind from" (negative: ahead).
                out += first ? "{\"from\":" : ",{\"from\":";
                first = false;
                append_json_string(out, name_of(a.link_id));
                out += ",\"to\":";
                append_json_string(out, name_of(c.link_id));
                std::snprintf(num, sizeof num,
                              ",\"offset_ms\":%.1f,\"deviation_ms\":%.1f,\"samples\":%u}",
                              static_cast<double>(p.offset_ns) / kMs,
                              static_cast<double>(p.mad_ns) / kMs, p.samples);
                out += num;
            }
        }
    }
    out += "]}";
    return out;
}

void Dedup::metrics(MetricOut& out) const {
    const mavbond_link* links[256];
    size_t n = std::min<size_t>(api_->links(host_, links, 256), 256);
    for (const Member& mem : members_) {
        if (mem.link_id == kNone)
            continue;
        const mavbond_link* l = nullptr;
        for (size_t i = 0; i < n && !l; i++)
            l = links[i]->id == mem.link_id ? links[i] : nullptr;
        if (!l || !l->name)
            continue;  // gone (a UDP peer forgotten): its figures are history, not a series
        std::initializer_list<mavbond_label> labels = {
            {"link", l->name}, {"bond", l->bond_name ? l->bond_name : ""}};
        out.counter("passed_frames", "Frames of a link that dedup let through (first copies).",
                    mem.passed, labels);
        out.counter("duplicates", "Copies of an earlier frame that dedup dropped, by link.",
                    mem.duplicates, labels);
        out.counter("stale", "Samples older than one already delivered that dedup dropped.",
                    mem.stale, labels);
    }
    out.gauge("entries", "Frames remembered in the window now.",
              static_cast<double>(fresh_ - free_count_));
    out.gauge("max_entries", "Frames remembered at most (max_entries).",
              static_cast<double>(capacity_));
    out.counter("evicted_early",
                "Frames forgotten before the window ended because max_entries was reached.",
                evicted_early_);
    out.counter("untracked_streams",
                "Timestamped frames not checked for staleness: too many streams.",
                untracked_streams_);
}

}  // namespace

MAVBOND_FILTER_PLUGIN(Dedup, "dedup", "0.1.0",
                      "drops copies of a frame that already arrived on another link of the bond",
                      kOptions)

}  // namespace mavbond::dedup
