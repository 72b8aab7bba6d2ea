// A flight log as an endpoint, a recorder: every frame routed (targeted frames included,
// wherever their target is) goes to .tlog files, each record an 8-byte big-endian timestamp
// (microseconds since the Unix epoch) then the frame, as MAVProxy and QGroundControl write.
//
// The loop's part is a copy into a bounded ring at the end of each batch, stamped with one
// clock read; TlogWriter's thread does the disk. When the ring is full, frames wait in the
// endpoint's transmit queue (tx_queue bytes) like on any slow link, and past that the oldest
// are dropped and counted (tx_dropped): the loop never waits for the disk. It never sends a
// frame into the sink.
#pragma once

#include <memory>

#include "core/event_loop.h"
#include "endpoints/endpoint.h"
#include "endpoints/tlog_writer.h"

namespace mavbond {

extern const EndpointSchema kTlogType;

class TlogEndpoint : public Endpoint {
public:
    static constexpr size_t kRingBytes = 1 << 20;

    static std::unique_ptr<TlogEndpoint> open(const EndpointConfig& config, EventLoop& loop,
                                              FrameSink& sink);
    /// Hands what waits to the writer (bounded), then the writer drains, fsyncs and closes.
    ~TlogEndpoint() override;
    const char* kind() const override { return "tlog"; }
    /// The loop's counters corrected by the writer's: frames lost to disk errors move from
    /// tx_frames to tx_dropped, failed writes count as tx_errors.
    LinkCounters total_counters() const override;

protected:
    int write_datagrams(const iovec* frames, size_t count) override;
    void on_backlog(bool backlog) override;

private:
    TlogEndpoint(const EndpointConfig& config, EventLoop& loop, FrameSink& sink);

    FrameSink& sink_;
    TlogWriter writer_;
    EventLoop::Timer retry_timer_;  // flushes the backlog while the ring is full
};

}  // namespace mavbond
