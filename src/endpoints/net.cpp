#include "endpoints/net.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <linux/sock_diag.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <mutex>
#include <optional>
#include <system_error>
#include <thread>

#include "core/log.h"

namespace mavbond {

std::string errno_text(int err) { return strerror(err); }

SocketAddress::SocketAddress(const sockaddr* addr, socklen_t len) {
    len_ = std::min<socklen_t>(len, sizeof storage_);
    std::memcpy(&storage_, addr, len_);
}

SocketAddress SocketAddress::numeric(const std::string& host, uint16_t port) {
    SocketAddress a;
    auto* v4 = reinterpret_cast<sockaddr_in*>(&a.storage_);
    auto* v6 = reinterpret_cast<sockaddr_in6*>(&a.storage_);
    if (inet_pton(AF_INET, host.c_str(), &v4->sin_addr) == 1) {
        v4->sin_family = AF_INET;
        v4->sin_port = htons(port);
        a.len_ = sizeof(sockaddr_in);
    } else if (inet_pton(AF_INET6, host.c_str(), &v6->sin6_addr) == 1) {
        v6->sin6_family = AF_INET6;
        v6->sin6_port = htons(port);
        a.len_ = sizeof(sockaddr_in6);
    } else {
        a = SocketAddress();
    }
    return a;
}

uint16_t SocketAddress::port() const {
    if (family() == AF_INET)
        return ntohs(reinterpret_cast<const sockaddr_in*>(&storage_)->sin_port);
    if (family() == AF_INET6)
        return ntohs(reinterpret_cast<const sockaddr_in6*>(&storage_)->sin6_port);
    return 0;
}

std::string SocketAddress::to_string() const {
    char text[INET6_ADDRSTRLEN] = "?";
    if (family() == AF_INET) {
        inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(&storage_)->sin_addr, text,
                  sizeof text);
        return std::string(text) + ":" + std::to_string(port());
    }
    if (family() == AF_INET6) {
        const in6_addr& a = reinterpret_cast<const sockaddr_in6*>(&storage_)->sin6_addr;
        // A dual-stack server sees an IPv4 peer as ::ffff:a.b.c.d: show it as what it is.
        if (IN6_IS_ADDR_V4MAPPED(&a)) {
            inet_ntop(AF_INET, &a.s6_addr[12], text, sizeof text);
            return std::string(text) + ":" + std::to_string(port());
        }
        inet_ntop(AF_INET6, &a, text, sizeof text);
        return "[" + std::string(text) + "]:" + std::to_string(port());
    }
    return "?";
}

bool same_address(const SocketAddress& a, const SocketAddress& b) {
    if (a.family() != b.family())
        return false;
    if (a.family() == AF_INET) {
        auto& x = *reinterpret_cast<const sockaddr_in*>(&a.storage_);
        auto& y = *reinterpret_cast<const sockaddr_in*>(&b.storage_);
        return x.sin_addr.s_addr == y.sin_addr.s_addr && x.sin_port == y.sin_port;
    }
    if (a.family() == AF_INET6) {
        auto& x = *reinterpret_cast<const sockaddr_in6*>(&a.storage_);
        auto& y = *reinterpret_cast<const sockaddr_in6*>(&b.storage_);
        return x.sin6_port == y.sin6_port && x.sin6_scope_id == y.sin6_scope_id &&
               std::memcmp(&x.sin6_addr, &y.sin6_addr, sizeof x.sin6_addr) == 0;
    }
    return a.len_ == b.len_;
}

bool same_host(const SocketAddress& a, const SocketAddress& b) {
    SocketAddress x = a, y = b;
    x.set_port(0);
    y.set_port(0);
    return same_address(x, y);
}

void SocketAddress::set_port(uint16_t port) {
    if (family() == AF_INET)
        reinterpret_cast<sockaddr_in*>(&storage_)->sin_port = htons(port);
    else if (family() == AF_INET6)
        reinterpret_cast<sockaddr_in6*>(&storage_)->sin6_port = htons(port);
}

bool is_numeric_host(const std::string& host) { return !SocketAddress::numeric(host, 0).empty(); }

std::string host_port_text(const std::string& host, uint16_t port) {
    bool v6 = host.find(':') != std::string::npos;
    return (v6 ? "[" + host + "]" : host) + ":" + std::to_string(port);
}

Result<SocketAddress> resolve(const std::string& host, uint16_t port, int socktype) {
    if (auto literal = SocketAddress::numeric(host, port); !literal.empty())
        return literal;
    addrinfo hints{};
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = socktype;
    addrinfo* res = nullptr;
    int rc = getaddrinfo(host.c_str(), std::to_string(port).c_str(), &hints, &res);
    if (rc != 0 || !res) {
        std::string why = rc == EAI_SYSTEM ? errno_text(errno) : gai_strerror(rc);
        if (res)
            freeaddrinfo(res);
        return make_error("cannot resolve '" + host + "': " + why);
    }
    // getaddrinfo sorts by RFC 6724 (gai.conf): its first choice is ours.
    SocketAddress addr(res->ai_addr, res->ai_addrlen);
    freeaddrinfo(res);
    return addr;
}

// --- NameResolver ----------------------------------------------------------------------------

struct NameResolver::Shared {
    UniqueFd event;  // written once per finished lookup
    std::mutex mutex;
    std::optional<Result<SocketAddress>> result;
};

NameResolver::NameResolver(EventLoop& loop, std::string host, uint16_t port, int socktype,
                           Done done)
    : loop_(loop), host_(std::move(host)), port_(port), socktype_(socktype),
      done_(std::move(done)) {}

NameResolver::~NameResolver() = default;  // a running lookup keeps `shared_` alive alone

Result<void> NameResolver::start() {
    if (running_)
        return {};
    if (!shared_) {
        auto shared = std::make_shared<Shared>();
        shared->event = UniqueFd(eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC));
        if (!shared->event)
            return make_error(std::string("eventfd: ") + errno_text(errno));
        auto w = loop_.watch(shared->event.get(), EPOLLIN, [this](uint32_t) { on_done(); });
        if (!w)
            return w.error();
        watch_ = std::move(w.value());
        shared_ = std::move(shared);
    }
    try {
        std::thread([shared = shared_, host = host_, port = port_, socktype = socktype_] {
            auto result = resolve(host, port, socktype);
            {
                std::lock_guard lock(shared->mutex);
                shared->result = std::move(result);
            }
            uint64_t one = 1;
            [[maybe_unused]] auto n = write(shared->event.get(), &one, sizeof one);
        }).detach();
    } catch (const std::system_error& e) {
        return make_error(std::string("cannot start a lookup thread: ") + e.what());
    }
    running_ = true;
    lookups_++;
    return {};
}

Result<void> NameResolver::start_every(Duration every) {
    if (auto r = start(); !r)
        return r;
    every_ = loop_.schedule(every, [this, every] {
        (void)start();
        return every;
    });
    return {};
}

void NameResolver::on_done() {
    uint64_t count = 0;
    [[maybe_unused]] auto n = read(shared_->event.get(), &count, sizeof count);
    std::optional<Result<SocketAddress>> result;
    {
        std::lock_guard lock(shared_->mutex);
        result.swap(shared_->result);
    }
    if (!result)
        return;
    running_ = false;
    if (!*result)
        failures_++;
    done_(std::move(*result));  // may start the next lookup, or destroy this resolver
}

namespace {

/// What a datagram socket needs: room for a stall's backlog, and arrival times.
void set_up_datagram_socket(int fd, size_t rx_buffer, const std::string& name) {
    // The kernel doubles what it is asked for (half is its bookkeeping), and counts the
    // bookkeeping against the buffer too: ask for half. Forced past net.core.rmem_max when
    // privileged; otherwise rmem_max caps it (the package raises it, see debian/).
    int half = static_cast<int>(std::min<size_t>(rx_buffer / 2, INT32_MAX / 2));
    if (setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &half, sizeof half) < 0)
        setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &half, sizeof half);
    int granted = 0;
    socklen_t len = sizeof granted;
    getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &granted, &len);
    if (static_cast<size_t>(granted) < rx_buffer)
        log_warning("[%s] rx_buffer: the kernel gave %d of %zu bytes (net.core.rmem_max caps an "
                    "unprivileged socket): a stall may overflow it",
                    name.c_str(), granted, rx_buffer);
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_TIMESTAMPNS, &one, sizeof one);
}

}  // namespace

uint64_t socket_drops(int fd) {
    uint32_t info[SK_MEMINFO_VARS] = {};
    socklen_t len = sizeof info;
    if (fd < 0 || getsockopt(fd, SOL_SOCKET, SO_MEMINFO, info, &len) < 0 ||
        len <= SK_MEMINFO_DROPS * sizeof(uint32_t))
        return 0;
    return info[SK_MEMINFO_DROPS];
}

Result<UniqueFd> make_socket(int family, int type, size_t rx_buffer, const std::string& name) {
    UniqueFd fd(socket(family, type | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(std::string("socket: ") + strerror(errno));
    if (type == SOCK_DGRAM)
        set_up_datagram_socket(fd.get(), rx_buffer, name);
    return fd;
}

Result<BoundSocket> bind_socket(int type, const std::string& host, uint16_t port,
                                size_t rx_buffer, const std::string& name) {
    auto addr = resolve(host, port, type);
    if (!addr)
        return addr.error();
    auto fd = make_socket(addr->family(), type, rx_buffer, name);
    if (!fd)
        return fd.error();
    // A listener may take its port back from connections of a daemon that just stopped
    // (TIME_WAIT). A UDP port has no such state, and SO_REUSEADDR there would let any local
    // user bind it too and take the datagrams meant for the daemon: never on UDP.
    if (type == SOCK_STREAM) {
        int one = 1;
        setsockopt(fd->get(), SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    }
    if (addr->family() == AF_INET6) {
        // [::] takes IPv4 peers too, whatever net.ipv6.bindv6only says; [::1] is IPv6 alone.
        int v6only = 0;
        setsockopt(fd->get(), IPPROTO_IPV6, IPV6_V6ONLY, &v6only, sizeof v6only);
    }
    if (bind(fd->get(), addr->get(), addr->size()) < 0) {
        int err = errno;
        std::string why = "cannot bind " + addr->to_string() + ": " + errno_text(err);
        if (err == EADDRINUSE)
            why += std::string(" (another process listens there: ss -") +
                   (type == SOCK_DGRAM ? "u" : "t") + "lpn 'sport = :" +
                   std::to_string(addr->port()) + "' names it)";
        return make_error(why);
    }
    return BoundSocket{std::move(fd.value()), *addr};
}

}  // namespace mavbond
