// One plugin source, built once per defect (see meson.build), so the loader's every refusal
// is proven against a real shared object. Without a DEFECT_* macro it is a good plugin that
// passes every frame and counts them; with PROVIDES_ALIGNED_POSITIONS it also declares it
// aligns its bonds' numberings (what `renumber: true` needs), with PROVIDES_ACTIVE_LINK that
// it chooses their active link (what `tx: active` needs).
//
// Its code, once loaded, leaves a trace: a constructor (run by dlopen, before any of the
// host's checks of the descriptor) appends the plugin's name to the file
// $MAVBOND_ABI_TEST_RAN, so a test proves a refused plugin never ran.
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "mavbond/plugin.h"

#ifndef PLUGIN_NAME
#define PLUGIN_NAME "good_plugin"
#endif

namespace {

__attribute__((constructor)) void leave_a_trace() {
    if (const char* path = std::getenv("MAVBOND_ABI_TEST_RAN")) {
        if (FILE* f = std::fopen(path, "a")) {
            std::fprintf(f, "%s\n", PLUGIN_NAME);
            std::fclose(f);
        }
    }
}

struct Counter {
    unsigned long frames = 0;
};

int create(const mavbond_host_api* api, mavbond_host* h, const mavbond_config* cfg, void** out,
           char* err, size_t err_len) {
#if defined(PROVIDES_ALIGNED_POSITIONS)
    api->provides(h, MAVBOND_PROVIDES_ALIGNED_POSITIONS);
#elif defined(PROVIDES_ACTIVE_LINK)
    api->provides(h, MAVBOND_PROVIDES_ACTIVE_LINK);
#else
    (void)h;
#endif
#ifdef DEFECT_FAILING_CREATE
    (void)out;
    api->cfg_error(cfg, "label", "this plugin always refuses", err, err_len);
    return -1;
#else
    const char* label = nullptr;
    if (api->cfg_string(cfg, "label", &label) == 0 && std::strcmp(label, "bad") == 0) {
        api->cfg_error(cfg, "label", "must not be 'bad'", err, err_len);
        return -1;
    }
    *out = new Counter;
    return 0;
#endif
}

void destroy(void* self) { delete static_cast<Counter*>(self); }

void on_ingress(void* self, mavbond_received*, size_t count) {
    static_cast<Counter*>(self)->frames += count;
}

// Samples that exercise the host's rules: escaping, a NaN gauge, and one it must refuse.
void metrics(void* self, mavbond_metric_sink sink, void* ctx) {
    mavbond_label odd[] = {{"link", "a\"b\\c\nd"}};
    mavbond_metric_sample s{};
    s.struct_size = sizeof s;
    s.type = MAVBOND_METRIC_COUNTER;
    s.name = "frames";
    s.help = "Frames seen.";
    s.labels = odd;
    s.label_count = 1;
    s.count = static_cast<Counter*>(self)->frames + 18446744073709551000ull;
    sink(ctx, &s);
    s = mavbond_metric_sample{};
    s.struct_size = sizeof s;
    s.type = MAVBOND_METRIC_GAUGE;
    s.name = "ratio";
    s.help = "Not known yet.";
    s.value = 0.0 / 0.0;
    sink(ctx, &s);
    mavbond_label stolen[] = {{"filter", "mine"}};
    s.name = "stolen";
    s.labels = stolen;
    s.label_count = 1;
    sink(ctx, &s);
    s.name = "bad-name";
    s.label_count = 0;
    sink(ctx, &s);
}

const mavbond_option kOptions[] = {
    {"label", MAVBOND_OPT_STRING, "none", "a free text, refused when 'bad'"},
    {"period", MAVBOND_OPT_DURATION, "1s", "a duration"},
    {nullptr, MAVBOND_OPT_BOOL, nullptr, nullptr},
};

mavbond_plugin_descriptor make_descriptor() {
    mavbond_plugin_descriptor d{};
    d.abi_version = MAVBOND_PLUGIN_ABI_VERSION;
    d.struct_size = sizeof d;
    d.name = PLUGIN_NAME;
    d.version = "1";
    d.description = "loader test plugin";
    d.options = kOptions;
    d.create = create;
    d.destroy = destroy;
    d.on_ingress = on_ingress;
    d.metrics = metrics;
#if defined(DEFECT_ABI_VERSION) || defined(DEFECT_DESCRIPTOR_ABI)
    d.abi_version = MAVBOND_PLUGIN_ABI_VERSION + 41;
#endif
#ifdef DEFECT_SMALL_STRUCT
    d.struct_size = 16;
#endif
#ifdef DEFECT_WRONG_NAME
    d.name = "somebody_else";
#endif
#ifdef DEFECT_NO_CREATE
    d.create = nullptr;
#endif
    return d;
}

const mavbond_plugin_descriptor kDescriptor = make_descriptor();

}  // namespace

// What the host reads from the file before loading it (a plugin built for ABI 4 had none).
#if defined(DEFECT_ABI_VERSION)
extern "C" MAVBOND_EXPORT const uint32_t mavbond_plugin_abi_version = MAVBOND_PLUGIN_ABI_VERSION + 41;
extern "C" MAVBOND_EXPORT const char mavbond_plugin_name[] = PLUGIN_NAME;
#elif defined(DEFECT_WRONG_NAME)
MAVBOND_PLUGIN_DATA("somebody_else");
#elif !defined(DEFECT_NO_ABI_DATA)
MAVBOND_PLUGIN_DATA(PLUGIN_NAME);
#endif

#ifndef DEFECT_NO_ENTRY
extern "C" MAVBOND_EXPORT const mavbond_plugin_descriptor* mavbond_plugin_entry(void) {
    return &kDescriptor;
}
#else
extern "C" MAVBOND_EXPORT const mavbond_plugin_descriptor* some_other_symbol(void) { return &kDescriptor; }
#endif
