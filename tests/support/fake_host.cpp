#include "fake_host.h"

#include <cerrno>
#include <iterator>
#include <sstream>

#include "mavlink/frame.h"
#include "mavlink/message_table.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {

std::vector<uint8_t> test_frame(uint8_t seq, uint8_t sysid, uint8_t compid, uint32_t msgid) {
    std::vector<uint8_t> raw(kHeaderLenV2 + 9 + kChecksumLen, 0);
    const uint8_t header[] = {kMagicV2, 9, 0, 0, seq, sysid, compid,
                              static_cast<uint8_t>(msgid), static_cast<uint8_t>(msgid >> 8),
                              static_cast<uint8_t>(msgid >> 16)};
    std::copy(std::begin(header), std::end(header), raw.begin());
    return raw;
}

FakeHost::FakeHost() { host_.services = this; }

FakeHost::~FakeHost() {
    if (plugin_ && self_)
        plugin_->destroy(self_);
}

const mavbond_link& FakeHost::add_link(const std::string& name, const std::string& bond) {
    auto slot = std::make_unique<LinkSlot>();
    slot->name = name;
    slot->bond = bond;
    slot->endpoint = name.substr(0, name.find('@'));
    slot->link.struct_size = sizeof(mavbond_link);
    slot->link.id = static_cast<uint32_t>(links_.size());
    slot->link.bond_id = MAVBOND_NO_BOND;
    if (!bond.empty()) {
        auto it = std::find(bonds_.begin(), bonds_.end(), bond);
        if (it == bonds_.end()) {
            bonds_.push_back(bond);
            it = bonds_.end() - 1;
        }
        slot->link.bond_id = static_cast<uint32_t>(it - bonds_.begin());
        uint32_t priority = 0;
        for (const auto& other : links_)
            priority += other->bond == bond ? 1 : 0;
        slot->link.priority = priority;
    }
    links_.push_back(std::move(slot));
    // Names are pointed at after every slot exists (the strings live in the slots).
    for (auto& l : links_) {
        l->link.name = l->name.c_str();
        l->link.endpoint = l->endpoint.c_str();
        l->link.bond_name = l->bond.empty() ? nullptr : l->bond.c_str();
    }
    return links_.back()->link;
}

void FakeHost::declare_endpoint(const std::string& name, const std::string& bond) {
    declared_.emplace_back(name, bond);
    if (std::find(bonds_.begin(), bonds_.end(), bond) == bonds_.end())
        bonds_.push_back(bond);
}

const mavbond_link& FakeHost::link(const std::string& name) const {
    for (const auto& l : links_) {
        if (l->name == name)
            return l->link;
    }
    ADD_FAILURE() << "no link " << name;
    return links_.front()->link;
}

void* FakeHost::create(const mavbond_plugin_descriptor* plugin, const std::string& options) {
    std::ostringstream yaml;
    yaml << "endpoints:\n";
    for (size_t i = 0; i < links_.size(); i++) {
        yaml << "  - {name: " << links_[i]->name << ", type: udp, mode: client, address: 127.0.0.1:"
             << 9000 + i;
        if (!links_[i]->bond.empty())
            yaml << ", bond: " << links_[i]->bond;
        yaml << "}\n";
    }
    for (size_t i = 0; i < declared_.size(); i++)
        yaml << "  - {name: " << declared_[i].first << ", type: udp, mode: server, address: "
             << "127.0.0.1:" << 8000 + i << ", bond: " << declared_[i].second << "}\n";
    if (links_.empty() && declared_.empty())
        yaml << "  - {name: none, type: udp, mode: client, address: 127.0.0.1:9}\n";
    if (!bonds_.empty()) {
        yaml << "bonds:\n";
        for (const auto& b : bonds_)
            yaml << "  - {name: " << b << "}\n";
    }
    yaml << "filters:\n  - plugin: " << plugin->name << "\n";
    std::istringstream lines(options);
    for (std::string line; std::getline(lines, line);)
        yaml << "    " << line << "\n";
    auto config = parse_config(yaml.str(), "test.yaml", endpoint_schemas());
    if (!config) {
        last_error_ = config.error().message;
        return nullptr;
    }
    config_ = std::make_unique<Config>(std::move(config.value()));
    auto pc = PluginConfig::create(config_->filters.back(), plugin->options, *config_);
    if (!pc) {
        last_error_ = pc.error().message;
        return nullptr;
    }
    plugin_config_ = std::move(pc.value());
    config_view_.config = plugin_config_.get();
    host_.name = plugin->name;
    char err[512] = "";
    void* self = nullptr;
    if (plugin->create(host_api(), &host_, &config_view_, &self, err, sizeof err) != 0) {
        last_error_ = err;
        return nullptr;
    }
    plugin_ = plugin;
    self_ = self;
    return self;
}

void FakeHost::advance(Duration d) {
    uint64_t until = now_ns_ + static_cast<uint64_t>(d.count());
    for (;;) {
        auto next = timers_.end();
        for (auto it = timers_.begin(); it != timers_.end(); ++it) {
            if (it->second.due <= until && (next == timers_.end() || it->second.due < next->second.due))
                next = it;
        }
        if (next == timers_.end())
            break;
        now_ns_ = next->second.due;
        uint64_t id = next->first;
        bool again = next->second.fn();
        auto it = timers_.find(id);
        if (it == timers_.end())
            continue;
        if (again)
            it->second.due += it->second.period;
        else
            timers_.erase(it);
    }
    now_ns_ = until;
}

mavbond_frame FakeHost::frame(const std::vector<uint8_t>& raw) const {
    mavbond_frame f{};
    f.struct_size = sizeof f;
    f.raw = raw.data();
    f.raw_len = static_cast<uint32_t>(raw.size());
    f.rx_time_ns = now_ns_;
    f.target_system = f.target_component = -1;
    f.timestamp_offset = -1;
    return f;
}

mavbond_frame FakeHost::frame(const std::vector<uint8_t>& raw, const mavbond_link& from,
                              uint64_t t_ns) {
    mavbond_frame f = frame(raw);
    bool v2 = raw.at(0) == kMagicV2;
    size_t header = v2 ? kHeaderLenV2 : kHeaderLenV1;
    f.version = v2 ? 2 : 1;
    f.incompat_flags = v2 ? raw.at(2) : 0;
    f.seq = raw.at(v2 ? 4 : 2);
    f.sysid = raw.at(v2 ? 5 : 3);
    f.compid = raw.at(v2 ? 6 : 4);
    f.msgid = v2 ? (raw.at(7) | raw.at(8) << 8 | raw.at(9) << 16) : raw.at(5);
    f.payload = raw.data() + header;
    f.payload_len = raw.at(1);
    f.crc_checked = 1;
    if (const MessageInfo* info = find_message(f.msgid)) {
        f.timestamp_offset = info->timestamp_ofs;
        f.timestamp_size = info->timestamp_size;
        f.timestamp_us = info->timestamp_us;
    }
    if (t_ns)
        f.rx_time_ns = t_ns;
    StreamStep step = positions_[from.id].track(f.sysid, f.compid, f.seq);
    f.stream_pos = step.pos;
    f.stream_lost = step.lost;
    f.stream_flags = step.flags;
    return f;
}

uint64_t FakeHost::timer_add(uint64_t period_ns, std::function<bool()> fn) {
    uint64_t id = next_timer_++;
    timers_[id] = Timer{now_ns_ + period_ns, period_ns, std::move(fn)};
    return id;
}

void FakeHost::timer_cancel(uint64_t id) { timers_.erase(id); }

bool FakeHost::in_scope(const mavbond_link& link) const {
    const LinkSlot& slot = *links_.at(link.id);
    // A learned peer ("radio@10.0.0.2:14550") is in scope as its endpoint is.
    return plugin_config_->in_scope(slot.bond, slot.name.substr(0, slot.name.find('@')));
}

mavbond_verdict FakeHost::ingress(const mavbond_frame& f, mavbond_frame_notes& notes,
                                  const mavbond_link& from) {
    if (!in_scope(from))
        return MAVBOND_PASS;
    mavbond_received r{&f, &notes, &from, MAVBOND_PASS};
    plugin_->on_ingress(self_, &r, 1);
    return r.verdict;
}

size_t FakeHost::links(const mavbond_host&, const mavbond_link** out, size_t max) {
    size_t n = 0;
    for (const auto& slot : links_) {
        if (!in_scope(slot->link))
            continue;
        if (n < max)
            out[n] = &slot->link;
        n++;
    }
    return n;
}

int FakeHost::bond_by_name(const std::string& name, uint32_t* out) {
    auto it = std::find(bonds_.begin(), bonds_.end(), name);
    if (it == bonds_.end())
        return -ENOENT;
    *out = static_cast<uint32_t>(it - bonds_.begin());
    return 0;
}

int FakeHost::set_active_link(uint32_t bond_id, uint32_t link_id) {
    if (link_id >= links_.size() || links_[link_id]->link.bond_id != bond_id)
        return -EINVAL;
    auto it = active_link.find(bond_id);
    if (it == active_link.end() || it->second != link_id)
        switches[bond_id]++;
    active_link[bond_id] = link_id;
    return 0;
}

int FakeHost::link_counters(uint32_t link_id, mavbond_link_counters* out) {
    if (link_id >= links_.size())
        return -ENOENT;
    *out = counters[link_id];
    out->struct_size = sizeof *out;
    return 0;
}

int FakeHost::bond_state(uint32_t bond_id, mavbond_bond_state* out) {
    if (bond_id >= bonds_.size())
        return -ENOENT;
    *out = mavbond_bond_state{};
    out->struct_size = sizeof *out;
    auto it = active_link.find(bond_id);
    out->active_link_id = it == active_link.end() ? UINT32_MAX : it->second;
    out->switches = switches[bond_id];
    auto resend = peer_resend.find(bond_id);
    out->peer_resend_ns = resend == peer_resend.end() ? 0 : resend->second;
    out->peer_resend_announced = resend != peer_resend.end();
    return 0;
}

void FakeHost::log(mavbond_log_level level, const std::string& instance, const char* message) {
    logs.push_back(message);
    HostServices::log(level, instance, message);
}

}  // namespace mavbond
