// A serial port in raw mode at any baud rate (standard or not, through termios2/BOTHER), with
// optional RTS/CTS. A device missing at start or unplugged later is reopened with backoff
// while the daemon keeps running; each state change is logged once.
#pragma once

#include "endpoints/stream_endpoint.h"

namespace mavbond {

extern const EndpointSchema kUartType;

class UartEndpoint : public StreamEndpoint {
public:
    static std::unique_ptr<UartEndpoint> open(const EndpointConfig& config, EventLoop& loop,
                                              FrameSink& sink, UnknownIdPolicy policy);
    ~UartEndpoint() override;
    const char* kind() const override { return "uart"; }

protected:
    void on_disconnect(const std::string& reason) override;

private:
    UartEndpoint(const EndpointConfig& config, EventLoop& loop, FrameSink& sink,
                 UnknownIdPolicy policy);
    void try_open();
    void retry_later(const std::string& reason);

    Backoff backoff_;
    EventLoop::Timer retry_timer_;
    bool failing_logged_ = false;
};

/// Opens and configures a serial device (raw, 8N1, `baud`, optional RTS/CTS). Exposed for tests.
Result<UniqueFd> open_serial(const std::string& device, uint32_t baud, bool flow_control);

}  // namespace mavbond
