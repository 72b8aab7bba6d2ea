#include "config/listeners.h"

#include <arpa/inet.h>

#include <algorithm>
#include <array>
#include <optional>

namespace mavbond {
namespace {

/// A literal's family and bytes (IPv4 in the first 4), or nullopt for a name.
struct Literal {
    int family;
    std::array<uint8_t, 16> bytes{};
    bool any() const {
        return std::all_of(bytes.begin(), bytes.end(), [](uint8_t b) { return b == 0; });
    }
};

std::optional<Literal> literal(const std::string& host) {
    Literal l{AF_INET};
    if (inet_pton(AF_INET, host.c_str(), l.bytes.data()) == 1)
        return l;
    l.family = AF_INET6;
    if (inet_pton(AF_INET6, host.c_str(), l.bytes.data()) == 1)
        return l;
    return std::nullopt;
}

}  // namespace

bool listen_addresses_overlap(const std::string& host_a, uint16_t port_a,
                              const std::string& host_b, uint16_t port_b) {
    if (port_a != port_b)
        return false;
    auto a = literal(host_a), b = literal(host_b);
    if (!a || !b)
        return host_a == host_b;
    // [::] listens dual stack (src/endpoints/net.cpp): every IPv4 and IPv6 address.
    if ((a->family == AF_INET6 && a->any()) || (b->family == AF_INET6 && b->any()))
        return true;
    if (a->family != b->family)
        return false;
    return a->any() || b->any() || a->bytes == b->bytes;
}

}  // namespace mavbond
