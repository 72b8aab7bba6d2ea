#include "endpoints/endpoint.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {

Result<Endpoint::Ptr> make_endpoint(const EndpointConfig& ep, const Config& config,
                                    EventLoop& loop, FrameSink& sink) {
    for (const EndpointType& t : endpoint_types()) {
        if (&t.schema != ep.schema)
            continue;
        auto e = t.open(ep, config, loop, sink);
        // A link its bond signs verifies with the bond's signing from its first frame on.
        if (e && ep.signing.by_bond && !e.value()->sign_with(sink.bond_signing(ep.bond)))
            return make_error("endpoint '" + ep.name + "': bond '" + ep.bond +
                              "' has no signing for it (a reload that changed the bond's "
                              "links too often: restart the daemon)");
        if (e)
            e.value()->set_marker_source(config.identity.sysid, config.identity.compid);
        return e;
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
