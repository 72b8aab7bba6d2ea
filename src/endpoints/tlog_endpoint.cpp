#include "endpoints/tlog_endpoint.h"

#include <array>
#include <ctime>
#include <thread>


namespace mavbond {
namespace {

constexpr Duration kBacklogRetry = milliseconds(10);
constexpr int kShutdownTries = 200;  // x kBacklogRetry: at most 2 s for the last backlog

std::array<uint8_t, TlogWriter::kTimestampBytes> wall_clock_stamp() {
    timespec ts{};
    clock_gettime(CLOCK_REALTIME, &ts);
    uint64_t us = static_cast<uint64_t>(ts.tv_sec) * 1'000'000 +
                  static_cast<uint64_t>(ts.tv_nsec) / 1'000;
    std::array<uint8_t, TlogWriter::kTimestampBytes> be;
    for (size_t i = 0; i < be.size(); i++)
        be[i] = static_cast<uint8_t>(us >> (8 * (be.size() - 1 - i)));
    return be;
}

}  // namespace

std::unique_ptr<TlogEndpoint> TlogEndpoint::open(const EndpointConfig& config, EventLoop& loop,
                                                 FrameSink& sink) {
    std::unique_ptr<TlogEndpoint> log(new TlogEndpoint(config, loop, sink));
    sink.attach(*log);
    return log;
}

TlogEndpoint::TlogEndpoint(const EndpointConfig& config, EventLoop& loop, FrameSink& sink)
    : Endpoint(config, config.name, TxQueue::Mode::Datagram, nullptr, Role::Recorder),
      loop_(loop), sink_(sink),
      writer_(config.name, config.directory, config.max_size, kRingBytes) {}

TlogEndpoint::~TlogEndpoint() {
    sink_.detach(*this);
    for (int i = 0; i < kShutdownTries && has_pending(); i++) {
        writer_.wake();
        std::this_thread::sleep_for(kBacklogRetry);
        flush();
    }
}

LinkCounters TlogEndpoint::total_counters() const {
    LinkCounters s = stats_;
    TlogWriter::Counters c = writer_.counters();
    s.tx_frames -= c.frames_lost;
    s.tx_bytes -= c.bytes_lost;
    s.tx_dropped += c.frames_lost;
    s.tx_errors += c.write_errors;
    return s;
}

int TlogEndpoint::write_datagrams(const iovec* frames, size_t count) {
    // One clock read per batch: the frames of a batch arrived together.
    auto stamp = wall_clock_stamp();
    size_t n = 0;
    while (n < count &&
           writer_.push(stamp, {static_cast<const uint8_t*>(frames[n].iov_base), frames[n].iov_len}))
        n++;
    writer_.pushed();
    return static_cast<int>(n);
}

void TlogEndpoint::on_backlog(bool backlog) {
    if (!backlog || retry_timer_.active())
        return;
    writer_.wake();
    retry_timer_ = loop_.schedule(kBacklogRetry, [this] {
        flush();
        return has_pending() ? kBacklogRetry : Duration::zero();
    });
}

}  // namespace mavbond
