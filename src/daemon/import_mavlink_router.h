// `mavbond --import-mavlink-router FILE`: mavlink-router's INI configuration (main.conf) as
// mavbond YAML. Every key of mavlink-router's documented format is either translated or kept as
// a "# not translated: ..." comment in the output, with a warning.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "core/result.h"

namespace mavbond {

constexpr int kExitDataError = 65;  // EX_DATAERR: the INI file is malformed

struct ImportedConfig {
    std::string yaml;
    std::vector<std::string> warnings;  // "file:line: what was not translated, and why"
};

/// Translates the text of a mavlink-router config; `file` names it in messages. A malformed
/// file (a line that is neither a section, a key = value pair nor a comment; a bad value; a
/// mandatory key missing) is an error "file:line: what".
Result<ImportedConfig> import_mavlink_router(std::string_view text, const std::string& file);

}  // namespace mavbond
