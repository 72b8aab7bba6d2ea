#include "routing/filter_chain.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

#include "core/log.h"
#include "mavlink/message_table.h"

namespace mavbond {

struct FilterChain::Instance {
    const LoadedPlugin* plugin;
    const FilterConfig* entry;
    std::unique_ptr<PluginConfig> config;
    mavbond_host host;
    mavbond_config view{};
    void* self = nullptr;
    uint64_t dropped = 0;
    bool bad_metric_logged = false;
};

namespace {

std::string where(const SourceMark& m) {
    return m.file + ":" + std::to_string(m.line) + ":" + std::to_string(m.column);
}

uint64_t to_ns(TimePoint t) {
    return static_cast<uint64_t>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(t.time_since_epoch()).count());
}

}  // namespace

FilterChain::FilterChain(EventLoop& loop, Router& router) : loop_(loop), router_(router) {}

Result<std::unique_ptr<FilterChain>> FilterChain::create(const Config& config,
                                                         const std::string& plugin_dir,
                                                         EventLoop& loop, Router& router) {
    std::unique_ptr<FilterChain> chain(new FilterChain(loop, router));
    chain->entries_ = config.filters;  // never resized after this: instances point into it
    for (const auto& entry : chain->entries_) {
        if (!entry.enabled)
            continue;
        std::string at = where(entry.mark) + ": filter '" + entry.plugin + "': ";
        if (chain->instances_.size() >= 64)
            return make_error(at + "more than 64 filters");
        const LoadedPlugin* plugin = nullptr;
        for (const auto& p : chain->plugins_) {
            if (p->descriptor().name == entry.plugin)
                plugin = p.get();
        }
        if (!plugin) {
            auto loaded = LoadedPlugin::load(plugin_dir, entry.plugin);
            if (!loaded)
                return make_error(at + loaded.error().message);
            chain->plugins_.push_back(std::move(loaded.value()));
            plugin = chain->plugins_.back().get();
        }
        auto pc = PluginConfig::create(entry, plugin->descriptor().options, config);
        if (!pc)
            return pc.error();
        auto inst = std::make_unique<Instance>();
        inst->plugin = plugin;
        inst->entry = &entry;
        inst->config = std::move(pc.value());
        inst->view.config = inst->config.get();
        inst->host.services = chain.get();
        inst->host.index = static_cast<uint32_t>(chain->instances_.size());
        int same = 0;
        for (const auto& other : chain->instances_)
            same += other->entry->plugin == entry.plugin ? 1 : 0;
        inst->host.name = same ? entry.plugin + "#" + std::to_string(same + 1) : entry.plugin;
        char err[512] = "";
        const mavbond_plugin_descriptor& d = plugin->descriptor();
        if (d.create(host_api(), &inst->host, &inst->view, &inst->self, err, sizeof err) != 0) {
            // An option the plugin refused: the message starts where that option's value is
            // (file:line:column), not at the filter entry.
            if (inst->config->option_refused() && err[0])
                return make_error(std::string(err) + " (" + plugin->path() + ": create failed)");
            return make_error(at + plugin->path() + ": create failed: " + (err[0] ? err : "no reason given"));
        }
        if (d.on_egress)
            chain->egress_hooks_ |= uint64_t{1} << chain->instances_.size();
        chain->instances_.push_back(std::move(inst));
    }
    if (auto r = chain->check_bonds(config); !r)
        return r.error();
    // Only a chain that stands is told of: an error is the first line a failed start prints.
    for (const auto& inst : chain->instances_)
        log_info("[filter:%s] loaded from %s", inst->host.name.c_str(), inst->plugin->path().c_str());
    return chain;
}

bool FilterChain::provides(const std::string& bond, uint32_t what) const {
    return std::any_of(instances_.begin(), instances_.end(), [&](const auto& inst) {
        return (inst->host.provides & what) && inst->config->covers_bond(bond);
    });
}

Result<void> FilterChain::check_bonds(const Config& config) const {
    // What a bond's settings need some filter on the bond to do: declared by the instances
    // (provides), never read from a plugin's options.
    for (const BondConfig& bond : config.bonds) {
        // Renumbering gives out the bond's positions of each frame: some filter must place
        // every link's copies in one numbering.
        if (bond.renumber.value_or(false) && !provides(bond.name, MAVBOND_PROVIDES_ALIGNED_POSITIONS))
            return make_error(where(bond.renumber_mark) + ": bond '" + bond.name +
                              "': 'renumber' needs a dedup filter on this bond, enabled and "
                              "scoped to it by 'bonds:' or unscoped");
        // An error, not a warning: with no one choosing the active link the bond sends on
        // every link, so a metered link meant to stay quiet is paid for in full, silently.
        if (bond.tx == BondConfig::Tx::Active && !provides(bond.name, MAVBOND_PROVIDES_ACTIVE_LINK))
            return make_error(where(bond.tx_mark) + ": bond '" + bond.name +
                              "': 'tx: active' needs a linkswitch filter on this bond, enabled "
                              "and scoped to it by 'bonds:' or unscoped, to choose the active "
                              "link (without one the bond would send on every link: that is "
                              "'tx: broadcast')");
    }
    return {};
}

std::vector<std::string> FilterChain::plugin_paths() const {
    std::vector<std::string> paths;
    for (const auto& p : plugins_)
        paths.push_back(p->path());
    return paths;
}

FilterChain::~FilterChain() {
    alive_.reset();
    for (auto& inst : instances_) {
        if (inst->self)
            inst->plugin->descriptor().destroy(inst->self);
    }
    timers_.clear();  // no callback into a plugin after this
    instances_.clear();
}

void FilterChain::on_link(const Link& link, bool added) {
    uint32_t id = link.id();
    while (id >= links_.size())
        links_.push_back(std::make_unique<LinkView>());
    LinkView& v = view(id);
    if (added) {
        v.source = &link;
        v.leaving = false;
        v.name = link.name();
        v.endpoint = link.endpoint_name();
        v.link = mavbond_link{};
        v.link.struct_size = sizeof(mavbond_link);
        v.link.id = id;
        v.link.name = v.name.c_str();
        v.link.endpoint = v.endpoint.c_str();
        uint32_t bond = router_.bond_of(link);
        v.link.bond_id = bond == Router::kNoBond ? MAVBOND_NO_BOND : bond;
        v.link.bond_name = bond == Router::kNoBond ? nullptr : router_.bonds()[bond].name().c_str();
        // Priority: the place among the bond's members in the config (peers share theirs).
        v.link.priority = bond == Router::kNoBond ? 0 : router_.member_of(link);
        v.scope_mask = 0;
        for (size_t i = 0; i < instances_.size(); i++) {
            if (instances_[i]->config->in_scope(link.bond(), link.endpoint_name()))
                v.scope_mask |= uint64_t{1} << i;
        }
    } else {
        v.leaving = true;  // no longer among links() while the instances hear it go, but its
                           // counters are there for their last look
    }
    for (size_t i = 0; i < instances_.size(); i++) {
        const auto& d = instances_[i]->plugin->descriptor();
        if (d.on_link && (v.scope_mask >> i & 1))
            d.on_link(instances_[i]->self, &v.link, added ? MAVBOND_LINK_ADDED : MAVBOND_LINK_REMOVED);
    }
    if (!added)
        v.source = nullptr;
}

void FilterChain::fill_c_frame(mavbond_frame& f, const Frame& frame, TimePoint rx_time) {
    // Every field written once, in place (a frame's view is made per frame).
    const MessageInfo* info = frame.info;
    f.struct_size = sizeof f;
    f.version = frame.version;
    f.incompat_flags = frame.incompat_flags;
    f.seq = frame.seq;
    f.sysid = frame.sysid;
    f.compid = frame.compid;
    f.crc_checked = frame.crc_checked;
    f.target_system = frame.target_system;
    f.target_component = frame.target_component;
    f.msgid = frame.msgid;
    f.raw = frame.bytes.data();
    f.raw_len = static_cast<uint32_t>(frame.bytes.size());
    f.payload = frame.payload.data();
    f.payload_len = static_cast<uint32_t>(frame.payload.size());
    f.timestamp_offset = info ? info->timestamp_ofs : -1;
    f.timestamp_size = info ? info->timestamp_size : 0;
    f.timestamp_us = info ? info->timestamp_us : 0;
    f.rx_time_ns = to_ns(rx_time);
    f.stream_pos = 0;
    f.stream_lost = 0;
    f.stream_flags = 0;
}

void FilterChain::on_ingress(ReceivedFrame* const* frames, size_t count, Ingress* out) {
    for (size_t done = 0; done < count; done += kChunk)
        filter_chunk(frames + done, std::min(kChunk, count - done), out + done);
}

void FilterChain::filter_chunk(ReceivedFrame* const* frames, size_t count, Ingress* out) {
    // The chunk as plugins see it: the frames in any filter's scope, each with its stream
    // position (the router's) and its notes.
    size_t shown = 0;
    uint64_t any_scope = 0, all_scope = ~uint64_t{0};
    for (size_t k = 0; k < count; k++) {
        const ReceivedFrame& r = *frames[k];
        LinkView& v = view(r.from->id());
        if (v.scope_mask == 0 || !r.routed)
            continue;
        any_scope |= v.scope_mask;
        all_scope &= v.scope_mask;
        mavbond_frame& f = c_frames_[shown];
        fill_c_frame(f, r.frame, r.arrival);
        const StreamStep& step = r.step;
        f.stream_pos = step.pos;
        f.stream_lost = step.lost;
        f.stream_flags = step.flags;
        mavbond_frame_notes& notes = notes_[shown];
        notes = mavbond_frame_notes{};
        notes.struct_size = sizeof notes;
        received_[shown] = mavbond_received{&f, &notes, &v.link, MAVBOND_PASS};
        shown_from_[shown] = static_cast<uint32_t>(k);
        shown++;
    }
    for (size_t i = 0; i < instances_.size() && shown > 0; i++) {
        const uint64_t bit = uint64_t{1} << i;
        Instance& inst = *instances_[i];
        auto hook = inst.plugin->descriptor().on_ingress;
        if (!hook || !(any_scope & bit))
            continue;
        // Usually every frame is in scope (a round of one bond's links) and the chunk goes as
        // it is; otherwise the frames in scope, in order (their notes are shared).
        mavbond_received* batch = received_.data();
        size_t n = shown;
        if (!(all_scope & bit)) {
            batch = subset_.data();
            n = 0;
            for (size_t j = 0; j < shown; j++) {
                if (view(received_[j].from->id).scope_mask & bit)
                    subset_[n++] = received_[j];
            }
        }
        for (size_t j = 0; j < n; j++)
            batch[j].verdict = MAVBOND_PASS;
        hook(inst.self, batch, n);
        // After one filter drops a frame, the rest still see it, flagged; only the first drop
        // counts (see the header).
        for (size_t j = 0; j < n; j++) {
            uint32_t& flags = batch[j].notes->flags;
            if (batch[j].verdict == MAVBOND_DROP && !(flags & MAVBOND_NOTE_DROPPED)) {
                inst.dropped++;
                flags |= MAVBOND_NOTE_DROPPED;
            }
        }
    }
    for (size_t j = 0; j < shown; j++) {
        const mavbond_frame_notes& notes = notes_[j];
        Ingress& o = out[shown_from_[j]];
        o.pass = !(notes.flags & MAVBOND_NOTE_DROPPED);
        if (notes.flags & MAVBOND_NOTE_POSITION)
            o.bond_pos = notes.bond_pos;
    }
}

bool FilterChain::on_egress(const Frame& frame, const Link& to) {
    const LinkView& v = view(to.id());
    if ((v.scope_mask & egress_hooks_) == 0)
        return true;
    mavbond_frame f;
    bool built = false;
    for (size_t i = 0; i < instances_.size(); i++) {
        Instance& inst = *instances_[i];
        auto hook = inst.plugin->descriptor().on_egress;
        if (!hook || !(v.scope_mask >> i & 1))
            continue;
        if (!built) {
            fill_c_frame(f, frame, loop_.now());
            built = true;
        }
        if (hook(inst.self, &f, &v.link) == MAVBOND_DROP) {
            inst.dropped++;
            return false;
        }
    }
    return true;
}

namespace {

/// Takes one instance's samples through the metrics hook: checks the ABI's rules, names and
/// labels each as /metrics shows it, and keeps those `families` (the whole chain's so far)
/// accepts.
struct MetricSink {
    std::vector<MetricSample>& out;
    MetricSet& families;
    const std::string& plugin;
    const std::string& instance;
    bool& bad_logged;

    static void take(void* ctx, const mavbond_metric_sample* s) noexcept {
        auto& self = *static_cast<MetricSink*>(ctx);
        try {
            std::string why = self.add(s);
            if (!why.empty() && !self.bad_logged) {
                self.bad_logged = true;
                log_warning("[filter:%s] metric skipped: %s (further ones are not logged)",
                            self.instance.c_str(), why.c_str());
            }
        } catch (...) {
            // Out of memory in a scrape: that sample is missing, the daemon goes on.
        }
    }

    /// Adds one sample; the reason when it breaks a rule.
    std::string add(const mavbond_metric_sample* s) {
        if (!s || s->struct_size < sizeof(mavbond_metric_sample) || !s->name || !s->help)
            return "a sample without name or help, or of an older struct size";
        MetricSample m;
        m.name = "mavbond_" + plugin + "_" + s->name;
        m.help = s->help;
        for (const char* c = s->name; *c; c++) {
            if (!(isalnum(static_cast<unsigned char>(*c)) || *c == '_'))
                return m.name + ": the name may hold only a-z A-Z 0-9 _";
        }
        if (s->label_count > MAVBOND_METRIC_MAX_LABELS || (s->label_count && !s->labels))
            return m.name + ": more than " + std::to_string(MAVBOND_METRIC_MAX_LABELS) + " labels";
        m.labels = {{"filter", instance}};
        for (uint32_t i = 0; i < s->label_count; i++) {
            const mavbond_label& l = s->labels[i];
            if (!l.name || !l.value)
                return m.name + ": a label without name or value";
            if (std::strcmp(l.name, "filter") == 0)
                return m.name + ": the label 'filter' is the host's";
            m.labels.emplace_back(l.name, l.value);
        }
        if (s->type == MAVBOND_METRIC_COUNTER) {
            m.type = MetricSet::Type::Counter;
            m.count = s->count;
        } else if (s->type == MAVBOND_METRIC_GAUGE) {
            m.type = MetricSet::Type::Gauge;
            m.value = s->value;
        } else {
            return m.name + ": unknown type " + std::to_string(static_cast<int>(s->type));
        }
        if (Result<void> r = families.add(m); !r)
            return r.error().message;
        out.push_back(std::move(m));
        return "";
    }
};

std::string status_of(const mavbond_plugin_descriptor& d, void* self) {
    if (!d.status_json)
        return "";
    std::string buf(16384, '\0');
    size_t need = d.status_json(self, buf.data(), buf.size());
    if (need >= buf.size()) {
        buf.assign(need + 1, '\0');
        need = d.status_json(self, buf.data(), buf.size());
    }
    buf.resize(need < buf.size() ? need : 0);
    return buf;
}

}  // namespace

std::vector<FilterReport> FilterChain::report() const {
    std::vector<FilterReport> reports;
    MetricSet families;  // what the chain's samples must agree on, as one /metrics document
    for (const auto& inst : instances_) {
        const mavbond_plugin_descriptor& d = inst->plugin->descriptor();
        FilterReport& r = reports.emplace_back();
        r.name = inst->host.name;
        r.plugin = inst->entry->plugin;
        r.dropped = inst->dropped;
        r.status_json = status_of(d, inst->self);
        MetricSample dropped{MetricSet::Type::Counter, kFilterDroppedMetric, kFilterDroppedHelp,
                             {{"filter", r.name}, {"plugin", r.plugin}}, inst->dropped, 0};
        families.add(dropped);
        r.samples.push_back(std::move(dropped));
        if (d.metrics) {
            MetricSink sink{r.samples, families, r.plugin, r.name, inst->bad_metric_logged};
            d.metrics(inst->self, MetricSink::take, &sink);
        }
    }
    return reports;
}

std::vector<std::string> FilterChain::describe(uint32_t bond) const {
    std::vector<std::string> lines;
    if (bond >= router_.bonds().size())
        return lines;
    const std::string& name = router_.bonds()[bond].name();
    for (const auto& inst : instances_) {
        auto hook = inst->plugin->descriptor().describe;
        if (!hook || !inst->config->covers_bond(name))
            continue;
        char buf[512];
        size_t n = hook(inst->self, bond, buf, sizeof buf);
        if (n > 0)
            lines.push_back(inst->host.name + ": " + std::string(buf, std::min(n, sizeof buf - 1)));
    }
    return lines;
}

// --- HostServices --------------------------------------------------------------------------

uint64_t FilterChain::now_ns() { return to_ns(router_.arrival_clock(loop_.now())); }

uint64_t FilterChain::timer_add(uint64_t period_ns, std::function<bool()> fn) {
    uint64_t id = next_timer_++;
    Duration period{static_cast<Duration::rep>(period_ns)};
    timers_[id] = loop_.schedule(period, [this, id, period, fn = std::move(fn)] {
        if (fn())
            return period;
        defer_erase(id);
        return Duration::zero();
    });
    return id;
}

// Erased after this dispatch round: a timer may end from inside its own callback. The chain
// may be gone by then (a reload replaced it), hence the weak token.
void FilterChain::defer_erase(uint64_t id) {
    loop_.defer([this, id, alive = std::weak_ptr<void>(alive_)] {
        if (!alive.expired())
            timers_.erase(id);
    });
}

void FilterChain::timer_cancel(uint64_t id) {
    auto it = timers_.find(id);
    if (it != timers_.end())
        it->second.cancel();
    defer_erase(id);
}

size_t FilterChain::links(const mavbond_host& h, const mavbond_link** out, size_t max) {
    const uint64_t bit = uint64_t{1} << h.index;
    size_t n = 0;
    for (const auto& v : links_) {
        if (!v->source || v->leaving || !(v->scope_mask & bit))
            continue;
        if (n < max)
            out[n] = &v->link;
        n++;
    }
    return n;
}

int FilterChain::bond_by_name(const std::string& name, uint32_t* out) {
    uint32_t b = router_.bond_index(name);
    if (b == Router::kNoBond)
        return -ENOENT;
    *out = b;
    return 0;
}

int FilterChain::set_active_link(uint32_t bond_id, uint32_t link_id) {
    return router_.set_active_link(bond_id, link_id) ? 0 : -EINVAL;
}

int FilterChain::link_counters(uint32_t link_id, mavbond_link_counters* out) {
    if (link_id >= links_.size() || !view(link_id).source)
        return -ENOENT;
    const Link& link = *view(link_id).source;
    const LinkCounters& s = link.counters();
    const LinkAccount& a = link.account();
    *out = mavbond_link_counters{sizeof(mavbond_link_counters), s.rx.frames, s.rx.bytes,
                                 s.rx.crc_errors, s.rx.garbage_bytes, s.rx.unknown_ids,
                                 s.tx_frames, s.tx_bytes, s.tx_dropped,
                                 (a.exact() ? MAVBOND_ACCOUNT_EXACT : 0u) |
                                     (a.peer_standby() ? MAVBOND_ACCOUNT_PEER_STANDBY : 0u) |
                                     (a.moved() ? MAVBOND_ACCOUNT_MOVED : 0u),
                                 a.exact() ? a.expected_now() : 0,
                                 a.exact() ? a.received_now() : 0};
    return 0;
}

int FilterChain::bond_state(uint32_t bond_id, mavbond_bond_state* out) {
    if (bond_id >= router_.bonds().size())
        return -ENOENT;
    const Bond& b = router_.bonds()[bond_id];
    *out = mavbond_bond_state{sizeof(mavbond_bond_state), b.active_link(), b.switches(),
                              static_cast<uint8_t>(b.tx_active()), 0, 0};
    if (const Standby* standby = b.standby()) {
        bool announced = false;
        out->peer_resend_ns = static_cast<uint64_t>(
            std::chrono::duration_cast<std::chrono::nanoseconds>(standby->peer_resend(&announced)).count());
        out->peer_resend_announced = announced;
    }
    return 0;
}

}  // namespace mavbond
