// linkswitch: active-backup link selection for bonds (the paper's Algorithm 1, extended).
//
// Per bond in scope, only frames from the active link pass on ingress; the others are dropped
// and counted. Every member is monitored (when it was last heard, its loss over `loss_window`
// from the stream positions the host gives each frame), so the switch goes to a backup known
// to be alive instead of blindly to "the other link" as in the paper. A host timer checks for
// silence, so a switch happens within switch_after + one tick. Reasons to switch, in order:
//   1. silence: the active link is silent for `switch_after`, or for three of its usual gaps
//      when its frames come further apart (a side that hears only the GCS's 1 Hz HEARTBEAT:
//      one lost HEARTBEAT is no silence); always allowed, even inside hold_down, and to any
//      link heard now, on probation or not: a dead active link is worse than any other;
//   2. loss: its loss over `loss_window` exceeds `max_loss` and a backup is clearly better
//      (lower by `switch_margin` and beyond chance, see clearly_better());
//   3. failback: a more preferred link has been healthy for `failback_after` (its loss judged
//      fine, or too few frames in its window to judge: a link carrying a HEARTBEAT a second
//      can never be judged, and is not kept from its place for that).
// 2 and 3 wait for `hold_down` after the previous switch. A loss figure is judged only once
// the link has been heard for a whole window holding enough frames (see judged()), and a
// link back from silence is on probation: no loss switch goes to it before it has been
// healthy for failback_after.
//
// The links of a bond carry one stream fanned out by the other side, so copies share their
// sequence bytes. The bond remembers, per source, which recent sequence numbers it delivered;
// after a switch the new active link's copies of frames the old one delivered are dropped,
// and what the old link lost but the new one carries is delivered (DeliveredHistory). While
// the active link is overdue (silent for twice its usual gap, and half of switch_after), a
// backup's new frames stand in for it: a frame both links brought, one just before a switch
// and the other just after, is otherwise lost on both, and the history keeps the active
// link's late copies out.
// Frames toward the peer are not touched: the host's bond tx policy decides that.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "mavbond/filter.hpp"
#include "mavbond/source_table.hpp"

namespace {

using mavbond::History128;
using mavbond::SourceTable;
using mavbond::JsonOut;

constexpr uint64_t kMs = 1'000'000;
constexpr uint64_t kSecond = 1'000'000'000;
constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
// The silence check runs every switch_after / 10, within these bounds: 50 ms keeps the paper's
// 1 s detection within 1.05 s at negligible cost; 5 ms stops a tiny switch_after spinning.
constexpr uint64_t kMaxTick = 50 * kMs;
constexpr uint64_t kMinTick = 5 * kMs;
// The loss window's resolution: buckets of loss_window / 10.
constexpr size_t kLossBuckets = 10;
// A loss figure over fewer expected frames is not judged: one frame is then more than a
// percentage point, and at the default max_loss (5%) the threshold is 5 lost frames, the
// usual minimum (n*p >= 5) for treating a count of losses as normal, which the comparison in
// clearly_better() does.
constexpr int64_t kMinExpected = 100;
// A backup is better beyond chance when its loss is this many standard errors below the
// active link's (two-proportion z-test, one-sided 0.1%). The test is repeated every tick on
// sliding windows, so it has to be strict: simulated over two links of equal loss (2% to 10%,
// 50 to 124 frames/s, 5 s window, switch_margin 5%) this makes fewer than 5 switches an
// hour, where "the backup does better" made about 500.
constexpr double kBetterZ = 3.09;
// Sources (sysid, compid) per bond whose delivered sequence numbers are remembered: the host
// tracks as many per link.
constexpr uint32_t kHistorySources = 64;

const mavbond_option kOptions[] = {
    {"switch_after", MAVBOND_OPT_DURATION, "1s",
     "switch when the active link has been silent this long (the paper: 1s)"},
    {"loss_window", MAVBOND_OPT_DURATION, "5s",
     "window over which each link's loss is measured; judged only once the link has been heard "
     "for a whole window holding at least 100 expected frames"},
    {"max_loss", MAVBOND_OPT_PERCENT, "5%",
     "switch when the active link's loss exceeds this and a backup is clearly better "
     "(the paper: 5%)"},
    {"switch_margin", MAVBOND_OPT_PERCENT, "5%",
     "a loss switch goes only to a backup whose loss is lower by at least this many percentage "
     "points, and by more than chance (3.09 standard errors), so links of similar loss do not "
     "trade places on noise"},
    {"priority", MAVBOND_OPT_STRINGS, nullptr,
     "endpoint names of the bonds in scope, in preference order (default: the bond's member "
     "order); a learned peer (radio@10.0.0.2:14550) ranks as its endpoint"},
    {"hold_down", MAVBOND_OPT_DURATION, "2s",
     "no loss or failback switch within this time of the previous switch"},
    {"failback_after", MAVBOND_OPT_DURATION, "30s",
     "return to a more preferred link once it has been healthy this long; a link back from "
     "silence is not a target of a loss switch before that either (0s: never fail back)"},
    {nullptr, MAVBOND_OPT_BOOL, nullptr, nullptr},
};

/// Time from `then` to `now`, 0 when `then` is later: a frame's arrival time may be a little
/// after the loop's clock that a timer reads.
uint64_t elapsed(uint64_t now, uint64_t then) { return now > then ? now - then : 0; }

/// "5s", "500ms" or "1.25s": configured durations read back as the user wrote them.
void format_duration(uint64_t ns, char* out, size_t len) {
    if (ns % kSecond == 0)
        snprintf(out, len, "%llus", static_cast<unsigned long long>(ns / kSecond));
    else if (ns % kMs == 0 && ns < kSecond)
        snprintf(out, len, "%llums", static_cast<unsigned long long>(ns / kMs));
    else
        snprintf(out, len, "%.2fs", static_cast<double>(ns) / 1e9);
}

/// A link's loss over the window: frames it should have brought, and those it did not.
struct LossFigure {
    int64_t expected = 0;
    int64_t lost = 0;
    double loss() const { return expected > 0 ? static_cast<double>(lost) / expected : 0.0; }
};

/// Received and lost frames over the last loss_window: ten buckets of loss_window / 10 and
/// the current one, which fills as time goes, so the figure always covers the whole window
/// (and at most a tenth more). Expiry is O(1) per frame.
class LossWindow {
public:
    void init(uint64_t window_ns) { width_ = std::max<uint64_t>(window_ns / kLossBuckets, 1); }
    void clear() {
        received_.fill(0);
        lost_.fill(0);
    }
    void add(uint64_t now, int64_t received, int64_t lost) {
        roll(now);
        size_t b = epoch_ % kRing;
        received_[b] += received;
        lost_[b] += lost;
    }
    /// Lost may be negative in a bucket when a late frame filled a gap counted before it (in
    /// an older bucket or before the window was cleared): the sum never goes below zero.
    LossFigure totals(uint64_t now) {
        roll(now);
        int64_t received = 0, lost = 0;
        for (size_t i = 0; i < kRing; i++) {
            received += received_[i];
            lost += lost_[i];
        }
        LossFigure f;
        f.lost = std::max<int64_t>(lost, 0);
        f.expected = received + f.lost;
        return f;
    }

private:
    static constexpr size_t kRing = kLossBuckets + 1;

    void roll(uint64_t now) {
        uint64_t e = now / width_;
        if (e <= epoch_)
            return;
        uint64_t n = std::min<uint64_t>(e - epoch_, kRing);
        for (uint64_t i = 1; i <= n; i++) {
            size_t b = (epoch_ + i) % kRing;
            received_[b] = lost_[b] = 0;
        }
        epoch_ = e;
    }

    uint64_t width_ = kSecond;
    uint64_t epoch_ = 0;
    std::array<int64_t, kRing> received_{}, lost_{};
};

/// Which sequence numbers a bond recently delivered, per source: the newest, and a bitmap of
/// the 128 before it. A fixed open-addressed table, so a frame never allocates.
///
/// A copy is recognised while the link bringing it is less than 128 frames of its source and
/// less than `horizon` behind the delivery of the original; a copy from further behind looks
/// new and is delivered again (a duplicate, never a loss). The horizon (switch_after, or the
/// time the source takes for 128 frames at its rate over the last second, if shorter) also
/// keeps the numbers apart after a silence: the new link's frames may then be 128 or more
/// ahead, which modulo 256 may look like "just behind", and a source's history that old is
/// forgotten instead.
class DeliveredHistory {
    static constexpr uint64_t kHistoryFrames = 128;

public:
    enum class Seen { kNew, kDelivered, kUntracked };

    /// Whether (sysid, compid, seq) was delivered; when not, records it as delivered now.
    /// `restart`: the source's numbering restarted (the host saw it), its history is void.
    Seen admit(uint8_t sysid, uint8_t compid, uint8_t seq, uint64_t now, uint64_t horizon,
               bool restart) {
        Source* s = sources_.find(sysid, compid);
        if (!s)
            return Seen::kUntracked;
        if (s->ns_per_frame != 0)
            horizon = std::min(horizon, kHistoryFrames * s->ns_per_frame);
        if (!s->delivered_any || restart || elapsed(now, s->last_delivery_ns) >= horizon) {
            s->delivered_any = true;
            s->newest = seq;
            s->behind.reset();
            s->span_start_ns = now;
            s->span_frames = 0;
        } else {
            auto ahead = static_cast<uint8_t>(seq - s->newest);
            if (ahead == 0)
                return Seen::kDelivered;
            if (ahead < 128) {  // the old newest becomes bit ahead - 1
                s->behind.shift(ahead);
                s->behind.set(ahead - 1u);
                s->newest = seq;
                s->span_frames += ahead;
                if (elapsed(now, s->span_start_ns) >= kSecond) {
                    s->ns_per_frame = elapsed(now, s->span_start_ns) / s->span_frames;
                    s->span_start_ns = now;
                    s->span_frames = 0;
                }
            } else {
                // 1..128 behind the newest: bit (behind - 1).
                unsigned bit = static_cast<uint8_t>(s->newest - seq) - 1u;
                if (s->behind.has(bit))
                    return Seen::kDelivered;
                s->behind.set(bit);
            }
        }
        s->last_delivery_ns = now;
        return Seen::kNew;
    }

private:
    struct Source {
        bool delivered_any = false;
        uint8_t newest = 0;
        History128 behind;  // bit i: newest - 1 - i was delivered
        uint64_t last_delivery_ns = 0;
        uint64_t span_start_ns = 0;  // the source's rate: frames its newest moved on over
        uint64_t span_frames = 0;    // spans of a second (none across a silence)
        uint64_t ns_per_frame = 0;   // 0: not measured yet
    };

    SourceTable<Source, kHistorySources> sources_;
};

enum Reason : size_t { kSilence, kLoss, kFailback, kRemoved, kReasons };
constexpr const char* kReasonNames[kReasons] = {"silence", "loss", "failback", "removed"};
// A link is dead after this many of its usual longest gaps without a frame (when that is
// longer than switch_after); the usual gap forgets a long one by half every kGapHalfLife.
constexpr double kSilentGaps = 3;
// ... and overdue, its frames stood in for by a backup's, after this many.
constexpr double kOverdueGaps = 2;
constexpr double kGapHalfLife = 5e9;

struct Link {
    bool present = false;
    std::string name;
    std::string endpoint;  // its configured endpoint (a peer's server): the metric label
    uint32_t bond = kNone;  // index into LinkSwitch::bonds_, kNone: not in a bond in scope
    uint32_t member_order = 0;  // the host's position among the bond's members
    bool heard = false;
    uint64_t last_heard_ns = 0;  // creation time until heard, so silence counts from start
    double gap_ns = -1;          // its usual longest gap between frames (decays by half in
                                 // 5 s); -1 until its second frame
    uint64_t heard_since_ns = 0;  // heard without a silence since (its loss window's start)
    bool on_probation = false;    // back from silence, not yet healthy for failback_after
    bool healthy = false;
    uint64_t healthy_since_ns = 0;
    bool thin_window_logged = false;
    LossWindow window;
    uint64_t passed = 0;
    uint64_t dropped = 0;
    uint64_t already_delivered = 0;
    uint64_t stood_in = 0;  // of those passed, while the active link was overdue
};

struct Bond {
    uint32_t id = kNone;
    std::string name;
    std::vector<uint32_t> members;  // link ids, most preferred first
    uint32_t active = kNone;        // link id
    uint64_t switches = 0;
    std::array<uint64_t, kReasons> switches_by{};
    bool switched = false;
    uint64_t last_switch_ns = 0;
    bool stranded = false;  // the active link is silent and no other is heard (logged once)
    DeliveredHistory delivered;
    uint64_t untracked = 0;  // frames passed unchecked: more sources than the history holds
};

class LinkSwitch {
public:
    LinkSwitch(const mavbond_host_api* api, mavbond_host* h) : api_(api), h_(h) {}
    ~LinkSwitch() {
        if (timer_)
            api_->timer_cancel(h_, timer_id_);
    }

    /// Reads options and the bonds in scope; 0, or -1 with a message in err.
    int init(const mavbond_config* cfg, char* err, size_t err_len);
    mavbond_verdict on_ingress(const mavbond_frame* f, const mavbond_frame_notes* notes,
                               const mavbond_link* from);
    void on_link(const mavbond_link* link, mavbond_link_event event);
    void status(JsonOut& out);
    void metrics(mavbond::MetricOut& out);
    int tick();

private:
    int check_priority(const mavbond_config* cfg, char* err, size_t err_len);
    Link* link_for(const mavbond_link* l);
    void adopt(const mavbond_link* l);
    void order_members(Bond& b);
    void evaluate(Bond& b, uint64_t now);
    void update_health(Link& l, uint64_t now);
    /// How long a link must be silent to be taken for dead (before its usual gap is known,
    /// the longest that gap may turn out to be).
    uint64_t silence(const Link& l) const {
        double gaps = kSilentGaps * (l.gap_ns < 0 ? static_cast<double>(switch_after_) : l.gap_ns);
        return std::max(switch_after_, static_cast<uint64_t>(gaps));
    }
    /// Silent long enough that a backup's new frames stand in for it (see the top).
    bool overdue(const Link& l, uint64_t now) const {
        double gaps = kOverdueGaps * std::max(l.gap_ns, 0.0);
        return elapsed(now, l.last_heard_ns) >= std::max(switch_after_ / 2, static_cast<uint64_t>(gaps));
    }
    bool alive(const Link& l, uint64_t now) const {
        return l.present && l.heard && elapsed(now, l.last_heard_ns) < silence(l);
    }
    bool judged(const Link& l, const LossFigure& f, uint64_t now) const {
        return alive(l, now) && elapsed(now, l.heard_since_ns) >= loss_window_ &&
               f.expected >= kMinExpected;
    }
    /// Heard for a whole window with too few frames in it to judge its loss.
    bool thin(const Link& l, const LossFigure& f, uint64_t now) const {
        return alive(l, now) && elapsed(now, l.heard_since_ns) >= loss_window_ &&
               f.expected < kMinExpected;
    }
    bool clearly_better(const LossFigure& active, const LossFigure& backup) const;
    uint32_t pick_alive(const Bond& b, uint64_t now, uint64_t heard_within);
    uint32_t pick_better(const Bond& b, uint64_t now, const LossFigure& active);
    void make_active(Bond& b, uint32_t link_id, Reason reason, const char* why);
    uint32_t rank_of(const char* name) const;

    const mavbond_host_api* api_;
    mavbond_host* h_;
    uint64_t switch_after_ = kSecond;
    uint64_t loss_window_ = 5 * kSecond;
    double max_loss_ = 0.05;
    double switch_margin_ = 0.05;
    uint64_t hold_down_ = 2 * kSecond;
    uint64_t failback_after_ = 30 * kSecond;
    std::vector<std::string> priority_;
    std::vector<std::string> scope_bonds_;  // empty: every bond
    std::vector<Link> links_;              // by link id
    std::vector<Bond> bonds_;
    std::vector<uint32_t> bond_index_;     // bond id -> index into bonds_ (kNone: out of scope)
    bool timer_ = false;
    uint64_t timer_id_ = 0;
};

int LinkSwitch::init(const mavbond_config* cfg, char* err, size_t err_len) {
    api_->cfg_duration_ns(cfg, "switch_after", &switch_after_);
    api_->cfg_duration_ns(cfg, "loss_window", &loss_window_);
    api_->cfg_percent(cfg, "max_loss", &max_loss_);
    api_->cfg_percent(cfg, "switch_margin", &switch_margin_);
    api_->cfg_duration_ns(cfg, "hold_down", &hold_down_);
    api_->cfg_duration_ns(cfg, "failback_after", &failback_after_);
    if (switch_after_ == 0) {
        api_->cfg_error(cfg, "switch_after", "must be greater than 0", err, err_len);
        return -1;
    }
    if (loss_window_ < kLossBuckets) {
        api_->cfg_error(cfg, "loss_window", "must be greater than 0", err, err_len);
        return -1;
    }
    const char* const* names = nullptr;
    size_t count = 0;
    if (api_->cfg_strings(cfg, "priority", &names, &count) == 0)
        priority_.assign(names, names + count);

    const char* const* bonds = nullptr;
    const char* const* endpoints = nullptr;
    size_t bond_count = 0, endpoint_count = 0;
    api_->scope(cfg, &bonds, &bond_count, &endpoints, &endpoint_count);
    scope_bonds_.assign(bonds, bonds + bond_count);
    if (check_priority(cfg, err, err_len) != 0)
        return -1;
    // It chooses the active link of the bonds in its scope: what `tx: active` sends on.
    api_->provides(h_, MAVBOND_PROVIDES_ACTIVE_LINK);

    size_t n = api_->links(h_, nullptr, 0);
    std::vector<const mavbond_link*> all(n);
    n = std::min(n, api_->links(h_, all.data(), all.size()));
    for (size_t i = 0; i < n; i++)
        adopt(all[i]);
    for (Bond& b : bonds_) {
        order_members(b);
        if (!b.members.empty())
            make_active(b, b.members.front(), kReasons, nullptr);
    }

    uint64_t tick = std::clamp(switch_after_ / 10, kMinTick, kMaxTick);
    int rc = api_->timer_add(
        h_, tick, [](void* self) { return static_cast<LinkSwitch*>(self)->tick(); }, this,
        &timer_id_);
    if (rc < 0) {
        snprintf(err, err_len, "linkswitch: cannot add a timer: %s", strerror(-rc));
        return -1;
    }
    timer_ = true;
    return 0;
}

/// `priority` names endpoints of the bonds in scope, each once. Checked against the config
/// (the links do not exist yet when filters are created). Without a `bonds:` scope the
/// plugin cannot list the config's bonds (ABI 3 has no call for it), so only repeats are
/// caught then.
int LinkSwitch::check_priority(const mavbond_config* cfg, char* err, size_t err_len) {
    for (size_t i = 0; i < priority_.size(); i++) {
        bool repeated = std::find(priority_.begin(), priority_.begin() + i, priority_[i]) !=
                        priority_.begin() + i;
        if (priority_[i].empty() || repeated) {
            std::string msg = priority_[i].empty() ? "empty link name"
                                                   : "'" + priority_[i] + "' is listed twice";
            api_->cfg_error(cfg, "priority", msg.c_str(), err, err_len);
            return -1;
        }
    }
    // The bonds the names may come from: those in scope, else every bond of the config.
    std::vector<std::string> bonds = scope_bonds_;
    if (bonds.empty()) {
        const char* const* all = nullptr;
        size_t n = 0;
        api_->cfg_bonds(cfg, &all, &n);
        bonds.assign(all, all + n);
    }
    std::string known;  // for the message: every endpoint the names may be
    std::vector<std::string> members;
    for (const std::string& bond : bonds) {
        const char* const* names = nullptr;
        size_t count = 0;
        if (api_->cfg_bond_members(cfg, bond.c_str(), &names, &count) != 0)
            continue;  // the host checks `bonds:` itself
        for (size_t i = 0; i < count; i++) {
            members.emplace_back(names[i]);
            known += (known.empty() ? "" : ", ") + members.back();
        }
    }
    for (size_t i = 0; i < priority_.size(); i++) {
        if (std::find(members.begin(), members.end(), priority_[i]) != members.end())
            continue;
        std::string msg = "'" + priority_[i] + "' is not an endpoint of bond" +
                          (bonds.size() > 1 ? "s " : " ");
        for (size_t j = 0; j < bonds.size(); j++)
            msg += (j ? ", " : "") + bonds[j];
        msg += known.empty() ? " (it has none)" : " (" + known + ")";
        api_->cfg_item_error(cfg, "priority", i, msg.c_str(), err, err_len);
        return -1;
    }
    return 0;
}

/// A link's place in `priority`: its endpoint's name matches, so a peer learned by a UDP or TCP
/// server ("radio@10.0.0.2:14550") ranks as its endpoint ("radio").
uint32_t LinkSwitch::rank_of(const char* name) const {
    const char* at = strchr(name, '@');
    size_t len = at ? static_cast<size_t>(at - name) : strlen(name);
    for (size_t i = 0; i < priority_.size(); i++) {
        const std::string& p = priority_[i];
        if (p == name || (p.size() == len && p.compare(0, len, name, len) == 0))
            return static_cast<uint32_t>(i);
    }
    return kNone;
}

/// Takes a link the host told us about (one in scope) into links_ and, in a bond, bonds_.
void LinkSwitch::adopt(const mavbond_link* l) {
    if (l->id >= links_.size())
        links_.resize(l->id + 1);
    Link& link = links_[l->id];
    if (!link.present) {
        link = Link{};
        link.present = true;
        link.name = l->name ? l->name : "?";
        link.endpoint = l->endpoint ? l->endpoint : link.name;
        link.last_heard_ns = api_->now_ns(h_);
        link.window.init(loss_window_);
    }
    link.member_order = l->priority;
    if (l->bond_id == MAVBOND_NO_BOND || !l->bond_name)
        return;
    if (l->bond_id >= bond_index_.size())
        bond_index_.resize(l->bond_id + 1, kNone);
    if (bond_index_[l->bond_id] == kNone) {
        bond_index_[l->bond_id] = static_cast<uint32_t>(bonds_.size());
        Bond b;
        b.id = l->bond_id;
        b.name = l->bond_name;
        bonds_.push_back(std::move(b));
    }
    link.bond = bond_index_[l->bond_id];
    Bond& b = bonds_[link.bond];
    if (std::find(b.members.begin(), b.members.end(), l->id) == b.members.end())
        b.members.push_back(l->id);
}

/// Preference order: the `priority` list first, then the bond's member order.
void LinkSwitch::order_members(Bond& b) {
    std::stable_sort(b.members.begin(), b.members.end(), [this](uint32_t x, uint32_t y) {
        uint32_t rx = rank_of(links_[x].name.c_str()), ry = rank_of(links_[y].name.c_str());
        if (rx != ry)
            return rx < ry;
        return links_[x].member_order < links_[y].member_order;
    });
}

Link* LinkSwitch::link_for(const mavbond_link* l) {
    if (l->id >= links_.size() || !links_[l->id].present)
        adopt(l);  // a link we were not told about: allocates once, on its first frame
    return &links_[l->id];
}

mavbond_verdict LinkSwitch::on_ingress(const mavbond_frame* f, const mavbond_frame_notes* notes,
                                       const mavbond_link* from) {
    Link* l = link_for(from);
    uint64_t now = f->rx_time_ns ? f->rx_time_ns : api_->now_ns(h_);
    // Heard for the first time, or back from silence: its loss window starts afresh here.
    // The host's figure for the first frame back is the sequence jump over the outage (modulo
    // 256 anything from 0 to 127 frames), which says nothing: the outage counted as silence.
    const uint64_t gap = elapsed(now, l->last_heard_ns);
    bool back = l->heard && gap >= silence(*l);
    if (l->heard && !back) {
        // The usual longest gap: a longer one is taken at once, a shorter one lets it decay
        // with time (not with frames: a burst of hundreds must not make it forget 1 Hz).
        double kept = l->gap_ns * std::exp2(-static_cast<double>(gap) / kGapHalfLife);
        l->gap_ns = std::max(static_cast<double>(gap), l->gap_ns < 0 ? 0 : kept);
    }
    if (!l->heard || back) {
        l->heard_since_ns = now;
        l->window.clear();
        l->on_probation = back;
    }
    // Every frame that arrived proves the link alive and feeds its loss figure, even one an
    // earlier filter dropped (a duplicate from a backup is still a sign of a working backup).
    l->heard = true;
    l->last_heard_ns = std::max(l->last_heard_ns, now);
    bool repeat = f->stream_flags & MAVBOND_STREAM_REPEAT;
    l->window.add(now, repeat ? 0 : 1, back ? 0 : f->stream_lost);
    if (l->bond == kNone)
        return MAVBOND_PASS;
    if (notes && (notes->flags & MAVBOND_NOTE_DROPPED))
        return MAVBOND_PASS;  // already dropped: our verdict would be ignored anyway
    Bond& b = bonds_[l->bond];
    if (b.active == kNone) {
        order_members(b);
        make_active(b, b.members.front(), kReasons, nullptr);
    }
    const bool standing_in = from->id != b.active;
    if (standing_in && !overdue(links_[b.active], now)) {
        l->dropped++;
        return MAVBOND_DROP;
    }
    bool restart = f->stream_flags & MAVBOND_STREAM_RESYNC;
    switch (b.delivered.admit(f->sysid, f->compid, f->seq, now, switch_after_, restart)) {
    case DeliveredHistory::Seen::kDelivered:
        l->already_delivered++;
        return MAVBOND_DROP;
    case DeliveredHistory::Seen::kUntracked:
        b.untracked++;
        break;
    case DeliveredHistory::Seen::kNew:
        break;
    }
    l->passed++;
    l->stood_in += standing_in ? 1 : 0;
    return MAVBOND_PASS;
}

void LinkSwitch::on_link(const mavbond_link* link, mavbond_link_event event) {
    if (event == MAVBOND_LINK_ADDED) {
        adopt(link);
        Link& l = links_[link->id];
        if (l.bond != kNone) {
            Bond& b = bonds_[l.bond];
            order_members(b);
            // Until the first switch, the active link is the most preferred one present: links
            // appear one by one as the daemon starts (or as peers first send), and the order
            // they happen to appear in is not a preference.
            if (b.active == kNone || (!b.switched && b.active != b.members.front()))
                make_active(b, b.members.front(), kReasons, nullptr);
        }
        return;
    }
    if (link->id >= links_.size() || !links_[link->id].present)
        return;
    Link& l = links_[link->id];
    l.present = false;
    if (l.bond == kNone)
        return;
    Bond& b = bonds_[l.bond];
    b.members.erase(std::remove(b.members.begin(), b.members.end(), link->id), b.members.end());
    if (b.active != link->id)
        return;
    uint32_t next = pick_alive(b, api_->now_ns(h_), switch_after_);
    if (next == kNone && !b.members.empty())
        next = b.members.front();
    char why[160];
    snprintf(why, sizeof why, "%s was removed", l.name.c_str());
    if (next != kNone)
        make_active(b, next, kRemoved, why);
    else
        b.active = kNone;
}

int LinkSwitch::tick() {
    uint64_t now = api_->now_ns(h_);
    for (Bond& b : bonds_)
        evaluate(b, now);
    return 1;
}

/// Healthy: alive and its loss, where judged, at most max_loss. A link back from silence
/// leaves probation once healthy for failback_after.
void LinkSwitch::update_health(Link& l, uint64_t now) {
    LossFigure f = l.window.totals(now);
    bool is_judged = judged(l, f, now);
    bool healthy = alive(l, now) && (!is_judged || f.loss() <= max_loss_);
    if (healthy && !l.healthy)
        l.healthy_since_ns = now;
    l.healthy = healthy;
    if (l.on_probation && healthy && (is_judged || thin(l, f, now)) &&
        elapsed(now, l.healthy_since_ns) >= failback_after_)
        l.on_probation = false;
    // A full window with too few frames to judge: say so once, or "max_loss never acts"
    // would be a mystery on a slow link.
    if (alive(l, now) && elapsed(now, l.heard_since_ns) >= loss_window_ &&
        f.expected < kMinExpected && !l.thin_window_logged) {
        char window[32], line[256];
        format_duration(loss_window_, window, sizeof window);
        snprintf(line, sizeof line,
                 "link %s: %lld frames expected over %s, fewer than the %lld needed to judge its "
                 "loss: no loss switch from or to it until it carries more (or loss_window is "
                 "longer)",
                 l.name.c_str(), static_cast<long long>(f.expected), window,
                 static_cast<long long>(kMinExpected));
        api_->log(h_, MAVBOND_LOG_INFO, line);
        l.thin_window_logged = true;
    }
}

/// The backup's loss is lower than the active link's by at least switch_margin, and by more
/// than chance: a pooled two-proportion z-test, z >= kBetterZ. Both figures are judged.
bool LinkSwitch::clearly_better(const LossFigure& active, const LossFigure& backup) const {
    double d = active.loss() - backup.loss();
    if (d <= 0 || d < switch_margin_)
        return false;
    double n_a = static_cast<double>(active.expected), n_b = static_cast<double>(backup.expected);
    double pooled = static_cast<double>(active.lost + backup.lost) / (n_a + n_b);
    double variance = pooled * (1 - pooled) * (1 / n_a + 1 / n_b);
    return d * d >= kBetterZ * kBetterZ * variance;
}

/// For a silence or removal: a member heard within `heard_within` other than the active one,
/// the most preferred whose loss is not judged above max_loss, else the least lossy.
uint32_t LinkSwitch::pick_alive(const Bond& b, uint64_t now, uint64_t heard_within) {
    uint32_t least_lossy = kNone;
    double least = 2.0;
    for (uint32_t id : b.members) {
        Link& l = links_[id];
        if (id == b.active || !alive(l, now) || elapsed(now, l.last_heard_ns) >= heard_within)
            continue;
        LossFigure f = l.window.totals(now);
        if (!judged(l, f, now) || f.loss() <= max_loss_)
            return id;
        if (f.loss() < least) {
            least = f.loss();
            least_lossy = id;
        }
    }
    return least_lossy;
}

/// For a loss switch: a judged member, not on probation, clearly better than the active link;
/// the most preferred within max_loss, else the least lossy.
uint32_t LinkSwitch::pick_better(const Bond& b, uint64_t now, const LossFigure& active) {
    uint32_t least_lossy = kNone;
    double least = 2.0;
    for (uint32_t id : b.members) {
        Link& l = links_[id];
        if (id == b.active || l.on_probation)
            continue;
        LossFigure f = l.window.totals(now);
        if (!judged(l, f, now) || !clearly_better(active, f))
            continue;
        if (f.loss() <= max_loss_)
            return id;
        if (f.loss() < least) {
            least = f.loss();
            least_lossy = id;
        }
    }
    return least_lossy;
}

void LinkSwitch::evaluate(Bond& b, uint64_t now) {
    for (uint32_t id : b.members)
        update_health(links_[id], now);
    if (b.active == kNone) {
        if (!b.members.empty())
            make_active(b, b.members.front(), kReasons, nullptr);
        return;
    }
    Link& active = links_[b.active];
    char why[200];

    // 1. Silence: the paper's rule, allowed even inside hold_down (a dead link is worse than a
    // flapping one). The backup must be heard now (within switch_after / 2), not merely less
    // long ago: when the vehicle stops sending, every link falls silent within their latency
    // difference of each other, and there is nothing to switch to.
    uint64_t silent = elapsed(now, active.last_heard_ns);
    if (silent >= silence(active)) {
        uint32_t next = pick_alive(b, now, switch_after_ / 2);
        if (next == kNone) {
            if (!b.stranded) {
                snprintf(why, sizeof why,
                         "active link %s silent for %.2fs and no other link of bond %s is heard",
                         active.name.c_str(), static_cast<double>(silent) / 1e9, b.name.c_str());
                api_->log(h_, MAVBOND_LOG_WARNING, why);
                b.stranded = true;
            }
            return;
        }
        snprintf(why, sizeof why, "%s %s for %.2fs", active.name.c_str(),
                 active.heard ? "silent" : "not heard", static_cast<double>(silent) / 1e9);
        make_active(b, next, kSilence, why);
        return;
    }
    b.stranded = false;
    if (b.switched && elapsed(now, b.last_switch_ns) < hold_down_)
        return;

    // 2. Loss over a judged window, only towards a backup that is clearly better.
    LossFigure fa = active.window.totals(now);
    if (judged(active, fa, now) && fa.loss() > max_loss_) {
        uint32_t next = pick_better(b, now, fa);
        if (next != kNone) {
            char window[32];
            format_duration(loss_window_, window, sizeof window);
            LossFigure fn = links_[next].window.totals(now);
            snprintf(why, sizeof why, "loss %.1f%% over %s > %g%%, %s %.1f%%", fa.loss() * 100,
                     window, max_loss_ * 100, links_[next].name.c_str(), fn.loss() * 100);
            make_active(b, next, kLoss, why);
            return;
        }
    }

    // 3. Failback to a more preferred link that has stayed healthy long enough.
    if (failback_after_ == 0)
        return;
    for (uint32_t id : b.members) {
        if (id == b.active)
            break;
        Link& l = links_[id];
        LossFigure f = l.window.totals(now);
        if (l.healthy && (judged(l, f, now) || thin(l, f, now)) &&
            elapsed(now, l.healthy_since_ns) >= failback_after_) {
            char after[32];
            format_duration(failback_after_, after, sizeof after);
            snprintf(why, sizeof why, "failback to %s after %s healthy", l.name.c_str(), after);
            make_active(b, id, kFailback, why);
            return;
        }
    }
}

/// Switches the bond's active link; `why` nullptr marks the initial choice (not a switch).
void LinkSwitch::make_active(Bond& b, uint32_t link_id, Reason reason, const char* why) {
    uint32_t previous = b.active;
    b.active = link_id;
    int rc = api_->set_active_link(h_, b.id, link_id);
    char line[320];
    if (rc < 0) {
        snprintf(line, sizeof line, "bond %s: the host refused %s as active link: %s",
                 b.name.c_str(), links_[link_id].name.c_str(), strerror(-rc));
        api_->log(h_, MAVBOND_LOG_WARNING, line);
    }
    if (!why || previous == kNone || previous == link_id) {
        snprintf(line, sizeof line, "bond %s: active link %s", b.name.c_str(),
                 links_[link_id].name.c_str());
        api_->log(h_, MAVBOND_LOG_INFO, line);
        return;
    }
    b.switches++;
    if (reason < kReasons)
        b.switches_by[reason]++;
    b.switched = true;
    b.last_switch_ns = api_->now_ns(h_);
    snprintf(line, sizeof line, "active link %s -> %s: %s", links_[previous].name.c_str(),
             links_[link_id].name.c_str(), why);
    api_->log(h_, MAVBOND_LOG_NOTICE, line);
}

void LinkSwitch::status(JsonOut& out) {
    uint64_t now = api_->now_ns(h_);
    out.raw("{\"bonds\":[");
    for (size_t i = 0; i < bonds_.size(); i++) {
        Bond& b = bonds_[i];
        out.raw("%s{\"name\":", i ? "," : "");
        out.str(b.name.c_str());
        out.raw(",\"active\":");
        out.str(b.active == kNone ? "" : links_[b.active].name.c_str());  // as the host does
        out.raw(",\"switches\":%llu,\"switches_by_reason\":{",
                static_cast<unsigned long long>(b.switches));
        for (size_t r = 0; r < kReasons; r++)
            out.raw("%s\"%s\":%llu", r ? "," : "", kReasonNames[r],
                    static_cast<unsigned long long>(b.switches_by[r]));
        out.raw("},\"untracked_frames\":%llu,\"links\":[",
                static_cast<unsigned long long>(b.untracked));
        for (size_t j = 0; j < b.members.size(); j++) {
            Link& l = links_[b.members[j]];
            LossFigure f = l.window.totals(now);
            out.raw("%s{\"name\":", j ? "," : "");
            out.str(l.name.c_str());
            out.raw(",\"heard\":%s,\"silent_ms\":%llu,\"alive\":%s,\"expected_frames\":%lld,"
                    "\"loss_pct\":",
                    l.heard ? "true" : "false",
                    static_cast<unsigned long long>(elapsed(now, l.last_heard_ns) / kMs),
                    alive(l, now) ? "true" : "false", static_cast<long long>(f.expected));
            if (judged(l, f, now))
                out.num(f.loss() * 100, 2);
            else
                out.raw("null");  // not heard for a whole window, or too few frames in it
            out.raw(",\"probation\":%s,\"passed\":%llu,\"dropped\":%llu,"
                    "\"already_delivered\":%llu,\"stood_in\":%llu}",
                    l.on_probation ? "true" : "false", static_cast<unsigned long long>(l.passed),
                    static_cast<unsigned long long>(l.dropped),
                    static_cast<unsigned long long>(l.already_delivered),
                    static_cast<unsigned long long>(l.stood_in));
        }
        out.raw("]}");
    }
    out.raw("]}");
}

void LinkSwitch::metrics(mavbond::MetricOut& out) {
    uint64_t now = api_->now_ns(h_);
    for (Bond& b : bonds_) {
        out.counter("switches", "Changes of a bond's active link.", b.switches,
                    {{"bond", b.name.c_str()}});
        for (size_t r = 0; r < kReasons; r++)
            out.counter("switches_by_reason",
                        "Changes of a bond's active link by reason: silence, loss, failback, "
                        "removed.",
                        b.switches_by[r], {{"bond", b.name.c_str()}, {"reason", kReasonNames[r]}});
        out.counter("untracked_frames",
                    "Frames passed without checking for a copy already delivered (more sources "
                    "than linkswitch remembers).",
                    b.untracked, {{"bond", b.name.c_str()}});
        for (uint32_t id : b.members) {
            Link& l = links_[id];
            // The endpoint's name: a peer's address changes with its NAT port, a label must not.
            std::initializer_list<mavbond_label> labels = {{"bond", b.name.c_str()},
                                                           {"link", l.endpoint.c_str()}};
            out.gauge("active", "1 for the link linkswitch made active, 0 for the others.",
                      id == b.active ? 1 : 0, labels);
            out.gauge("alive", "1 while a link is heard (within switch_after).",
                      alive(l, now) ? 1 : 0, labels);
            LossFigure f = l.window.totals(now);
            out.gauge("loss_ratio",
                      "A link's loss over loss_window (0..1); NaN until judged (heard for a "
                      "whole window holding at least 100 expected frames).",
                      judged(l, f, now) ? f.loss() : std::numeric_limits<double>::quiet_NaN(),
                      labels);
            out.counter("passed_frames", "Frames of a link that linkswitch let through.",
                        l.passed, labels);
            out.counter("dropped_frames", "Frames of a link that linkswitch dropped (not active).",
                        l.dropped, labels);
            out.counter("already_delivered_frames",
                        "Frames of the active link dropped because the bond already delivered "
                        "their sequence number (copies the previous active link delivered "
                        "before a switch).",
                        l.already_delivered, labels);
            out.counter("stood_in_frames",
                        "Frames of a backup link passed while the active link was overdue "
                        "(new ones only; counted in passed_frames too).",
                        l.stood_in, labels);
        }
    }
}

}  // namespace

MAVBOND_FILTER_PLUGIN(LinkSwitch, "linkswitch", "0.2.0",
                      "active-backup: only the active link of a bond passes; switch on silence or loss",
                      kOptions)
