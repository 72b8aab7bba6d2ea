// Loads a filter plugin (NAME.so from plugin_dir) and checks it before anything of it runs:
// a plain name ([a-z0-9_]), a directory and a file that nobody but their owner may write, an entry symbol, the exact ABI
// version, a descriptor of at least the known size, the name it claims, create/destroy.
// Every refusal names the file; the handle is closed on every path.
#pragma once

#include <memory>
#include <string>

#include "core/result.h"
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
    LoadedPlugin(void* handle, const mavbond_plugin_descriptor* d, std::string path)
        : handle_(handle), descriptor_(d), path_(std::move(path)) {}
    void* handle_;
    const mavbond_plugin_descriptor* descriptor_;
    std::string path_;
};

}  // namespace mavbond
