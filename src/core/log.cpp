#include "core/log.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <ctime>

namespace mavbond {
namespace {

LogLevel g_level = LogLevel::Info;

/// Whether stderr is the journal's stream: JOURNAL_STREAM names it ("DEV:INODE"), and is
/// inherited by whatever the service starts, so it counts only if it is still stderr.
bool stderr_is_journal() {
    const char* stream = std::getenv("JOURNAL_STREAM");
    unsigned long long dev = 0, ino = 0;
    struct stat st {};
    return stream && sscanf(stream, "%llu:%llu", &dev, &ino) == 2 && fstat(STDERR_FILENO, &st) == 0 &&
           st.st_dev == dev && st.st_ino == ino;
}

// Decided once: journald reads priorities from "<N>" prefixes on a stream it set up.
const bool g_journal = stderr_is_journal();

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
        // journald stamps each line itself.
        int priority = level == LogLevel::Trace ? 7 : static_cast<int>(level);
        fprintf(stderr, "<%d>%s\n", priority, line);
    } else {
        // By hand, or under another supervisor: the wall clock's local time, to the ms.
        timespec now{};
        clock_gettime(CLOCK_REALTIME, &now);
        tm local{};
        localtime_r(&now.tv_sec, &local);
        char stamp[32];
        size_t n = strftime(stamp, sizeof stamp, "%Y-%m-%d %H:%M:%S", &local);
        snprintf(stamp + n, sizeof stamp - n, ".%03ld", now.tv_nsec / 1'000'000);
        fprintf(stderr, "%s mavbond: %s: %s\n", stamp, level_word(level), line);
    }
}

}  // namespace mavbond
