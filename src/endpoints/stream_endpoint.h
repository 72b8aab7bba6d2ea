// Byte-stream endpoints (TCP connections, UARTs): large reads into a StreamParser, coalesced
// writes (writev) from the transmit queue, EPOLLOUT only while a backlog waits.
#pragma once

#include <string>

#include "core/event_loop.h"
#include "endpoints/endpoint.h"

namespace mavbond {

/// Exponential backoff between min and max.
class Backoff {
public:
    Backoff(Duration min, Duration max) : min_(min), max_(max), next_(min) {}
    Duration next() {
        Duration d = next_;
        next_ = std::min(next_ * 2, max_);
        return d;
    }
    void reset() { next_ = min_; }
    Duration max() const { return max_; }

private:
    Duration min_, max_, next_;
};

// The options of an endpoint that reconnects (a TCP client, a UART), and their rule.
inline constexpr EndpointOption kReconnectMin = {
    "reconnect_min", OptionKind::Time, "500ms",
    "The first wait before trying again after a failure; each failure doubles it, up to "
    "reconnect_max."};
inline constexpr EndpointOption kReconnectMax = {
    "reconnect_max", OptionKind::Time, "5s",
    "The longest wait between two attempts; not below reconnect_min."};
std::optional<std::pair<const char*, std::string>> reconnect_bounds(const EndpointOptions& o);
/// A client that may be given a host name (UDP, TCP): how often it is looked up again.
inline constexpr EndpointOption kResolveInterval = {
    "resolve_interval", OptionKind::Time, "60s",
    "How often a host name in address is looked up again (dynamic DNS); also after a send or "
    "connect fails, no sooner than reconnect_min. A name that does not resolve is retried with "
    "backoff (reconnect_min to reconnect_max). An address literal is never looked up."};
/// The backoff reconnect_min and reconnect_max of `config` give.
Backoff reconnect_backoff(const EndpointConfig& config);

class StreamEndpoint : public Endpoint {
public:
    StreamEndpoint(const EndpointConfig& config, std::string name, EventLoop& loop, FrameSink& sink,
                   UnknownIdPolicy policy, const Endpoint* parent = nullptr);
    ~StreamEndpoint() override;
    bool ready() const override { return fd_.valid() && !write_failed_; }

protected:
    /// Starts reading and writing on a connected/opened fd.
    Result<void> start_stream(UniqueFd fd);
    /// Stops using the fd: closes it, drops what was queued (a new connection starts at a
    /// frame boundary). Safe inside the endpoint's own handlers.
    void stop_stream();
    /// The stream ended or failed: subclasses reconnect, reopen or go away.
    virtual void on_disconnect(const std::string& reason) = 0;

    ssize_t write_stream(const iovec* iov, size_t count) override;
    void on_backlog(bool backlog) override;
    void on_write_error(int err) override;
    bool wait_writable(TimePoint deadline) override;

    FrameSink& sink_;

private:
    void on_events(uint32_t events);
    void read_frames();

    UniqueFd fd_;
    EventLoop::Watch watch_;
    StreamParser parser_;
    ReceivedBatch frames_{sink_};
    bool write_failed_ = false;  // closing after a write error, once what is unread is read
};

}  // namespace mavbond
