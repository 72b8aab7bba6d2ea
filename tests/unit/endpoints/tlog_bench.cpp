// tlog_bench: what a tlog endpoint costs the event loop per frame. Routes the same frames
// through a Router to one sink, then to the sink and a tlog endpoint, and prints ns/frame for
// each and the difference (the loop's share: the router's delivery, the lend, one clock read
// per batch, the copy into the ring). The writer thread's disk work is not on the loop.
//
//   tlog_bench [FRAMES] [DIR]     (defaults: 200000 frames, a directory under /tmp)
// Between batches it sleeps (untimed) so the writer keeps up, as at any realistic rate.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "core/event_loop.h"
#include "endpoints/endpoint.h"
#include "endpoints/tlog_endpoint.h"
#include "routing/router.h"

namespace mavbond {
namespace {

constexpr size_t kBatch = 32;  // frames per receive batch, as a busy UDP read gives

class NullEndpoint : public Endpoint {
public:
    NullEndpoint(const EndpointConfig& config, EventLoop& loop)
        : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram) {}
    const char* kind() const override { return "null"; }

protected:
    int write_datagrams(const iovec*, size_t count) override { return static_cast<int>(count); }
};

/// ns per frame to route `frames` from `from` through `router`.
double route_ns(Router& router, Endpoint& from, const std::vector<Frame>& frames, size_t total) {
    using Steady = std::chrono::steady_clock;
    Steady::duration timed{};
    TimePoint now = Clock::now();
    ReceivedBatch batch(router);
    for (size_t done = 0; done < total; done += kBatch) {
        auto t0 = Steady::now();
        for (size_t i = 0; i < kBatch; i++)
            batch.add(frames[(done + i) % frames.size()], from, now, true);
        batch.submit();
        router.end_batch();
        timed += Steady::now() - t0;
        if (done % (kBatch * 64) == 0)
            std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return std::chrono::duration<double, std::nano>(timed).count() / static_cast<double>(total);
}

int run(size_t total, const std::string& dir) {
    auto loop = EventLoop::create();
    if (!loop) {
        std::fprintf(stderr, "%s\n", loop.error().message.c_str());
        return 1;
    }
    // A 40-byte v2 frame (ATTITUDE-sized), broadcast: it goes to every endpoint.
    std::vector<std::vector<uint8_t>> storage;
    std::vector<Frame> frames;
    for (int i = 0; i < 64; i++) {
        storage.emplace_back(40, static_cast<uint8_t>(i));
        storage.back()[0] = kMagicV2;
    }
    for (const auto& bytes : storage) {
        Frame f;
        f.bytes = bytes;
        f.version = 2;
        f.sysid = 1;
        f.compid = 1;
        f.msgid = 30;
        f.crc_checked = true;
        frames.push_back(f);
    }
    EndpointConfig src_cfg, sink_cfg, log_cfg;
    src_cfg.name = "source";
    sink_cfg.name = "sink";
    log_cfg.name = "bench";
    log_cfg.schema = &kTlogType;
    log_cfg.options.set("directory", OptionValue{.text = dir});
    Router router(*loop.value(), seconds(30));
    NullEndpoint source(src_cfg, **loop), sink(sink_cfg, **loop);
    router.attach(source);
    router.attach(sink);
    route_ns(router, source, frames, total / 4);  // warm up
    double base = route_ns(router, source, frames, total);
    double with_log;
    LinkCounters st;
    {
        auto log = TlogEndpoint::open(log_cfg, *loop.value(), router);
        route_ns(router, source, frames, total / 4);
        with_log = route_ns(router, source, frames, total);
        st = log->total_counters();
    }
    std::printf("frames %zu x 40 B, batches of %zu\n", total, kBatch);
    std::printf("router to one sink:            %6.1f ns/frame\n", base);
    std::printf("router to one sink + tlog:     %6.1f ns/frame\n", with_log);
    std::printf("tlog endpoint, loop side:      %6.1f ns/frame\n", with_log - base);
    std::printf("tlog tx_frames %llu, tx_dropped %llu, tx_errors %llu\n",
                static_cast<unsigned long long>(st.tx_frames),
                static_cast<unsigned long long>(st.tx_dropped),
                static_cast<unsigned long long>(st.tx_errors));
    router.detach(sink);
    router.detach(source);
    return 0;
}

}  // namespace
}  // namespace mavbond

int main(int argc, char** argv) {
    size_t total = argc > 1 ? std::strtoul(argv[1], nullptr, 10) : 200000;
    std::string dir = argc > 2 ? argv[2]
                               : (std::filesystem::temp_directory_path() / "tlog_bench").string();
    int code = mavbond::run(total, dir);
    std::printf("files in %s\n", dir.c_str());
    return code;
}
