// Logging to stderr, journald-friendly: under systemd (JOURNAL_STREAM set) each line carries a
// "<N>" syslog priority prefix that journald maps to a level (journald adds the time);
// otherwise the local time to the millisecond and a level word.
#pragma once

#include <optional>
#include <string_view>

namespace mavbond {

enum class LogLevel { Error = 3, Warning = 4, Notice = 5, Info = 6, Debug = 7, Trace = 8 };

void log_set_level(LogLevel level);
LogLevel log_level();
std::optional<LogLevel> parse_log_level(std::string_view name);
inline bool log_enabled(LogLevel level) { return level <= log_level(); }

void log_write(LogLevel level, const char* fmt, ...) __attribute__((format(printf, 2, 3)));

}  // namespace mavbond

#define MAVBOND_LOG(level, ...)                                   \
    do {                                                          \
        if (::mavbond::log_enabled(level))                        \
            ::mavbond::log_write(level, __VA_ARGS__);             \
    } while (0)
#define log_error(...) MAVBOND_LOG(::mavbond::LogLevel::Error, __VA_ARGS__)
#define log_warning(...) MAVBOND_LOG(::mavbond::LogLevel::Warning, __VA_ARGS__)
#define log_notice(...) MAVBOND_LOG(::mavbond::LogLevel::Notice, __VA_ARGS__)
#define log_info(...) MAVBOND_LOG(::mavbond::LogLevel::Info, __VA_ARGS__)
#define log_debug(...) MAVBOND_LOG(::mavbond::LogLevel::Debug, __VA_ARGS__)
