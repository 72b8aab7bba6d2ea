#include "daemon/metrics.h"

#include <map>

#include "routing/router.h"
#include "routing/filter_chain.h"
#include "mavbond_build_config.h"

namespace mavbond {
namespace {

/// Help texts of the endpoint counters, in for_each_counter's names.
const std::map<std::string, const char*>& counter_help() {
    static const std::map<std::string, const char*> help = {
        {"rx_frames", "Frames received whole (CRC checked, or of an unknown id when forwarded)."},
        {"rx_bytes", "Bytes received."},
        {"crc_errors", "Frames received with a bad CRC (dropped)."},
        {"garbage_bytes", "Received bytes that were not part of any frame."},
        {"unknown_ids", "Frames received with a message id the daemon does not know."},
        {"bad_flags", "Frames received with unknown incompatibility flags (dropped)."},
        {"rx_filtered", "Received frames dropped by allow_in/block_in."},
        {"rx_overflows", "Datagrams the kernel dropped because the receive buffer was full."},
        {"tx_frames", "Frames sent."},
        {"tx_bytes", "Bytes sent."},
        {"tx_filtered", "Frames not sent because of allow_out/block_out."},
        {"tx_dropped", "Frames dropped on transmit: queue full, link down or a write error."},
        {"tx_errors", "Hard write errors (ICMP unreachable, EIO, ...)."},
        {"sig_unsigned", "Unsigned frames on a signing endpoint (dropped when signing is required)."},
        {"sig_bad", "Frames dropped because their signature does not verify."},
        {"sig_replay", "Signed frames dropped as replayed or too old."},
    };
    return help;
}

/// Help texts of the renumbering counters, in RenumberStage::counters' names.
const std::map<std::string, const char*>& renumber_help() {
    static const std::map<std::string, const char*> help = {
        {"renumbered", "Frames the bond delivered with a new sequence number."},
        {"gaps", "Sequence numbers skipped on output: frames lost on every link of the bond."},
        {"late_filled", "Frames delivered after a later one, given the number they had kept."},
        {"unplaced", "Frames delivered before dedup could place them in the stream (given the next number)."},
        {"untracked", "Frames of sources beyond the renumbering table (left as they were)."},
        {"signed_left_alone", "Signed frames passed with their own number (the signature covers it)."},
    };
    return help;
}

}  // namespace

MetricSet metrics_document(const std::vector<Endpoint::Ptr>& endpoints, const Router& router,
                           const FilterChain& chain, TimePoint started, TimePoint now) {
    MetricSet set;
    set.gauge("mavbond_build_info", "Always 1; the version in a label.", 1,
              {{"version", MAVBOND_VERSION}});
    set.gauge("mavbond_uptime_seconds", "Seconds since the daemon started.",
              std::chrono::duration<double>(now - started).count());
    // One family per counter, one sample per configured endpoint (a server's with every peer
    // or connection it has had).
    for (const auto& e : endpoints) {
        MetricLabels labels{{"endpoint", e->name()}, {"kind", e->kind()},
                            {"bond", e->config().bond}};
        LinkCounters stats = e->total_counters();
        for_each_counter(stats, [&](const char* name, uint64_t value) {
            auto help = counter_help().find(name);
            set.counter(std::string("mavbond_endpoint_") + name,
                        help == counter_help().end() ? name : help->second, value, labels);
        });
        // "Last heard" for alerts on a silent link; absent until the first frame.
        if (stats.last_rx != TimePoint{})
            set.gauge("mavbond_endpoint_last_rx_age_seconds",
                      "Seconds since a frame last came in on the endpoint.",
                      std::chrono::duration<double>(now - stats.last_rx).count(), labels);
    }
    set.counter("mavbond_router_frames_routed", "Frames the router handled (after ingress filters).",
                router.frames_routed());
    set.counter("mavbond_router_frames_without_destination",
                "Frames that had nowhere to go (no other endpoint, or an unknown target).",
                router.frames_without_destination());
    set.counter("mavbond_router_frames_held_back",
                "Frames of a bond's link held back past the round that read them for frames "
                "that arrived before them on another link (after a stall).",
                router.frames_held_back());
    const char* active_help = "1 for the active link of a bond (tx: active), 0 for its others.";
    set.declare("mavbond_bond_active_link", active_help, MetricSet::Type::Gauge);
    for (size_t b = 0; b < router.bonds().size(); b++) {
        const Bond& bond = router.bonds()[b];
        set.counter("mavbond_bond_switches", "Changes of a bond's active link.", bond.switches(),
                    {{"bond", bond.name()}});
        set.gauge("mavbond_bond_tx_active", "1 when the bond sends on its active link only.",
                  bond.tx_active() ? 1 : 0, {{"bond", bond.name()}});
        for (LinkId id = 0; id < router.link_id_bound(); id++) {
            const Link* link = router.link(id);
            if (link && router.bond_of(*link) == b)
                set.gauge("mavbond_bond_active_link", active_help,
                          id == bond.active_link() ? 1 : 0,
                          {{"bond", bond.name()}, {"link", link->name()}});
        }
        for (const auto& [name, value] : bond.renumber_counters())
            set.counter(std::string("mavbond_renumber_") + name, renumber_help().at(name), value,
                        {{"bond", bond.name()}});
    }
    chain.collect_metrics(set);
    return set;
}

}  // namespace mavbond
