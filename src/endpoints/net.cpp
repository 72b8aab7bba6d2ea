#include "endpoints/net.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <linux/sock_diag.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>
#include <cstdint>
#include <cstring>

#include "core/log.h"

namespace mavbond {

std::string errno_text(int err) { return strerror(err); }

Result<sockaddr_in> resolve_ipv4(const std::string& host, uint16_t port) {
    sockaddr_in addr{};
    addr.sin_family = AF_INET;
    addr.sin_port = htons(port);
    if (inet_pton(AF_INET, host.c_str(), &addr.sin_addr) == 1)
        return addr;
    addrinfo hints{};
    hints.ai_family = AF_INET;
    addrinfo* res = nullptr;
    int rc = getaddrinfo(host.c_str(), nullptr, &hints, &res);
    if (rc != 0 || !res)
        return make_error("cannot resolve '" + host + "': " + gai_strerror(rc));
    addr.sin_addr = reinterpret_cast<sockaddr_in*>(res->ai_addr)->sin_addr;
    freeaddrinfo(res);
    return addr;
}

std::string to_string(const sockaddr_in& addr) {
    char text[INET_ADDRSTRLEN] = "?";
    inet_ntop(AF_INET, &addr.sin_addr, text, sizeof text);
    return std::string(text) + ":" + std::to_string(ntohs(addr.sin_port));
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

Result<UniqueFd> make_socket(int type, size_t rx_buffer, const std::string& name) {
    UniqueFd fd(socket(AF_INET, type | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(std::string("socket: ") + strerror(errno));
    if (type == SOCK_DGRAM)
        set_up_datagram_socket(fd.get(), rx_buffer, name);
    return fd;
}

Result<BoundSocket> bind_socket(int type, const std::string& host, uint16_t port,
                                size_t rx_buffer, const std::string& name) {
    auto addr = resolve_ipv4(host, port);
    if (!addr)
        return addr.error();
    auto fd = make_socket(type, rx_buffer, name);
    if (!fd)
        return fd.error();
    int one = 1;
    setsockopt(fd->get(), SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd->get(), reinterpret_cast<const sockaddr*>(&*addr), sizeof(sockaddr_in)) < 0)
        return make_error("cannot bind " + to_string(*addr) + ": " + errno_text(errno));
    return BoundSocket{std::move(fd.value()), *addr};
}

}  // namespace mavbond
