#include "endpoints/net.h"

#include <arpa/inet.h>
#include <netdb.h>
#include <sys/socket.h>

#include <cerrno>
#include <cstring>

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

Result<UniqueFd> make_socket(int type) {
    UniqueFd fd(socket(AF_INET, type | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
    if (!fd)
        return make_error(std::string("socket: ") + strerror(errno));
    if (type == SOCK_DGRAM) {
        // A link that bursts hundreds of datagrams (a replay, a radio flushing its buffer)
        // must not overflow the default ~200 KiB. Forced past rmem_max when privileged.
        int size = 2 << 20;
        if (setsockopt(fd.get(), SOL_SOCKET, SO_RCVBUFFORCE, &size, sizeof size) < 0)
            setsockopt(fd.get(), SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
    }
    return fd;
}

Result<BoundSocket> bind_socket(int type, const std::string& host, uint16_t port) {
    auto addr = resolve_ipv4(host, port);
    if (!addr)
        return addr.error();
    auto fd = make_socket(type);
    if (!fd)
        return fd.error();
    int one = 1;
    setsockopt(fd->get(), SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(fd->get(), reinterpret_cast<const sockaddr*>(&*addr), sizeof(sockaddr_in)) < 0)
        return make_error("cannot bind " + to_string(*addr) + ": " + errno_text(errno));
    return BoundSocket{std::move(fd.value()), *addr};
}

}  // namespace mavbond
