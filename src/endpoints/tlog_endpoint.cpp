#include "endpoints/tlog_endpoint.h"

#include <array>
#include <ctime>
#include <thread>

namespace mavbond {
namespace {

constexpr EndpointOption kTlogOptions[] = {
    {"directory", OptionKind::Text, nullptr,
     "Where the files go. Created with its parents until it has existed once; a directory that "
     "vanishes later is an error, not recreated.", true},
    {"max_size", OptionKind::Size, "0",
     "A new file before the current one passes this many bytes (64MiB, 1GiB; at least 4KiB); "
     "0: no limit.", false, 4096},
};

}  // namespace

// A log only takes what is routed to it: nothing comes in, it is no link of a bond.
const EndpointSchema kTlogType = {
    "tlog", nullptr,
    "A flight log: every routed frame, targeted frames included, goes to .tlog files (each "
    "record an 8-byte big-endian timestamp in microseconds since the Unix epoch, then the frame, "
    "as MAVProxy and QGroundControl write them), named from the wall clock in UTC "
    "(2026-11-21_14-03-07.tlog; _001 and up when taken, never overwritten). A new file at each "
    "start, before max_size would be passed, and when an autopilot (component 1) reboots: its "
    "SYSTEM_TIME.time_boot_ms goes back by more than 5 s. A writer thread does the disk work; "
    "when it falls behind, frames wait in tx_queue and past it are dropped and counted "
    "(tx_dropped). Disk errors drop the frames they hit, counted, and are logged once per change "
    "of state; routing goes on. Besides its own options it takes only name, type, tx_queue, "
    "allow_out and block_out.",
    kTlogOptions, false};

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
    : Endpoint(config, config.name, loop, TxQueue::Mode::Datagram, nullptr, Role::Recorder),
      sink_(sink),
      writer_(config.name, config.options.text("directory"), config.options.number("max_size"),
              kRingBytes) {}

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
