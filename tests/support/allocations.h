// Every heap allocation in a test binary that links tests/support is counted, so a test can
// show that a frame path makes none: read allocations() before and after.
#pragma once

#include <cstdint>

namespace mavbond {

uint64_t allocations();

}  // namespace mavbond
