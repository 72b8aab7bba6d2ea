// Small socket helpers shared by the UDP and TCP endpoints: one address type for IPv4 and IPv6,
// name resolution (blocking at startup for a server, off the loop for a client), sockets.
#pragma once

#include <netinet/in.h>
#include <sys/socket.h>

#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include "core/event_loop.h"
#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

/// An IPv4 or IPv6 address and port, as the kernel takes it. A value: no allocation.
class SocketAddress {
public:
    SocketAddress() = default;
    SocketAddress(const sockaddr* addr, socklen_t len);
    /// An IPv4 or IPv6 literal (no brackets, no name) and a port; empty when `host` is neither.
    static SocketAddress numeric(const std::string& host, uint16_t port);

    bool empty() const { return len_ == 0; }
    int family() const { return storage_.ss_family; }
    uint16_t port() const;
    void set_port(uint16_t port);
    const sockaddr* get() const { return reinterpret_cast<const sockaddr*>(&storage_); }
    socklen_t size() const { return len_; }
    /// For recvfrom/accept: the kernel fills it, then set_size() says how much it wrote.
    sockaddr* buffer() { return reinterpret_cast<sockaddr*>(&storage_); }
    static constexpr socklen_t capacity() { return sizeof(sockaddr_storage); }
    void set_size(socklen_t len) { len_ = len; }

    /// "192.0.2.1:14550", "[2001:db8::5]:14550"; an IPv4-mapped IPv6 address (a peer of a
    /// dual-stack server) as the IPv4 address it is.
    std::string to_string() const;
    /// The same address and port (what tells two peers apart).
    friend bool same_address(const SocketAddress& a, const SocketAddress& b);
    /// The same address, whatever the ports (one host's connections).
    friend bool same_host(const SocketAddress& a, const SocketAddress& b);

private:
    sockaddr_storage storage_{};
    socklen_t len_ = 0;
};

inline std::string to_string(const SocketAddress& addr) { return addr.to_string(); }

/// Resolves a host (an IPv4 or IPv6 literal or a name) and port: the first address
/// getaddrinfo prefers. Blocks on a name: for startup, or off the loop (NameResolver).
Result<SocketAddress> resolve(const std::string& host, uint16_t port, int socktype);
/// Whether `host` is an address literal (no name to look up).
bool is_numeric_host(const std::string& host);
/// "[::1]:14550" or "host:14550": how a host and port are written in the config.
std::string host_port_text(const std::string& host, uint16_t port);

/// Looks a name up on a thread of its own and tells the loop when it is done: getaddrinfo
/// blocks (seconds on a dead DNS server) and the loop never waits on it. One lookup at a
/// time. Destroying it never waits: a lookup still running finishes into nothing.
class NameResolver {
public:
    using Done = std::function<void(Result<SocketAddress>)>;
    NameResolver(EventLoop& loop, std::string host, uint16_t port, int socktype, Done done);
    ~NameResolver();
    NameResolver(const NameResolver&) = delete;
    NameResolver& operator=(const NameResolver&) = delete;

    /// Starts a lookup unless one is running; `done` is called on the loop with its result.
    Result<void> start();
    /// Starts one now and then every `every` (a client's resolve_interval: a dynamic DNS name
    /// moves); a later one that cannot start is tried again at the next.
    Result<void> start_every(Duration every);
    bool running() const { return running_; }
    const std::string& host() const { return host_; }
    /// Lookups started, and those that failed (counters).
    uint64_t lookups() const { return lookups_; }
    uint64_t failures() const { return failures_; }

private:
    struct Shared;  // what the lookup thread and the loop both hold
    void on_done();

    EventLoop& loop_;
    std::string host_;
    uint16_t port_;
    int socktype_;
    Done done_;
    std::shared_ptr<Shared> shared_;
    EventLoop::Watch watch_;
    EventLoop::Timer every_;
    bool running_ = false;
    uint64_t lookups_ = 0;
    uint64_t failures_ = 0;
};

/// A non-blocking, close-on-exec socket of `family`. A datagram socket gets a receive buffer
/// of `rx_buffer` bytes (as the kernel counts them) and stamps each datagram with its arrival
/// time and the socket's drop count; `name` names it in a warning when the kernel gives less.
Result<UniqueFd> make_socket(int family, int type, size_t rx_buffer = 0,
                             const std::string& name = "");
/// A socket of `type` bound to host:port, for the servers: a port in use is an error (a TCP
/// listener takes SO_REUSEADDR, for its old connections only; a UDP socket never shares). An
/// IPv6 wildcard (`[::]`) takes IPv4 peers too (dual stack).
struct BoundSocket {
    UniqueFd fd;
    SocketAddress addr;
};
Result<BoundSocket> bind_socket(int type, const std::string& host, uint16_t port,
                                size_t rx_buffer = 0, const std::string& name = "");
std::string errno_text(int err);
/// Datagrams the kernel dropped for this socket since it was made (its receive buffer full):
/// the socket's own counter (SO_MEMINFO), exact whenever it is read.
uint64_t socket_drops(int fd);

}  // namespace mavbond
