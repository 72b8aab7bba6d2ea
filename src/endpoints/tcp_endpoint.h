// TCP endpoints. A server accepts clients (up to 32, max_clients_per_address from one address),
// each an endpoint (and route target) until it disconnects or brings no valid frame for
// idle_timeout. A client connects without blocking the loop and reconnects with backoff.
#pragma once

#include <netinet/in.h>

#include <memory>
#include <vector>

#include "core/log_budget.h"
#include "endpoints/net.h"
#include "endpoints/stream_endpoint.h"

namespace mavbond {

extern const EndpointSchema kTcpServerType;
extern const EndpointSchema kTcpClientType;

class TcpServer;

/// One accepted client of a TcpServer.
class TcpConnection : public StreamEndpoint {
public:
    TcpConnection(TcpServer& server, const SocketAddress& peer, TimePoint now);
    ~TcpConnection() override;
    const char* kind() const override { return "tcp-conn"; }
    Result<void> start(UniqueFd fd) { return start_stream(std::move(fd)); }
    const SocketAddress& peer() const { return peer_; }
    TimePoint connected_at() const { return connected_at_; }
    /// Closes the connection (the server forgets it after this round).
    void close(const std::string& reason);

protected:
    void on_disconnect(const std::string& reason) override;

private:
    TcpServer& server_;
    SocketAddress peer_;
    TimePoint connected_at_;
};

class TcpServer : public Endpoint {
public:
    static Result<std::unique_ptr<TcpServer>> open(const EndpointConfig& config, EventLoop& loop,
                                                   FrameSink& sink, UnknownIdPolicy policy);
    ~TcpServer() override;
    const char* kind() const override { return "tcp-server"; }
    LinkCounters total_counters() const override;
    void for_each_link(const std::function<void(const Link&)>& f) const override {
        for (const auto& c : clients_)
            f(*c);
    }
    void finish(TimePoint deadline) override;
    void retune(const TxBudgetConfig& budget) override;
    void set_marker_source(uint8_t sysid, uint8_t compid) override;

private:
    friend class TcpConnection;
    TcpServer(const EndpointConfig& config, EventLoop& loop, FrameSink& sink, UnknownIdPolicy policy,
              UniqueFd fd);
    void on_accept();
    /// Forgets a client after the current dispatch round (it may be inside its own handler).
    void drop_client(TcpConnection& client);
    /// Closes the clients that brought no valid frame for idle_timeout.
    void close_idle_clients();

    static constexpr size_t kMaxClients = 32;
    FrameSink& sink_;
    UnknownIdPolicy policy_;
    UniqueFd fd_;
    EventLoop::Watch watch_;
    EventLoop::Timer idle_timer_;
    std::vector<std::unique_ptr<TcpConnection>> clients_;
    LinkCounters retired_;
    LogBudget client_log_{20, seconds(10)};  // clients connected and gone
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
