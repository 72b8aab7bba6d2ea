// dedup: turns the copies of one stream that arrive over a bond's links back into one stream
// (the redundant-telemetry paper's method, made exact).
//
// Identity, not timing. Every frame has a place in its source's (sysid, compid) stream: the
// host unwraps each link's sequence numbers into positions (mavbond_frame.stream_pos). A
// link's positions are aligned to the bond's numbering the first time one of its frames
// matches an instance another link delivered (same key: every byte, or with `key: content`
// the message without its sequence byte, for links that number the stream each their own
// way). From then on a frame at bond position P is a copy exactly when P was delivered with
// the same key: a repeat of the same bytes 256 positions later is a new frame however early or
// late it comes, and a frame one link lost is recognised when another link brings it, however
// far behind. A signed frame (MAVLink 2 signing: link id and 48-bit timestamp) is its own
// identity: its bytes never recur.
//
// Time only chooses what identity cannot, and then by the kernel's receive time: which of
// several instances of a recurring key a link's first frame of a source belongs to, and where
// a link stands after an outage of more than 128 frames of a source (its sequence byte's step
// is ambiguous modulo 256; the frame's own key settles it when another link delivered it). A
// link whose alignment keeps being contradicted by unique keys is aligned anew.
//
// Memory: a ring of instances in arrival order (expiry pops its head: O(1) amortised), a slab
// of entries (one per key, up to kInstances instances each), an open-addressing table over the
// slab, and a table of streams (bond, source) with each link's lane in it; all allocated in
// create and sized by max_entries. Nothing is allocated per frame.
#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#include <string>
#include <type_traits>
#include <vector>

#include "mavbond/filter.hpp"
#include "murmur3.h"

namespace mavbond::dedup {
namespace {

constexpr uint64_t kMs = 1'000'000;
constexpr uint64_t kSecond = 1'000 * kMs;
constexpr uint32_t kNone = UINT32_MAX;
constexpr int64_t kUnknownPos = INT64_MIN;

// Bond ids and member positions index fixed arrays; bonds join a handful of links. A link
// beyond these passes untouched (logged once).
constexpr uint32_t kMaxBonds = 16;
constexpr uint32_t kMaxMembers = 8;
// Instances remembered per key. Identical bytes recur every 256 frames of a source, or every
// second with key: content (HEARTBEAT): 8 covers a 5 s window at 1 Hz plus the copies in flight.
// When full, the oldest instance of that key is forgotten (its late copy passes: fail open).
constexpr int kInstances = 8;
// (bond, source) streams tracked (power of two). Real vehicles have a handful of sources per
// bond; a frame of a stream beyond the table passes (fail open, counted and logged once).
constexpr uint32_t kStreams = 1024;
// A step of a source's sequence byte is ambiguous once a link may have missed this many
// frames of it (modulo 256, half the range either way).
constexpr int64_t kAmbiguousStep = 128;
// The source's frame rate is measured over spans of this length (to tell an outage by time).
constexpr uint64_t kRateSpan = kSecond;
// A link's lag behind the first copy is averaged with gain 1/16 (it only chooses between
// instances whose identity is ambiguous).
constexpr int64_t kLagGain = 16;
// A timestamp going back by more than this is an autopilot reboot (time_boot_ms restarts),
// not a late copy: a late copy lags by the links' skew, which the window is sized to cover.
constexpr uint64_t kMinRebootJump = 2 * kSecond;
constexpr uint64_t kEvictLogPeriod = 10 * kSecond;
// (bond, sysid, compid, msgid) streams whose newest timestamp is kept (power of two). A
// stream beyond it is not checked for staleness (fail open); real vehicles have a few hundred.
constexpr uint32_t kSampleStreams = 4096;
// Upper bound for max_entries: a typo must not allocate gigabytes at start.
constexpr int64_t kMaxEntriesLimit = int64_t{1} << 24;

enum class HashKind { murmur3_128, murmur3_32 };
enum class KeyKind { frame, content };

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

/// One delivered instance of a key, in the ring in arrival order.
struct Record {
    uint64_t h1, h2;         // its key
    uint64_t t0;             // arrival of the first copy
    int64_t pos;             // its bond position; kUnknownPos until its link is aligned
    int64_t link_pos;        // the first copy's position on its own link
    uint32_t entry;          // kNone: forgotten (its slot was reused), skipped by expiry
    uint32_t first_link_id;  // for the notes
    uint32_t stream;
    uint8_t slot;            // index in the entry's rec[]
    uint8_t first_member;    // position of the first link in its bond
    uint8_t seen;            // members that have had this instance (bit = member position)
    uint8_t by_time;         // placed by a tentative alignment (time chose it)
};

/// One key: its hash, its bond and its live instances (ring positions).
struct Entry {
    uint64_t h1, h2;
    uint32_t bond;
    uint32_t home;  // table slot the key hashes to (for backward-shift deletion)
    uint32_t rec[kInstances];
    uint8_t count;
};

/// A source's frames in one bond, numbered by the bond (positions of the first link heard).
struct Stream {
    uint64_t key;        // bond << 16 | sysid << 8 | compid; 0: empty (bond + 1 keeps it apart)
    int64_t first_pos;   // the first position delivered
    int64_t head;        // the highest position delivered; kUnknownPos: none yet
    uint64_t head_t;     // when it was
    int64_t span_pos;    // where the current rate span started
    uint64_t span_t;
    uint64_t ns_per_frame;  // the source's frame interval; 0: not measured yet
    uint32_t head_member;   // the link that brought the head (whose timing head_t is)
};

/// One link's view of one stream: how its positions map to the bond's.
struct Lane {
    uint32_t generation;  // the member's generation it belongs to; older: a fresh lane
    uint8_t aligned;
    uint8_t tentative;       // time chose the alignment among several: a unique key may overrule it
    uint8_t contradictions;  // unique keys in a row found elsewhere than the alignment says
    int64_t offset;          // bond position = link position + offset
    uint64_t tentative_since;  // when the tentative alignment began
    int64_t head_before;       // the stream's head then
    int64_t proposed;        // the offset those contradictions agree on
    int64_t behind_head;     // how far behind the stream's head its last placed frame was
    int64_t last_pos;        // where its last placed frame was
    int64_t head_then;       // the stream's head when the link's last frame came
    uint64_t last_t;
};

struct Member {
    uint32_t link_id = kNone;
    uint32_t generation = 1;
    uint64_t passed = 0, duplicates = 0, stale = 0;
    uint64_t aligned = 0;    // lanes aligned (one per stream, more after outages)
    uint64_t by_time = 0;    // of those, where the time of arrival chose among instances
    uint64_t realigned = 0;  // a lane's alignment replaced (outage, restart, contradiction)
    int64_t lag_ns = 0;      // how long after the first copy this link's copies come
    bool lag_known = false;
};

struct SampleStream {
    uint64_t key = UINT64_MAX;  // UINT64_MAX: empty
    uint64_t newest_ns = 0;
};

constexpr const char* kHashNames[] = {"murmur3_128", "murmur3_32"};
constexpr const char* kKeyNames[] = {"frame", "content"};

// Defaults, and why:
// - window 2s: must exceed the largest latency skew between a bond's links. Radio links run at
//   tens of ms; LTE and satellite paths sit hundreds of ms behind and spike past 1 s under load.
//   Matching by identity keeps a long window safe, so 2 s leaves a margin; copies later than
//   that pass, and drop_stale still catches late timestamped samples. (The paper used 5 s.)
// - hash murmur3_128: with N keys in the window, a new frame collides with one of them with
//   probability N/2^bits, and a collision drops a good frame. At 1000 frames/s and 2 s that is
//   one lost frame every ~35 minutes with 32 bits, never in practice with 128. The hash is
//   computed once over <= 280 bytes, cheap on a Pi's 64-bit core.
// - key frame: the other gateway fans out one stream, so copies are byte-identical; `content`
//   is for an autopilot feeding two radios with separate sequence counters.
// - drop_stale true, stale_after 250ms: delivering a position sample well behind one already
//   delivered makes the vehicle jump back on the map (the paper's "rubberbanding"), but a
//   sample a few tens of ms behind moves it by centimetres while dropping it is a lost frame:
//   at 1,000 frames/s a copy the slower link brings 30 ms late would be. 250 ms lets through
//   what a radio's jitter and queue or an LTE modem add in normal operation (measured in
//   scripts/compare: its radio57600 and skew scenarios), and still stops a second-old sample.
// - max_entries 32768: instances remembered (one per unique frame, copies add none). At 2 s
//   that holds 16k unique frames/s, 7x a 921600-baud UART full of small frames.
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
     "drop a timestamped sample older than the newest delivered of its (sysid, compid, msgid) "
     "by more than stale_after"},
    {"stale_after", MAVBOND_OPT_DURATION, "250ms",
     "how far behind the newest delivered sample a late one may be and still pass"},
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

int64_t abs64(int64_t x) { return x < 0 ? -x : x; }

class Dedup {
public:
    Dedup(const mavbond_host_api* api, mavbond_host* h) : api_(api), host_(h) {}

    /// Reads and checks the options and allocates all memory. Non-zero with err filled on error.
    int init(const mavbond_config* cfg, char* err, size_t err_len);

    mavbond_verdict on_ingress(const mavbond_frame* f, mavbond_frame_notes* notes,
                               const mavbond_link* from);
    void status(JsonOut& out) const;
    void metrics(MetricOut& out) const;

private:
    struct Key {
        uint64_t h1, h2;
    };
    /// What one frame is: a copy of a delivered instance, or new; and where it stands.
    struct Verdict {
        bool duplicate = false;
        int64_t pos = kUnknownPos;
        uint32_t entry = kNone;  // the frame's key in the table, when it was looked up
        uint32_t first_link_id = kNone;
        int64_t skew_ns = 0;
    };
    /// The frame being decided, as the matching steps see it.
    struct Arrival {
        uint32_t bond, member, link_id, stream;
        int64_t link_pos;
        uint64_t t;
        bool is_signed;
        // Its key never recurs: signed (a 48-bit timestamp in the signature), or a message
        // carrying time_boot_ms / time_usec. Only such a key may overrule an alignment.
        bool unique;
        // The host read its step as one back (a late frame filling a gap, or a repeat): with
        // 128 frames or more missed, it may as well be a step forward.
        bool stepped_back;
    };

    /// Whether frames of `link` are deduplicated: a member of a bond, within the tables' bounds.
    bool deduplicates(const mavbond_link* link);
    Key hash(const mavbond_frame* f) const;
    uint32_t stream_of(uint32_t bond, uint8_t sysid, uint8_t compid);
    Lane& lane_of(const Arrival& a);
    Verdict decide(const Arrival& a, Key key, uint32_t flags);
    /// Whether the link was silent long enough to miss `frames` frames, at the source's rate.
    bool silent_for(const Lane& lane, const Stream& s, uint64_t t, int64_t frames) const;
    /// Whether key entry `e` has an instance of the arrival's stream its link has not had.
    bool unseen_instance(const Arrival& a, uint32_t e) const;
    /// A link not aligned (or no longer: `why` it is aligned anew): finds the frame's place,
    /// after position `after` when the frame is known to follow one there.
    Verdict align(const Arrival& a, Lane& lane, uint32_t e, const char* why,
                  int64_t after = kUnknownPos);
    Verdict copy_of(const Arrival& a, uint32_t rec);
    /// Aligns a link's lane; a changed alignment is logged with `why`.
    void set_alignment(const Arrival& a, Lane& lane, int64_t offset, const char* why);
    /// Marks a lane's alignment as chosen by time (or standing without evidence) from now on.
    void mark_tentative(const Arrival& a, Lane& lane);
    /// A link's tentative alignment (`was`) found wrong and replaced (`now`): what the link
    /// alone placed under it moves to where `now` puts it, and the stream's head back if it
    /// carried the head too far.
    void correct_tentative(uint32_t stream, uint32_t member, const Lane& was, const Lane& now);
    /// Record `rec`, placed by time and had by its first link alone, is at `pos`, as a link
    /// that never left shows: it moves there, and with it its link's alignment (and what the
    /// link delivered since) when that still stands.
    void move_placed_by_time(const Arrival& a, uint32_t rec, int64_t pos);
    void learn_lag(Member& m, int64_t skew_ns);
    /// Remembers a new frame; `e`: its key's entry as decide() found it (kNone: none yet).
    void remember(const Arrival& a, Key key, int64_t pos, uint32_t e);
    void note_position(const Arrival& a, Lane& lane, int64_t pos);
    uint32_t pos_home(uint32_t stream, int64_t pos) const;
    /// The instance delivered at a stream's position, or kNone.
    uint32_t at(uint32_t stream, int64_t pos) const;
    void place(uint32_t rec);
    void unplace(uint32_t rec);
    bool stale(uint32_t bond, const mavbond_frame* f);

    uint32_t table_home(uint64_t h1, uint32_t bond) const {
        uint64_t x = (h1 ^ (uint64_t{bond} * 0x9e3779b97f4a7c15ull)) * 0xbf58476d1ce4e5b9ull;
        return static_cast<uint32_t>(x >> (64 - table_bits_));
    }
    uint32_t find(uint32_t bond, Key key) const;
    uint32_t insert_entry(uint32_t bond, Key key);
    void erase_entry(uint32_t e);
    /// Adds an instance to key e (forgetting its oldest when full); returns its ring index.
    uint32_t add_instance(uint32_t e, const Record& r);
    void remove_instance(uint32_t e, uint8_t slot);
    void pop_front(bool early, uint64_t now);
    void expire(uint64_t now);

    Member& member_of(uint32_t bond, uint32_t member) { return members_[bond * kMaxMembers + member]; }
    /// A link's name for a log line ("?" when it is gone).
    const char* link_name(uint32_t id) const;

    const mavbond_host_api* api_;
    mavbond_host* host_;

    uint64_t window_ns_ = 0;
    HashKind hash_ = HashKind::murmur3_128;
    KeyKind key_ = KeyKind::frame;
    bool drop_stale_ = true;
    uint64_t stale_after_ns_ = 250 * kMs;
    uint64_t reboot_jump_ns_ = kMinRebootJump;

    uint32_t capacity_ = 0;  // max_entries
    ZeroedArray<Record> ring_;
    uint32_t ring_head_ = 0, ring_count_ = 0;
    ZeroedArray<Entry> entries_;
    ZeroedArray<uint32_t> free_entries_;  // entries given back, a stack
    uint32_t free_count_ = 0;
    uint32_t fresh_ = 0;                  // entries never used yet start here
    ZeroedArray<uint32_t> table_;         // entry + 1; 0: an empty slot
    ZeroedArray<uint32_t> at_pos_;        // by (stream, position): ring index + 1; 0: empty
    uint32_t table_bits_ = 0, table_mask_ = 0;

    ZeroedArray<Stream> streams_;
    ZeroedArray<Lane> lanes_;  // [stream * kMaxMembers + member]
    uint32_t streams_used_ = 0;
    uint64_t untracked_sources_ = 0;
    std::vector<Member> members_;
    std::vector<SampleStream> samples_;
    uint32_t samples_used_ = 0;

    uint64_t clock_ns_ = 0;  // newest arrival seen: time never runs backwards here
    uint64_t evicted_early_ = 0, evicted_since_log_ = 0, last_evict_log_ns_ = 0;
    bool evict_logged_ = false, overflow_logged_ = false, samples_full_logged_ = false;
    bool sources_full_logged_ = false;
    uint64_t untracked_samples_ = 0;
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
            // Each link numbers its copies its own way; the positions noted are the bond's.
            api_->provides(host_, MAVBOND_PROVIDES_ALIGNED_POSITIONS);
        } else {
            api_->cfg_error(cfg, "key", "must be frame or content", err, err_len);
            return -1;
        }
    }
    int b = 1;
    api_->cfg_bool(cfg, "drop_stale", &b);
    drop_stale_ = b != 0;
    api_->cfg_duration_ns(cfg, "stale_after", &stale_after_ns_);
    int64_t max_entries = 32768;
    api_->cfg_int(cfg, "max_entries", &max_entries);
    if (max_entries < 1 || max_entries > kMaxEntriesLimit) {
        api_->cfg_error(cfg, "max_entries", "must be between 1 and 16777216", err, err_len);
        return -1;
    }
    reboot_jump_ns_ = std::max({kMinRebootJump, 2 * window_ns_, 2 * stale_after_ns_});

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
    at_pos_.allocate(size_t{1} << table_bits_);
    streams_.allocate(kStreams);
    lanes_.allocate(size_t{kStreams} * kMaxMembers);
    members_.assign(size_t{kMaxBonds} * kMaxMembers, Member{});
    samples_.assign(kSampleStreams, SampleStream{});
    return 0;
}

bool Dedup::deduplicates(const mavbond_link* link) {
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
    return true;
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

void Dedup::expire(uint64_t now) {
    // The ring is in arrival order, so expiry stops at the first instance in the window.
    while (ring_count_ > 0) {
        const Record& r = ring_[ring_head_];
        if ((r.entry != kNone || r.pos != kUnknownPos) && now - r.t0 <= window_ns_)
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

// --- streams and lanes ---------------------------------------------------------------------

uint32_t Dedup::stream_of(uint32_t bond, uint8_t sysid, uint8_t compid) {
    uint64_t key = uint64_t{bond + 1} << 16 | uint64_t{sysid} << 8 | compid;
    uint32_t i = static_cast<uint32_t>((key * 0x9e3779b97f4a7c15ull) >> 54) & (kStreams - 1);
    for (uint32_t probes = 0; probes < kStreams; probes++, i = (i + 1) & (kStreams - 1)) {
        Stream& s = streams_[i];
        if (s.key == key)
            return i;
        if (s.key == 0) {
            if (streams_used_ * 4 >= kStreams * 3)
                break;
            s = Stream{};
            s.key = key;
            s.head = kUnknownPos;
            streams_used_++;
            return i;
        }
    }
    untracked_sources_++;
    if (!sources_full_logged_) {
        sources_full_logged_ = true;
        api_->log(host_, MAVBOND_LOG_WARNING,
                  "too many sources: frames of new ones pass without deduplication");
    }
    return kNone;
}

Lane& Dedup::lane_of(const Arrival& a) {
    Lane& lane = lanes_[size_t{a.stream} * kMaxMembers + a.member];
    uint32_t generation = member_of(a.bond, a.member).generation;
    if (lane.generation != generation) {  // unused, or another link's in this place
        lane = Lane{};
        lane.generation = generation;
    }
    return lane;
}

bool Dedup::silent_for(const Lane& lane, const Stream& s, uint64_t t, int64_t frames) const {
    return s.ns_per_frame != 0 && t - lane.last_t >= static_cast<uint64_t>(frames) * s.ns_per_frame;
}

void Dedup::set_alignment(const Arrival& a, Lane& lane, int64_t offset, const char* why) {
    Member& m = member_of(a.bond, a.member);
    if (lane.aligned && lane.offset != offset) {
        m.realigned++;
        const Stream& s = streams_[a.stream];
        char msg[240];
        std::snprintf(msg, sizeof msg,
                      "link %s: source %u/%u aligned anew, %+" PRId64 " positions (%s)",
                      link_name(a.link_id), static_cast<unsigned>(s.key >> 8 & 0xff),
                      static_cast<unsigned>(s.key & 0xff), offset - lane.offset, why);
        api_->log(host_, MAVBOND_LOG_INFO, msg);
    }
    if (!lane.aligned)
        m.aligned++;
    lane.aligned = 1;
    lane.offset = offset;
    lane.contradictions = 0;
    lane.tentative = 0;
}

void Dedup::mark_tentative(const Arrival& a, Lane& lane) {
    if (lane.tentative)
        return;
    lane.tentative = 1;
    lane.tentative_since = a.t;
    lane.head_before = streams_[a.stream].head;
}

void Dedup::move_placed_by_time(const Arrival& a, uint32_t rec, int64_t pos) {
    Record& r = ring_[rec];
    Lane& first = lanes_[size_t{a.stream} * kMaxMembers + r.first_member];
    if (first.generation == member_of(a.bond, r.first_member).generation && first.tentative &&
        r.t0 >= first.tentative_since && r.pos == r.link_pos + first.offset) {
        const Lane was = first;
        Arrival at_first = a;
        at_first.member = r.first_member;
        at_first.link_id = r.first_link_id;
        set_alignment(at_first, first, pos - r.link_pos,
                      "a link that never left has its frame elsewhere");
        correct_tentative(a.stream, r.first_member, was, first);  // r among them
    } else {  // the link was aligned anew since: the frame alone
        unplace(rec);
        r.pos = pos;
        place(rec);
    }
    r.by_time = 0;
}

void Dedup::correct_tentative(uint32_t stream, uint32_t member, const Lane& was,
                              const Lane& now) {
    if (!was.aligned || !was.tentative || !now.aligned || now.offset == was.offset)
        return;
    // What the link placed since is at the ring's tail (arrival order). All of it is taken
    // out before any is put back, so no moved frame finds another's old place taken.
    auto since_then = [&](auto fn) {
        for (uint32_t i = ring_count_; i-- > 0;) {
            uint32_t r = ring_head_ + i >= capacity_ ? ring_head_ + i - capacity_ : ring_head_ + i;
            if (ring_[r].t0 < was.tentative_since)
                break;
            if (ring_[r].stream == stream)
                fn(r, ring_[r], ring_[r].first_member == member && ring_[r].seen == (1u << member));
        }
    };
    since_then([&](uint32_t r, Record& x, bool alone) {
        if (alone && x.pos == x.link_pos + was.offset) {
            unplace(r);
            x.pos = x.link_pos + now.offset;
        }
    });
    int64_t head = was.head_before;
    since_then([&](uint32_t r, Record& x, bool alone) {
        if (alone && x.pos == x.link_pos + now.offset) {
            if (at(stream, x.pos) == kNone)
                place(r);
            else
                x.pos = kUnknownPos;  // taken after all: placed when a copy comes
        }
        head = std::max(head, x.pos);
    });
    streams_[stream].head = std::min(streams_[stream].head, head);
}

void Dedup::learn_lag(Member& m, int64_t skew_ns) {
    if (!m.lag_known) {
        m.lag_ns = skew_ns;
        m.lag_known = true;
        return;
    }
    m.lag_ns += (skew_ns - m.lag_ns) / kLagGain;
}

Dedup::Verdict Dedup::copy_of(const Arrival& a, uint32_t rec) {
    Record& r = ring_[rec];
    r.seen |= static_cast<uint8_t>(1u << a.member);
    Verdict v;
    v.duplicate = true;
    v.pos = r.pos;
    v.first_link_id = r.first_link_id;
    v.skew_ns = static_cast<int64_t>(a.t - r.t0);
    if (r.first_member != a.member)
        learn_lag(member_of(a.bond, a.member), v.skew_ns);
    return v;
}

Dedup::Verdict Dedup::align(const Arrival& a, Lane& lane, uint32_t e, const char* why,
                            int64_t after) {
    const bool outage = why != nullptr;
    Stream& s = streams_[a.stream];
    Verdict v;
    v.entry = e;
    if (s.head == kUnknownPos) {
        // The stream's first frame: this link's numbering becomes the bond's.
        set_alignment(a, lane, 0, "the stream's first frame");
        v.pos = a.link_pos;
        return v;
    }
    // The places the frame may have: an instance of its key this link has not had (a copy),
    // and with key: frame, where the offset stays a whole number of turns of 256, a position
    // no link delivered (a frame the others lost). Time chooses when there is a choice: the
    // kernel's receive time against the first copy's, as far apart as the two links usually
    // are; before that is known, in a young stream the place nearest its first frame (the
    // links came up with the stream), else the oldest copy.
    const Member& m = member_of(a.bond, a.member);
    bool young = s.head - s.first_pos < 2 * 256;
    bool by_time = m.lag_known || (outage && s.ns_per_frame != 0);
    auto lag = [this, &a](uint32_t member) {
        const Member& x = member_of(a.bond, member);
        return x.lag_known ? x.lag_ns : 0;
    };
    int64_t best_pos = kUnknownPos, best_err = INT64_MAX;
    uint32_t best_rec = kNone;
    int options = 0;
    auto consider = [&](int64_t pos, uint32_t rec, uint64_t t_first, uint32_t first_member,
                        bool copy) {
        if (pos <= after)
            return;
        options++;
        int64_t err;
        if (by_time)
            err = abs64(static_cast<int64_t>(a.t - t_first) - (lag(a.member) - lag(first_member)));
        else if (young)
            err = abs64(pos - s.first_pos);  // where the stream began
        else
            err = copy ? static_cast<int64_t>(t_first) : INT64_MAX - 1;  // the oldest copy
        if (err < best_err) {
            best_err = err;
            best_pos = pos;
            best_rec = rec;
        }
    };
    if (e != kNone) {
        const Entry& en = entries_[e];
        for (int i = 0; i < en.count; i++) {
            const Record& r = ring_[en.rec[i]];
            if (r.stream != a.stream || r.pos == kUnknownPos || (r.seen >> a.member & 1))
                continue;
            if (a.unique) {  // a key that never recurs: this is the frame, no choice to make
                set_alignment(a, lane, r.pos - a.link_pos, why ? why : "its first frames");
                return copy_of(a, en.rec[i]);
            }
            consider(r.pos, en.rec[i], r.t0, r.first_member, true);
        }
    }
    if (key_ == KeyKind::frame) {
        // The turns of 256 within what the window still remembers of the stream (before the
        // source's rate is known, from a turn before its first frame: another link may bring
        // frames the first one lost).
        int64_t lo = s.first_pos - 255;
        if (s.ns_per_frame != 0) {
            uint64_t since = a.t - s.head_t;
            uint64_t left = window_ns_ > since ? window_ns_ - since : 0;
            lo = std::max(lo, s.head - static_cast<int64_t>(left / s.ns_per_frame));
        }
        int64_t first = lo + ((a.link_pos - lo) % 256 + 256) % 256;  // the first turn from lo
        for (int64_t pos = first; pos <= s.head + 255; pos += 256) {
            if (at(a.stream, pos) != kNone)
                continue;  // delivered: a copy of it was considered above, or another frame
            int64_t behind = s.head - pos;  // when its first copy would have come
            uint64_t t_first = s.head_t - static_cast<uint64_t>(behind * static_cast<int64_t>(s.ns_per_frame));
            consider(pos, kNone, t_first, s.head_member, false);
        }
    }
    if (best_pos == kUnknownPos) {
        // A copy of a frame another link brought before it was placed: a copy still.
        if (e != kNone) {
            const Entry& en = entries_[e];
            for (int i = 0; i < en.count; i++) {
                const Record& r = ring_[en.rec[i]];
                if (r.stream == a.stream && r.pos == kUnknownPos && !(r.seen >> a.member & 1))
                    return copy_of(a, en.rec[i]);
            }
        }
        if (outage) {
            // New, with nothing to place it by (its key's numbering restarted): it goes on from
            // the stream's head, until a unique key says otherwise.
            v.pos = s.head + 1;
            set_alignment(a, lane, v.pos - a.link_pos, why);
            mark_tentative(a, lane);
            return v;
        }
        // Not placed yet: the frame is new, and its position is learned when another link's
        // copy of it comes (see decide()).
        lane.aligned = 0;
        return v;
    }
    set_alignment(a, lane, best_pos - a.link_pos, why ? why : "its first frames");
    if (options > 1) {
        mark_tentative(a, lane);
        member_of(a.bond, a.member).by_time += by_time ? 1 : 0;
    }
    if (best_rec != kNone)
        return copy_of(a, best_rec);
    v.pos = best_pos;
    return v;
}

bool Dedup::unseen_instance(const Arrival& a, uint32_t e) const {
    const Entry& en = entries_[e];
    for (int i = 0; i < en.count; i++) {
        const Record& r = ring_[en.rec[i]];
        if (r.stream == a.stream && !(r.seen >> a.member & 1))
            return true;
    }
    return false;
}

Dedup::Verdict Dedup::decide(const Arrival& a, Key key, uint32_t flags) {
    Lane& lane = lane_of(a);
    Stream& s = streams_[a.stream];
    if (!lane.aligned)
        return align(a, lane, find(a.bond, key), nullptr);
    if (flags & MAVBOND_STREAM_RESYNC)
        return align(a, lane, find(a.bond, key), "its numbering restarted");
    // A link that may have missed 128 frames or more (silent that long at the source's rate,
    // the others moved the stream that far, its frame lands that much further behind the
    // stream's head than the link ran, or the host read its step as one back to a position
    // it had where the bond holds nothing): its step modulo 256 is ambiguous, and it is placed
    // anew (identity first, then time). Yet a link that merely lags behind a burst the others
    // delivered, never silent, looks the same by positions, and its frames continue where its
    // last one was: when the position its alignment gives is free and its key was delivered
    // nowhere, nothing says otherwise, and the alignment stands, tentatively (placing it by
    // time instead, with the source's rate thrown by the burst, put the link's next frames
    // where their copies were not, and delivered them twice).
    // That holds for a step forward only: a step the host read as one back (a late frame, a
    // repeat) may as well be one forward of 128 or more, as a sparse link's (one frame per
    // ~128 of the source) often is; it is placed anew. A repeat where the bond holds nothing
    // is none: the step forward, after the link's last frame. And where the bond holds this
    // very frame at the position its step gives, that is where it is, unless its key recurs
    // and the link's silence fits a step of a turn more better (the instance there is the
    // frame's earlier one). A queued link's burst after a stall moved the head past a sparse
    // link's next frame: the step is no less plain for it.
    const int64_t continued = a.link_pos + lane.offset;  // where its step says it is
    const uint32_t held_there = at(a.stream, continued);
    const bool this_frame_there =
        held_there != kNone && ring_[held_there].h1 == key.h1 && ring_[held_there].h2 == key.h2 &&
        !silent_for(lane, s, a.t, std::max<int64_t>(continued - lane.last_pos + kAmbiguousStep, 0));
    const bool silent = silent_for(lane, s, a.t, kAmbiguousStep);
    const bool no_repeat = (flags & MAVBOND_STREAM_REPEAT) && held_there == kNone;
    if (!this_frame_there && (silent || s.head - lane.head_then >= kAmbiguousStep ||
                              s.head - continued - lane.behind_head >= kAmbiguousStep || no_repeat)) {
        uint32_t e = find(a.bond, key);
        if (silent || a.stepped_back || held_there != kNone || (e != kNone && unseen_instance(a, e)))
            return align(a, lane, e, "a step of 128 frames or more",
                         no_repeat ? lane.last_pos : kUnknownPos);
        mark_tentative(a, lane);
    }

    Verdict v;
    v.pos = continued;
    if (held_there != kNone) {
        if (ring_[held_there].h1 == key.h1 && ring_[held_there].h2 == key.h2) {
            lane.contradictions = 0;
            if (a.unique) {  // a unique key confirms the alignment, and the first copy's
                Lane& first = lanes_[size_t{a.stream} * kMaxMembers + ring_[held_there].first_member];
                if (!lane.tentative)
                    first.tentative = 0;
                lane.tentative = 0;
            }
            return copy_of(a, held_there);  // the bond delivered this very position
        }
        // Another frame holds this position: the alignment is wrong (a counter restarted
        // without a run of frames to show it, or time chose wrong). Placed anew, by identity
        // first.
        const Lane was = lane;
        Verdict placed = align(a, lane, find(a.bond, key), "another frame holds its position");
        correct_tentative(a.stream, a.member, was, lane);
        return placed;
    }
    uint32_t e = find(a.bond, key);
    v.entry = e;
    if (e == kNone)
        return v;
    const Entry& en = entries_[e];
    int unplaced = -1, elsewhere = -1, unseen = 0;
    for (int i = 0; i < en.count; i++) {
        const Record& r = ring_[en.rec[i]];
        if (r.stream != a.stream || (r.seen >> a.member & 1))
            continue;
        unseen++;
        if (r.pos == kUnknownPos)
            unplaced = i;
        else
            elsewhere = i;
    }
    if (unplaced >= 0) {
        // The first copy came on a link not aligned yet: this one places it, and its link.
        uint32_t rec = en.rec[unplaced];
        Record& r = ring_[rec];
        r.pos = v.pos;
        place(rec);
        Lane& first = lanes_[size_t{a.stream} * kMaxMembers + r.first_member];
        if (first.generation == member_of(a.bond, r.first_member).generation && !first.aligned) {
            Arrival at_first = a;
            at_first.member = r.first_member;
            set_alignment(at_first, first, v.pos - r.link_pos, "another link's copy placed it");
        }
        return copy_of(a, rec);
    }
    if (elsewhere >= 0 && a.unique && unseen == 1) {
        // The key is unique, yet the bond has it at another position: either a new frame
        // whose bytes happen to equal one this link lost (rare), or this link's alignment is
        // wrong. A signature settles it at once, and so does any unique key against an
        // alignment time chose; otherwise two such frames in a row agreeing on one do.
        uint32_t rec = en.rec[elsewhere];
        const Record& r = ring_[rec];
        if (!lane.tentative && r.by_time && r.seen == (1u << r.first_member)) {
            // Time placed it, and this link never left: its position is the evidence.
            move_placed_by_time(a, rec, v.pos);
            return copy_of(a, rec);
        }
        int64_t offset = r.pos - a.link_pos;
        if (a.is_signed || lane.tentative ||
            (lane.contradictions > 0 && lane.proposed == offset)) {
            const Lane was = lane;
            set_alignment(a, lane, offset, "a unique frame the bond has at another position");
            correct_tentative(a.stream, a.member, was, lane);
            return copy_of(a, rec);
        }
        lane.contradictions = 1;
        lane.proposed = offset;
    }
    return v;
}

void Dedup::note_position(const Arrival& a, Lane& lane, int64_t pos) {
    Stream& s = streams_[a.stream];
    if (pos != kUnknownPos) {
        if (s.head == kUnknownPos) {
            s.first_pos = pos;
            s.head = pos;
            s.head_t = a.t;
            s.head_member = a.member;
            s.span_pos = pos;
            s.span_t = a.t;
        } else if (pos > s.head) {
            // The source's frame interval, over spans of a second (none across a silence).
            if (a.t - s.span_t > 5 * kRateSpan) {
                s.span_pos = pos;
                s.span_t = a.t;
            } else if (a.t - s.span_t >= kRateSpan) {
                s.ns_per_frame = (a.t - s.span_t) / static_cast<uint64_t>(pos - s.span_pos);
                s.span_pos = pos;
                s.span_t = a.t;
            }
            s.head = pos;
            s.head_t = a.t;
            s.head_member = a.member;
        }
        if (lane.aligned) {
            lane.behind_head = s.head - pos;
            lane.last_pos = pos;
        }
    }
    lane.head_then = s.head;
    lane.last_t = a.t;
}

void Dedup::remember(const Arrival& a, Key key, int64_t pos, uint32_t e) {
    // At the cap the oldest instance overall is forgotten first, which may be this key's last
    // one: look the key up again after making room.
    if (ring_count_ == capacity_) {
        pop_front(true, a.t);
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
    uint32_t i = static_cast<uint32_t>((k * 0x9e3779b97f4a7c15ull) >> 52) & (kSampleStreams - 1);
    for (uint32_t probes = 0; samples_[i].key != k; i = (i + 1) & (kSampleStreams - 1)) {
        if (samples_[i].key == UINT64_MAX) {
            if (samples_used_ * 4 >= kSampleStreams * 3) {
                untracked_samples_++;
                if (!samples_full_logged_) {
                    samples_full_logged_ = true;
                    api_->log(host_, MAVBOND_LOG_WARNING,
                              "too many message streams: new ones are not checked for staleness");
                }
                return false;
            }
            samples_[i].key = k;
            samples_[i].newest_ns = ts_ns;
            samples_used_++;
            return false;
        }
        if (++probes == kSampleStreams)
            return false;
    }
    SampleStream& s = samples_[i];
    if (ts_ns < s.newest_ns) {
        uint64_t behind = s.newest_ns - ts_ns;
        if (behind <= reboot_jump_ns_)
            return behind > stale_after_ns_;  // late, and by how much decides
    }
    // Newer, or so much older that the source restarted its clock.
    s.newest_ns = ts_ns;
    return false;
}

mavbond_verdict Dedup::on_ingress(const mavbond_frame* f, mavbond_frame_notes* notes,
                                  const mavbond_link* from) {
    // A frame an earlier filter dropped must leave no trace: remembered, it would make its
    // good copy from another link look like a duplicate.
    if (notes && (notes->flags & MAVBOND_NOTE_DROPPED))
        return MAVBOND_PASS;
    if (!from || !deduplicates(from))
        return MAVBOND_PASS;
    uint64_t t = f->rx_time_ns ? f->rx_time_ns : api_->now_ns(host_);
    // Arrivals come in order; a stream endpoint's read time may trail a datagram's kernel time.
    if (t < clock_ns_)
        t = clock_ns_;
    clock_ns_ = t;

    uint32_t bond = from->bond_id;
    uint32_t member = from->priority;
    Member& mem = member_of(bond, member);
    if (mem.link_id != from->id) {
        // Another link took this place in the bond: its lanes and lag are its own.
        uint32_t generation = mem.generation + 1;
        mem = Member{};
        mem.link_id = from->id;
        mem.generation = generation;
    }

    if (window_ns_ > 0) {
        Key key = hash(f);
        if (notes) {
            notes->flags |= MAVBOND_NOTE_HASHED;
            notes->hash[0] = key.h1;
            notes->hash[1] = key.h2;
        }
        expire(t);
        bool is_signed = key_ == KeyKind::frame && (f->incompat_flags & 0x01) != 0;
        Arrival a{bond, member, from->id, stream_of(bond, f->sysid, f->compid), f->stream_pos, t,
                  is_signed, is_signed || f->timestamp_offset >= 0,
                  f->stream_lost < 0 || (f->stream_flags & MAVBOND_STREAM_REPEAT) != 0};
        if (a.stream != kNone && !(f->stream_flags & MAVBOND_STREAM_UNTRACKED)) {
            Verdict v = decide(a, key, f->stream_flags);
            Lane& lane = lane_of(a);
            note_position(a, lane, v.pos);
            if (notes && v.pos != kUnknownPos) {
                notes->flags |= MAVBOND_NOTE_POSITION;
                notes->bond_pos = v.pos;
            }
            if (v.duplicate) {
                if (notes) {
                    notes->flags |= MAVBOND_NOTE_DUPLICATE;
                    notes->first_link_id = v.first_link_id;
                    notes->skew_ns = v.skew_ns;
                }
                mem.duplicates++;
                return MAVBOND_DROP;
            }
            remember(a, key, v.pos, v.entry);
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

// --- status --------------------------------------------------------------------------------

const char* Dedup::link_name(uint32_t id) const {
    const mavbond_link* links[256];
    size_t n = std::min<size_t>(api_->links(host_, links, 256), 256);
    for (size_t i = 0; i < n; i++) {
        if (links[i]->id == id && links[i]->name)
            return links[i]->name;
    }
    return "?";
}

void Dedup::status(JsonOut& out) const {
    out.raw("{\"window_ms\":%.1f,\"hash\":\"%s\",\"key\":\"%s\",",
            static_cast<double>(window_ns_) / kMs, kHashNames[static_cast<int>(hash_)],
            kKeyNames[static_cast<int>(key_)]);
    out.raw("\"drop_stale\":%s,\"stale_after_ms\":%.1f,\"entries\":%u,\"instances\":%u,"
            "\"max_entries\":%u,",
            drop_stale_ ? "true" : "false", static_cast<double>(stale_after_ns_) / kMs,
            fresh_ - free_count_, ring_count_, capacity_);
    out.raw("\"evicted_early\":%" PRIu64 ",\"untracked_sources\":%" PRIu64
            ",\"untracked_streams\":%" PRIu64 ",\"links\":[",
            evicted_early_, untracked_sources_, untracked_samples_);
    bool first = true;
    for (const Member& mem : members_) {
        if (mem.link_id == kNone)
            continue;
        out.raw("%s", first ? "{\"name\":" : ",{\"name\":");
        first = false;
        out.str(link_name(mem.link_id));
        out.raw(",\"passed\":%" PRIu64 ",\"duplicates\":%" PRIu64 ",\"stale\":%" PRIu64
                ",\"aligned\":%" PRIu64 ",\"aligned_by_time\":%" PRIu64 ",\"realigned\":%" PRIu64
                ",\"lag_ms\":",
                mem.passed, mem.duplicates, mem.stale, mem.aligned, mem.by_time, mem.realigned);
        if (mem.lag_known)
            out.raw("%.1f}", static_cast<double>(mem.lag_ns) / kMs);
        else
            out.raw("null}");
    }
    out.raw("]}");
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
        out.counter("alignments",
                    "A link's numbering of a source aligned to the bond's (one per source, more "
                    "after outages).",
                    mem.aligned, labels);
        out.counter("realignments",
                    "A link's alignment replaced (an outage, a restarted sequence counter).",
                    mem.realigned, labels);
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
                untracked_samples_);
    out.counter("untracked_sources",
                "Frames passed without deduplication: too many sources in the bonds.",
                untracked_sources_);
}

}  // namespace

MAVBOND_FILTER_PLUGIN(Dedup, "dedup", "0.2.0",
                      "drops copies of a frame that already arrived on another link of the bond",
                      kOptions)

}  // namespace mavbond::dedup
