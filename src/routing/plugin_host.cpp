#include "routing/plugin_host.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>

#include "core/log.h"

namespace mavbond {
namespace {

std::string where(const SourceMark& m) {
    return m.file + ":" + std::to_string(m.line) + ":" + std::to_string(m.column);
}

const char* type_name(mavbond_option_type t) {
    switch (t) {
    case MAVBOND_OPT_BOOL: return "true or false";
    case MAVBOND_OPT_INT: return "an integer";
    case MAVBOND_OPT_DURATION: return "a duration with a unit (250ms, 2s)";
    case MAVBOND_OPT_PERCENT: return "a percentage (5%)";
    case MAVBOND_OPT_STRING: return "a string";
    case MAVBOND_OPT_STRINGS: return "a list of strings";
    }
    return "?";
}

/// Converts YAML text to a typed value; false when it does not fit the type.
bool convert(mavbond_option_type type, const std::string& text, const std::vector<std::string>& items,
             bool is_sequence, PluginOptionValue& out) {
    out.type = type;
    if (type == MAVBOND_OPT_STRINGS) {
        if (!is_sequence)
            return false;
        out.items = items;
        return true;
    }
    if (is_sequence)
        return false;
    out.text = text;
    switch (type) {
    case MAVBOND_OPT_BOOL:
        if (text == "true" || text == "false") {
            out.b = text == "true";
            return true;
        }
        return false;
    case MAVBOND_OPT_INT: {
        char* end = nullptr;
        errno = 0;
        long long v = strtoll(text.c_str(), &end, 10);
        if (text.empty() || *end != '\0' || errno != 0)
            return false;
        out.i = v;
        return true;
    }
    case MAVBOND_OPT_DURATION: {
        auto d = parse_duration(text);
        if (!d || d->count() < 0)
            return false;
        out.ns = static_cast<uint64_t>(d->count());
        return true;
    }
    case MAVBOND_OPT_PERCENT: {
        if (text.size() < 2 || text.back() != '%')
            return false;
        char* end = nullptr;
        double v = strtod(text.c_str(), &end);
        if (end != text.c_str() + text.size() - 1 || !std::isfinite(v) || v < 0 || v > 100)
            return false;
        out.fraction = v / 100.0;
        return true;
    }
    case MAVBOND_OPT_STRING:
        return true;
    case MAVBOND_OPT_STRINGS:
        break;
    }
    return false;
}

}  // namespace

Result<std::unique_ptr<PluginConfig>> PluginConfig::create(const FilterConfig& entry,
                                                           const mavbond_option* declared,
                                                           const Config& config) {
    std::unique_ptr<PluginConfig> cfg(new PluginConfig(entry));
    auto find_declared = [declared](const std::string& key) -> const mavbond_option* {
        for (const mavbond_option* o = declared; o && o->key; o++) {
            if (key == o->key)
                return o;
        }
        return nullptr;
    };
    for (const auto& opt : entry.options) {
        const mavbond_option* d = find_declared(opt.key);
        if (!d) {
            std::string known;
            for (const mavbond_option* o = declared; o && o->key; o++)
                known += std::string(known.empty() ? "" : ", ") + o->key;
            return make_error(where(opt.mark) + ": filter '" + entry.plugin + "': unknown option '" +
                              opt.key + "' (it takes: " + (known.empty() ? "none" : known) + ")");
        }
        PluginOptionValue v;
        v.mark = opt.value_mark;
        v.item_marks = opt.item_marks;
        if (!convert(d->type, opt.value, opt.items, opt.is_sequence, v))
            return make_error(where(opt.value_mark) + ": filter '" + entry.plugin + "': option '" +
                              opt.key + "' must be " + type_name(d->type) + ", not '" + opt.value + "'");
        cfg->values_[opt.key] = std::move(v);
    }
    for (const mavbond_option* o = declared; o && o->key; o++) {
        if (!o->default_value || cfg->values_.count(o->key))
            continue;
        PluginOptionValue v;
        v.mark = entry.mark;
        bool seq = o->type == MAVBOND_OPT_STRINGS;
        if (!convert(o->type, o->default_value, {}, seq, v))
            return make_error(std::string("plugin '") + entry.plugin + "': bad default for option '" +
                              o->key + "'");
        cfg->values_[o->key] = std::move(v);
    }
    for (auto& [key, v] : cfg->values_) {
        for (const auto& item : v.items)
            v.item_ptrs.push_back(item.c_str());
    }
    for (const auto& b : entry.bonds)
        cfg->bond_ptrs_.push_back(b.c_str());
    for (const auto& e : entry.endpoints)
        cfg->endpoint_ptrs_.push_back(e.c_str());
    for (const auto& b : config.bonds)
        cfg->members_[b.name];
    for (const auto& ep : config.endpoints) {
        if (auto it = cfg->members_.find(ep.bond); it != cfg->members_.end())
            it->second.push_back(ep.name);
    }
    for (const auto& [bond, names] : cfg->members_) {
        auto& ptrs = cfg->member_ptrs_[bond];
        for (const auto& n : names)
            ptrs.push_back(n.c_str());
    }
    for (const auto& b : config.bonds)
        cfg->bond_names_.push_back(cfg->members_.find(b.name)->first.c_str());
    return cfg;
}

const PluginOptionValue* PluginConfig::find(const char* key) const {
    auto it = values_.find(key);
    return it == values_.end() ? nullptr : &it->second;
}

std::string PluginConfig::error_at(const char* key, const std::string& message) const {
    const PluginOptionValue* v = find(key);
    return where(v ? v->mark : entry_.mark) + ": filter '" + entry_.plugin + "': option '" + key +
           "': " + message;
}

std::string PluginConfig::item_error_at(const char* key, size_t index,
                                       const std::string& message) const {
    const PluginOptionValue* v = find(key);
    if (!v || index >= v->item_marks.size())
        return error_at(key, message);
    return where(v->item_marks[index]) + ": filter '" + entry_.plugin + "': option '" + key +
           "': " + message;
}

bool PluginConfig::in_scope(const std::string& bond, const std::string& endpoint) const {
    const FilterConfig& e = entry_;
    if (e.bonds.empty() && e.endpoints.empty())
        return true;
    return (!bond.empty() && std::find(e.bonds.begin(), e.bonds.end(), bond) != e.bonds.end()) ||
           std::find(e.endpoints.begin(), e.endpoints.end(), endpoint) != e.endpoints.end();
}

bool PluginConfig::covers_bond(const std::string& bond) const {
    const FilterConfig& e = entry_;
    return (e.bonds.empty() && e.endpoints.empty()) ||
           std::find(e.bonds.begin(), e.bonds.end(), bond) != e.bonds.end();
}

const std::vector<const char*>* PluginConfig::bond_members(const char* bond) const {
    auto it = member_ptrs_.find(std::string_view(bond));
    return it == member_ptrs_.end() ? nullptr : &it->second;
}

// --- the function table --------------------------------------------------------------------

void HostServices::log(mavbond_log_level level, const std::string& instance, const char* message) {
    auto lvl = static_cast<LogLevel>(level < MAVBOND_LOG_ERROR   ? MAVBOND_LOG_ERROR
                                     : level > MAVBOND_LOG_DEBUG ? MAVBOND_LOG_DEBUG
                                                                 : level);
    MAVBOND_LOG(lvl, "[filter:%s] %s", instance.c_str(), message);
}

struct HostApiImpl {
    static void log(mavbond_host* h, mavbond_log_level level, const char* message) {
        h->services->log(level, h->name, message ? message : "");
    }
    static uint64_t now_ns(mavbond_host* h) { return h->services->now_ns(); }
    static int timer_add(mavbond_host* h, uint64_t period_ns, int (*cb)(void*), void* user,
                         uint64_t* out_id) {
        if (!cb || period_ns == 0 || !out_id)
            return -EINVAL;
        *out_id = h->services->timer_add(period_ns, [cb, user] { return cb(user) != 0; });
        return 0;
    }
    static void timer_cancel(mavbond_host* h, uint64_t id) { h->services->timer_cancel(id); }
    static size_t links(mavbond_host* h, const mavbond_link** out, size_t max) {
        return h->services->links(*h, out, max);
    }
    static int bond_by_name(mavbond_host* h, const char* name, uint32_t* out) {
        return name && out ? h->services->bond_by_name(name, out) : -EINVAL;
    }
    static int set_active_link(mavbond_host* h, uint32_t bond_id, uint32_t link_id) {
        return h->services->set_active_link(bond_id, link_id);
    }
    static int link_counters(mavbond_host* h, uint32_t link_id, mavbond_link_counters* out) {
        return out ? h->services->link_counters(link_id, out) : -EINVAL;
    }
    static int bond_state(mavbond_host* h, uint32_t bond_id, mavbond_bond_state* out) {
        return out ? h->services->bond_state(bond_id, out) : -EINVAL;
    }
    static const PluginOptionValue* value(const mavbond_config* c, const char* key, mavbond_option_type t) {
        if (!c || !key)
            return nullptr;
        const PluginOptionValue* v = c->config->find(key);
        return v && v->type == t ? v : nullptr;
    }
    static int cfg_bool(const mavbond_config* c, const char* key, int* out) {
        auto* v = value(c, key, MAVBOND_OPT_BOOL);
        return v ? (*out = v->b, 0) : -ENOENT;
    }
    static int cfg_int(const mavbond_config* c, const char* key, int64_t* out) {
        auto* v = value(c, key, MAVBOND_OPT_INT);
        return v ? (*out = v->i, 0) : -ENOENT;
    }
    static int cfg_duration_ns(const mavbond_config* c, const char* key, uint64_t* out) {
        auto* v = value(c, key, MAVBOND_OPT_DURATION);
        return v ? (*out = v->ns, 0) : -ENOENT;
    }
    static int cfg_percent(const mavbond_config* c, const char* key, double* out) {
        auto* v = value(c, key, MAVBOND_OPT_PERCENT);
        return v ? (*out = v->fraction, 0) : -ENOENT;
    }
    static int cfg_string(const mavbond_config* c, const char* key, const char** out) {
        auto* v = value(c, key, MAVBOND_OPT_STRING);
        return v ? (*out = v->text.c_str(), 0) : -ENOENT;
    }
    static int cfg_strings(const mavbond_config* c, const char* key, const char* const** out,
                           size_t* count) {
        auto* v = value(c, key, MAVBOND_OPT_STRINGS);
        if (!v)
            return -ENOENT;
        *out = v->item_ptrs.data();
        *count = v->item_ptrs.size();
        return 0;
    }
    static void cfg_error(const mavbond_config* c, const char* key, const char* message, char* err,
                          size_t err_len) {
        if (!err || err_len == 0)
            return;
        std::string text = c->config->error_at(key ? key : "?", message ? message : "");
        c->config->option_refused_ = true;
        snprintf(err, err_len, "%s", text.c_str());
    }
    static void scope(const mavbond_config* c, const char* const** bonds, size_t* bond_count,
                      const char* const** endpoints, size_t* endpoint_count) {
        const PluginConfig& p = *c->config;
        *bonds = p.bond_ptrs_.empty() ? nullptr : p.bond_ptrs_.data();
        *bond_count = p.bond_ptrs_.size();
        *endpoints = p.endpoint_ptrs_.empty() ? nullptr : p.endpoint_ptrs_.data();
        *endpoint_count = p.endpoint_ptrs_.size();
    }
    static int cfg_bond_members(const mavbond_config* c, const char* bond, const char* const** names,
                                size_t* count) {
        const std::vector<const char*>* members = bond ? c->config->bond_members(bond) : nullptr;
        if (!members)
            return -ENOENT;
        *names = members->data();
        *count = members->size();
        return 0;
    }
    static void cfg_bonds(const mavbond_config* c, const char* const** names, size_t* count) {
        const auto& bonds = c->config->bond_names();
        *names = bonds.data();
        *count = bonds.size();
    }
    static void cfg_item_error(const mavbond_config* c, const char* key, size_t index,
                               const char* message, char* err, size_t err_len) {
        if (!err || err_len == 0)
            return;
        std::string text = c->config->item_error_at(key ? key : "?", index, message ? message : "");
        c->config->option_refused_ = true;
        snprintf(err, err_len, "%s", text.c_str());
    }
    static void provides(mavbond_host* h, uint32_t what) { h->provides |= what; }
};

const mavbond_host_api* host_api() {
    static const mavbond_host_api api = {
        sizeof(mavbond_host_api),  HostApiImpl::log,           HostApiImpl::now_ns,
        HostApiImpl::timer_add,    HostApiImpl::timer_cancel,  HostApiImpl::links,
        HostApiImpl::bond_by_name, HostApiImpl::set_active_link, HostApiImpl::link_counters,
        HostApiImpl::bond_state,   HostApiImpl::cfg_bool,
        HostApiImpl::cfg_int,      HostApiImpl::cfg_duration_ns, HostApiImpl::cfg_percent,
        HostApiImpl::cfg_string,   HostApiImpl::cfg_strings,   HostApiImpl::cfg_error,
        HostApiImpl::scope,        HostApiImpl::cfg_bond_members, HostApiImpl::cfg_bonds,
        HostApiImpl::cfg_item_error, HostApiImpl::provides,
    };
    return &api;
}

}  // namespace mavbond
