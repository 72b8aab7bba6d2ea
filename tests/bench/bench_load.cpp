// bench_load: the benchmark's load generator and receiver, in one process so that send and
// receive times come from one CLOCK_MONOTONIC.
//
//   bench_load --templates FILE --link HOST:PORT [--link HOST:PORT] --listen HOST:PORT
//              [--rate FRAMES_PER_S | --rate 0 --inflight K] [--seconds S | --frames N]
//              [--warmup-seconds W] [--pid PID] [--ready-timeout S]
//
// Frames: valid MAVLink v2 frames built before sending from the templates (one per line:
// `sysid compid msgid crc_extra payload-hex`, from a real recording, see run_bench.py). Frame i
// uses template i mod T, carries i as a little-endian uint32 in payload bytes 0..3 (so every
// frame is unique and the receiver knows which one arrived), the next sequence number of its
// (sysid, compid) and a correct CRC. Each frame is sent on every --link (the bond's members),
// in batches through sendmmsg: one socket per link.
//
// Phases: probe (one frame every 20 ms until one comes back: the relay is up), warm-up (W s
// at the rate), drain, then the measured phase (S s at the rate, or N frames), drain. The
// CPU time of --pid (every thread's first /proc/PID/task/TID/schedstat field: ns on CPU, user
// plus system) is read right before and after the measured phase; its VmHWM at the end.
// --rate 0 is closed loop: at most K frames in flight (sent, not yet delivered), for replays
// under valgrind where speed does not matter and loss would.
//
// Prints one JSON object: frames sent and delivered (first copy of each), duplicates
// received, latency percentiles of the first copy (ns), the send rate achieved, cpu_ns, and
// peak RSS. Exit 0, or 1 with a message (relay never came up).
#include <arpa/inet.h>
#include <dirent.h>
#include <netinet/in.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace {

using u64 = uint64_t;

[[noreturn]] void die(const std::string& what) {
    std::fprintf(stderr, "bench_load: %s\n", what.c_str());
    std::exit(1);
}

u64 now_ns() {
    timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return static_cast<u64>(ts.tv_sec) * 1'000'000'000u + static_cast<u64>(ts.tv_nsec);
}

void sleep_until(u64 t) {
    timespec ts{static_cast<time_t>(t / 1'000'000'000u), static_cast<long>(t % 1'000'000'000u)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
}

sockaddr_in parse_addr(const std::string& text) {
    auto colon = text.rfind(':');
    if (colon == std::string::npos)
        die("bad address " + text + " (HOST:PORT)");
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<uint16_t>(std::atoi(text.c_str() + colon + 1)));
    std::string host = text.substr(0, colon);
    if (host == "localhost")
        host = "127.0.0.1";
    if (inet_pton(AF_INET, host.c_str(), &a.sin_addr) != 1)
        die("bad host " + host);
    return a;
}

struct Template {
    uint8_t sysid, compid, crc_extra;
    uint32_t msgid;
    std::vector<uint8_t> payload;
};

std::vector<Template> read_templates(const std::string& path) {
    std::ifstream in(path);
    if (!in)
        die("cannot read " + path);
    std::vector<Template> out;
    std::string line;
    while (std::getline(in, line)) {
        if (line.empty() || line[0] == '#')
            continue;
        std::istringstream ss(line);
        unsigned sys, comp, extra;
        uint32_t msgid;
        std::string hex;
        if (!(ss >> sys >> comp >> msgid >> extra >> hex) || hex.size() % 2 || hex.size() < 8)
            die("bad template line: " + line);
        Template t{static_cast<uint8_t>(sys), static_cast<uint8_t>(comp),
                   static_cast<uint8_t>(extra), msgid, {}};
        for (size_t i = 0; i < hex.size(); i += 2)
            t.payload.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
        if (t.payload.size() > 255)
            die("payload too long: " + line);
        out.push_back(std::move(t));
    }
    if (out.empty())
        die("no templates in " + path);
    return out;
}

void crc_accumulate(uint8_t b, uint16_t& crc) {
    uint8_t tmp = b ^ static_cast<uint8_t>(crc & 0xff);
    tmp ^= static_cast<uint8_t>(tmp << 4);
    crc = static_cast<uint16_t>((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4));
}

/// Every frame of the run, built before the first send: one arena, one iovec per frame.
struct Frames {
    std::vector<uint8_t> arena;
    std::vector<iovec> iov;

    Frames(const std::vector<Template>& templates, size_t count) {
        size_t bytes = 0;
        for (size_t i = 0; i < count; i++)
            bytes += 12 + templates[i % templates.size()].payload.size();
        arena.resize(bytes);
        iov.resize(count);
        std::vector<uint8_t> seq(65536, 0);
        uint8_t* p = arena.data();
        for (size_t i = 0; i < count; i++) {
            const Template& t = templates[i % templates.size()];
            size_t len = t.payload.size();
            p[0] = 0xFD;
            p[1] = static_cast<uint8_t>(len);
            p[2] = 0;
            p[3] = 0;
            p[4] = seq[t.sysid << 8 | t.compid]++;
            p[5] = t.sysid;
            p[6] = t.compid;
            p[7] = static_cast<uint8_t>(t.msgid);
            p[8] = static_cast<uint8_t>(t.msgid >> 8);
            p[9] = static_cast<uint8_t>(t.msgid >> 16);
            std::memcpy(p + 10, t.payload.data(), len);
            auto idx = static_cast<uint32_t>(i);
            std::memcpy(p + 10, &idx, 4);  // little-endian hosts only (x86, arm)
            uint16_t crc = 0xFFFF;
            for (size_t k = 1; k < 10 + len; k++)
                crc_accumulate(p[k], crc);
            crc_accumulate(t.crc_extra, crc);
            p[10 + len] = static_cast<uint8_t>(crc & 0xff);
            p[11 + len] = static_cast<uint8_t>(crc >> 8);
            iov[i] = iovec{p, 12 + len};
            p += 12 + len;
        }
    }
};

/// CPU time of every thread of a process, in ns (user + system, scheduler accounting).
u64 cpu_ns(int pid) {
    u64 total = 0;
    std::string dir = "/proc/" + std::to_string(pid) + "/task";
    DIR* d = opendir(dir.c_str());
    if (!d)
        return 0;
    while (dirent* e = readdir(d)) {
        if (e->d_name[0] == '.')
            continue;
        std::ifstream f(dir + "/" + e->d_name + "/schedstat");
        u64 ns = 0;
        if (f >> ns)
            total += ns;
    }
    closedir(d);
    return total;
}

long vm_hwm_kb(int pid) {
    std::ifstream f("/proc/" + std::to_string(pid) + "/status");
    std::string line;
    while (std::getline(f, line))
        if (line.rfind("VmHWM:", 0) == 0)
            return std::atol(line.c_str() + 6);
    return -1;
}

struct Receiver {
    int fd = -1;
    std::vector<u64> recv_time;  // per frame index, 0 = not arrived
    std::atomic<u64> unique{0};
    std::atomic<u64> dups{0};
    std::atomic<u64> foreign{0};
    std::atomic<bool> stop{false};

    void run() {
        constexpr unsigned kBatch = 64;
        constexpr size_t kSlot = 2048;
        std::vector<uint8_t> buf(kBatch * kSlot);
        std::array<iovec, kBatch> iov{};
        std::array<mmsghdr, kBatch> msgs{};
        for (unsigned i = 0; i < kBatch; i++) {
            iov[i] = iovec{buf.data() + i * kSlot, kSlot};
            msgs[i].msg_hdr.msg_iov = &iov[i];
            msgs[i].msg_hdr.msg_iovlen = 1;
        }
        u64 n_unique = 0, n_dups = 0, n_foreign = 0;
        while (!stop.load(std::memory_order_relaxed)) {
            int n = recvmmsg(fd, msgs.data(), kBatch, MSG_WAITFORONE, nullptr);
            if (n <= 0)
                continue;  // SO_RCVTIMEO: look at the stop flag
            u64 t = now_ns();
            for (int m = 0; m < n; m++) {
                const uint8_t* p = buf.data() + static_cast<size_t>(m) * kSlot;
                size_t left = msgs[static_cast<size_t>(m)].msg_len;
                while (left >= 16) {
                    if (p[0] != 0xFD) {
                        n_foreign++;
                        break;
                    }
                    size_t flen = 12 + p[1] + ((p[2] & 1) ? 13 : 0);
                    if (flen > left || p[1] < 4) {
                        n_foreign++;
                        break;
                    }
                    uint32_t idx;
                    std::memcpy(&idx, p + 10, 4);
                    if (idx >= recv_time.size()) {
                        n_foreign++;
                    } else if (recv_time[idx] == 0) {
                        recv_time[idx] = t;
                        n_unique++;
                    } else {
                        n_dups++;
                    }
                    p += flen;
                    left -= flen;
                }
            }
            unique.store(n_unique, std::memory_order_release);
            dups.store(n_dups, std::memory_order_relaxed);
            foreign.store(n_foreign, std::memory_order_relaxed);
        }
    }
};

struct Sender {
    std::vector<int> fds;
    const Frames* frames = nullptr;
    std::vector<u64>* send_time = nullptr;
    std::array<mmsghdr, 64> msgs{};

    /// Sends frames [first, first+n) (n <= 64) on every link, stamping their send time.
    void send(size_t first, size_t n) {
        u64 t = now_ns();
        for (size_t k = 0; k < n; k++)
            (*send_time)[first + k] = t;
        for (int fd : fds) {
            for (size_t k = 0; k < n; k++) {
                msgs[k].msg_hdr = msghdr{};
                msgs[k].msg_hdr.msg_iov = const_cast<iovec*>(&frames->iov[first + k]);
                msgs[k].msg_hdr.msg_iovlen = 1;
            }
            size_t off = 0;
            while (off < n) {
                int sent = sendmmsg(fd, msgs.data() + off, static_cast<unsigned>(n - off), 0);
                if (sent < 0) {
                    if (errno == EINTR)
                        continue;
                    break;  // ECONNREFUSED before the relay is up: the frame is lost
                }
                off += static_cast<size_t>(sent);
            }
        }
    }

    /// Sends [first, last) paced at `rate` frames/s from now: every frame is sent as soon as
    /// it is due, together with the others that are due (never waiting to fill a batch).
    void paced(size_t first, size_t last, double rate) {
        u64 t0 = now_ns();
        double period = 1e9 / rate;
        size_t i = first;
        while (i < last) {
            u64 t = now_ns();
            auto due = first + static_cast<size_t>(static_cast<double>(t - t0) / period) + 1;
            due = std::min(due, last);
            if (due <= i) {
                sleep_until(t0 + static_cast<u64>(static_cast<double>(i - first) * period));
                continue;
            }
            size_t n = std::min<size_t>(due - i, 64);
            send(i, n);
            i += n;
        }
    }
};

/// Waits until every frame sent so far has arrived once, or nothing arrived for `quiet_ns`.
void drain(Receiver& rx, u64 expected, u64 quiet_ns, u64 max_ns) {
    u64 start = now_ns(), last_progress = start, seen = rx.unique.load();
    while (seen < expected) {
        sleep_until(now_ns() + 1'000'000);
        u64 s = rx.unique.load();
        u64 t = now_ns();
        if (s != seen) {
            seen = s;
            last_progress = t;
        }
        if (t - last_progress > quiet_ns || t - start > max_ns)
            break;
    }
}

u64 percentile(const std::vector<u64>& sorted, double q) {
    if (sorted.empty())
        return 0;
    auto k = static_cast<size_t>(q * static_cast<double>(sorted.size() - 1) + 0.5);
    return sorted[std::min(k, sorted.size() - 1)];
}

}  // namespace

int main(int argc, char** argv) {
    std::string templates_path, listen;
    std::vector<std::string> links;
    double rate = 1000, seconds = 2, warmup = 0.3, ready_timeout = 30;
    long frames_arg = -1, inflight = 8, pid = -1;
    for (int i = 1; i < argc; i++) {
        std::string a = argv[i];
        auto val = [&]() -> std::string {
            if (i + 1 >= argc)
                die("missing value for " + a);
            return argv[++i];
        };
        if (a == "--templates") templates_path = val();
        else if (a == "--link") links.push_back(val());
        else if (a == "--listen") listen = val();
        else if (a == "--rate") rate = std::stod(val());
        else if (a == "--seconds") seconds = std::stod(val());
        else if (a == "--frames") frames_arg = std::stol(val());
        else if (a == "--warmup-seconds") warmup = std::stod(val());
        else if (a == "--inflight") inflight = std::stol(val());
        else if (a == "--pid") pid = std::stol(val());
        else if (a == "--ready-timeout") ready_timeout = std::stod(val());
        else die("unknown option " + a + " (see the comment at the top of bench_load.cpp)");
    }
    if (templates_path.empty() || links.empty() || listen.empty())
        die("need --templates, --link and --listen");
    bool closed_loop = rate <= 0;
    if (closed_loop && frames_arg < 0)
        die("--rate 0 needs --frames");

    // Precise pacing: the default 50 us timer slack would bunch frames at 10k/s and more.
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);

    auto templates = read_templates(templates_path);
    constexpr size_t kProbes = 2000;
    size_t n_warm = closed_loop ? static_cast<size_t>(std::min<long>(frames_arg / 10 + 50, 2000))
                                : static_cast<size_t>(std::max(200.0, rate * warmup));
    size_t n_meas = frames_arg >= 0 ? static_cast<size_t>(frames_arg)
                                    : static_cast<size_t>(rate * seconds);
    size_t total = kProbes + n_warm + n_meas;
    Frames frames(templates, total);
    std::vector<u64> send_time(total, 0);

    Receiver rx;
    rx.recv_time.assign(total, 0);
    rx.fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    int big = 8 << 20;
    if (setsockopt(rx.fd, SOL_SOCKET, SO_RCVBUFFORCE, &big, sizeof big) < 0)
        setsockopt(rx.fd, SOL_SOCKET, SO_RCVBUF, &big, sizeof big);
    timeval tv{0, 20'000};
    setsockopt(rx.fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    sockaddr_in la = parse_addr(listen);
    int one = 1;
    setsockopt(rx.fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (bind(rx.fd, reinterpret_cast<sockaddr*>(&la), sizeof la) < 0)
        die("cannot bind " + listen + ": " + std::strerror(errno));

    Sender tx;
    tx.frames = &frames;
    tx.send_time = &send_time;
    for (auto& l : links) {
        int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        int sz = 4 << 20;
        if (setsockopt(fd, SOL_SOCKET, SO_SNDBUFFORCE, &sz, sizeof sz) < 0)
            setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sz, sizeof sz);
        sockaddr_in a = parse_addr(l);
        if (connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) < 0)
            die("cannot connect to " + l);
        tx.fds.push_back(fd);
    }

    std::thread rthread([&] { rx.run(); });

    // Probe: the relay (or mavbond under valgrind) may still be starting.
    size_t next = 0;
    u64 probe_deadline = now_ns() + static_cast<u64>(ready_timeout * 1e9);
    while (rx.unique.load() == 0) {
        if (next >= kProbes || now_ns() > probe_deadline) {
            rx.stop = true;
            rthread.join();
            die("nothing came back from the relay under test");
        }
        tx.send(next++, 1);
        sleep_until(now_ns() + 20'000'000);
    }
    u64 quiet = closed_loop ? 2'000'000'000ull : 100'000'000ull;
    drain(rx, next, quiet, 5'000'000'000ull);
    size_t probes_sent = next;
    next = kProbes;

    auto closed = [&](size_t first, size_t last) {
        // At most `inflight` frames sent and not delivered; a frame that never comes back
        // stops the window for 200 ms, then counts as lost.
        u64 allowance = 0, d0 = rx.unique.load(), last_seen = d0, last_progress = now_ns();
        for (size_t i = first; i < last;) {
            u64 delivered = rx.unique.load();
            u64 done = std::min<u64>(delivered - d0, i - first);
            if ((i - first) - done < static_cast<u64>(inflight) + allowance) {
                tx.send(i, 1);
                i++;
                continue;
            }
            u64 t = now_ns();
            if (delivered != last_seen) {
                last_seen = delivered;
                last_progress = t;
            } else if (t - last_progress > 200'000'000ull) {
                allowance++;
                last_progress = t;
            }
            sleep_until(t + 20'000);
        }
    };

    // Warm-up, drain, measured phase, drain.
    if (closed_loop)
        closed(next, next + n_warm);
    else
        tx.paced(next, next + n_warm, rate);
    next += n_warm;
    drain(rx, probes_sent + n_warm, quiet, 5'000'000'000ull);

    size_t m0 = next, m1 = next + n_meas;
    u64 cpu0 = pid > 0 ? cpu_ns(static_cast<int>(pid)) : 0;
    u64 dups0 = rx.dups.load();
    u64 t_start = now_ns();
    if (closed_loop)
        closed(m0, m1);
    else
        tx.paced(m0, m1, rate);
    u64 t_sent = now_ns();
    drain(rx, probes_sent + n_warm + n_meas, quiet, 10'000'000'000ull);
    u64 cpu1 = pid > 0 ? cpu_ns(static_cast<int>(pid)) : 0;
    long hwm = pid > 0 ? vm_hwm_kb(static_cast<int>(pid)) : -1;
    // Late copies (the second copy of the last frames) may still be on their way.
    sleep_until(now_ns() + 20'000'000);
    rx.stop = true;
    rthread.join();

    std::vector<u64> lat;
    lat.reserve(n_meas);
    for (size_t i = m0; i < m1; i++)
        if (rx.recv_time[i] != 0)
            lat.push_back(rx.recv_time[i] > send_time[i] ? rx.recv_time[i] - send_time[i] : 0);
    u64 delivered = lat.size();
    std::sort(lat.begin(), lat.end());
    double mean = 0;
    for (u64 v : lat)
        mean += static_cast<double>(v);
    mean = lat.empty() ? 0 : mean / static_cast<double>(lat.size());
    double span = n_meas > 1 ? static_cast<double>(send_time[m1 - 1] - send_time[m0]) / 1e9 : 0;
    double achieved = span > 0 ? static_cast<double>(n_meas - 1) / span : 0;
    u64 bytes = 0;
    for (size_t i = m0; i < m1; i++)
        bytes += frames.iov[i].iov_len;

    std::printf(
        "{\"rate\": %.1f, \"links\": %zu, \"sent\": %zu, \"delivered\": %" PRIu64
        ", \"duplicates\": %" PRIu64 ", \"foreign\": %" PRIu64
        ", \"loss\": %.6f, \"achieved_rate\": %.1f, \"send_seconds\": %.4f, "
        "\"mean_frame_bytes\": %.2f, \"lat_p50_ns\": %" PRIu64 ", \"lat_p99_ns\": %" PRIu64
        ", \"lat_max_ns\": %" PRIu64 ", \"lat_mean_ns\": %.0f, \"cpu_ns\": %" PRIu64
        ", \"vm_hwm_kb\": %ld, \"probes\": %zu, \"warmup\": %zu, \"total_delivered\": %" PRIu64
        "}\n",
        closed_loop ? 0.0 : rate, links.size(), n_meas, delivered, rx.dups.load() - dups0,
        rx.foreign.load(),
        n_meas ? 1.0 - static_cast<double>(delivered) / static_cast<double>(n_meas) : 0.0,
        achieved, static_cast<double>(t_sent - t_start) / 1e9,
        n_meas ? static_cast<double>(bytes) / static_cast<double>(n_meas) : 0.0,
        percentile(lat, 0.50), percentile(lat, 0.99), lat.empty() ? 0 : lat.back(), mean,
        cpu1 - cpu0, hwm, probes_sent, n_warm, rx.unique.load());
    return 0;
}
