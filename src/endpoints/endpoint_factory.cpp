#include "endpoints/endpoint.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {

Result<Endpoint::Ptr> make_endpoint(const EndpointConfig& ep, const Config& config,
                                    EventLoop& loop, FrameSink& sink) {
    for (const EndpointType& t : endpoint_types()) {
        if (&t.schema == ep.schema)
            return t.open(ep, config, loop, sink);
    }
    return make_error("endpoint '" + ep.name + "': a type this daemon does not know");
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
