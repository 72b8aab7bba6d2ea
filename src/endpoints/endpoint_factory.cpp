#include "endpoints/endpoint.h"
#include "endpoints/tcp_endpoint.h"
#include "endpoints/tlog_endpoint.h"
#include "endpoints/uart_endpoint.h"
#include "endpoints/udp_endpoint.h"

namespace mavbond {

Result<Endpoint::Ptr> make_endpoint(const EndpointConfig& ep, const Config& config,
                                    EventLoop& loop, FrameSink& sink) {
    auto upcast = [](auto result) -> Result<Endpoint::Ptr> {
        if (!result)
            return result.error();
        return Endpoint::Ptr(std::move(result.value()));
    };
    auto policy = config.unknown_messages;
    switch (ep.type) {
    case EndpointType::Udp:
        return ep.mode == EndpointMode::Server ? upcast(UdpServer::open(ep, loop, sink, policy))
                                               : upcast(UdpClient::open(ep, loop, sink, policy));
    case EndpointType::Tcp:
        return ep.mode == EndpointMode::Server ? upcast(TcpServer::open(ep, loop, sink, policy))
                                               : upcast(TcpClient::open(ep, loop, sink, policy));
    case EndpointType::Uart:
        return Endpoint::Ptr(UartEndpoint::open(ep, loop, sink, policy));
    case EndpointType::Tlog:
        return Endpoint::Ptr(TlogEndpoint::open(ep, loop, sink));
    }
    return make_error("unknown endpoint type");
}

Result<std::vector<Endpoint::Ptr>> make_endpoints(const Config& config, EventLoop& loop,
                                                  FrameSink& sink) {
    std::vector<Endpoint::Ptr> endpoints;
    for (const auto& ep : config.endpoints) {
        auto e = make_endpoint(ep, config, loop, sink);
        if (!e)
            return make_error("endpoint '" + ep.name + "': " + e.error().message);
        endpoints.push_back(std::move(e.value()));
    }
    return endpoints;
}

}  // namespace mavbond
