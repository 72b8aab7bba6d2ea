// Every endpoint type the daemon knows: its table of options (for the config loader, the
// manual, the importer) and how it opens. Adding a type is its own file (its table and its
// endpoint class) and one line in endpoint_types.cpp.
#pragma once

#include <span>

#include "config/config.h"
#include "core/event_loop.h"
#include "endpoints/endpoint.h"
#include "routing/frame_sink.h"

namespace mavbond {

struct EndpointType {
    const EndpointSchema& schema;
    /// Opens an endpoint of this type, its links attached to `sink`.
    Result<Endpoint::Ptr> (*open)(const EndpointConfig& endpoint, const Config& config,
                                  EventLoop& loop, FrameSink& sink);
};

std::span<const EndpointType> endpoint_types();
/// Their tables, in the same order: what the config loader reads endpoints by.
EndpointSchemas endpoint_schemas();

}  // namespace mavbond
