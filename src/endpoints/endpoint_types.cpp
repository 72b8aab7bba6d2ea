#include "endpoints/endpoint_types.h"

#include <vector>

#include "endpoints/tcp_endpoint.h"
#include "endpoints/tlog_endpoint.h"
#include "endpoints/uart_endpoint.h"
#include "endpoints/udp_endpoint.h"

namespace mavbond {
namespace {

/// An endpoint class's open(), as a type's: T::open(endpoint, loop, sink[, policy for
/// unknown message ids, when it parses frames]) returning Result<std::unique_ptr<T>> or
/// std::unique_ptr<T> (one that cannot fail to start: it retries in the background).
template <typename T>
Result<Endpoint::Ptr> open(const EndpointConfig& endpoint, const Config& config, EventLoop& loop,
                           FrameSink& sink) {
    auto opened = [&] {
        if constexpr (requires { T::open(endpoint, loop, sink, config.unknown_messages); })
            return T::open(endpoint, loop, sink, config.unknown_messages);
        else
            return T::open(endpoint, loop, sink);
    }();
    if constexpr (requires { opened.has_value(); }) {
        if (!opened)
            return opened.error();
        return Endpoint::Ptr(std::move(opened.value()));
    } else {
        return Endpoint::Ptr(std::move(opened));
    }
}

// In the order the config's messages list them.
const EndpointType kTypes[] = {
    {kUdpServerType, open<UdpServer>},
    {kUdpClientType, open<UdpClient>},
    {kTcpServerType, open<TcpServer>},
    {kTcpClientType, open<TcpClient>},
    {kUartType, open<UartEndpoint>},
    {kTlogType, open<TlogEndpoint>},
};

}  // namespace

std::span<const EndpointType> endpoint_types() { return kTypes; }

EndpointSchemas endpoint_schemas() {
    static const std::vector<const EndpointSchema*> schemas = [] {
        std::vector<const EndpointSchema*> out;
        for (const EndpointType& t : kTypes)
            out.push_back(&t.schema);
        return out;
    }();
    return schemas;
}

}  // namespace mavbond
