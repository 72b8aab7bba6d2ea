// A bound on log lines that strangers can cause (a peer learned, a connection accepted, ...):
// each one is worth a line while they are few, but a flood of them must not flood the log.
#pragma once

#include <cstdint>
#include <string>

#include "core/clock.h"
#include "core/log.h"

namespace mavbond {

/// Lets at most `burst` lines through in each `period` (all of them at log level debug); the
/// rest are counted, and the first line let through afterwards says how many were left out.
class LogBudget {
public:
    LogBudget(uint32_t burst, Duration period) : burst_(burst), period_(period) {}

    /// Whether a line may be logged now (else it is counted as left out). At log level debug
    /// every line is: the operator asked for all of them.
    bool allow(TimePoint now) {
        if (log_enabled(LogLevel::Debug))
            return true;
        if (now - period_start_ >= period_) {
            period_start_ = now;
            used_ = 0;
        }
        if (used_ < burst_) {
            used_++;
            return true;
        }
        left_out_++;
        return false;
    }
    /// For the line allow() let through: " (N more not logged)" once after lines were left
    /// out, else "".
    std::string left_out_note() {
        if (left_out_ == 0)
            return "";
        std::string note = " (" + std::to_string(left_out_) + " more like it not logged)";
        left_out_ = 0;
        return note;
    }

private:
    uint32_t burst_;
    Duration period_;
    TimePoint period_start_{};
    uint32_t used_ = 0;
    uint64_t left_out_ = 0;
};

}  // namespace mavbond
