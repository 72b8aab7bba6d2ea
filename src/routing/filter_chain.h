// The chain of filter plugins the config names, in config order, on the router's data path.
// Ingress: every filter in scope sees the frame; after one drops it, the rest still observe it
// (flagged MAVBOND_NOTE_DROPPED, verdicts ignored), so stats count what dedup dropped and dedup
// never learns from a frame another filter dropped. Egress: the first drop stops the frame.
#pragma once

#include <array>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/event_loop.h"
#include "core/metric_set.h"
#include "routing/plugin_host.h"
#include "routing/plugin_loader.h"
#include "routing/router.h"
#include "routing/stream_positions.h"

namespace mavbond {

/// The family each filter's drop count is a sample of (FilterReport::samples).
inline constexpr const char* kFilterDroppedMetric = "mavbond_filter_dropped";
inline constexpr const char* kFilterDroppedHelp = "Frames a filter dropped (its own verdicts).";

/// A filter as the status shows it at one moment: the status socket, /metrics, the logs.
struct FilterReport {
    std::string name;         // "dedup", or "dedup#2" for a second instance
    std::string plugin;
    uint64_t dropped = 0;     // frames its own verdicts dropped
    std::string status_json;  // its plugin's status object; "" without the hook
    /// Its drop count and its plugin's metrics hook's samples, named mavbond_PLUGIN_NAME and
    /// labelled filter="INSTANCE". A sample that breaks a rule of the ABI, or one the chain's
    /// families cannot take, is left out (logged once per filter).
    std::vector<MetricSample> samples;
};

class FilterChain : public FrameFilter, private HostServices {
public:
    /// Loads every enabled `filters:` entry's plugin from plugin_dir and creates its instance.
    /// Errors name the config entry (file:line:column) and the plugin file.
    static Result<std::unique_ptr<FilterChain>> create(const Config& config,
                                                       const std::string& plugin_dir,
                                                       EventLoop& loop, Router& router);
    ~FilterChain() override;
    /// The files the chain's plugins were loaded from, in load order.
    std::vector<std::string> plugin_paths() const;

    void on_ingress(ReceivedFrame* const* frames, size_t count, Ingress* out) override;
    bool on_egress(const Frame& frame, const Link& to) override;
    void on_link(const Link& link, bool added) override;

    size_t size() const { return instances_.size(); }
    /// Whether bond `bond` renumbers what it delivers: as its `renumber` says, and when it says
    /// nothing, wherever a filter gives the positions (dedup): a copy a slower link rescued
    /// comes after frames sent after it, and a GCS counts each step back as ~255 lost.
    bool renumbers(const BondConfig& bond) const {
        return bond.renumber.value_or(provides(bond.name, MAVBOND_PROVIDES_ALIGNED_POSITIONS));
    }
    /// What each filter shows of itself now, in chain order (see FilterReport).
    std::vector<FilterReport> report() const;
    /// What the filters acting on bond `bond` (an index of the router's) say they derived
    /// for it (their describe hook), each as "NAME: text", in chain order.
    std::vector<std::string> describe(uint32_t bond) const;

private:
    struct Instance;
    struct LinkView {
        mavbond_link link{};
        std::string name;
        std::string endpoint;
        const Link* source = nullptr;  // nullptr: no link has this id now
        bool leaving = false;          // the instances hear it go: not among links() any more
        uint64_t scope_mask = 0;  // bit i: instance i applies to this link
    };
    FilterChain(EventLoop& loop, Router& router);
    static void fill_c_frame(mavbond_frame& f, const Frame& frame, TimePoint rx_time);
    /// What a bond asks of its filters is provided: aligned positions for `renumber`, a
    /// chosen active link for `tx: active`.
    Result<void> check_bonds(const Config& config) const;
    /// Whether an enabled instance on `bond` declares `what` (MAVBOND_PROVIDES_*): aligned
    /// positions of the frames it delivers, a chosen active link.
    bool provides(const std::string& bond, uint32_t what) const;

    // HostServices (what the plugins' host API calls land on)
    uint64_t now_ns() override;
    uint64_t timer_add(uint64_t period_ns, std::function<bool()> fn) override;
    void timer_cancel(uint64_t id) override;
    size_t links(const mavbond_host& h, const mavbond_link** out, size_t max) override;
    int bond_by_name(const std::string& name, uint32_t* out) override;
    int set_active_link(uint32_t bond_id, uint32_t link_id) override;
    int link_counters(uint32_t link_id, mavbond_link_counters* out) override;
    int bond_state(uint32_t bond_id, mavbond_bond_state* out) override;

    EventLoop& loop_;
    Router& router_;
    std::vector<FilterConfig> entries_;  // the chain's own copy: a reload may replace the Config
    std::vector<std::unique_ptr<LoadedPlugin>> plugins_;  // destroyed after the instances
    std::vector<std::unique_ptr<Instance>> instances_;
    uint64_t egress_hooks_ = 0;  // bit i: instance i has an egress hook
    // Index = link id. Each view stays where it is (plugins hold its mavbond_link) while the
    // table grows.
    std::vector<std::unique_ptr<LinkView>> links_;
    LinkView& view(LinkId id) { return *links_[id]; }
    std::map<uint64_t, EventLoop::Timer> timers_;
    uint64_t next_timer_ = 1;
    std::shared_ptr<void> alive_ = std::make_shared<int>(0);  // expires with the chain
    void defer_erase(uint64_t timer_id);
    /// Filters up to kChunk frames of a batch.
    void filter_chunk(ReceivedFrame* const* frames, size_t count, Ingress* out);
    // One chunk of an ingress batch as the instances get it.
    static constexpr size_t kChunk = 64;
    std::array<mavbond_frame, kChunk> c_frames_;
    std::array<mavbond_frame_notes, kChunk> notes_;
    std::array<mavbond_received, kChunk> received_;
    std::array<uint32_t, kChunk> shown_from_;      // received_[j] is frame shown_from_[j]
    std::array<mavbond_received, kChunk> subset_;  // the frames in one instance's scope
};

}  // namespace mavbond
