// The host side of the plugin ABI: a filter instance's view of the daemon (mavbond_host), its
// validated options (mavbond_config) and the function table handed to plugins. What the host
// provides (clock, timers, links, bonds) comes from HostServices: the daemon's is backed by
// the event loop and the router, the unit tests' by a manual clock.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "config/config.h"
#include "core/result.h"
#include "mavbond/plugin.h"

namespace mavbond {

class HostServices {
public:
    virtual ~HostServices() = default;
    virtual void log(mavbond_log_level level, const std::string& instance, const char* message);
    virtual uint64_t now_ns() = 0;
    /// Calls fn every period until it returns false or the timer is cancelled.
    virtual uint64_t timer_add(uint64_t period_ns, std::function<bool()> fn) = 0;
    virtual void timer_cancel(uint64_t id) = 0;
    /// The links in the scope of instance `h`, in id order: fills up to max, returns how many.
    virtual size_t links(const mavbond_host& h, const mavbond_link** out, size_t max) = 0;
    virtual int bond_by_name(const std::string& name, uint32_t* out) = 0;
    virtual int set_active_link(uint32_t bond_id, uint32_t link_id) = 0;
    virtual int link_counters(uint32_t link_id, mavbond_link_counters* out) = 0;
    virtual int bond_state(uint32_t bond_id, mavbond_bond_state* out) = 0;
};

/// One option value after validation against the plugin's declared type.
struct PluginOptionValue {
    mavbond_option_type type;
    bool b = false;
    int64_t i = 0;
    uint64_t ns = 0;
    double fraction = 0;
    std::string text;
    std::vector<std::string> items;
    std::vector<const char*> item_ptrs;  // C view of items
    SourceMark mark;
    std::vector<SourceMark> item_marks;
};

/// A filter entry's options, checked against the plugin's option table: unknown keys and
/// values of the wrong type are errors naming file:line:column; defaults are filled in.
class PluginConfig {
public:
    /// `config` gives the bonds' members (cfg_bond_members); it may go away after create.
    static Result<std::unique_ptr<PluginConfig>> create(const FilterConfig& entry,
                                                        const mavbond_option* declared,
                                                        const Config& config);
    const PluginOptionValue* find(const char* key) const;
    const FilterConfig& entry() const { return entry_; }
    /// "file:line:column: filter 'NAME': option 'KEY': message" (the entry's mark if absent).
    std::string error_at(const char* key, const std::string& message) const;
    /// The same at item `index` of a list option (the option's place when there is no such item).
    std::string item_error_at(const char* key, size_t index, const std::string& message) const;
    /// The endpoints of a bond, in config order; nullptr when the config has no such bond.
    const std::vector<const char*>* bond_members(const char* bond) const;
    /// Every bond the config declares, in config order.
    const std::vector<const char*>& bond_names() const { return bond_names_; }
    /// Whether the plugin refused an option through cfg_error (its message names the place).
    bool option_refused() const { return option_refused_; }
    /// Whether a link of bond `bond` ("" none), of configured endpoint `endpoint`, is in the
    /// entry's scope: none given, its bond in `bonds:` or its endpoint in `endpoints:`.
    bool in_scope(const std::string& bond, const std::string& endpoint) const;
    /// Whether bond `bond` is in scope as a whole: none given, or it is in `bonds:`.
    bool covers_bond(const std::string& bond) const;

private:
    explicit PluginConfig(const FilterConfig& entry) : entry_(entry) {}
    const FilterConfig& entry_;
    std::map<std::string, PluginOptionValue, std::less<>> values_;
    std::vector<const char*> bond_ptrs_, endpoint_ptrs_;
    std::map<std::string, std::vector<std::string>, std::less<>> members_;  // bond -> endpoints
    std::map<std::string, std::vector<const char*>, std::less<>> member_ptrs_;
    std::vector<const char*> bond_names_;  // into members_' keys
    mutable bool option_refused_ = false;  // set through the const view plugins get
    friend struct HostApiImpl;
};

}  // namespace mavbond

/// What a plugin's mavbond_host pointer points at: one per filter instance.
struct mavbond_host {
    mavbond::HostServices* services;
    std::string name;          // "dedup", "dedup#2", ... for log prefixes
    uint32_t index = 0;        // its place in the chain
    uint32_t provides = 0;     // MAVBOND_PROVIDES_*, as declared in create
};
/// What a plugin's mavbond_config pointer points at.
struct mavbond_config {
    const mavbond::PluginConfig* config;
};

namespace mavbond {
/// The function table handed to every plugin.
const mavbond_host_api* host_api();
}  // namespace mavbond
