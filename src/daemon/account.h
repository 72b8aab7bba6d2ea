// What the daemon derived from settings that depend on each other, and why, one line each: the
// account it logs at start and at every reload, per bond (how long dedup remembers, whether
// it renumbers, what a metered member carries in standby, when a link counts as lost and who
// tells the GCS) and for mavbond's own identity. Where a choice is the user's, the line says
// what was chosen and what it costs.
#pragma once

#include <string>
#include <vector>

#include "config/config.h"
#include "routing/filter_chain.h"
#include "routing/router.h"

namespace mavbond {

std::vector<std::string> derived_settings(const Config& config, const Router& router,
                                          const FilterChain& chain);

}  // namespace mavbond
