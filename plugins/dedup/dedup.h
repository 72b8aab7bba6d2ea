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
// identity: its bytes never recur. (A signed bond's own signature never gets here: the
// receiving endpoint verifies it and takes it off, so a signed link's copy and an unsigned
// link's are the same bytes; a signed frame here was signed by its source, and is the same
// bytes on every link. src/mavlink/bond_signing.h.)
//
// A copy is known for one only while its first copy is remembered: how long that is follows
// what the links really do (window.h), the user's `window` being the least, and what a link
// behind has not had yet is kept for it past that (awaited()): its first copy later than the
// window is still known.
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
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <new>
#include <string>
#include <type_traits>
#include <vector>

#include "mavbond/filter.hpp"
#include "window.h"

namespace mavbond::dedup {

constexpr uint64_t kMs = 1'000'000;
constexpr uint64_t kSecond = 1'000 * kMs;
constexpr uint32_t kNone = UINT32_MAX;
constexpr int64_t kUnknownPos = INT64_MIN;

// Bond ids and member positions index fixed arrays; bonds join a handful of links. A link
// beyond these passes untouched (logged once).
constexpr uint32_t kMaxBonds = Window::kMaxBonds;
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
// A timestamp going back by more than this (or twice the window) is an autopilot reboot
// (time_boot_ms restarts), not a late copy: a late copy lags by the links' skew, which the
// window covers.
constexpr uint64_t kMinRebootJump = 2 * kSecond;
constexpr uint64_t kEvictLogPeriod = 10 * kSecond;
// (bond, sysid, compid, msgid) streams whose newest timestamp is kept (power of two). A
// stream beyond it is not checked for staleness (fail open); real vehicles have a few hundred.
constexpr uint32_t kSampleStreams = 4096;
// Upper bound for max_entries: a typo must not allocate gigabytes at start.
constexpr int64_t kMaxEntriesLimit = int64_t{1} << 24;

// The source's frame interval over a span of `span_ns` in which its head moved `frames`
// forward. None or fewer where a correction moved the head back behind the span's start
// (correct_tentative): the span tells nothing then, and the interval known stays (dividing by
// it crashed the daemon in the operator stage).
inline uint64_t frame_interval(uint64_t span_ns, int64_t frames, uint64_t known) {
    return frames > 0 ? span_ns / static_cast<uint64_t>(frames) : known;
}

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
    int64_t forgotten_pos;  // the highest position expiry forgot (kUnknownPos: none yet)...
    uint64_t forgotten_t0;  // ...and when its first copy came
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
    uint64_t beyond_window = 0;  // frames at a position the window had forgotten already
    int64_t lag_ns = 0;      // how long after the first copy this link's copies come
    bool lag_known = false;
};

struct SampleStream {
    uint64_t key = UINT64_MAX;  // UINT64_MAX: empty
    uint64_t newest_ns = 0;
};

inline int64_t abs64(int64_t x) { return x < 0 ? -x : x; }

class Dedup {
public:
    Dedup(const mavbond_host_api* api, mavbond_host* h) : api_(api), host_(h) {}

    /// Reads and checks the options and allocates all memory. Non-zero with err filled on error.
    int init(const mavbond_config* cfg, char* err, size_t err_len);

    mavbond_verdict on_ingress(const mavbond_frame* f, mavbond_frame_notes* notes,
                               const mavbond_link* from);
    void status(JsonOut& out) const;
    void metrics(MetricOut& out) const;
    /// What it derived for bond `bond`: its window, and why.
    void describe(uint32_t bond, JsonOut& out);

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
    /// Whether the window holds more than one instance of the key of entry `e` in a's stream.
    bool recurs(const Arrival& a, uint32_t e) const;
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
    /// Every second: the far sides' resends as the host knows them, the window re-derived,
    /// and a change logged.
    void review_window();
    /// "bond NAME" of a bond in use, for the log ("bond #ID" when no link says its name).
    std::string bond_name(uint32_t bond) const;
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
    /// Whether a link of the bond that has not had record `r` yet had its stream's frames up
    /// to before it, and was heard within the longest window: a link behind, whose queue may
    /// still bring r's copy (a radio that stood still for longer than the window, holding
    /// what it had), not one that lost it. Kept until then, that copy is known for one.
    bool awaited(const Record& r, uint64_t now) const;
    void expire(uint64_t now);

    Member& member_of(uint32_t bond, uint32_t member) { return members_[bond * kMaxMembers + member]; }
    /// A link's name for a log line ("?" when it is gone).
    const char* link_name(uint32_t id) const;

    const mavbond_host_api* api_;
    mavbond_host* host_;

    Window window_;
    uint64_t window_logged_ns_ = 0;  // the window the log last told of
    HashKind hash_ = HashKind::murmur3_128;
    KeyKind key_ = KeyKind::frame;
    bool drop_stale_ = true;
    uint64_t stale_after_ns_ = 250 * kMs;

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

}  // namespace mavbond::dedup
