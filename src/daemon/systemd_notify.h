// What systemd learns from the daemon (sd_notify(3)'s protocol, spoken directly: one datagram
// of newline-separated KEY=VALUE lines to the AF_UNIX socket in $NOTIFY_SOCKET, no libsystemd):
// READY=1 once every endpoint is open, RELOADING=1 (with MONOTONIC_USEC, as Type=notify-reload
// needs) and READY=1 again around a reload, STOPPING=1 at a stop, WATCHDOG=1 from a timer on
// the loop itself (a hung loop stops feeding it and systemd restarts the daemon), and a STATUS=
// line that `systemctl status` shows.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "core/clock.h"
#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

class SystemdNotify {
public:
    /// From $NOTIFY_SOCKET (a path, or "@name" in the abstract namespace) and, for this
    /// process only ($WATCHDOG_PID, when set, names it), $WATCHDOG_USEC. nullptr when the
    /// daemon was not started by systemd with Type=notify; an error for a socket that is set
    /// but unusable.
    static Result<std::unique_ptr<SystemdNotify>> from_environment();

    /// Sends one message, e.g. "READY=1\nSTATUS=...". A failure is logged once, never fatal:
    /// systemd going away must not stop the telemetry.
    void send(std::string_view message);
    void ready(std::string_view status);
    void reloading();
    void stopping();
    void status(std::string_view status);
    void watchdog() { send("WATCHDOG=1"); }

    /// How often to send WATCHDOG=1: half of what systemd allows ($WATCHDOG_USEC), as
    /// sd_watchdog_enabled(3) advises; zero when it watches nothing.
    Duration watchdog_period() const { return watchdog_ / 2; }

private:
    SystemdNotify(UniqueFd fd, std::string address, std::string label, Duration watchdog)
        : fd_(std::move(fd)), address_(std::move(address)), label_(std::move(label)),
          watchdog_(watchdog) {}

    UniqueFd fd_;
    std::string address_;  // sun_path bytes; a leading '\0' for the abstract namespace
    std::string label_;    // as $NOTIFY_SOCKET gave it
    Duration watchdog_;
    bool failed_logged_ = false;
};

}  // namespace mavbond
