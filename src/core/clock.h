// Every timeout runs on the monotonic clock: a Pi has no RTC and its wall clock jumps at boot.
#pragma once

#include <chrono>

namespace mavbond {

using Clock = std::chrono::steady_clock;
using TimePoint = Clock::time_point;
using Duration = std::chrono::nanoseconds;
using std::chrono::milliseconds;
using std::chrono::seconds;

}  // namespace mavbond
