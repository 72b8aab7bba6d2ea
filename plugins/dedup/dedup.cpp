// dedup: its options, the per-frame entry point, status and metrics. What it is and how it
// works: dedup.h; what it remembers: memory.cpp; where a frame stands: alignment.cpp; late
// samples: staleness.cpp.
#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <string>

#include "dedup.h"
#include "murmur3.h"

namespace mavbond::dedup {
namespace {

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
     "how long a frame is remembered at least; longer while the bond's links bring copies later "
     "or the far side resends further back (0 disables dedup)"},
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
}  // namespace

int Dedup::init(const mavbond_config* cfg, char* err, size_t err_len) {
    uint64_t window = 0;
    api_->cfg_duration_ns(cfg, "window", &window);
    window_ = Window(window);
    window_logged_ns_ = window;
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
    api_->cfg_duration_ns(cfg, "stale_after", &stale_after_ns_);
    int64_t max_entries = 32768;
    api_->cfg_int(cfg, "max_entries", &max_entries);
    if (max_entries < 1 || max_entries > kMaxEntriesLimit) {
        api_->cfg_error(cfg, "max_entries", "must be between 1 and 16777216", err, err_len);
        return -1;
    }
    // Every frame it delivers gets its place in the bond's numbering of its source (links
    // that number the stream each their own way aligned to one, and with key: frame a copy
    // rescued from a slower link placed where it was sent, not where it came): the bond may
    // renumber in delivery order.
    if (window > 0)
        api_->provides(host_, MAVBOND_PROVIDES_ALIGNED_POSITIONS);
    uint64_t timer = 0;
    if (window > 0 &&
        api_->timer_add(host_, kSecond, [](void* self) {
            try {
                static_cast<Dedup*>(self)->review_window();
            } catch (...) {
                // Out of memory for a log line: the window is reviewed again in a second.
            }
            return 1;
        }, this, &timer) != 0) {
        std::snprintf(err, err_len, "no timer for the window's review");
        return -1;
    }

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

    if (window_.floor() > 0) {
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

// --- the window ----------------------------------------------------------------------------

std::string Dedup::bond_name(uint32_t bond) const {
    const mavbond_link* links[256];
    size_t n = std::min<size_t>(api_->links(host_, links, 256), 256);
    for (size_t i = 0; i < n; i++) {
        if (links[i]->bond_id == bond && links[i]->bond_name)
            return std::string("bond ") + links[i]->bond_name;
    }
    return "bond #" + std::to_string(bond);
}

void Dedup::review_window() {
    // The bonds this instance has seen frames of, and what the host says of their far sides.
    for (uint32_t bond = 0; bond < kMaxBonds; bond++) {
        bool used = false;
        for (uint32_t m = 0; m < kMaxMembers && !used; m++)
            used = member_of(bond, m).link_id != kNone;
        mavbond_bond_state st{};
        st.struct_size = sizeof st;
        if (used && api_->bond_state(host_, bond, &st) == 0)
            window_.peer_resend(bond, st.peer_resend_ns);
    }
    window_.age(api_->now_ns(host_));
    // A change of a fifth or more is told (a link's lag moves a little all the time).
    const uint64_t now = window_.ns(), was = window_logged_ns_;
    if (now * 5 < was * 4 || now * 4 > was * 5) {
        window_logged_ns_ = now;
        char msg[320];
        int n = std::snprintf(msg, sizeof msg, "window now %.2fs (was %.2fs; at least %.2fs)",
                              static_cast<double>(now) / kSecond, static_cast<double>(was) / kSecond,
                              static_cast<double>(window_.floor()) / kSecond);
        for (uint32_t bond = 0; bond < kMaxBonds && n > 0 && static_cast<size_t>(n) < sizeof msg; bond++) {
            Window::Need need = window_.need(bond);
            if (need.ns != now)
                continue;
            n += std::snprintf(msg + n, sizeof msg - static_cast<size_t>(n),
                               ": %s brings copies up to %.2fs after the first, its far side "
                               "resends %.2fs back",
                               bond_name(bond).c_str(), static_cast<double>(need.late_ns) / kSecond,
                               static_cast<double>(need.resend_ns) / kSecond);
            break;
        }
        api_->log(host_, now > was ? MAVBOND_LOG_NOTICE : MAVBOND_LOG_INFO, msg);
    }
}

void Dedup::describe(uint32_t bond, JsonOut& out) {
    if (window_.floor() == 0) {
        out.raw("off (window: 0s), copies are delivered");
        return;
    }
    if (bond >= kMaxBonds)
        return;
    mavbond_bond_state st{};
    st.struct_size = sizeof st;
    if (api_->bond_state(host_, bond, &st) == 0)
        window_.peer_resend(bond, st.peer_resend_ns);
    const Window::Need need = window_.need(bond);
    out.raw("frames remembered %.2fs, at least its window %.2fs", static_cast<double>(need.ns) / kSecond,
            static_cast<double>(window_.floor()) / kSecond);
    if (need.resend_ns > 0)
        out.raw(", to cover the far side's resend of %.2fs on failover%s",
                static_cast<double>(need.resend_ns) / kSecond,
                st.peer_resend_announced ? "" : " (taken as this side's until it says)");
    if (need.late_ns > 0)
        out.raw(", copies come up to %.2fs after the first", static_cast<double>(need.late_ns) / kSecond);
    out.raw("; longer while the links bring copies later, and for a link behind what it has not "
            "had, up to %.0fs (logged); key %s",
            static_cast<double>(std::max(window_.floor(), Window::kMaxWindow)) / kSecond,
            kKeyNames[static_cast<int>(key_)]);
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
    out.raw("{\"window_ms\":%.1f,\"window_floor_ms\":%.1f,\"hash\":\"%s\",\"key\":\"%s\",",
            static_cast<double>(window_.ns()) / kMs, static_cast<double>(window_.floor()) / kMs,
            kHashNames[static_cast<int>(hash_)], kKeyNames[static_cast<int>(key_)]);
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
                ",\"beyond_window\":%" PRIu64 ",\"lag_ms\":",
                mem.passed, mem.duplicates, mem.stale, mem.aligned, mem.by_time, mem.realigned,
                mem.beyond_window);
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
        // The endpoint's name: a peer's address changes with its NAT port, a label must not.
        std::initializer_list<mavbond_label> labels = {
            {"link", l->endpoint ? l->endpoint : l->name}, {"bond", l->bond_name ? l->bond_name : ""}};
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
        out.counter("beyond_window",
                    "Frames of a link at a position the window had forgotten already (copies that "
                    "late pass: the window grows to cover them).",
                    mem.beyond_window, labels);
    }
    out.gauge("window_seconds",
              "How long a delivered frame is remembered now: the window, grown to cover the links' "
              "lateness and the far side's resend.",
              static_cast<double>(window_.ns()) / kSecond);
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


MAVBOND_FILTER_PLUGIN(Dedup, "dedup", "0.2.0",
                      "drops copies of a frame that already arrived on another link of the bond",
                      kOptions)

}  // namespace mavbond::dedup
