#include "endpoints/stream_endpoint.h"

#include <poll.h>
#include <sys/socket.h>
#include <sys/uio.h>

#include <cerrno>
#include <cstring>

#include "core/log.h"
#include "endpoints/net.h"

namespace mavbond {

std::optional<std::pair<const char*, std::string>> reconnect_bounds(const EndpointOptions& o) {
    Duration min = o.duration("reconnect_min"), max = o.duration("reconnect_max");
    if (max >= min)
        return std::nullopt;
    // The one written is at fault (reconnect_min above the default maximum).
    return std::pair{o.given("reconnect_max") ? "reconnect_max" : "reconnect_min",
                     "'reconnect_max' (" + format_duration(max) +
                         ") must not be below 'reconnect_min' (" + format_duration(min) + ")"};
}

Backoff reconnect_backoff(const EndpointConfig& config) {
    return Backoff(config.options.duration("reconnect_min"), config.options.duration("reconnect_max"));
}

StreamEndpoint::StreamEndpoint(const EndpointConfig& config, std::string name, EventLoop& loop,
                               FrameSink& sink, UnknownIdPolicy policy, const Endpoint* parent)
    : Endpoint(config, std::move(name), loop, TxQueue::Mode::Stream, parent), sink_(sink),
      parser_(policy, 8192) {}

StreamEndpoint::~StreamEndpoint() = default;

Result<void> StreamEndpoint::start_stream(UniqueFd fd) {
    auto w = loop_.watch(fd.get(), EPOLLIN | EPOLLRDHUP,
                         [this](uint32_t events) { on_events(events); });
    if (!w)
        return w.error();
    fd_ = std::move(fd);
    watch_ = std::move(w.value());
    parser_.reset();
    return {};
}

void StreamEndpoint::stop_stream() {
    watch_.reset();
    fd_.reset();
    clear_tx();
    stats_.rx = parser_.counters();
}

ssize_t StreamEndpoint::write_stream(const iovec* iov, size_t count) {
    if (!fd_)
        return -ENOTCONN;
    ssize_t n = writev(fd_.get(), iov, static_cast<int>(count));
    return n < 0 ? -errno : n;
}

void StreamEndpoint::on_backlog(bool backlog) {
    if (watch_.active())
        watch_.set_events(EPOLLIN | EPOLLRDHUP | (backlog ? EPOLLOUT : 0u));
}

void StreamEndpoint::on_write_error(int err) {
    // The peer is gone, but what it sent before going may still wait unread (a TCP client
    // that sent a frame and closed): read it, then close. After this round, not here: the
    // sink may be in the middle of a batch.
    if (write_failed_)
        return;
    write_failed_ = true;
    clear_tx();
    defer(loop_, [this, err] {
        write_failed_ = false;
        if (!fd_)
            return;  // the read path saw the end meanwhile and closed
        read_frames();
        if (fd_) {
            stop_stream();
            on_disconnect("write failed: " + errno_text(err));
        }
    });
}

bool StreamEndpoint::wait_writable(TimePoint deadline) {
    auto left = std::chrono::duration_cast<milliseconds>(deadline - Clock::now()).count();
    if (!fd_ || left <= 0)
        return false;
    // At most 2 ms: TCP signals POLLOUT only once a third of its buffer is free, but the rest
    // of one frame fits as soon as the peer reads a little.
    pollfd p{fd_.get(), POLLOUT, 0};
    poll(&p, 1, static_cast<int>(std::min<int64_t>(left, 2)));
    return true;
}

void StreamEndpoint::on_events(uint32_t events) {
    if (events & EPOLLOUT)
        flush();
    if (fd_ && (events & (EPOLLIN | EPOLLRDHUP | EPOLLHUP | EPOLLERR)))
        read_frames();
}

void StreamEndpoint::read_frames() {
    // A few reads per wakeup at most, so one busy link cannot starve the others.
    for (int round = 0; round < 4 && fd_; round++) {
        auto area = parser_.write_area();
        ssize_t n = read(fd_.get(), area.data(), area.size());
        if (n > 0) {
            // A byte stream carries no arrival times: a frame arrived when the read that
            // completed it was made (not when the loop's round began).
            TimePoint arrival = Clock::now();
            parser_.commit(static_cast<size_t>(n));
            Frame frame;
            bool any_valid = false;
            while (parser_.next(frame))
                any_valid |= valid(receive(frames_, frame, arrival));
            if (any_valid)
                heard_valid(arrival);
            frames_.submit();
            stats_.rx = parser_.counters();
            // Frames lent to other links point into the parser: sent before reading on.
            sink_.end_batch();
            if (static_cast<size_t>(n) < area.size())
                return;
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
            return;
        if (n < 0 && errno == EINTR)
            continue;
        std::string reason = n == 0 ? "closed by peer" : errno_text(errno);
        stop_stream();
        on_disconnect(reason);
        return;
    }
}

}  // namespace mavbond
