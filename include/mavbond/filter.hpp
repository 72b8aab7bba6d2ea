// A C++ filter plugin in a few lines: write a class, let FilterPlugin<T> make the C ABI's
// trampolines and descriptor. No exception crosses the boundary; on any failure a frame
// passes (fail open: a filter bug must not cut the telemetry).
//
// T provides:
//   T(const mavbond_host_api* api, mavbond_host* host);
//   int init(const mavbond_config* cfg, char* err, size_t err_len);   // 0, or a message in err
//   mavbond_verdict on_ingress(const mavbond_frame*, mavbond_frame_notes*, const mavbond_link*);
//     (or returning void: an observer that never drops), called for each frame of a batch in
//     turn: the batch is the ABI's, T sees one frame at a time with its code inlined in the loop
// and, when it needs them:
//   void on_link(const mavbond_link* link, mavbond_link_event event);
//   void status(mavbond::JsonOut& out);           // one JSON object for the status socket
//   void metrics(mavbond::MetricOut& out);        // out.counter(...), out.gauge(...)
//   void describe(uint32_t bond, mavbond::JsonOut& out);  // a line of text: what it derived
// The host hands a filter only the links and frames of its scope.
//
// In the plugin:
//   MAVBOND_FILTER_PLUGIN(MyFilter, "myfilter", "1.0", "what it does", kOptions)
#ifndef MAVBOND_FILTER_HPP
#define MAVBOND_FILTER_HPP

#include <cstdio>
#include <exception>
#include <initializer_list>
#include <memory>
#include <new>
#include <type_traits>

#include "mavbond/json.hpp"
#include "mavbond/plugin.h"

namespace mavbond {

/// What a plugin's metrics() writes to: one call per sample, straight through to the host.
class MetricOut {
public:
    MetricOut(mavbond_metric_sink sink, void* ctx) : sink_(sink), ctx_(ctx) {}
    void counter(const char* name, const char* help, uint64_t count,
                 std::initializer_list<mavbond_label> labels = {}) {
        emit(MAVBOND_METRIC_COUNTER, name, help, labels, count, 0);
    }
    void gauge(const char* name, const char* help, double value,
               std::initializer_list<mavbond_label> labels = {}) {
        emit(MAVBOND_METRIC_GAUGE, name, help, labels, 0, value);
    }

private:
    void emit(mavbond_metric_type type, const char* name, const char* help,
              std::initializer_list<mavbond_label> labels, uint64_t count, double value) {
        mavbond_metric_sample s{};
        s.struct_size = sizeof s;
        s.type = type;
        s.name = name;
        s.help = help;
        s.labels = labels.begin();
        s.label_count = static_cast<uint32_t>(labels.size());
        s.count = count;
        s.value = value;
        sink_(ctx_, &s);
    }
    mavbond_metric_sink sink_;
    void* ctx_;
};

template <typename T>
struct FilterPlugin {
    static int create(const mavbond_host_api* api, mavbond_host* h, const mavbond_config* cfg,
                      void** out_self, char* err, size_t err_len) noexcept {
        try {
            auto self = std::make_unique<T>(api, h);
            if (self->init(cfg, err, err_len) != 0)
                return -1;
            *out_self = self.release();
            return 0;
        } catch (const std::bad_alloc&) {
            std::snprintf(err, err_len, "out of memory");
        } catch (const std::exception& e) {
            std::snprintf(err, err_len, "%s", e.what());
        } catch (...) {
            std::snprintf(err, err_len, "unexpected error in create");
        }
        return -1;
    }

    static void destroy(void* self) noexcept { delete static_cast<T*>(self); }

    static void on_ingress(void* self, mavbond_received* frames, size_t count) noexcept {
        T& t = *static_cast<T*>(self);
        for (size_t i = 0; i < count; i++) {
            mavbond_received& r = frames[i];
            try {
                if constexpr (std::is_void_v<decltype(t.on_ingress(r.frame, r.notes, r.from))>)
                    t.on_ingress(r.frame, r.notes, r.from);
                else
                    r.verdict = t.on_ingress(r.frame, r.notes, r.from);
            } catch (...) {
                r.verdict = MAVBOND_PASS;
            }
        }
    }

    static void on_link(void* self, const mavbond_link* link, mavbond_link_event event) noexcept {
        try {
            static_cast<T*>(self)->on_link(link, event);
        } catch (...) {
        }
    }

    static size_t status_json(void* self, char* buf, size_t len) noexcept {
        JsonOut out(buf, len);
        try {
            static_cast<T*>(self)->status(out);
            return out.length();
        } catch (...) {
            if (buf && len > 0)
                buf[0] = '\0';
            return 0;
        }
    }

    static void metrics(void* self, mavbond_metric_sink sink, void* ctx) noexcept {
        try {
            MetricOut out(sink, ctx);
            static_cast<T*>(self)->metrics(out);
        } catch (...) {
        }
    }

    static size_t describe(void* self, uint32_t bond, char* buf, size_t len) noexcept {
        JsonOut out(buf, len);
        try {
            static_cast<T*>(self)->describe(bond, out);
            return out.length();
        } catch (...) {
            if (buf && len > 0)
                buf[0] = '\0';
            return 0;
        }
    }

    static constexpr mavbond_plugin_descriptor descriptor(const char* name, const char* version,
                                                          const char* description,
                                                          const mavbond_option* options) {
        mavbond_plugin_descriptor d{};
        d.abi_version = MAVBOND_PLUGIN_ABI_VERSION;
        d.struct_size = sizeof(mavbond_plugin_descriptor);
        d.name = name;
        d.version = version;
        d.description = description;
        d.options = options;
        d.create = create;
        d.destroy = destroy;
        d.on_ingress = on_ingress;
        if constexpr (requires(T t) { t.on_link(nullptr, MAVBOND_LINK_ADDED); })
            d.on_link = on_link;
        if constexpr (requires(T t, JsonOut& o) { t.status(o); })
            d.status_json = status_json;
        if constexpr (requires(T t, MetricOut& o) { t.metrics(o); })
            d.metrics = metrics;
        if constexpr (requires(T t, JsonOut& o) { t.describe(0u, o); })
            d.describe = describe;
        return d;
    }
};

}  // namespace mavbond

/// Exports plugin class T under `name` (which must equal the file name NAME.so).
#define MAVBOND_FILTER_PLUGIN(T, name, version, description, options)                        \
    MAVBOND_PLUGIN_DATA(name);                                                               \
    extern "C" MAVBOND_EXPORT const mavbond_plugin_descriptor* mavbond_plugin_entry(void) {  \
        static constexpr mavbond_plugin_descriptor kDescriptor =                            \
            ::mavbond::FilterPlugin<T>::descriptor(name, version, description, options);    \
        return &kDescriptor;                                                                 \
    }

#endif  // MAVBOND_FILTER_HPP
