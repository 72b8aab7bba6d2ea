// TCP endpoints. A server accepts clients, each an endpoint (and route target) until it
// disconnects. A client connects without blocking the loop and reconnects with backoff.
#pragma once

#include <netinet/in.h>

#include <memory>
#include <vector>

#include "endpoints/net.h"
#include "endpoints/stream_endpoint.h"

namespace mavbond {

extern const EndpointSchema kTcpServerType;
extern const EndpointSchema kTcpClientType;

class TcpServer;

/// One accepted client of a TcpServer.
class TcpConnection : public StreamEndpoint {
public:
    TcpConnection(TcpServer& server, const SocketAddress& peer);
    ~TcpConnection() override;
    const char* kind() const override { return "tcp-conn"; }
    Result<void> start(UniqueFd fd) { return start_stream(std::move(fd)); }

protected:
    void on_disconnect(const std::string& reason) override;

private:
    TcpServer& server_;
};

class TcpServer : public Endpoint {
public:
    static Result<std::unique_ptr<TcpServer>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~TcpServer() override;
    const char* kind() const override { return "tcp-server"; }
    LinkCounters total_counters() const override;
    void finish(TimePoint deadline) override;
    void retune(const TxBudgetConfig& budget) override;

private:
    friend class TcpConnection;
    TcpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              UniqueFd fd);
    void on_accept();
    /// Forgets a client after the current dispatch round (it may be inside its own handler).
    void drop_client(TcpConnection& client);

    static constexpr size_t kMaxClients = 32;
    FrameSink& sink_;
    UnknownIdPolicy policy_;
    UniqueFd fd_;
    EventLoop::Watch watch_;
    std::vector<std::unique_ptr<TcpConnection>> clients_;
    LinkCounters retired_;
};

class TcpClient : public StreamEndpoint {
public:
    static Result<std::unique_ptr<TcpClient>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~TcpClient() override;
    const char* kind() const override { return "tcp-client"; }

protected:
    void on_disconnect(const std::string& reason) override;

private:
    TcpClient(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              const SocketAddress& addr);
    void connect_now();
    void on_connecting(uint32_t events);
    void retry_later(const std::string& reason);
    void on_resolved(Result<SocketAddress> result);

    SocketAddress addr_;  // empty until a name resolves
    std::unique_ptr<NameResolver> resolver_;  // null for an address literal
    bool resolve_failing_logged_ = false;
    Backoff backoff_;
    UniqueFd connecting_fd_;
    EventLoop::Watch connecting_watch_;
    EventLoop::Timer retry_timer_;
    bool was_connected_ = false;
    bool failing_logged_ = false;
};

}  // namespace mavbond
