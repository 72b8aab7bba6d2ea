#include "endpoints/uart_endpoint.h"

// termios2 (any baud rate via BOTHER) lives in the kernel's header, which clashes with
// <termios.h>: this file uses the kernel one only.
#include <asm/termbits.h>
#include <fcntl.h>
#include <sys/ioctl.h>

#include <cerrno>

#include "core/log.h"
#include "endpoints/net.h"

namespace mavbond {

namespace {

constexpr EndpointOption kUartOptions[] = {
    {"device", OptionKind::Text, nullptr,
     "The serial device, for example /dev/ttyAMA0 or /dev/serial/by-id/... (the names that stay "
     "the same across reboots).", true},
    {"baud", OptionKind::Count, "57600", "Any rate, standard or not (921600, 1500000)."},
    {"flow_control", OptionKind::Flag, "false", "RTS/CTS hardware flow control."},
    kReconnectMin,
    kReconnectMax,
};

}  // namespace

const EndpointSchema kUartType = {"uart", nullptr,
                                  "A serial port (an autopilot, a radio), raw. A device that is "
                                  "missing at start or unplugged later is opened again with "
                                  "backoff; the daemon keeps running.",
                                  kUartOptions, true, reconnect_bounds};

Result<UniqueFd> open_serial(const std::string& device, uint32_t baud, bool flow_control) {
    UniqueFd fd(::open(device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC));
    if (!fd) {
        const int err = errno;
        // What to do about the two usual ones.
        const char* hint =
            err == EACCES || err == EPERM
                ? " (the daemon's user needs read and write on it: Debian gives serial devices to "
                  "group dialout; the service runs with SupplementaryGroups=dialout; by hand: "
                  "sudo adduser $USER dialout, then log in again)"
            : err == ENOENT ? " (not plugged in, or another name: ls /dev/serial/by-id/)"
                            : "";
        return make_error("cannot open " + device + ": " + errno_text(err) + hint);
    }
    termios2 tio{};
    if (ioctl(fd.get(), TCGETS2, &tio) < 0)
        return make_error(device + " is not a serial port: " + errno_text(errno));
    // Raw mode, as cfmakeraw does, plus 8N1 and the receiver on.
    tio.c_iflag &= ~static_cast<tcflag_t>(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR |
                                          ICRNL | IXON | IXOFF | IXANY);
    tio.c_oflag &= ~static_cast<tcflag_t>(OPOST);
    tio.c_lflag &= ~static_cast<tcflag_t>(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    tio.c_cflag &= ~static_cast<tcflag_t>(CSIZE | PARENB | CSTOPB | CBAUD | CRTSCTS);
    tio.c_cflag |= CS8 | CLOCAL | CREAD | BOTHER;
    if (flow_control)
        tio.c_cflag |= CRTSCTS;
    tio.c_ispeed = baud;
    tio.c_ospeed = baud;
    // VMIN 1: a non-blocking read with nothing to read says EAGAIN (VMIN 0 would return 0,
    // which looks like a hangup).
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (ioctl(fd.get(), TCSETS2, &tio) < 0)
        return make_error("cannot set " + std::to_string(baud) + " baud on " + device + ": " +
                          errno_text(errno));
    ioctl(fd.get(), TCFLSH, TCIOFLUSH);
    return fd;
}

std::unique_ptr<UartEndpoint> UartEndpoint::open(const EndpointConfig& config, EventLoop& loop,
                                                 FrameSink& sink, UnknownIdPolicy policy) {
    std::unique_ptr<UartEndpoint> uart(new UartEndpoint(config, loop, sink, policy));
    sink.attach(*uart);
    uart->try_open();
    return uart;
}

UartEndpoint::UartEndpoint(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                           UnknownIdPolicy policy)
    : StreamEndpoint(config, config.name, loop, sink, policy),
      backoff_(reconnect_backoff(config)) {}

UartEndpoint::~UartEndpoint() { sink_.detach(*this); }

void UartEndpoint::try_open() {
    const EndpointOptions& o = config().options;
    auto fd = open_serial(o.text("device"), static_cast<uint32_t>(o.number("baud")),
                          o.flag("flow_control"));
    if (!fd) {
        retry_later(fd.error().message);
        return;
    }
    if (auto r = start_stream(std::move(fd.value())); !r) {
        retry_later(r.error().message);
        return;
    }
    backoff_.reset();
    failing_logged_ = false;
    open_error_.clear();
    log_notice("[uart:%s] %s open at %u baud%s", name().c_str(), o.text("device").c_str(),
               static_cast<unsigned>(o.number("baud")), o.flag("flow_control") ? " with RTS/CTS" : "");
}

void UartEndpoint::retry_later(const std::string& reason) {
    open_error_ = reason;
    if (!failing_logged_) {
        log_warning("[uart:%s] %s; retrying with backoff up to %.1fs", name().c_str(),
                    reason.c_str(), std::chrono::duration<double>(backoff_.max()).count());
        failing_logged_ = true;
    }
    retry_timer_ = loop_.schedule(backoff_.next(), [this] {
        try_open();
        return Duration::zero();
    });
}

void UartEndpoint::on_disconnect(const std::string& reason) {
    log_warning("[uart:%s] %s lost: %s", name().c_str(), config().options.text("device").c_str(),
                reason.c_str());
    failing_logged_ = true;
    retry_later(reason);
}

}  // namespace mavbond
