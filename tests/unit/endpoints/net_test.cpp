// SocketAddress (one address type for IPv4 and IPv6) and NameResolver (lookups off the loop),
// with the real resolver: names that resolve on any machine (localhost, an address literal) and
// one that cannot (the .invalid top-level domain, RFC 6761).
#include "endpoints/net.h"

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netdb.h>

#include <optional>

namespace mavbond {
namespace {

/// Whether this machine's own resolver (getaddrinfo, nothing of ours) knows "localhost": a
/// build chroot without /etc/hosts does not, and then there is nothing to hold resolve() to.
bool machine_resolves_localhost() {
    addrinfo* list = nullptr;
    int rc = getaddrinfo("localhost", nullptr, nullptr, &list);
    if (list)
        freeaddrinfo(list);
    return rc == 0;
}

#define SKIP_UNLESS_LOCALHOST_RESOLVES()                                                   \
    if (!machine_resolves_localhost())                                                     \
    GTEST_SKIP() << "getaddrinfo cannot resolve 'localhost' on this machine (no /etc/hosts?)"

TEST(SocketAddress, ReadsIpv4AndIpv6LiteralsAndNothingElse) {
    SocketAddress v4 = SocketAddress::numeric("192.0.2.1", 14550);
    ASSERT_FALSE(v4.empty());
    EXPECT_EQ(AF_INET, v4.family());
    EXPECT_EQ(14550, v4.port());
    EXPECT_EQ("192.0.2.1:14550", v4.to_string());
    EXPECT_EQ(sizeof(sockaddr_in), v4.size());

    SocketAddress v6 = SocketAddress::numeric("2001:db8::5", 14550);
    ASSERT_FALSE(v6.empty());
    EXPECT_EQ(AF_INET6, v6.family());
    EXPECT_EQ(14550, v6.port());
    EXPECT_EQ("[2001:db8::5]:14550", v6.to_string());
    EXPECT_EQ(sizeof(sockaddr_in6), v6.size());

    EXPECT_TRUE(SocketAddress::numeric("lte.example.net", 1).empty());
    EXPECT_TRUE(SocketAddress::numeric("[::1]", 1).empty());  // brackets are the config's
    EXPECT_TRUE(SocketAddress::numeric("300.1.2.3", 1).empty());
    EXPECT_TRUE(is_numeric_host("::1"));
    EXPECT_FALSE(is_numeric_host("localhost"));
}

TEST(SocketAddress, ShowsAnIpv4MappedPeerAsIpv4) {
    // What a dual-stack server ([::]) sees for an IPv4 peer.
    SocketAddress mapped = SocketAddress::numeric("::ffff:127.0.0.1", 5760);
    EXPECT_EQ(AF_INET6, mapped.family());
    EXPECT_EQ("127.0.0.1:5760", mapped.to_string());
}

TEST(SocketAddress, TellsAddressesApartByFamilyAddressAndPort) {
    auto a = SocketAddress::numeric("127.0.0.1", 1);
    EXPECT_TRUE(same_address(a, SocketAddress::numeric("127.0.0.1", 1)));
    EXPECT_FALSE(same_address(a, SocketAddress::numeric("127.0.0.1", 2)));
    EXPECT_FALSE(same_address(a, SocketAddress::numeric("127.0.0.2", 1)));
    EXPECT_FALSE(same_address(a, SocketAddress::numeric("::ffff:127.0.0.1", 1)));
    auto b = SocketAddress::numeric("::1", 1);
    EXPECT_TRUE(same_address(b, SocketAddress::numeric("::1", 1)));
    EXPECT_FALSE(same_address(b, SocketAddress::numeric("::2", 1)));
    EXPECT_FALSE(same_address(b, SocketAddress()));
}

TEST(SocketAddress, CopiesWhatTheKernelWrote) {
    sockaddr_in6 raw{};
    raw.sin6_family = AF_INET6;
    raw.sin6_port = htons(7);
    inet_pton(AF_INET6, "2001:db8::1", &raw.sin6_addr);
    SocketAddress a(reinterpret_cast<const sockaddr*>(&raw), sizeof raw);
    EXPECT_EQ("[2001:db8::1]:7", a.to_string());
    EXPECT_EQ("[::1]:14550", host_port_text("::1", 14550));
    EXPECT_EQ("lte.example.net:14550", host_port_text("lte.example.net", 14550));
}

TEST(Resolve, LooksUpNamesAndTakesLiteralsAsTheyAre) {
    auto literal = resolve("::1", 9, SOCK_DGRAM);
    ASSERT_TRUE(literal);
    EXPECT_EQ("[::1]:9", literal->to_string());
    auto bad = resolve("no-such-host.invalid", 9, SOCK_DGRAM);
    ASSERT_FALSE(bad);
    EXPECT_NE(std::string::npos, bad.error().message.find("cannot resolve 'no-such-host.invalid'"))
        << bad.error().message;
}

TEST(Resolve, LooksUpALocalName) {
    SKIP_UNLESS_LOCALHOST_RESOLVES();
    auto name = resolve("localhost", 9, SOCK_DGRAM);
    ASSERT_TRUE(name) << name.error().message;
    EXPECT_EQ(9, name->port());
}

TEST(BindSocket, TheIpv6WildcardTakesIpv4PeersToo) {
    auto bound = bind_socket(SOCK_DGRAM, "::", 0);
    ASSERT_TRUE(bound) << bound.error().message;
    SocketAddress local;
    socklen_t len = SocketAddress::capacity();
    ASSERT_EQ(0, getsockname(bound->fd.get(), local.buffer(), &len));
    local.set_size(len);
    // An IPv4 client sends to the dual-stack socket's port on 127.0.0.1.
    auto client = make_socket(AF_INET, SOCK_DGRAM);
    ASSERT_TRUE(client);
    auto to = SocketAddress::numeric("127.0.0.1", local.port());
    ASSERT_EQ(1, sendto(client->get(), "x", 1, 0, to.get(), to.size()));
    char byte = 0;
    SocketAddress from;
    socklen_t from_len = SocketAddress::capacity();
    ssize_t n = -1;
    for (int i = 0; i < 100 && n < 0; i++) {
        n = recvfrom(bound->fd.get(), &byte, 1, 0, from.buffer(), &from_len);
        if (n < 0)
            usleep(10000);
    }
    ASSERT_EQ(1, n);
    from.set_size(from_len);
    EXPECT_EQ(AF_INET6, from.family());
    EXPECT_EQ(0u, from.to_string().find("127.0.0.1:")) << from.to_string();
}

/// Runs the loop until `done` or 10 s of rounds (a lookup of localhost or .invalid answers
/// from /etc/hosts or at once).
template <typename F>
void run_until(EventLoop& loop, F done) {
    for (int i = 0; i < 200 && !done(); i++)
        loop.run_once(milliseconds(50));
}

TEST(NameResolver, AnswersOnTheLoopWithoutBlockingIt) {
    SKIP_UNLESS_LOCALHOST_RESOLVES();
    auto loop = EventLoop::create();
    ASSERT_TRUE(loop);
    std::optional<Result<SocketAddress>> got;
    NameResolver resolver(**loop, "localhost", 14550, SOCK_DGRAM,
                          [&](Result<SocketAddress> r) { got = std::move(r); });
    ASSERT_TRUE(resolver.start());
    EXPECT_TRUE(resolver.running());
    ASSERT_TRUE(resolver.start());  // one lookup at a time: a second start is a no-op
    EXPECT_EQ(1u, resolver.lookups());
    run_until(**loop, [&] { return got.has_value(); });
    ASSERT_TRUE(got.has_value());
    ASSERT_TRUE(*got) << got->error().message;
    EXPECT_EQ(14550, (*got)->port());
    EXPECT_FALSE(resolver.running());
}

TEST(NameResolver, AFailedLookupComesBackTheSameWayCounted) {
    auto loop = EventLoop::create();
    ASSERT_TRUE(loop);
    std::optional<Result<SocketAddress>> got;
    NameResolver bad(**loop, "no-such-host.invalid", 1, SOCK_DGRAM,
                     [&](Result<SocketAddress> r) { got = std::move(r); });
    ASSERT_TRUE(bad.start());
    run_until(**loop, [&] { return got.has_value(); });
    ASSERT_TRUE(got.has_value());
    EXPECT_FALSE(*got);
    EXPECT_EQ(1u, bad.failures());
}

TEST(NameResolver, GoingAwayDuringALookupNeitherWaitsNorCallsBack) {
    auto loop = EventLoop::create();
    ASSERT_TRUE(loop);
    bool called = false;
    {
        NameResolver resolver(**loop, "localhost", 1, SOCK_STREAM, [&](auto) { called = true; });
        ASSERT_TRUE(resolver.start());
    }
    // The lookup thread finishes into its own state; nothing reaches the loop.
    for (int i = 0; i < 20; i++)
        (*loop)->run_once(milliseconds(10));
    EXPECT_FALSE(called);
}

}  // namespace
}  // namespace mavbond
