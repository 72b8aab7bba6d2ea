#include "daemon/systemd_notify.h"

#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstdlib>
#include <cstring>
#include <ctime>

#include "core/log.h"

namespace mavbond {
namespace {

/// A decimal number from the environment; nullopt when absent or not one.
std::optional<uint64_t> env_number(const char* name) {
    const char* text = std::getenv(name);
    if (!text || !*text)
        return std::nullopt;
    uint64_t value = 0;
    const char* end = text + std::strlen(text);
    auto [ptr, ec] = std::from_chars(text, end, value);
    if (ec != std::errc() || ptr != end)
        return std::nullopt;
    return value;
}

}  // namespace

Result<std::unique_ptr<SystemdNotify>> SystemdNotify::from_environment() {
    const char* socket_path = std::getenv("NOTIFY_SOCKET");
    if (!socket_path || !*socket_path)
        return std::unique_ptr<SystemdNotify>();
    std::string address = socket_path;
    if (address.front() == '@')
        address.front() = '\0';  // the abstract namespace
    else if (address.front() != '/')
        return make_error(std::string("NOTIFY_SOCKET=") + socket_path +
                          ": neither a path nor an abstract socket (@name)");
    if (address.size() >= sizeof(sockaddr_un::sun_path))
        return make_error(std::string("NOTIFY_SOCKET=") + socket_path + ": too long");
    UniqueFd fd(socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0));
    if (!fd)
        return make_error(std::string("NOTIFY_SOCKET: socket: ") + strerror(errno));
    // The watchdog is this process's only if WATCHDOG_PID, when set, says so (a child would
    // inherit the variables).
    Duration watchdog{};
    auto pid = env_number("WATCHDOG_PID");
    auto usec = env_number("WATCHDOG_USEC");
    if (usec && *usec > 0 && (!pid || *pid == static_cast<uint64_t>(getpid())))
        watchdog = std::chrono::microseconds(*usec);
    return std::unique_ptr<SystemdNotify>(
        new SystemdNotify(std::move(fd), std::move(address), socket_path, watchdog));
}

void SystemdNotify::send(std::string_view message) {
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::memcpy(addr.sun_path, address_.data(), address_.size());
    const auto len = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + address_.size());
    // One datagram; systemd reads it whole. Non-blocking: a full queue loses one message,
    // never the loop.
    ssize_t n = sendto(fd_.get(), message.data(), message.size(), MSG_NOSIGNAL,
                       reinterpret_cast<const sockaddr*>(&addr), len);
    if (n < 0 && !failed_logged_) {
        failed_logged_ = true;
        log_warning("systemd notification to %s failed: %s (further failures are not logged)",
                    label_.c_str(), strerror(errno));
    }
}

void SystemdNotify::ready(std::string_view status) {
    send("READY=1\nSTATUS=" + std::string(status));
}

void SystemdNotify::reloading() {
    // MONOTONIC_USEC: when the reload began, so systemd (Type=notify-reload, 253 and later)
    // can tell this reload from an earlier one.
    timespec ts{};
    clock_gettime(CLOCK_MONOTONIC, &ts);
    const uint64_t usec = static_cast<uint64_t>(ts.tv_sec) * 1'000'000 +
                          static_cast<uint64_t>(ts.tv_nsec) / 1'000;
    send("RELOADING=1\nMONOTONIC_USEC=" + std::to_string(usec) + "\nSTATUS=reloading");
}

void SystemdNotify::stopping() { send("STOPPING=1\nSTATUS=stopping"); }

void SystemdNotify::status(std::string_view status) { send("STATUS=" + std::string(status)); }

}  // namespace mavbond
