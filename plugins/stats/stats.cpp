// stats: an observer (always PASS) that turns what the links deliver into numbers.
//
// Per link: frames and bytes seen on ingress, the host's CRC error and garbage counters, and
// its loss: exact where the far side is mavbond (its count markers say how many frames it wrote
// on the link, the host counts what arrived), else from MAVLink sequence gaps per source (which
// also count what the far side chose not to send there). Each figure says which it is. Per bond: what was delivered (member frames no
// earlier filter dropped), duplicates and stale frames dropped (from dedup's notes), the loss
// of the delivered stream (the figure the paper improves), the latency skew between links
// (from dedup's skew_ns), and the active link from the host. Every `interval` a log line and
// optionally a CSV row per link and bond. Put stats last in the chain: it reads the notes the
// filters before it wrote.
#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "mavbond/filter.hpp"
#include "seq_loss.h"

namespace {

using mavbond::JsonOut;
using mavbond_plugins::loss_fraction;
using mavbond_plugins::SeqStep;
using mavbond_plugins::DeliveredLoss;

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
constexpr double kNsPerMs = 1e6;
// Skew histogram bin upper edges in ms: roughly logarithmic, from a wired link's jitter to an
// LTE link buffering for seconds. The last bin takes everything above.
constexpr std::array<double, 12> kSkewEdgesMs = {1, 2, 5, 10, 20, 50, 100, 200, 500, 1000, 2000,
                                                 5000};
constexpr size_t kSkewBins = kSkewEdgesMs.size() + 1;

const mavbond_option kOptions[] = {
    {"interval", MAVBOND_OPT_DURATION, "1s",
     "how often the figures are summarised (log line, CSV rows, interval figures)"},
    {"csv", MAVBOND_OPT_STRING, nullptr,
     "append one row per interval per link and bond to this CSV file (default: none)"},
    // Off by default: a line a second is 86,400 journal lines a day on a Pi, and `mavbondctl
    // watch`, status, /metrics and the CSV show the same figures.
    {"log", MAVBOND_OPT_BOOL, "false", "log one summary line per interval"},
    {nullptr, MAVBOND_OPT_BOOL, nullptr, nullptr},
};

/// Latency skew of duplicates: a copy's arrival minus the first copy's, as count, sum, max and
/// a fixed histogram (for p50), so a frame costs O(1) and no allocation.
struct Skew {
    uint64_t count = 0;
    double sum_ms = 0;
    double max_ms = 0;
    std::array<uint64_t, kSkewBins> bins{};

    void add(double ms) {
        count++;
        sum_ms += ms;
        max_ms = std::max(max_ms, ms);
        size_t b = 0;
        while (b < kSkewEdgesMs.size() && ms > kSkewEdgesMs[b])
            b++;
        bins[b]++;
    }
    double mean() const { return count ? sum_ms / static_cast<double>(count) : 0.0; }
    /// The upper edge of the bin holding the median (at most the maximum seen).
    double p50() const {
        uint64_t seen = 0;
        for (size_t b = 0; b < kSkewBins; b++) {
            seen += bins[b];
            if (count && seen * 2 >= count)
                return b < kSkewEdgesMs.size() ? std::min(kSkewEdgesMs[b], max_ms) : max_ms;
        }
        return 0.0;
    }
};

/// Counters that only grow; interval figures are differences of two of these.
struct LinkTotals {
    bool by_markers = false;  // received and lost are the count markers' figures
    uint64_t frames = 0;
    uint64_t bytes = 0;
    int64_t received = 0;  // distinct sequence numbers
    int64_t lost = 0;
    uint64_t crc_errors = 0;
    uint64_t garbage_bytes = 0;
};

struct BondTotals {
    uint64_t frames = 0;  // every ingress frame of a member, before any filter's verdict
    uint64_t bytes = 0;
    uint64_t delivered = 0;
    uint64_t duplicates = 0;
    uint64_t stale = 0;
    int64_t received = 0;  // of the delivered stream
    int64_t lost = 0;
    uint64_t crc_errors = 0;
    uint64_t skew_count = 0;
    double skew_sum_ms = 0;
    double skew_max_ms = 0;
};

/// What a link's loss is read from.
enum class Basis { Sequence, Markers };
const char* basis_name(Basis b) { return b == Basis::Markers ? "markers" : "sequence"; }

/// A link's figures that /metrics sums per endpoint (a server's peers, present and past, are
/// one series: a NAT's new port changes no label).
struct Counted {
    uint64_t frames = 0, bytes = 0, crc_errors = 0;
    int64_t seq_received = 0, seq_lost = 0;          // by sequence gaps
    uint64_t acct_expected = 0, acct_received = 0;   // by the far side's count markers
    bool markers = false;                            // a far side ever counted
    Counted& operator+=(const Counted& o) {
        frames += o.frames;
        bytes += o.bytes;
        crc_errors += o.crc_errors;
        seq_received += o.seq_received;
        seq_lost += o.seq_lost;
        acct_expected += o.acct_expected;
        acct_received += o.acct_received;
        markers = markers || o.markers;
        return *this;
    }
};

struct LinkStats {
    bool present = false;
    std::string name;
    std::string endpoint;   // the configured endpoint (a peer's server): the metric label
    uint32_t bond = kNone;  // index into Stats::bonds_
    uint32_t member = 0;    // position among the bond's members
    LinkTotals total, prev, interval;  // received/lost by `basis`
    Basis basis = Basis::Sequence;
    bool peer_standby = false;  // the far side's last marker: it keeps the link in standby
    int64_t seq_received = 0, seq_lost = 0;  // every frame's step, whatever the basis
    uint64_t acct_expected = 0, acct_received = 0;  // the host's, once the far side counts
    bool acct_moved = false;  // another link of the endpoint goes on with this account
    /// What /metrics counts of it: its sequence figures only until the far side counts (then
    /// they stop, kept in the endpoint's retired figures, and the markers' go on); its
    /// markers' none once another link carries them on (counted there: a rebound peer's
    /// series read twice its frames).
    Counted counted() const {
        Counted c{total.frames, total.bytes, total.crc_errors, 0, 0,
                  acct_moved ? 0 : acct_expected, acct_moved ? 0 : acct_received,
                  basis == Basis::Markers};
        if (basis == Basis::Sequence) {
            c.seq_received = seq_received;
            c.seq_lost = seq_lost;
        }
        return c;
    }
};

struct BondStats {
    uint32_t id = kNone;
    std::string name;
    std::vector<uint32_t> members;  // link ids
    uint32_t width = 0;             // skew matrix side: positions 0..width-1
    std::vector<Skew> skew;         // [first copy's member position * width + late copy's]
    BondTotals total, prev, interval;
    DeliveredLoss delivered_sources;
    mavbond_bond_state state{};
};

class Stats {
public:
    Stats(const mavbond_host_api* api, mavbond_host* h) : api_(api), h_(h) {}
    ~Stats() {
        if (timer_)
            api_->timer_cancel(h_, timer_id_);
        if (csv_)
            fclose(csv_);
    }

    int init(const mavbond_config* cfg, char* err, size_t err_len);
    void on_ingress(const mavbond_frame* f, const mavbond_frame_notes* notes,
                    const mavbond_link* from);
    void on_link(const mavbond_link* link, mavbond_link_event event);
    void status(JsonOut& out);
    void metrics(mavbond::MetricOut& out);
    int tick();

private:
    void adopt(const mavbond_link* l);
    /// The host's counters of a link now: CRC errors, garbage, its count markers' account
    /// (the basis of its loss moves to it when the far side starts counting).
    void refresh_counters(LinkStats& l);
    void write_csv(double t);
    void write_log();

    const mavbond_host_api* api_;
    mavbond_host* h_;
    uint64_t interval_ns_ = 1'000'000'000;
    bool log_ = false;
    std::string csv_path_;
    FILE* csv_ = nullptr;
    uint64_t start_ns_ = 0;
    uint64_t intervals_ = 0;
    std::vector<LinkStats> links_;      // by link id
    /// Per endpoint: the figures of its links that went away, and the sequence figures of
    /// those whose far side started counting (so every series only grows).
    std::map<std::string, Counted> retired_;
    std::vector<BondStats> bonds_;
    std::vector<uint32_t> bond_index_;  // bond id -> index into bonds_
    bool timer_ = false;
    uint64_t timer_id_ = 0;
};

int Stats::init(const mavbond_config* cfg, char* err, size_t err_len) {
    api_->cfg_duration_ns(cfg, "interval", &interval_ns_);
    int log = 1;
    if (api_->cfg_bool(cfg, "log", &log) == 0)
        log_ = log != 0;
    if (interval_ns_ == 0) {
        api_->cfg_error(cfg, "interval", "must be greater than 0", err, err_len);
        return -1;
    }
    const char* path = nullptr;
    if (api_->cfg_string(cfg, "csv", &path) == 0 && path && *path) {
        csv_path_ = path;
        // Appending keeps the series of earlier runs; the header goes only into a new file.
        csv_ = fopen(path, "a");
        if (!csv_) {
            std::string msg = std::string("cannot open '") + path + "': " + strerror(errno);
            api_->cfg_error(cfg, "csv", msg.c_str(), err, err_len);
            return -1;
        }
        fseek(csv_, 0, SEEK_END);
        if (ftell(csv_) == 0) {
            fputs("time_s,kind,name,frames,bytes,lost,loss_pct,delivered,duplicates,stale,"
                  "crc_errors,skew_ms_mean,active\n",
                  csv_);
            fflush(csv_);
        }
    }

    start_ns_ = api_->now_ns(h_);
    size_t n = api_->links(h_, nullptr, 0);
    std::vector<const mavbond_link*> all(n);
    n = std::min(n, api_->links(h_, all.data(), all.size()));
    for (size_t i = 0; i < n; i++)
        adopt(all[i]);

    int rc = api_->timer_add(
        h_, interval_ns_, [](void* self) { return static_cast<Stats*>(self)->tick(); }, this,
        &timer_id_);
    if (rc < 0) {
        snprintf(err, err_len, "stats: cannot add a timer: %s", strerror(-rc));
        return -1;
    }
    timer_ = true;
    return 0;
}

void Stats::adopt(const mavbond_link* l) {
    if (l->id >= links_.size())
        links_.resize(l->id + 1);
    LinkStats& link = links_[l->id];
    if (!link.present) {
        link = LinkStats{};
        link.present = true;
        link.name = l->name ? l->name : "?";
        link.endpoint = l->endpoint ? l->endpoint : link.name;
    }
    link.member = l->priority;
    if (l->bond_id == MAVBOND_NO_BOND || !l->bond_name)
        return;
    if (l->bond_id >= bond_index_.size())
        bond_index_.resize(l->bond_id + 1, kNone);
    if (bond_index_[l->bond_id] == kNone) {
        bond_index_[l->bond_id] = static_cast<uint32_t>(bonds_.size());
        BondStats b;
        b.id = l->bond_id;
        b.name = l->bond_name;
        bonds_.push_back(std::move(b));
    }
    link.bond = bond_index_[l->bond_id];
    BondStats& b = bonds_[link.bond];
    if (std::find(b.members.begin(), b.members.end(), l->id) == b.members.end())
        b.members.push_back(l->id);
    if (l->priority >= b.width) {
        // Grow the skew matrix, keeping what was measured (only when links are added).
        uint32_t width = l->priority + 1;
        std::vector<Skew> grown(static_cast<size_t>(width) * width);
        for (uint32_t i = 0; i < b.width; i++) {
            for (uint32_t j = 0; j < b.width; j++)
                grown[i * width + j] = b.skew[i * b.width + j];
        }
        b.skew = std::move(grown);
        b.width = width;
    }
}

void Stats::on_ingress(const mavbond_frame* f, const mavbond_frame_notes* notes,
                       const mavbond_link* from) {
    if (from->id >= links_.size() || !links_[from->id].present)
        adopt(from);  // a link we were not told about: allocates once, on its first frame
    LinkStats& l = links_[from->id];
    uint32_t flags = notes ? notes->flags : 0;
    l.total.frames++;
    l.total.bytes += f->raw_len;
    // The host tracks each link's positions per source: the gaps in them.
    l.seq_received += (f->stream_flags & MAVBOND_STREAM_REPEAT) ? 0 : 1;
    l.seq_lost += f->stream_lost;
    if (l.bond == kNone)
        return;

    BondStats& b = bonds_[l.bond];
    b.total.frames++;
    b.total.bytes += f->raw_len;
    if (!(flags & MAVBOND_NOTE_DROPPED)) {
        b.total.delivered++;
        // The delivered stream, by the position dedup gives it when it does (the same for
        // every link's copy, whatever each link's own counter), else by its own numbers.
        const int64_t* pos = notes && (flags & MAVBOND_NOTE_POSITION) ? &notes->bond_pos : nullptr;
        SeqStep d = b.delivered_sources.step(f->sysid, f->compid, pos, f->seq,
                                             static_cast<int64_t>(f->rx_time_ns), f->stream_flags,
                                             l.member);
        b.total.received += d.received;
        b.total.lost += d.lost;
    } else {
        if (flags & MAVBOND_NOTE_DUPLICATE)
            b.total.duplicates++;
        else if (flags & MAVBOND_NOTE_STALE)
            b.total.stale++;
    }
    b.delivered_sources.heard(l.member, static_cast<int64_t>(f->rx_time_ns));
    if ((flags & MAVBOND_NOTE_DUPLICATE) && notes) {
        double ms = static_cast<double>(notes->skew_ns < 0 ? -notes->skew_ns : notes->skew_ns) /
                    kNsPerMs;
        b.total.skew_count++;
        b.total.skew_sum_ms += ms;
        b.total.skew_max_ms = std::max(b.total.skew_max_ms, ms);
        uint32_t first = notes->first_link_id;
        if (first < links_.size() && links_[first].bond == l.bond) {
            uint32_t i = links_[first].member, j = l.member;
            if (i < b.width && j < b.width)
                b.skew[i * b.width + j].add(ms);
        }
    }
}

void Stats::on_link(const mavbond_link* link, mavbond_link_event event) {
    if (event == MAVBOND_LINK_ADDED) {
        adopt(link);
        return;
    }
    // A removed link's figures stay in its endpoint's series (a learned UDP peer that went
    // quiet, or moved to a new port, is still history); it leaves the status and the rows.
    if (link->id >= links_.size() || !links_[link->id].present)
        return;
    LinkStats& l = links_[link->id];
    refresh_counters(l);  // the host still has its counters while we hear it go
    retired_[l.endpoint] += l.counted();
    l.present = false;
}

void Stats::refresh_counters(LinkStats& l) {
    mavbond_link_counters c{};
    c.struct_size = sizeof c;
    uint32_t id = static_cast<uint32_t>(&l - links_.data());
    if (api_->link_counters(h_, id, &c) == 0) {
        l.total.crc_errors = c.crc_errors;
        l.total.garbage_bytes = c.garbage_bytes;
        if (c.account_flags & MAVBOND_ACCOUNT_EXACT) {
            l.acct_expected = c.account_expected;
            l.acct_received = c.account_received;
            l.peer_standby = (c.account_flags & MAVBOND_ACCOUNT_PEER_STANDBY) != 0;
            l.acct_moved = (c.account_flags & MAVBOND_ACCOUNT_MOVED) != 0;
            if (l.basis == Basis::Sequence) {
                // The far side counts from now: the sequence figures so far stay in the
                // endpoint's series, frozen; this link's loss is the markers' from here on.
                Counted seq;
                seq.seq_received = l.seq_received;
                seq.seq_lost = l.seq_lost;
                retired_[l.endpoint] += seq;
                l.basis = Basis::Markers;
            }
        }
    }
    if (l.basis == Basis::Markers) {
        l.total.received = static_cast<int64_t>(l.acct_received);
        l.total.lost = static_cast<int64_t>(l.acct_expected) - static_cast<int64_t>(l.acct_received);
    } else {
        l.total.received = l.seq_received;
        l.total.lost = l.seq_lost;
    }
}

int Stats::tick() {
    uint64_t now = api_->now_ns(h_);
    intervals_++;
    for (LinkStats& l : links_) {
        if (!l.present)
            continue;
        refresh_counters(l);
        l.total.by_markers = l.basis == Basis::Markers;
        if (l.prev.by_markers != l.total.by_markers) {  // the far side began to count
            l.prev.received = l.total.received;
            l.prev.lost = l.total.lost;
        }
        l.interval = LinkTotals{l.total.by_markers,
                                l.total.frames - l.prev.frames,
                                l.total.bytes - l.prev.bytes,
                                l.total.received - l.prev.received,
                                l.total.lost - l.prev.lost,
                                l.total.crc_errors - l.prev.crc_errors,
                                l.total.garbage_bytes - l.prev.garbage_bytes};
        l.prev = l.total;
    }
    for (BondStats& b : bonds_) {
        b.total.lost += b.delivered_sources.expire(static_cast<int64_t>(now));
        b.total.crc_errors = 0;
        for (uint32_t id : b.members)
            b.total.crc_errors += links_[id].total.crc_errors;
        b.state = mavbond_bond_state{};
        b.state.struct_size = sizeof b.state;
        if (api_->bond_state(h_, b.id, &b.state) != 0)
            b.state.active_link_id = kNone;
        const BondTotals& t = b.total;
        b.interval = BondTotals{t.frames - b.prev.frames,
                                t.bytes - b.prev.bytes,
                                t.delivered - b.prev.delivered,
                                t.duplicates - b.prev.duplicates,
                                t.stale - b.prev.stale,
                                t.received - b.prev.received,
                                t.lost - b.prev.lost,
                                t.crc_errors - b.prev.crc_errors,
                                t.skew_count - b.prev.skew_count,
                                t.skew_sum_ms - b.prev.skew_sum_ms,
                                0};
        b.prev = t;
    }
    try {
        if (csv_)
            write_csv(static_cast<double>(now - start_ns_) / 1e9);
        if (log_)
            write_log();
    } catch (...) {
        // Out of memory building a log line: skip this interval's line, keep counting.
    }
    return 1;
}

/// A CSV field: quoted when it holds a separator or quote (learned peers are "name@ip:port").
void csv_field(FILE* out, const char* s) {
    if (!strpbrk(s, ",\"\n")) {
        fputs(s, out);
        return;
    }
    fputc('"', out);
    for (; *s; s++) {
        if (*s == '"')
            fputc('"', out);
        fputc(*s, out);
    }
    fputc('"', out);
}

/// One row per link and per bond with this interval's figures. Columns that do not apply to
/// the kind stay empty; `active` is 1/0 for a bond member, the active link's name for a bond.
void Stats::write_csv(double t) {
    for (const LinkStats& l : links_) {
        if (!l.present)
            continue;
        const LinkTotals& i = l.interval;
        fprintf(csv_, "%.3f,link,", t);
        csv_field(csv_, l.name.c_str());
        fprintf(csv_, ",%llu,%llu,%lld,%.3f,,,,%llu,,", static_cast<unsigned long long>(i.frames),
                static_cast<unsigned long long>(i.bytes), static_cast<long long>(i.lost),
                loss_fraction(i.received, i.lost) * 100,
                static_cast<unsigned long long>(i.crc_errors));
        if (l.bond != kNone) {
            uint32_t id = static_cast<uint32_t>(&l - links_.data());
            fputs(bonds_[l.bond].state.active_link_id == id ? "1" : "0", csv_);
        }
        fputc('\n', csv_);
    }
    for (const BondStats& b : bonds_) {
        const BondTotals& i = b.interval;
        fprintf(csv_, "%.3f,bond,", t);
        csv_field(csv_, b.name.c_str());
        fprintf(csv_, ",%llu,%llu,%lld,%.3f,%llu,%llu,%llu,%llu,",
                static_cast<unsigned long long>(i.frames),
                static_cast<unsigned long long>(i.bytes), static_cast<long long>(i.lost),
                loss_fraction(i.received, i.lost) * 100,
                static_cast<unsigned long long>(i.delivered),
                static_cast<unsigned long long>(i.duplicates),
                static_cast<unsigned long long>(i.stale),
                static_cast<unsigned long long>(i.crc_errors));
        if (i.skew_count)
            fprintf(csv_, "%.3f", i.skew_sum_ms / static_cast<double>(i.skew_count));
        fputc(',', csv_);
        uint32_t active = b.state.active_link_id;
        if (active < links_.size())
            csv_field(csv_, links_[active].name.c_str());
        fputc('\n', csv_);
    }
    fflush(csv_);
}

/// One line per interval: each bond (delivered figures, then its links), then lone links.
void Stats::write_log() {
    std::string line;
    char part[256];
    auto add_link = [&](const LinkStats& l) {
        const LinkTotals& i = l.interval;
        snprintf(part, sizeof part, "%s %llu loss %.1f%%%s", l.name.c_str(),
                 static_cast<unsigned long long>(i.frames),
                 loss_fraction(i.received, i.lost) * 100, i.crc_errors ? " crc " : "");
        line += part;
        if (i.crc_errors)
            line += std::to_string(i.crc_errors);
    };
    for (const BondStats& b : bonds_) {
        const BondTotals& i = b.interval;
        snprintf(part, sizeof part, "%s%s: delivered %llu loss %.1f%% dup %llu stale %llu",
                 line.empty() ? "" : "; ", b.name.c_str(),
                 static_cast<unsigned long long>(i.delivered),
                 loss_fraction(i.received, i.lost) * 100,
                 static_cast<unsigned long long>(i.duplicates),
                 static_cast<unsigned long long>(i.stale));
        line += part;
        if (i.skew_count) {
            snprintf(part, sizeof part, " skew %.1fms",
                     i.skew_sum_ms / static_cast<double>(i.skew_count));
            line += part;
        }
        if (b.state.active_link_id < links_.size()) {
            line += " active ";
            line += links_[b.state.active_link_id].name;
        }
        line += " (";
        bool first = true;
        for (uint32_t id : b.members) {
            if (!links_[id].present)
                continue;
            line += first ? "" : ", ";
            first = false;
            add_link(links_[id]);
        }
        line += ")";
    }
    for (const LinkStats& l : links_) {
        if (!l.present || l.bond != kNone)
            continue;
        line += line.empty() ? "" : "; ";
        add_link(l);
    }
    if (!line.empty())
        api_->log(h_, MAVBOND_LOG_INFO, line.c_str());
}

void Stats::status(JsonOut& out) {
    out.raw("{\"interval_s\":");
    out.num(static_cast<double>(interval_ns_) / 1e9);
    out.raw(",\"intervals\":%llu,\"links\":[", static_cast<unsigned long long>(intervals_));
    bool first = true;
    for (LinkStats& l : links_) {
        if (!l.present)
            continue;
        refresh_counters(l);  // the host's counters are current even between intervals
        const LinkTotals& t = l.total;
        out.raw("%s{\"name\":", first ? "" : ",");
        first = false;
        out.str(l.name.c_str());
        out.raw(",\"endpoint\":");
        out.str(l.endpoint.c_str());
        out.raw(",\"bond\":");
        // "" rather than null for "none", as in the host's own status document.
        out.str(l.bond == kNone ? "" : bonds_[l.bond].name.c_str());
        // lost and loss_pct by `basis`: "markers" (what the far side wrote on the link,
        // exact) or "sequence" (gaps in the sources' sequence numbers).
        out.raw(",\"frames\":%llu,\"bytes\":%llu,\"basis\":\"%s\",\"expected\":%lld,"
                "\"lost\":%lld,\"loss_pct\":",
                static_cast<unsigned long long>(t.frames), static_cast<unsigned long long>(t.bytes),
                basis_name(l.basis), static_cast<long long>(t.received + t.lost),
                static_cast<long long>(std::max<int64_t>(t.lost, 0)));
        out.num(loss_fraction(t.received, t.lost) * 100);
        out.raw(",\"peer_standby\":%s,\"crc_errors\":%llu,\"garbage_bytes\":%llu",
                l.peer_standby ? "true" : "false", static_cast<unsigned long long>(t.crc_errors),
                static_cast<unsigned long long>(t.garbage_bytes));
        const LinkTotals& i = l.interval;
        out.raw(",\"interval\":{\"frames\":%llu,\"bytes\":%llu,\"lost\":%lld,\"loss_pct\":",
                static_cast<unsigned long long>(i.frames), static_cast<unsigned long long>(i.bytes),
                static_cast<long long>(i.lost));
        out.num(loss_fraction(i.received, i.lost) * 100);
        out.raw(",\"crc_errors\":%llu}}", static_cast<unsigned long long>(i.crc_errors));
    }
    out.raw("],\"bonds\":[");
    first = true;
    for (BondStats& b : bonds_) {
        mavbond_bond_state state{};
        state.struct_size = sizeof state;
        bool known = api_->bond_state(h_, b.id, &state) == 0;
        const BondTotals& t = b.total;
        out.raw("%s{\"name\":", first ? "" : ",");
        first = false;
        out.str(b.name.c_str());
        out.raw(",\"frames\":%llu,\"delivered\":%llu,\"duplicates\":%llu,\"stale\":%llu,"
                "\"delivered_lost\":%lld,\"delivered_loss_pct\":",
                static_cast<unsigned long long>(t.frames),
                static_cast<unsigned long long>(t.delivered),
                static_cast<unsigned long long>(t.duplicates),
                static_cast<unsigned long long>(t.stale),
                static_cast<long long>(std::max<int64_t>(t.lost, 0)));
        out.num(loss_fraction(t.received, t.lost) * 100);
        out.raw(",\"skew_ms\":{\"count\":%llu,\"mean\":",
                static_cast<unsigned long long>(t.skew_count));
        out.num(t.skew_count ? t.skew_sum_ms / static_cast<double>(t.skew_count) : 0.0);
        out.raw(",\"max\":");
        out.num(t.skew_max_ms);
        out.raw(",\"pairs\":[");
        bool first_pair = true;
        for (uint32_t i = 0; i < b.width; i++) {
            for (uint32_t j = 0; j < b.width; j++) {
                const Skew& s = b.skew[i * b.width + j];
                if (!s.count)
                    continue;
                const char* a = "?";
                const char* c = "?";
                for (uint32_t id : b.members) {
                    if (links_[id].member == i)
                        a = links_[id].name.c_str();
                    if (links_[id].member == j)
                        c = links_[id].name.c_str();
                }
                out.raw("%s{\"first\":", first_pair ? "" : ",");
                first_pair = false;
                out.str(a);
                out.raw(",\"late\":");
                out.str(c);
                out.raw(",\"count\":%llu,\"mean\":", static_cast<unsigned long long>(s.count));
                out.num(s.mean());
                out.raw(",\"p50\":");
                out.num(s.p50());
                out.raw(",\"max\":");
                out.num(s.max_ms);
                out.raw("}");
            }
        }
        out.raw("]},\"active\":");
        bool has_active = known && state.active_link_id < links_.size();
        out.str(has_active ? links_[state.active_link_id].name.c_str() : "");
        out.raw(",\"switches\":%llu", static_cast<unsigned long long>(known ? state.switches : 0));
        const BondTotals& i = b.interval;
        out.raw(",\"interval\":{\"frames\":%llu,\"delivered\":%llu,\"duplicates\":%llu,"
                "\"stale\":%llu,\"delivered_lost\":%lld,\"delivered_loss_pct\":",
                static_cast<unsigned long long>(i.frames),
                static_cast<unsigned long long>(i.delivered),
                static_cast<unsigned long long>(i.duplicates),
                static_cast<unsigned long long>(i.stale), static_cast<long long>(i.lost));
        out.num(loss_fraction(i.received, i.lost) * 100);
        out.raw(",\"skew_ms_mean\":");
        out.num(i.skew_count ? i.skew_sum_ms / static_cast<double>(i.skew_count) : 0.0);
        out.raw("}}");
    }
    out.raw("]}");
}

/// Counters only grow, so loss is given as expected and received frames (lost = expected -
/// received): both only grow, even when a late frame fills a gap counted as lost, and
/// 1 - rate(received) / rate(expected) is the loss over any window Prometheus looks at.
void Stats::metrics(mavbond::MetricOut& out) {
    // One series per configured endpoint (labels never carry a peer's address), each figure
    // summed over its links, present and past.
    std::map<std::string, std::pair<Counted, const char*>> by_endpoint;  // -> (figures, bond)
    for (const auto& [endpoint, c] : retired_)
        by_endpoint[endpoint].first += c;
    for (LinkStats& l : links_) {
        if (!l.present)
            continue;
        refresh_counters(l);
        auto& e = by_endpoint[l.endpoint];
        e.first += l.counted();
        e.second = l.bond == kNone ? "" : bonds_[l.bond].name.c_str();
    }
    for (auto& [endpoint, e] : by_endpoint) {
        const Counted& c = e.first;
        if (!e.second) {  // only links gone: their bond, from any link of the endpoint seen
            e.second = "";
            for (const LinkStats& l : links_) {
                if (l.endpoint == endpoint && l.bond != kNone)
                    e.second = bonds_[l.bond].name.c_str();
            }
        }
        std::initializer_list<mavbond_label> labels = {{"link", endpoint.c_str()}, {"bond", e.second}};
        out.counter("link_frames", "Frames a link received (every copy, before any filter).",
                    c.frames, labels);
        out.counter("link_bytes", "Bytes of the frames a link received.", c.bytes, labels);
        out.counter("link_crc_errors", "Frames with a bad CRC on a link.", c.crc_errors, labels);
        // Loss as expected and received frames (lost = expected - received): both only grow,
        // even when a late frame fills a gap counted as lost, so 1 - rate(received) /
        // rate(expected) is the loss over any window. By basis: "markers", what the far side
        // wrote on the link (a far mavbond's count markers: exact); "sequence", the gaps in the
        // sources' sequence numbers (until the far side counts, or where it never does).
        auto loss = [&](const char* basis, int64_t expected, int64_t received) {
            std::initializer_list<mavbond_label> with_basis = {
                {"link", endpoint.c_str()}, {"bond", e.second}, {"basis", basis}};
            out.counter("link_expected_frames",
                        "Frames a link should have received: what the far side wrote on it "
                        "(basis markers), or what its sequence numbers say (basis sequence).",
                        static_cast<uint64_t>(std::max<int64_t>(expected, 0)), with_basis);
            out.counter("link_received_frames",
                        "Of a link's expected frames, those that arrived (expected minus lost).",
                        static_cast<uint64_t>(std::max<int64_t>(received, 0)), with_basis);
        };
        const bool has_sequence = c.seq_received + c.seq_lost > 0 || !c.markers;
        if (has_sequence)
            loss("sequence", c.seq_received + c.seq_lost, c.seq_received);
        if (c.markers)
            loss("markers", static_cast<int64_t>(c.acct_expected), static_cast<int64_t>(c.acct_received));
        const int64_t received = c.markers ? static_cast<int64_t>(c.acct_received) : c.seq_received;
        const int64_t lost = c.markers ? static_cast<int64_t>(c.acct_expected) - received : c.seq_lost;
        out.gauge("link_loss_ratio",
                  "A link's loss since the start (0..1), by the basis its label names.",
                  loss_fraction(received, lost),
                  {{"link", endpoint.c_str()}, {"bond", e.second}, {"basis", c.markers ? "markers" : "sequence"}});
    }
    for (BondStats& b : bonds_) {
        const BondTotals& t = b.total;
        std::initializer_list<mavbond_label> labels = {{"bond", b.name.c_str()}};
        out.counter("bond_frames", "Frames of a bond's links, every copy.", t.frames, labels);
        out.counter("bond_delivered_frames", "Frames of a bond that no filter dropped.",
                    t.delivered, labels);
        out.counter("bond_duplicates", "Copies of a bond's frames that dedup dropped.",
                    t.duplicates, labels);
        out.counter("bond_stale", "Stale samples of a bond that dedup dropped.", t.stale, labels);
        out.counter("bond_delivered_expected_frames",
                    "Frames the delivered stream should have had, from sequence numbers.",
                    static_cast<uint64_t>(std::max<int64_t>(t.received + t.lost, 0)), labels);
        out.counter("bond_delivered_received_frames",
                    "Distinct sequence numbers the delivered stream had.",
                    static_cast<uint64_t>(t.received), labels);
        out.gauge("bond_delivered_loss_ratio",
                  "Loss of a bond's delivered stream since the start (0..1).",
                  loss_fraction(t.received, t.lost), labels);
    }
}

}  // namespace

MAVBOND_FILTER_PLUGIN(Stats, "stats", "0.1.0",
                      "per link and bond: frames, loss from sequence gaps, delivered loss, duplicates, skew",
                      kOptions)
