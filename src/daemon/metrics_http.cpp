#include "daemon/metrics_http.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "core/log.h"

namespace mavbond {

struct MetricsHttpServer::Connection {
    enum class State { Reading, Writing, Closing };
    UniqueFd fd;
    EventLoop::Watch watch;
    EventLoop::Timer deadline;
    State state = State::Reading;
    std::string request;   // never longer than Limits::max_request
    std::string response;
    size_t sent = 0;
    size_t drained = 0;    // bytes thrown away after the response
};

namespace {

const char* reason(int status) {
    switch (status) {
    case 200: return "OK";
    case 400: return "Bad Request";
    case 404: return "Not Found";
    case 405: return "Method Not Allowed";
    case 431: return "Request Header Fields Too Large";
    case 503: return "Service Unavailable";
    default: return "Internal Server Error";
    }
}

std::string response_head(int status, size_t length) {
    std::string head = "HTTP/1.1 " + std::to_string(status) + " " + reason(status) + "\r\n";
    head += status == 200 ? "Content-Type: text/plain; version=0.0.4; charset=utf-8\r\n"
                          : "Content-Type: text/plain; charset=utf-8\r\n";
    if (status == 405)
        head += "Allow: GET, HEAD\r\n";
    head += "Content-Length: " + std::to_string(length) + "\r\nConnection: close\r\n\r\n";
    return head;
}

/// RFC 9110 tchar: what a method or a header name is made of.
bool is_token(std::string_view s) {
    if (s.empty())
        return false;
    for (char c : s) {
        if (!(isalnum(static_cast<unsigned char>(c)) || strchr("!#$%&'*+-.^_`|~", c)))
            return false;
    }
    return true;
}

// What a client may still send after its response before it is cut off: enough for a body
// it sent along, not a way to keep the server reading.
constexpr size_t kDrainBudget = 64 * 1024;

/// Reads and throws away what the peer sent, adding to `drained`; false once it closed,
/// failed, or sent more than kDrainBudget.
bool drain(int fd, size_t& drained) {
    char scratch[4096];
    while (drained <= kDrainBudget) {
        ssize_t n = recv(fd, scratch, sizeof scratch, MSG_DONTWAIT);
        if (n > 0) {
            drained += static_cast<size_t>(n);
            continue;
        }
        return n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR);
    }
    return false;
}

}  // namespace

int classify_http_request(std::string_view head, bool& head_only) {
    head_only = false;
    std::vector<std::string_view> lines;
    while (!head.empty()) {
        size_t eol = head.find('\n');
        std::string_view line = head.substr(0, eol);
        if (!line.empty() && line.back() == '\r')
            line.remove_suffix(1);
        lines.push_back(line);
        head = eol == std::string_view::npos ? std::string_view() : head.substr(eol + 1);
    }
    while (!lines.empty() && lines.back().empty())
        lines.pop_back();
    if (lines.empty())
        return 400;
    // The request line: METHOD SP TARGET SP HTTP/1.x, nothing else.
    std::string_view rl = lines[0];
    size_t sp1 = rl.find(' ');
    size_t sp2 = sp1 == std::string_view::npos ? sp1 : rl.find(' ', sp1 + 1);
    if (sp2 == std::string_view::npos || rl.find(' ', sp2 + 1) != std::string_view::npos)
        return 400;
    std::string_view method = rl.substr(0, sp1);
    std::string_view target = rl.substr(sp1 + 1, sp2 - sp1 - 1);
    std::string_view version = rl.substr(sp2 + 1);
    if (!is_token(method) || target.empty() || target[0] != '/' ||
        (version != "HTTP/1.1" && version != "HTTP/1.0"))
        return 400;
    for (char c : target) {
        if (static_cast<unsigned char>(c) <= 0x20 || c == 0x7f)
            return 400;
    }
    bool has_host = false;
    for (size_t i = 1; i < lines.size(); i++) {
        size_t colon = lines[i].find(':');
        if (colon == std::string_view::npos || !is_token(lines[i].substr(0, colon)))
            return 400;
        std::string_view name = lines[i].substr(0, colon);
        has_host |= name.size() == 4 && strncasecmp(name.data(), "host", 4) == 0;
    }
    if (version == "HTTP/1.1" && !has_host)
        return 400;  // RFC 9112 3.2: a 1.1 request without Host is malformed
    std::string_view path = target.substr(0, target.find('?'));
    if (path != "/metrics")
        return 404;
    if (method == "HEAD")
        head_only = true;
    else if (method != "GET")
        return 405;
    return 200;
}

Result<std::unique_ptr<MetricsHttpServer>> MetricsHttpServer::open(const std::string& host,
                                                                   uint16_t port,
                                                                   const Limits& limits,
                                                                   EventLoop& loop,
                                                                   Producer producer) {
    std::string where = "metrics endpoint " + host + ":" + std::to_string(port);
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(port);
    if (inet_pton(AF_INET, host.c_str(), &addr.sin_addr) != 1)
        return make_error(where + ": not an IPv4 address");
    UniqueFd fd(socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(where + ": socket: " + strerror(errno));
    int one = 1;
    setsockopt(fd.get(), SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd.get(), reinterpret_cast<const sockaddr*>(&addr), sizeof addr) < 0)
        return make_error("cannot bind " + where + ": " + strerror(errno));
    if (listen(fd.get(), 16) < 0)
        return make_error("cannot listen on " + where + ": " + strerror(errno));
    socklen_t len = sizeof addr;
    getsockname(fd.get(), reinterpret_cast<sockaddr*>(&addr), &len);
    std::unique_ptr<MetricsHttpServer> s(
        new MetricsHttpServer(loop, std::move(fd), limits, std::move(producer)));
    s->port_ = ntohs(addr.sin_port);
    auto w = loop.watch(s->fd_.get(), EPOLLIN, [p = s.get()](uint32_t) { p->on_accept(); });
    if (!w)
        return w.error();
    s->accept_watch_ = std::move(w.value());
    log_info("metrics at http://%s:%u/metrics", host.c_str(), s->port_);
    return s;
}

MetricsHttpServer::MetricsHttpServer(EventLoop& loop, UniqueFd fd, const Limits& limits,
                                     Producer producer)
    : loop_(loop), fd_(std::move(fd)), limits_(limits), producer_(std::move(producer)) {}

MetricsHttpServer::~MetricsHttpServer() {
    connections_.clear();
    accept_watch_.reset();
}

void MetricsHttpServer::on_accept() {
    for (;;) {
        UniqueFd client(accept4(fd_.get(), nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC));
        if (!client) {
            if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
                // The pending connection stays queued and would wake the loop at once, again
                // and again: stop listening for a second instead of spinning.
                log_warning("metrics endpoint: accept: %s; pausing for 1s", strerror(errno));
                accept_watch_.set_events(0);
                accept_pause_ = loop_.schedule(seconds(1), [this] {
                    accept_watch_.set_events(EPOLLIN);
                    return Duration::zero();
                });
            }
            return;
        }
        if (connections_.size() >= limits_.max_connections) {
            refuse(std::move(client));
            continue;
        }
        auto c = std::make_unique<Connection>();
        Connection* raw = c.get();
        c->fd = std::move(client);
        c->request.reserve(limits_.max_request);
        auto w = loop_.watch(c->fd.get(), EPOLLIN | EPOLLRDHUP,
                             [this, raw](uint32_t events) { on_io(*raw, events); });
        if (!w) {
            log_warning("metrics endpoint: %s", w.error().message.c_str());
            continue;
        }
        c->watch = std::move(w.value());
        c->deadline = loop_.schedule(limits_.timeout, [this, raw] {
            timed_out_++;
            log_debug("metrics endpoint: a client timed out");
            close(*raw);
            return Duration::zero();
        });
        connections_.push_back(std::move(c));
    }
}

void MetricsHttpServer::refuse(UniqueFd client) {
    refused_++;
    static const std::string kBody = "too many connections\n";
    std::string reply = response_head(503, kBody.size()) + kBody;
    // A fresh socket's send buffer takes this whole: one non-blocking send, then closed.
    ssize_t n = send(client.get(), reply.data(), reply.size(), MSG_DONTWAIT | MSG_NOSIGNAL);
    (void)n;
    shutdown(client.get(), SHUT_WR);
    size_t drained = 0;
    drain(client.get(), drained);  // unread input would turn the close into a reset
    log_debug("metrics endpoint: %zu connections open, one refused", connections_.size());
}

void MetricsHttpServer::on_io(Connection& c, uint32_t events) {
    switch (c.state) {
    case Connection::State::Reading:
        read_request(c);
        return;
    case Connection::State::Writing:
        if (events & (EPOLLERR | EPOLLHUP))
            close(c);
        else
            write_response(c);
        return;
    case Connection::State::Closing:
        if (!drain(c.fd.get(), c.drained) || (events & (EPOLLERR | EPOLLHUP)))
            close(c);
        return;
    }
}

void MetricsHttpServer::read_request(Connection& c) {
    for (;;) {
        size_t room = limits_.max_request - c.request.size();
        if (room == 0) {
            start_response(c, 431, "request too large\n", false);
            return;
        }
        size_t old = c.request.size();
        c.request.resize(old + room);  // within the capacity reserved at accept
        ssize_t n = recv(c.fd.get(), c.request.data() + old, room, 0);
        c.request.resize(old + static_cast<size_t>(std::max<ssize_t>(n, 0)));
        if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
            close(c);  // gone before asking anything complete
            return;
        }
        if (n < 0)
            return;  // wait for more
        // The head ends at the first blank line; look from just before the new bytes.
        size_t from = old >= 3 ? old - 3 : 0;
        size_t end = c.request.find("\r\n\r\n", from);
        size_t lf = c.request.find("\n\n", old >= 1 ? old - 1 : 0);
        if (end != std::string::npos || lf != std::string::npos) {
            size_t cut = std::min(end == std::string::npos ? lf + 2 : end + 4,
                                  lf == std::string::npos ? end + 4 : lf + 2);
            c.request.resize(cut);
            answer(c);
            return;
        }
    }
}

void MetricsHttpServer::answer(Connection& c) {
    requests_++;
    bool head_only = false;
    int status = classify_http_request(c.request, head_only);
    std::string body;
    switch (status) {
    case 200: {
        MetricSet set = producer_();
        add_own_metrics(set);
        body = set.text();
        break;
    }
    case 404: body = "not found: the metrics are at /metrics\n"; break;
    case 405: body = "method not allowed: use GET\n"; break;
    default: body = "bad request\n"; break;
    }
    start_response(c, status, body, head_only);
}

void MetricsHttpServer::start_response(Connection& c, int status, const std::string& body,
                                       bool head_only) {
    log_debug("metrics endpoint: %d %s", status, reason(status));
    c.request = std::string();  // its memory back now, not at close
    c.response = response_head(status, body.size());
    if (!head_only)
        c.response += body;
    c.sent = 0;
    c.state = Connection::State::Writing;
    write_response(c);
}

void MetricsHttpServer::write_response(Connection& c) {
    while (c.sent < c.response.size()) {
        ssize_t n = send(c.fd.get(), c.response.data() + c.sent, c.response.size() - c.sent,
                         MSG_DONTWAIT | MSG_NOSIGNAL);
        if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            c.watch.set_events(EPOLLOUT);  // the client reads slowly: wait, its timeout runs
            return;
        }
        if (n < 0 && errno == EINTR)
            continue;
        if (n <= 0) {
            close(c);
            return;
        }
        c.sent += static_cast<size_t>(n);
    }
    // Sent: half-close, then read until the client closes too (or the timeout, or the drain
    // budget), so input still arriving never turns the close into a reset that loses the
    // response.
    c.response = std::string();
    shutdown(c.fd.get(), SHUT_WR);
    c.state = Connection::State::Closing;
    c.watch.set_events(EPOLLIN | EPOLLRDHUP);
    if (!drain(c.fd.get(), c.drained))
        close(c);
}

void MetricsHttpServer::close(Connection& c) {
    auto it = std::find_if(connections_.begin(), connections_.end(),
                           [&c](const auto& p) { return p.get() == &c; });
    if (it == connections_.end())
        return;
    // Destroyed after this round: `c` may be the object whose handler is running now.
    c.watch.reset();
    c.deadline.cancel();
    c.fd.reset();
    loop_.defer([owned = std::shared_ptr<Connection>(std::move(*it))] {});
    connections_.erase(it);
}

void MetricsHttpServer::add_own_metrics(MetricSet& set) const {
    set.counter("mavbond_metrics_http_requests",
                "Complete requests to the metrics endpoint (this one included).", requests_);
    set.counter("mavbond_metrics_http_refused",
                "Connections to the metrics endpoint refused (503): too many at once.", refused_);
    set.counter("mavbond_metrics_http_timeouts",
                "Connections to the metrics endpoint closed by their timeout.", timed_out_);
    set.gauge("mavbond_metrics_http_connections", "Connections open to the metrics endpoint.",
              static_cast<double>(connections_.size()));
}

}  // namespace mavbond
