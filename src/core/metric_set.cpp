#include "core/metric_set.h"

#include <charconv>
#include <cmath>

namespace mavbond {
namespace {

bool name_start(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
bool name_char(char c) { return name_start(c) || (c >= '0' && c <= '9'); }

}  // namespace

bool valid_metric_name(std::string_view name) {
    if (name.empty() || !(name_start(name[0]) || name[0] == ':'))
        return false;
    for (char c : name) {
        if (!name_char(c) && c != ':')
            return false;
    }
    return true;
}

bool valid_label_name(std::string_view name) {
    if (name.empty() || !name_start(name[0]) || name.substr(0, 2) == "__")
        return false;
    for (char c : name) {
        if (!name_char(c))
            return false;
    }
    return true;
}

std::string escape_label_value(std::string_view value) {
    std::string out;
    out.reserve(value.size());
    for (char c : value) {
        if (c == '\\' || c == '"')
            out += '\\', out += c;
        else if (c == '\n')
            out += "\\n";
        else
            out += c;
    }
    return out;
}

std::string escape_help(std::string_view help) {
    std::string out;
    out.reserve(help.size());
    for (char c : help) {
        if (c == '\\')
            out += "\\\\";
        else if (c == '\n')
            out += "\\n";
        else
            out += c;
    }
    return out;
}

std::string format_gauge(double value) {
    if (std::isnan(value))
        return "NaN";
    if (std::isinf(value))
        return value > 0 ? "+Inf" : "-Inf";
    char buf[64];
    auto r = std::to_chars(buf, buf + sizeof buf, value);
    return std::string(buf, r.ptr);
}

Result<MetricSet::Family*> MetricSet::family(std::string_view name, std::string_view help,
                                             Type type) {
    if (!valid_metric_name(name))
        return make_error("invalid metric name '" + std::string(name) + "'");
    std::string full(name);
    if (type == Type::Counter)
        full += "_total";
    auto it = index_.find(full);
    if (it == index_.end()) {
        index_.emplace(full, families_.size());
        families_.push_back(Family{full, std::string(help), type, {}, {}});
        return &families_.back();
    }
    Family& f = families_[it->second];
    if (f.type != type || f.help != help)
        return make_error("metric " + full + " declared twice with another type or help");
    return &f;
}

Result<void> MetricSet::add(const MetricSample& s) {
    return s.type == Type::Counter ? counter(s.name, s.help, s.count, s.labels)
                                   : gauge(s.name, s.help, s.value, s.labels);
}

Result<void> MetricSet::declare(std::string_view name, std::string_view help, Type type) {
    auto f = family(name, help, type);
    if (!f)
        return f.error();
    return {};
}

Result<void> MetricSet::add(std::string_view name, std::string_view help, Type type,
                            const MetricLabels& labels, std::string value) {
    std::string text;
    for (size_t i = 0; i < labels.size(); i++) {
        const auto& [key, val] = labels[i];
        if (!valid_label_name(key))
            return make_error("metric " + std::string(name) + ": invalid label name '" + key + "'");
        for (size_t j = 0; j < i; j++) {
            if (labels[j].first == key)
                return make_error("metric " + std::string(name) + ": label '" + key + "' twice");
        }
        text += text.empty() ? "{" : ",";
        text += key + "=\"" + escape_label_value(val) + "\"";
    }
    if (!text.empty())
        text += "}";
    auto f = family(name, help, type);
    if (!f)
        return f.error();
    Family& fam = *f.value();
    if (!fam.label_sets.insert(text).second)
        return make_error("metric " + fam.name + text + " given twice");
    fam.samples.emplace_back(std::move(text), std::move(value));
    return {};
}

Result<void> MetricSet::counter(std::string_view name, std::string_view help, uint64_t value,
                                const MetricLabels& labels) {
    return add(name, help, Type::Counter, labels, std::to_string(value));
}

Result<void> MetricSet::gauge(std::string_view name, std::string_view help, double value,
                              const MetricLabels& labels) {
    return add(name, help, Type::Gauge, labels, format_gauge(value));
}

std::string MetricSet::text() const {
    std::string out;
    for (const Family& f : families_) {
        out += "# HELP " + f.name + " " + escape_help(f.help) + "\n";
        out += "# TYPE " + f.name + (f.type == Type::Counter ? " counter\n" : " gauge\n");
        for (const auto& [labels, value] : f.samples)
            out += f.name + labels + " " + value + "\n";
    }
    return out;
}

}  // namespace mavbond
