// bench_relay: the bare relay the benchmark compares mavbond against. The least a UDP relay
// can do: one thread, one epoll loop, recvmmsg a batch from whichever of its input sockets is
// readable and sendmmsg that batch, unparsed and unfiltered, to one output. Every datagram
// received is forwarded, so with two bonded links it forwards both copies of each frame.
//
//   bench_relay --in HOST:PORT --in HOST:PORT ... --out HOST:PORT
//
// It reads one batch per readiness event (as mavbond does), with the same receive buffer size
// (2 MiB, forced past rmem_max when privileged). SIGINT/SIGTERM: exit 0.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/epoll.h>
#include <sys/signalfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

constexpr unsigned kBatch = 64;
constexpr size_t kSlot = 2048;

[[noreturn]] void die(const std::string& what) {
    std::fprintf(stderr, "bench_relay: %s: %s\n", what.c_str(), std::strerror(errno));
    std::exit(1);
}

sockaddr_in parse_addr(const std::string& text) {
    auto colon = text.rfind(':');
    if (colon == std::string::npos) {
        std::fprintf(stderr, "bench_relay: bad address %s (HOST:PORT)\n", text.c_str());
        std::exit(64);
    }
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(std::atoi(text.c_str() + colon + 1)));
    std::string host = text.substr(0, colon);
    if (host == "localhost")
        host = "127.0.0.1";
    if (inet_pton(AF_INET, host.c_str(), &a.sin_addr) != 1) {
        std::fprintf(stderr, "bench_relay: bad host %s\n", host.c_str());
        std::exit(64);
    }
    return a;
}

int udp_socket() {
    int fd = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0)
        die("socket");
    int size = 2 << 20;  // as mavbond's make_socket
    if (setsockopt(fd, SOL_SOCKET, SO_RCVBUFFORCE, &size, sizeof size) < 0)
        setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
    return fd;
}

}  // namespace

int main(int argc, char** argv) {
    std::vector<sockaddr_in> ins;
    sockaddr_in out{};
    bool have_out = false;
    for (int i = 1; i < argc; i++) {
        std::string a = argv[i];
        if (a == "--in" && i + 1 < argc) {
            ins.push_back(parse_addr(argv[++i]));
        } else if (a == "--out" && i + 1 < argc) {
            out = parse_addr(argv[++i]);
            have_out = true;
        } else {
            std::fprintf(stderr, "usage: bench_relay --in HOST:PORT [--in HOST:PORT ...] --out HOST:PORT\n");
            return 64;
        }
    }
    if (ins.empty() || !have_out) {
        std::fprintf(stderr, "usage: bench_relay --in HOST:PORT [--in HOST:PORT ...] --out HOST:PORT\n");
        return 64;
    }

    int ep = epoll_create1(EPOLL_CLOEXEC);
    if (ep < 0)
        die("epoll_create1");
    std::vector<int> in_fds;
    for (auto& a : ins) {
        int fd = udp_socket();
        int one = 1;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) < 0)
            die("bind");
        epoll_event ev{};
        ev.events = EPOLLIN;
        ev.data.fd = fd;
        if (epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev) < 0)
            die("epoll_ctl");
        in_fds.push_back(fd);
    }
    int out_fd = udp_socket();
    if (connect(out_fd, reinterpret_cast<const sockaddr*>(&out), sizeof out) < 0)
        die("connect");

    sigset_t mask;
    sigemptyset(&mask);
    sigaddset(&mask, SIGINT);
    sigaddset(&mask, SIGTERM);
    sigprocmask(SIG_BLOCK, &mask, nullptr);
    int sfd = signalfd(-1, &mask, SFD_CLOEXEC);
    if (sfd < 0)
        die("signalfd");
    epoll_event sev{};
    sev.events = EPOLLIN;
    sev.data.fd = sfd;
    epoll_ctl(ep, EPOLL_CTL_ADD, sfd, &sev);

    std::vector<uint8_t> arena(kBatch * kSlot);
    std::array<iovec, kBatch> iov{};
    std::array<mmsghdr, kBatch> rx{};
    std::array<mmsghdr, kBatch> tx{};
    for (unsigned i = 0; i < kBatch; i++) {
        iov[i] = iovec{arena.data() + i * kSlot, kSlot};
        rx[i].msg_hdr.msg_iov = &iov[i];
        rx[i].msg_hdr.msg_iovlen = 1;
    }
    std::array<iovec, kBatch> out_iov{};
    for (unsigned i = 0; i < kBatch; i++) {
        tx[i].msg_hdr.msg_iov = &out_iov[i];
        tx[i].msg_hdr.msg_iovlen = 1;
    }
    std::fprintf(stderr, "bench_relay: ready\n");

    std::array<epoll_event, 8> events{};
    for (;;) {
        int n = epoll_wait(ep, events.data(), static_cast<int>(events.size()), -1);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            die("epoll_wait");
        }
        for (int e = 0; e < n; e++) {
            int fd = events[static_cast<size_t>(e)].data.fd;
            if (fd == sfd)
                return 0;
            int got = recvmmsg(fd, rx.data(), kBatch, MSG_DONTWAIT, nullptr);
            if (got <= 0)
                continue;
            for (int i = 0; i < got; i++) {
                auto k = static_cast<size_t>(i);
                out_iov[k] = iovec{iov[k].iov_base, rx[k].msg_len};
            }
            int off = 0;
            while (off < got) {
                int sent = sendmmsg(out_fd, tx.data() + off, static_cast<unsigned>(got - off),
                                    MSG_DONTWAIT | MSG_NOSIGNAL);
                if (sent <= 0)
                    break;  // the output would block: drop the rest, as a full queue would
                off += sent;
            }
        }
    }
}
