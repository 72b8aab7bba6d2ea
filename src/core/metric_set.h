// The Prometheus text exposition format, version 0.0.4: samples are added in any order and
// grouped into families (one # HELP and # TYPE each, samples together), label values and help
// texts escaped, counters exact integers named NAME_total, gauges shortest round-trip floats
// with NaN, +Inf and -Inf. Built once per scrape, off the data path.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "core/result.h"

namespace mavbond {

using MetricLabels = std::vector<std::pair<std::string, std::string>>;
struct MetricSample;

class MetricSet {
public:
    enum class Type { Counter, Gauge };

    /// A counter sample of family `name` (without _total: the text adds it).
    Result<void> counter(std::string_view name, std::string_view help, uint64_t value,
                         const MetricLabels& labels = {});
    Result<void> gauge(std::string_view name, std::string_view help, double value,
                       const MetricLabels& labels = {});
    /// Declares a family that may have no sample yet (its HELP and TYPE are written anyway).
    Result<void> declare(std::string_view name, std::string_view help, Type type);
    /// A sample kept as a value (see MetricSample).
    Result<void> add(const MetricSample& sample);

    std::string text() const;

private:
    struct Family {
        std::string name;  // as written: counters end in _total
        std::string help;
        Type type;
        std::vector<std::pair<std::string, std::string>> samples;  // {labels text, value text}
        std::unordered_set<std::string> label_sets;
    };
    Result<void> add(std::string_view name, std::string_view help, Type type,
                     const MetricLabels& labels, std::string value);
    Result<Family*> family(std::string_view name, std::string_view help, Type type);

    std::vector<Family> families_;  // first-added first
    std::unordered_map<std::string, size_t> index_;
};

/// One sample as a value, for a status taken now and rendered later.
struct MetricSample {
    MetricSet::Type type = MetricSet::Type::Counter;
    std::string name;  // the family, without _total
    std::string help;
    MetricLabels labels;
    uint64_t count = 0;  // a counter's
    double value = 0;    // a gauge's
};

/// [a-zA-Z_:][a-zA-Z0-9_:]*
bool valid_metric_name(std::string_view name);
/// [a-zA-Z_][a-zA-Z0-9_]*, not starting with "__" (reserved by Prometheus)
bool valid_label_name(std::string_view name);
/// Backslash, double quote and newline escaped (a label value inside "...").
std::string escape_label_value(std::string_view value);
/// Backslash and newline escaped (a # HELP text).
std::string escape_help(std::string_view help);
/// Shortest text that reads back as the same double; NaN, +Inf, -Inf.
std::string format_gauge(double value);

}  // namespace mavbond
