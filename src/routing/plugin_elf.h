// What a plugin's file says about it, read as data, never run: an ELF shared object for this
// machine, exporting the entry symbol and (ABI 5) its ABI version and name as plain data
// symbols. Checked before dlopen, which runs the file's constructors.
#pragma once

#include <cstdint>
#include <string>

#include "core/result.h"

namespace mavbond {

struct PluginIdentity {
    uint32_t abi_version = 0;
    std::string name;
};

/// Reads the identity from the open file `fd` (`path` only names it in errors). An error says
/// what the file is not: an ELF shared object for this machine, a mavbond plugin (no entry
/// symbol), one built for ABI 5 or later (no version symbol).
Result<PluginIdentity> read_plugin_identity(int fd, const std::string& path);

}  // namespace mavbond
