#include "routing/plugin_loader.h"

#include <dlfcn.h>
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

namespace mavbond {
namespace {

/// Closes a dlopen handle unless released: every refusal path closes it.
struct HandleGuard {
    void* handle;
    ~HandleGuard() {
        if (handle)
            dlclose(handle);
    }
    void* release() { return std::exchange(handle, nullptr); }
};

}  // namespace

Result<std::unique_ptr<LoadedPlugin>> LoadedPlugin::load(const std::string& dir,
                                                         const std::string& name) {
    std::string path = dir + "/" + name + ".so";
    auto refuse = [&path](const std::string& why) -> Error { return make_error(path + ": " + why); };

    // The config allows only these names; checked again here, so no caller can reach a file
    // outside the directory ("../x", "/abs").
    bool plain = !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
    });
    if (!plain)
        return make_error("invalid plugin name '" + name + "' (allowed characters: a-z 0-9 _)");
    // Whoever may write the directory may put any file under a plugin's name.
    struct stat dir_st {};
    if (stat(dir.c_str(), &dir_st) < 0)
        return make_error("plugin_dir " + dir + ": " + strerror(errno));
    if (dir_st.st_mode & (S_IWGRP | S_IWOTH)) {
        char mode[8];
        snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(dir_st.st_mode & 07777));
        return make_error("plugin_dir " + dir + ": refusing a plugin directory that others than "
                          "its owner may write (mode " + std::string(mode) + ")");
    }

    struct stat st {};
    if (stat(path.c_str(), &st) < 0)
        return refuse(std::string("cannot load plugin: ") + strerror(errno) +
                      " (plugin_dir is " + dir + ")");
    if (!S_ISREG(st.st_mode))
        return refuse("not a regular file");
    // Whoever may write the file may run code in the daemon: only its owner may.
    if (st.st_mode & (S_IWGRP | S_IWOTH))
    {
        char mode[8];
        snprintf(mode, sizeof mode, "%03o", st.st_mode & 0777);
        return refuse(std::string("refusing a plugin that others than its owner may write (mode ") +
                      mode + ")");
    }

    // RTLD_LOCAL: plugins never see each other's symbols; RTLD_NOW: a missing symbol fails here.
    HandleGuard guard{dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL)};
    if (!guard.handle)
        return refuse(std::string("cannot load plugin: ") + dlerror());
    auto entry = reinterpret_cast<mavbond_plugin_entry_fn>(dlsym(guard.handle, MAVBOND_PLUGIN_ENTRY_SYMBOL));
    if (!entry)
        return refuse("no entry symbol " MAVBOND_PLUGIN_ENTRY_SYMBOL " (not a mavbond plugin?)");
    const mavbond_plugin_descriptor* d = entry();
    if (!d)
        return refuse(MAVBOND_PLUGIN_ENTRY_SYMBOL " returned no descriptor");
    if (d->abi_version != MAVBOND_PLUGIN_ABI_VERSION)
        return refuse("built for plugin ABI version " + std::to_string(d->abi_version) +
                      ", this mavbond speaks version " + std::to_string(MAVBOND_PLUGIN_ABI_VERSION) +
                      ": rebuild the plugin");
    if (d->struct_size < sizeof(mavbond_plugin_descriptor))
        return refuse("descriptor of " + std::to_string(d->struct_size) + " bytes, expected " +
                      std::to_string(sizeof(mavbond_plugin_descriptor)));
    if (!d->name || name != d->name)
        return refuse(std::string("calls itself '") + (d->name ? d->name : "(null)") +
                      "', but was loaded as '" + name + "'");
    if (!d->create || !d->destroy)
        return refuse("lacks create or destroy");
    return std::unique_ptr<LoadedPlugin>(new LoadedPlugin(guard.release(), d, path));
}

LoadedPlugin::~LoadedPlugin() { dlclose(handle_); }

}  // namespace mavbond
