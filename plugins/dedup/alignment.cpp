// Where a frame stands: each link's numbering of a source aligned to the bond's (by identity,
// time only where identity cannot tell), and from that whether the frame is a copy of one
// delivered or new.
#include "dedup.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>

namespace mavbond::dedup {

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
            s.forgotten_pos = kUnknownPos;
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
    if (r.first_member != a.member) {
        learn_lag(member_of(a.bond, a.member), v.skew_ns);
        window_.late(a.bond, static_cast<uint64_t>(std::max<int64_t>(v.skew_ns, 0)), a.t);
    }
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
    // A free position's first copy would have come at a time known from the source's rate
    // only: before it is measured, by time, any copy of the key is nearer (taking a time for
    // it, one turn of 256 away, put a link's first frames a turn off their copies, and the
    // bond delivered them twice).
    auto consider = [&](int64_t pos, uint32_t rec, uint64_t t_first, uint32_t first_member,
                        bool copy) {
        if (pos <= after)
            return;
        options++;
        int64_t err;
        if (by_time && !copy && s.ns_per_frame == 0)
            err = INT64_MAX - 1;
        else if (by_time)
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
            uint64_t left = window_.ns() > since ? window_.ns() - since : 0;
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

bool Dedup::recurs(const Arrival& a, uint32_t e) const {
    if (e == kNone)
        return false;
    const Entry& en = entries_[e];
    int instances = 0;
    for (int i = 0; i < en.count; i++)
        instances += ring_[en.rec[i]].stream == a.stream;
    return instances > 1;
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
    // frame's earlier one). Bytes the window holds once only are this frame's, however long
    // the link was silent: the source's own silence (an autopilot's UART that stood still, no
    // frame on any link) makes a lagging link silent as long without its missing a frame, and
    // time then put its held copies a turn ahead, where the bond had nothing, and delivered
    // them again. A queued link's burst after a stall moved the head past a sparse link's
    // next frame: the step is no less plain for it.
    const int64_t continued = a.link_pos + lane.offset;  // where its step says it is
    const uint32_t held_there = at(a.stream, continued);
    const uint32_t e = find(a.bond, key);
    const bool this_frame_there =
        held_there != kNone && ring_[held_there].h1 == key.h1 && ring_[held_there].h2 == key.h2 &&
        (!recurs(a, e) ||
         !silent_for(lane, s, a.t, std::max<int64_t>(continued - lane.last_pos + kAmbiguousStep, 0)));
    const bool silent = silent_for(lane, s, a.t, kAmbiguousStep);
    const bool no_repeat = (flags & MAVBOND_STREAM_REPEAT) && held_there == kNone;
    if (!this_frame_there && (silent || s.head - lane.head_then >= kAmbiguousStep ||
                              s.head - continued - lane.behind_head >= kAmbiguousStep || no_repeat)) {
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
        Verdict placed = align(a, lane, e, "another frame holds its position");
        correct_tentative(a.stream, a.member, was, lane);
        return placed;
    }
    if (s.forgotten_pos != kUnknownPos && continued <= s.forgotten_pos) {
        // Its place is forgotten already: a copy later than the window (delivered again), or
        // a frame every other link lost, as late. Either way the link is that much behind the
        // others: the window grows to cover it from now on.
        member_of(a.bond, a.member).beyond_window++;
        window_.late(a.bond, a.t - s.forgotten_t0, a.t);
    }
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
                s.ns_per_frame = frame_interval(a.t - s.span_t, pos - s.span_pos, s.ns_per_frame);
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

}  // namespace mavbond::dedup
