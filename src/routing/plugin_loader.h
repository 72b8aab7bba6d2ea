// Loads a filter plugin (NAME.so from plugin_dir) and checks it before anything of it runs:
// a plain name ([a-z0-9_]); the file and every directory and symlink on the way to it owned
// by someone the daemon trusts and writable by no one else (plugin_trust.h); read as data, an
// ELF shared object for this machine with the entry symbol, the exact ABI version and the
// name it is loaded as (plugin_elf.h). Only then is it loaded, from the descriptor that was
// checked, and its descriptor checked: the ABI version again, at least the known size, the
// name it claims, create/destroy. Every refusal names the file; the handle is closed on every
// path.
#pragma once

#include <memory>
#include <string>

#include "core/result.h"
#include "core/unique_fd.h"
#include "mavbond/plugin.h"

namespace mavbond {

class LoadedPlugin {
public:
    static Result<std::unique_ptr<LoadedPlugin>> load(const std::string& dir, const std::string& name);
    ~LoadedPlugin();
    LoadedPlugin(const LoadedPlugin&) = delete;
    LoadedPlugin& operator=(const LoadedPlugin&) = delete;

    const mavbond_plugin_descriptor& descriptor() const { return *descriptor_; }
    const std::string& path() const { return path_; }

private:
    LoadedPlugin(void* handle, UniqueFd fd, const mavbond_plugin_descriptor* d, std::string path)
        : handle_(handle), fd_(std::move(fd)), descriptor_(d), path_(std::move(path)) {}
    void* handle_;
    // Loaded as /proc/self/fd/N: kept open while loaded, so no other plugin gets that name
    // (the dynamic loader takes a name it has loaded for the object it loaded).
    UniqueFd fd_;
    const mavbond_plugin_descriptor* descriptor_;
    std::string path_;  // as resolved
};

}  // namespace mavbond
