// Small socket helpers shared by the UDP and TCP endpoints.
#pragma once

#include <netinet/in.h>

#include <string>

#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

/// Resolves an IPv4 host (dotted quad or name) and port. Runs once at startup.
Result<sockaddr_in> resolve_ipv4(const std::string& host, uint16_t port);
std::string to_string(const sockaddr_in& addr);
inline bool same_address(const sockaddr_in& a, const sockaddr_in& b) {
    return a.sin_addr.s_addr == b.sin_addr.s_addr && a.sin_port == b.sin_port;
}
/// A non-blocking, close-on-exec socket. A datagram socket gets a receive buffer of
/// `rx_buffer` bytes (as the kernel counts them) and stamps each datagram with its arrival
/// time and the socket's drop count; `name` names it in a warning when the kernel gives less.
Result<UniqueFd> make_socket(int type, size_t rx_buffer = 0, const std::string& name = "");
/// A socket of `type` bound to host:port (SO_REUSEADDR), for the servers.
struct BoundSocket {
    UniqueFd fd;
    sockaddr_in addr;
};
Result<BoundSocket> bind_socket(int type, const std::string& host, uint16_t port,
                                size_t rx_buffer = 0, const std::string& name = "");
std::string errno_text(int err);
/// Datagrams the kernel dropped for this socket since it was made (its receive buffer full):
/// the socket's own counter (SO_MEMINFO), exact whenever it is read.
uint64_t socket_drops(int fd);

}  // namespace mavbond
