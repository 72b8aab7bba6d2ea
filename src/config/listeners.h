// Two servers cannot listen on one address: the kernel gives a UDP port to one socket (mavbond
// never shares it, see src/endpoints/net.cpp) and a TCP port to one listener. The loader refuses
// a config that declares two, at the second, naming the first.
#pragma once

#include <cstdint>
#include <string>

namespace mavbond {

/// Whether two listeners of one protocol, on `host_a`:`port_a` and `host_b`:`port_b` (hosts as
/// the config gives them: an IPv4 address, an IPv6 address without brackets or a name), take
/// one address: the same port, and the same host, or a wildcard covering the other's
/// (0.0.0.0 every IPv4 address; ::, dual stack, every address). Names are compared as written:
/// what they resolve to is known only at start (where a bind that fails is an error too).
bool listen_addresses_overlap(const std::string& host_a, uint16_t port_a,
                              const std::string& host_b, uint16_t port_b);

}  // namespace mavbond
