#include "routing/plugin_loader.h"

#include <dlfcn.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <climits>
#include <cstring>
#include <optional>

#include "routing/plugin_elf.h"
#include "routing/plugin_trust.h"

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

/// The name the dynamic loader opens an open file by.
std::string fd_path(int fd) { return "/proc/self/fd/" + std::to_string(fd); }

/// Where a build tree keeps its plugins, when this mavbond runs from one (BUILD/src/mavbond,
/// BUILD/plugins/NAME.so), for a hint: the compiled-in plugin_dir is where they are
/// installed, and a build tree's are found only with --plugin-dir.
std::optional<std::string> build_tree_plugins(const std::string& name) {
    std::array<char, PATH_MAX> exe{};
    ssize_t n = readlink("/proc/self/exe", exe.data(), exe.size() - 1);
    if (n <= 0)
        return std::nullopt;
    std::string dir(exe.data(), static_cast<size_t>(n));
    for (int up = 0; up < 2; up++)
        dir = dir.substr(0, dir.rfind('/'));
    dir += "/plugins";
    if (access((dir + "/" + name + ".so").c_str(), F_OK) != 0)
        return std::nullopt;
    return dir;
}

std::string abi_refusal(uint32_t version) {
    return "built for plugin ABI version " + std::to_string(version) +
           ", this mavbond speaks version " + std::to_string(MAVBOND_PLUGIN_ABI_VERSION) +
           ": rebuild the plugin";
}

}  // namespace

Result<std::unique_ptr<LoadedPlugin>> LoadedPlugin::load(const std::string& dir,
                                                         const std::string& name) {
    // The config allows only these names; checked again here, so no caller can reach a file
    // outside the directory ("../x", "/abs").
    bool plain = !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
        return (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_';
    });
    if (!plain)
        return make_error("invalid plugin name '" + name + "' (allowed characters: a-z 0-9 _)");
    const std::string wanted = dir + "/" + name + ".so";
    if (access(wanted.c_str(), F_OK) != 0) {
        const int err = errno;
        std::string hint = " (plugin_dir is " + dir + ")";
        if (auto built = build_tree_plugins(name); built && *built != dir)
            hint = " (plugin_dir is " + dir + "; this mavbond runs from a build tree: "
                   "--plugin-dir " + *built + ")";
        return make_error(wanted + ": cannot load plugin: " + strerror(err) + hint);
    }
    auto file = open_trusted_file(dir, name + ".so");
    if (!file)
        return make_error(file.error().message + " (plugin_dir is " + dir + ")");
    const std::string& path = file->path;
    auto refuse = [&path](const std::string& why) -> Error { return make_error(path + ": " + why); };

    // Read, not run: dlopen runs a file's constructors, so nothing of a plugin built for
    // another ABI or under another name may get that far.
    auto id = read_plugin_identity(file->fd.get(), path);
    if (!id)
        return id.error();
    if (id->abi_version != MAVBOND_PLUGIN_ABI_VERSION)
        return refuse(abi_refusal(id->abi_version));
    if (id->name != name)
        return refuse("calls itself '" + id->name + "', but was loaded as '" + name + "'");

    // The descriptor that was checked, not the name (which could lead elsewhere by now).
    // RTLD_LOCAL: plugins never see each other's symbols; RTLD_NOW: a missing symbol fails here.
    HandleGuard guard{dlopen(fd_path(file->fd.get()).c_str(), RTLD_NOW | RTLD_LOCAL)};
    if (!guard.handle)
        return refuse(std::string("cannot load plugin: ") + dlerror());
    auto entry = reinterpret_cast<mavbond_plugin_entry_fn>(dlsym(guard.handle, MAVBOND_PLUGIN_ENTRY_SYMBOL));
    if (!entry)
        return refuse("no entry symbol " MAVBOND_PLUGIN_ENTRY_SYMBOL " (not a mavbond plugin?)");
    const mavbond_plugin_descriptor* d = entry();
    if (!d)
        return refuse(MAVBOND_PLUGIN_ENTRY_SYMBOL " returned no descriptor");
    if (d->abi_version != MAVBOND_PLUGIN_ABI_VERSION)
        return refuse(abi_refusal(d->abi_version));
    if (d->struct_size < sizeof(mavbond_plugin_descriptor))
        return refuse("descriptor of " + std::to_string(d->struct_size) + " bytes, expected " +
                      std::to_string(sizeof(mavbond_plugin_descriptor)));
    if (!d->name || name != d->name)
        return refuse(std::string("calls itself '") + (d->name ? d->name : "(null)") +
                      "', but was loaded as '" + name + "'");
    if (!d->create || !d->destroy)
        return refuse("lacks create or destroy");
    return std::unique_ptr<LoadedPlugin>(
        new LoadedPlugin(guard.release(), std::move(file->fd), d, path));
}

LoadedPlugin::~LoadedPlugin() {
    dlclose(handle_);
    // An object the dynamic loader keeps (a plugin with a unique symbol, which C++ makes of
    // some statics, is never unloaded) keeps its name too: a plugin loaded later through the
    // same descriptor number would be taken for it. So its descriptor stays open, for good.
    if (void* still = dlopen(fd_path(fd_.get()).c_str(), RTLD_LAZY | RTLD_NOLOAD)) {
        dlclose(still);
        fd_.release();
    }
}

}  // namespace mavbond
