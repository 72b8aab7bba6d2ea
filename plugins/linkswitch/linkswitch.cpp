// linkswitch: active-backup link selection for bonds (the paper's Algorithm 1, extended).
//
// Per bond in scope, only frames from the active link pass on ingress; the others are dropped
// and counted. Every member is monitored (when it was last heard, its loss over `loss_window`
// from MAVLink sequence gaps), so the switch goes to a backup known to be alive instead of
// blindly to "the other link" as in the paper. A host timer checks for silence, so a switch
// happens within switch_after + one tick. Reasons to switch, in order:
//   1. the active link is silent for `switch_after` (always allowed, even inside hold_down);
//   2. its loss over `loss_window` exceeds `max_loss` and an alive backup does better;
//   3. failback: a more preferred link has been healthy for `failback_after`.
// 2 and 3 wait for `hold_down` after the previous switch, so two links of similar quality do
// not flap. Frames toward the peer are not touched: the host's bond tx policy decides that.
#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "json_out.h"
#include "mavbond/filter.hpp"
#include "seq_loss.h"

namespace {

using mavbond_plugins::JsonOut;
using mavbond_plugins::SeqStep;
using mavbond_plugins::SourceTable;

constexpr uint64_t kMs = 1'000'000;
constexpr uint64_t kSecond = 1'000'000'000;
constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
// The silence check runs every switch_after / 10, within these bounds: 50 ms keeps the paper's
// 1 s detection within 1.05 s at negligible cost; 5 ms stops a tiny switch_after spinning.
constexpr uint64_t kMaxTick = 50 * kMs;
constexpr uint64_t kMinTick = 5 * kMs;
// The loss window is a ring of buckets, so expiry is O(1) per frame.
constexpr size_t kLossBuckets = 10;
// Below this many expected frames in the window a loss rate is noise (one lost heartbeat of
// ten would read as 10%), so the link counts as "loss unknown", neither good nor bad.
constexpr int64_t kMinExpected = 20;

const mavbond_option kOptions[] = {
    {"switch_after", MAVBOND_OPT_DURATION, "1s",
     "switch when the active link has been silent this long (the paper: 1s)"},
    {"loss_window", MAVBOND_OPT_DURATION, "5s", "window over which each link's loss is measured"},
    {"max_loss", MAVBOND_OPT_PERCENT, "5%",
     "switch when the active link's loss exceeds this and a backup does better (the paper: 5%)"},
    {"priority", MAVBOND_OPT_STRINGS, nullptr,
     "link names in preference order (default: the bond's member order)"},
    {"hold_down", MAVBOND_OPT_DURATION, "2s",
     "no loss or failback switch within this time of the previous switch"},
    {"failback_after", MAVBOND_OPT_DURATION, "0s",
     "return to the most preferred link once healthy this long (0s: never)"},
    {nullptr, MAVBOND_OPT_BOOL, nullptr, nullptr},
};

/// "5s", "500ms" or "1.25s": configured durations read back as the user wrote them.
void format_duration(uint64_t ns, char* out, size_t len) {
    if (ns % kSecond == 0)
        snprintf(out, len, "%llus", static_cast<unsigned long long>(ns / kSecond));
    else if (ns % kMs == 0 && ns < kSecond)
        snprintf(out, len, "%llums", static_cast<unsigned long long>(ns / kMs));
    else
        snprintf(out, len, "%.2fs", static_cast<double>(ns) / 1e9);
}

/// Received and lost frames over the last loss_window, in buckets of loss_window / 10.
class LossWindow {
public:
    void init(uint64_t window_ns) { width_ = std::max<uint64_t>(window_ns / kLossBuckets, 1); }
    void add(uint64_t now, SeqStep s) {
        roll(now);
        size_t b = epoch_ % kLossBuckets;
        received_[b] += s.received;
        lost_[b] += s.lost;
    }
    /// Expected frames and the loss fraction over the window (lost may be negative in a bucket
    /// when a late frame filled a gap counted in the previous one).
    void totals(uint64_t now, int64_t& expected, double& loss) {
        roll(now);
        int64_t received = 0, lost = 0;
        for (size_t i = 0; i < kLossBuckets; i++) {
            received += received_[i];
            lost += lost_[i];
        }
        expected = received + std::max<int64_t>(lost, 0);
        loss = mavbond_plugins::loss_fraction(received, lost);
    }

private:
    void roll(uint64_t now) {
        uint64_t e = now / width_;
        if (e <= epoch_)
            return;
        uint64_t n = std::min<uint64_t>(e - epoch_, kLossBuckets);
        for (uint64_t i = 1; i <= n; i++) {
            size_t b = (epoch_ + i) % kLossBuckets;
            received_[b] = lost_[b] = 0;
        }
        epoch_ = e;
    }

    uint64_t width_ = kSecond;
    uint64_t epoch_ = 0;
    std::array<int64_t, kLossBuckets> received_{}, lost_{};
};

struct Link {
    bool present = false;
    std::string name;
    uint32_t bond = kNone;  // index into LinkSwitch::bonds_, kNone: not in a bond in scope
    uint32_t member_order = 0;  // the host's position among the bond's members
    bool heard = false;
    uint64_t last_heard_ns = 0;  // creation time until heard, so silence counts from start
    bool healthy = false;
    uint64_t healthy_since_ns = 0;
    SourceTable sources;
    LossWindow window;
    uint64_t passed = 0;
    uint64_t dropped = 0;
};

struct Bond {
    uint32_t id = kNone;
    std::string name;
    std::vector<uint32_t> members;  // link ids, most preferred first
    uint32_t active = kNone;        // link id
    uint64_t switches = 0;
    bool switched = false;
    uint64_t last_switch_ns = 0;
    bool stranded = false;  // the active link is silent and no other is heard (logged once)
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
    size_t status_json(char* buf, size_t len);
    void metrics(mavbond::MetricOut& out);
    int tick();

private:
    Link* link_for(const mavbond_link* l);
    void adopt(const mavbond_link* l);
    void order_members(Bond& b);
    void evaluate(Bond& b, uint64_t now);
    void update_health(Link& l, uint64_t now);
    bool alive(const Link& l, uint64_t now) const {
        return l.present && l.heard && now - l.last_heard_ns < switch_after_;
    }
    uint32_t pick_backup(const Bond& b, uint64_t now, double worse_than);
    void make_active(Bond& b, uint32_t link_id, const char* reason);
    uint32_t rank_of(const char* name) const;

    const mavbond_host_api* api_;
    mavbond_host* h_;
    uint64_t switch_after_ = kSecond;
    uint64_t loss_window_ = 5 * kSecond;
    double max_loss_ = 0.05;
    uint64_t hold_down_ = 2 * kSecond;
    uint64_t failback_after_ = 0;
    std::vector<std::string> priority_;
    std::vector<std::string> scope_bonds_;  // empty: every bond
    uint64_t created_ns_ = 0;
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

    created_ns_ = api_->now_ns(h_);
    size_t n = api_->links(h_, nullptr, 0);
    std::vector<const mavbond_link*> all(n);
    n = std::min(n, api_->links(h_, all.data(), all.size()));
    for (size_t i = 0; i < n; i++)
        adopt(all[i]);

    // The names cannot be checked against the links here: the daemon creates filters before
    // its endpoints, and learned peers appear later still. A repeat is certainly a mistake.
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
    for (Bond& b : bonds_) {
        order_members(b);
        if (!b.members.empty())
            make_active(b, b.members.front(), nullptr);
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

/// Takes a link the host told us about into links_ and, when its bond is in scope, bonds_.
void LinkSwitch::adopt(const mavbond_link* l) {
    if (l->id >= links_.size())
        links_.resize(l->id + 1);
    Link& link = links_[l->id];
    if (!link.present) {
        link = Link{};
        link.present = true;
        link.name = l->name ? l->name : "?";
        link.last_heard_ns = api_->now_ns(h_);
        link.window.init(loss_window_);
    }
    link.member_order = l->priority;
    if (l->bond_id == MAVBOND_NO_BOND || !l->bond_name)
        return;
    bool in_scope = scope_bonds_.empty() ||
                    std::find(scope_bonds_.begin(), scope_bonds_.end(), l->bond_name) !=
                        scope_bonds_.end();
    if (!in_scope)
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
    // A link back from silence: the sequence jump over the outage says nothing (modulo 256 it
    // is anything from 0 to 127 frames) and the outage already counted as silence, so loss is
    // measured afresh from here rather than charging a random figure to the returning link.
    if (l->heard && now - l->last_heard_ns >= switch_after_)
        l->sources.clear();
    // Every frame that arrived proves the link alive and feeds its loss figure, even one an
    // earlier filter dropped (a duplicate from a backup is still a sign of a working backup).
    l->heard = true;
    l->last_heard_ns = now;
    l->window.add(now, l->sources.step(f->sysid, f->compid, f->seq));
    if (l->bond == kNone)
        return MAVBOND_PASS;
    if (notes && (notes->flags & MAVBOND_NOTE_DROPPED))
        return MAVBOND_PASS;  // already dropped: our verdict would be ignored anyway
    Bond& b = bonds_[l->bond];
    if (b.active == kNone) {
        order_members(b);
        make_active(b, b.members.front(), nullptr);
    }
    if (from->id == b.active) {
        l->passed++;
        return MAVBOND_PASS;
    }
    l->dropped++;
    return MAVBOND_DROP;
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
                make_active(b, b.members.front(), nullptr);
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
    uint64_t now = api_->now_ns(h_);
    uint32_t next = pick_backup(b, now, 2.0);
    if (next == kNone && !b.members.empty())
        next = b.members.front();
    char reason[160];
    snprintf(reason, sizeof reason, "%s was removed", l.name.c_str());
    if (next != kNone)
        make_active(b, next, reason);
    else
        b.active = kNone;
}

int LinkSwitch::tick() {
    uint64_t now = api_->now_ns(h_);
    for (Bond& b : bonds_)
        evaluate(b, now);
    return 1;
}

/// Healthy: heard within switch_after and loss at most max_loss (or too few frames to tell).
void LinkSwitch::update_health(Link& l, uint64_t now) {
    int64_t expected = 0;
    double loss = 0;
    l.window.totals(now, expected, loss);
    bool healthy = alive(l, now) && (expected < kMinExpected || loss <= max_loss_);
    if (healthy && !l.healthy)
        l.healthy_since_ns = now;
    l.healthy = healthy;
}

/// The best alive member other than the active one whose loss is below `worse_than`:
/// the most preferred within max_loss (or not yet measurable), else the least lossy.
uint32_t LinkSwitch::pick_backup(const Bond& b, uint64_t now, double worse_than) {
    uint32_t least_lossy = kNone;
    double least = worse_than;
    for (uint32_t id : b.members) {
        Link& l = links_[id];
        if (id == b.active || !alive(l, now))
            continue;
        int64_t expected = 0;
        double loss = 0;
        l.window.totals(now, expected, loss);
        bool measured = expected >= kMinExpected;
        if (worse_than <= 1.0 && !measured)
            continue;  // judging loss: a backup must show it does better, not just exist
        if ((!measured || loss <= max_loss_) && loss < worse_than)
            return id;
        if (loss < least) {
            least = loss;
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
            make_active(b, b.members.front(), nullptr);
        return;
    }
    Link& active = links_[b.active];
    char reason[200];

    // 1. Silence: the paper's rule, allowed even inside hold_down (a dead link is worse than a
    // flapping one).
    uint64_t silent = now - active.last_heard_ns;
    if (silent >= switch_after_) {
        uint32_t next = pick_backup(b, now, 2.0);  // any alive link beats a silent one
        if (next == kNone) {
            if (!b.stranded) {
                snprintf(reason, sizeof reason,
                         "active link %s silent for %.2fs and no other link of bond %s is heard",
                         active.name.c_str(), static_cast<double>(silent) / 1e9, b.name.c_str());
                api_->log(h_, MAVBOND_LOG_WARNING, reason);
                b.stranded = true;
            }
            return;
        }
        snprintf(reason, sizeof reason, "%s %s for %.2fs", active.name.c_str(),
                 active.heard ? "silent" : "not heard", static_cast<double>(silent) / 1e9);
        make_active(b, next, reason);
        return;
    }
    b.stranded = false;
    if (b.switched && now - b.last_switch_ns < hold_down_)
        return;

    // 2. Loss over the window, only towards a backup that measurably does better.
    int64_t expected = 0;
    double loss = 0;
    active.window.totals(now, expected, loss);
    if (expected >= kMinExpected && loss > max_loss_) {
        uint32_t next = pick_backup(b, now, loss);
        if (next != kNone) {
            char window[32];
            format_duration(loss_window_, window, sizeof window);
            snprintf(reason, sizeof reason, "loss %.1f%% over %s > %g%%", loss * 100, window,
                     max_loss_ * 100);
            make_active(b, next, reason);
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
        if (l.healthy && now - l.healthy_since_ns >= failback_after_) {
            char after[32];
            format_duration(failback_after_, after, sizeof after);
            snprintf(reason, sizeof reason, "failback to %s after %s healthy", l.name.c_str(),
                     after);
            make_active(b, id, reason);
            return;
        }
    }
}

/// Switches the bond's active link; reason nullptr marks the initial choice (not a switch).
void LinkSwitch::make_active(Bond& b, uint32_t link_id, const char* reason) {
    uint32_t previous = b.active;
    b.active = link_id;
    int rc = api_->set_active_link(h_, b.id, link_id);
    char line[320];
    if (rc < 0) {
        snprintf(line, sizeof line, "bond %s: the host refused %s as active link: %s",
                 b.name.c_str(), links_[link_id].name.c_str(), strerror(-rc));
        api_->log(h_, MAVBOND_LOG_WARNING, line);
    }
    if (!reason || previous == kNone || previous == link_id) {
        snprintf(line, sizeof line, "bond %s: active link %s", b.name.c_str(),
                 links_[link_id].name.c_str());
        api_->log(h_, MAVBOND_LOG_INFO, line);
        return;
    }
    b.switches++;
    b.switched = true;
    b.last_switch_ns = api_->now_ns(h_);
    snprintf(line, sizeof line, "active link %s -> %s: %s", links_[previous].name.c_str(),
             links_[link_id].name.c_str(), reason);
    api_->log(h_, MAVBOND_LOG_NOTICE, line);
}

size_t LinkSwitch::status_json(char* buf, size_t len) {
    uint64_t now = api_->now_ns(h_);
    JsonOut out(buf, len);
    out.raw("{\"bonds\":[");
    for (size_t i = 0; i < bonds_.size(); i++) {
        Bond& b = bonds_[i];
        out.raw("%s{\"name\":", i ? "," : "");
        out.str(b.name.c_str());
        out.raw(",\"active\":");
        out.str(b.active == kNone ? "" : links_[b.active].name.c_str());  // as the host does
        out.raw(",\"switches\":%llu,\"links\":[", static_cast<unsigned long long>(b.switches));
        for (size_t j = 0; j < b.members.size(); j++) {
            Link& l = links_[b.members[j]];
            int64_t expected = 0;
            double loss = 0;
            l.window.totals(now, expected, loss);
            out.raw("%s{\"name\":", j ? "," : "");
            out.str(l.name.c_str());
            out.raw(",\"heard\":%s,\"silent_ms\":%llu,\"alive\":%s,\"loss_pct\":",
                    l.heard ? "true" : "false",
                    static_cast<unsigned long long>((now - l.last_heard_ns) / kMs),
                    alive(l, now) ? "true" : "false");
            if (expected >= kMinExpected)
                out.num(loss * 100, 2);
            else
                out.raw("null");  // too few frames in the window to tell
            out.raw(",\"passed\":%llu,\"dropped\":%llu}", static_cast<unsigned long long>(l.passed),
                    static_cast<unsigned long long>(l.dropped));
        }
        out.raw("]}");
    }
    out.raw("]}");
    return out.length();
}

void LinkSwitch::metrics(mavbond::MetricOut& out) {
    uint64_t now = api_->now_ns(h_);
    for (Bond& b : bonds_) {
        out.counter("switches", "Changes of a bond's active link.", b.switches,
                    {{"bond", b.name.c_str()}});
        for (uint32_t id : b.members) {
            Link& l = links_[id];
            std::initializer_list<mavbond_label> labels = {{"bond", b.name.c_str()},
                                                           {"link", l.name.c_str()}};
            out.gauge("active", "1 for the link linkswitch made active, 0 for the others.",
                      id == b.active ? 1 : 0, labels);
            out.gauge("alive", "1 while a link is heard (within switch_after).",
                      alive(l, now) ? 1 : 0, labels);
            int64_t expected = 0;
            double loss = 0;
            l.window.totals(now, expected, loss);
            out.gauge("loss_ratio",
                      "A link's loss over loss_window (0..1); NaN: too few frames to tell.",
                      expected >= kMinExpected ? loss : std::numeric_limits<double>::quiet_NaN(),
                      labels);
            out.counter("passed_frames", "Frames of a link that linkswitch let through.",
                        l.passed, labels);
            out.counter("dropped_frames", "Frames of a link that linkswitch dropped (not active).",
                        l.dropped, labels);
        }
    }
}

}  // namespace

MAVBOND_FILTER_PLUGIN(LinkSwitch, "linkswitch", "0.1.0",
                      "active-backup: only the active link of a bond passes; switch on silence or loss",
                      kOptions)
