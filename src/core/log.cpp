#include "core/log.h"

#include <cstdarg>
#include <cstdio>
#include <cstdlib>

namespace mavbond {
namespace {

LogLevel g_level = LogLevel::Info;
// Decided once: journald reads priorities from "<N>" prefixes on a stream it set up.
const bool g_journal = std::getenv("JOURNAL_STREAM") != nullptr;

const char* level_word(LogLevel level) {
    switch (level) {
    case LogLevel::Error: return "error";
    case LogLevel::Warning: return "warning";
    case LogLevel::Notice: return "notice";
    case LogLevel::Info: return "info";
    case LogLevel::Debug: return "debug";
    case LogLevel::Trace: return "trace";
    }
    return "?";
}

}  // namespace

void log_set_level(LogLevel level) { g_level = level; }
LogLevel log_level() { return g_level; }

std::optional<LogLevel> parse_log_level(std::string_view name) {
    for (auto level : {LogLevel::Error, LogLevel::Warning, LogLevel::Notice, LogLevel::Info,
                       LogLevel::Debug, LogLevel::Trace}) {
        if (name == level_word(level))
            return level;
    }
    return std::nullopt;
}

void log_write(LogLevel level, const char* fmt, ...) {
    char line[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (g_journal) {
        int priority = level == LogLevel::Trace ? 7 : static_cast<int>(level);
        fprintf(stderr, "<%d>%s\n", priority, line);
    } else {
        fprintf(stderr, "mavbond: %s: %s\n", level_word(level), line);
    }
}

}  // namespace mavbond
