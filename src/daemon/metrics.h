// What the metrics endpoint serves: every endpoint's counters, the bonds' state, the router's
// totals, the uptime, what renumbering did, and each filter's own samples (the stats plugin's per-link and delivered
// loss, dedup's duplicates, linkswitch's active link), as Prometheus families.
#pragma once

#include <vector>

#include "core/clock.h"
#include "core/metric_set.h"
#include "endpoints/endpoint.h"

namespace mavbond {

class Router;
class FilterChain;

MetricSet metrics_document(const std::vector<Endpoint::Ptr>& endpoints, const Router& router,
                           const FilterChain& chain, TimePoint started, TimePoint now);

}  // namespace mavbond
