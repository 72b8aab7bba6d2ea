// A host for plugin unit tests: the daemon's real option validation and API table, with a
// manual monotonic clock, links declared by the test, and captured log lines.
#pragma once

#include <gtest/gtest.h>

#include <map>
#include <memory>
#include <string>
#include <vector>

#include "config/config.h"
#include "routing/plugin_host.h"
#include "routing/stream_positions.h"

namespace mavbond {

/// A minimal MAVLink v2 frame: the header, a 9-byte zero payload (HEARTBEAT's size) and a
/// dummy CRC, 21 bytes. Plugins read the fields from mavbond_frame: the bytes only must exist.
std::vector<uint8_t> test_frame(uint8_t seq, uint8_t sysid, uint8_t compid, uint32_t msgid = 0);

class FakeHost : public HostServices {
public:
    FakeHost();
    ~FakeHost() override;

    /// Declares a link (an endpoint), optionally a member of `bond`. Call before create().
    const mavbond_link& add_link(const std::string& name, const std::string& bond = "");
    /// Declares an endpoint of the config with no link yet (a UDP server whose peers, the
    /// links, come later as "NAME@address"). Call before create().
    void declare_endpoint(const std::string& name, const std::string& bond);
    /// Builds an instance of `plugin` with `options` (YAML lines of the filter entry, e.g.
    /// "window: 500ms\nkey: content"). Returns the instance; on failure returns nullptr
    /// and stores the message in last_error().
    void* create(const mavbond_plugin_descriptor* plugin, const std::string& options = "");
    const std::string& last_error() const { return last_error_; }

    /// Moves the clock forward by `d`, firing due timers in order.
    void advance(Duration d);
    const mavbond_link& link(const std::string& name) const;
    /// The name of the link with id `id` ("?" when there is none).
    std::string link_name(uint32_t id) const {
        return id < links_.size() ? links_[id]->name : "?";
    }

    /// Hands one frame to the plugin as the daemon does: a frame of a link out of the
    /// instance's scope is not shown to it at all (PASS); otherwise it goes as an ingress
    /// batch of one. `notes` carries the earlier filters' notes in and the plugin's out.
    mavbond_verdict ingress(const mavbond_frame& f, mavbond_frame_notes& notes,
                            const mavbond_link& from);
    /// Whether `link` is in the created instance's scope.
    bool in_scope(const mavbond_link& link) const;

    /// A frame view over `raw` (which must outlive the call it is used in).
    mavbond_frame frame(const std::vector<uint8_t>& raw) const;
    /// What the daemon hands a filter for `raw` (a v1 or v2 frame) arriving on `from` at
    /// `t_ns` (0: now): the header read, the message's timestamp and target fields from the
    /// message table, and the link's stream position tracked as the host tracks it.
    mavbond_frame frame(const std::vector<uint8_t>& raw, const mavbond_link& from,
                        uint64_t t_ns = 0);

    // HostServices
    uint64_t now_ns() override { return now_ns_; }
    uint64_t timer_add(uint64_t period_ns, std::function<bool()> fn) override;
    void timer_cancel(uint64_t id) override;
    size_t links(const mavbond_host& h, const mavbond_link** out, size_t max) override;
    int bond_by_name(const std::string& name, uint32_t* out) override;
    int set_active_link(uint32_t bond_id, uint32_t link_id) override;
    int link_counters(uint32_t link_id, mavbond_link_counters* out) override;
    int bond_state(uint32_t bond_id, mavbond_bond_state* out) override;
    void log(mavbond_log_level level, const std::string& instance, const char* message) override;

    std::vector<std::string> logs;
    std::map<uint32_t, uint32_t> active_link;  // bond id -> link id
    std::map<uint32_t, uint64_t> switches;     // bond id -> changes of the active link
    std::map<uint32_t, uint64_t> peer_resend;  // bond id -> the far side's resend (ns)
    std::map<uint32_t, mavbond_link_counters> counters;  // link id -> what link_counters says

private:
    struct Timer {
        uint64_t due;
        uint64_t period;
        std::function<bool()> fn;
    };
    struct LinkSlot {
        std::string name, bond, endpoint;  // endpoint: the name before '@' (a learned peer's server)
        mavbond_link link{};
    };
    uint64_t now_ns_ = 1'000'000'000;
    uint64_t next_timer_ = 1;
    std::map<uint64_t, Timer> timers_;
    std::vector<std::unique_ptr<LinkSlot>> links_;
    std::map<uint32_t, StreamPositions> positions_;  // by link id
    std::vector<std::string> bonds_;
    std::vector<std::pair<std::string, std::string>> declared_;  // config-only endpoints
    const mavbond_plugin_descriptor* plugin_ = nullptr;
    void* self_ = nullptr;
    std::unique_ptr<Config> config_;
    std::unique_ptr<PluginConfig> plugin_config_;
    mavbond_host host_{};
    mavbond_config config_view_{};
    std::string last_error_;
};

}  // namespace mavbond
