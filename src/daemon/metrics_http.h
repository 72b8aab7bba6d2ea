// A tiny HTTP/1.1 server on the event loop for Prometheus scrapes. GET or HEAD /metrics answers
// 200 with the text exposition format; another path 404, another method 405, a request that is
// not HTTP 400, one longer than max_request 431; beyond max_connections a client gets 503 at
// once. Every response carries Connection: close. Nothing blocks: a slow or silent client holds
// one slot and at most max_request bytes until `timeout` after it connected, then it is closed.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/clock.h"
#include "core/event_loop.h"
#include "core/metric_set.h"
#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

class MetricsHttpServer {
public:
    struct Limits {
        size_t max_request = 8192;   // request line and headers
        size_t max_connections = 8;
        Duration timeout = seconds(5);  // from accept to close, whatever the client does
    };
    /// Builds the metrics of one scrape (the server adds its own to them).
    using Producer = std::function<MetricSet()>;

    /// Listens on host:port (IPv4 dotted quad; port 0: any, see port()).
    static Result<std::unique_ptr<MetricsHttpServer>> open(const std::string& host, uint16_t port,
                                                           const Limits& limits, EventLoop& loop,
                                                           Producer producer);
    ~MetricsHttpServer();
    MetricsHttpServer(const MetricsHttpServer&) = delete;
    MetricsHttpServer& operator=(const MetricsHttpServer&) = delete;

    uint16_t port() const { return port_; }

private:
    struct Connection;
    MetricsHttpServer(EventLoop& loop, UniqueFd fd, const Limits& limits, Producer producer);
    void on_accept();
    void refuse(UniqueFd client);
    void on_io(Connection& c, uint32_t events);
    void read_request(Connection& c);
    void answer(Connection& c);
    void start_response(Connection& c, int status, const std::string& body, bool head_only);
    void write_response(Connection& c);
    void close(Connection& c);
    void add_own_metrics(MetricSet& set) const;

    EventLoop& loop_;
    UniqueFd fd_;
    Limits limits_;
    Producer producer_;
    uint16_t port_ = 0;
    EventLoop::Watch accept_watch_;
    EventLoop::Timer accept_pause_;  // out of file descriptors: accept again later
    std::vector<std::unique_ptr<Connection>> connections_;
    uint64_t requests_ = 0, refused_ = 0, timed_out_ = 0;
};

/// Parses the head of an HTTP request (request line and headers, up to the blank line) and
/// returns the status to answer: 200 for GET or HEAD /metrics, 404, 405 or 400. `head_only`
/// is set for HEAD.
int classify_http_request(std::string_view head, bool& head_only);

}  // namespace mavbond
