// Whose files the daemon runs as its own code. A plugin runs with the daemon's rights (root,
// when started by hand with sudo or for --check-config), so whoever may change its file, or
// any directory on the way to it, or a symlink that leads there, may run code as the daemon.
// Trusted owners: root, the user the daemon runs as, and the owner of the daemon's own
// executable (who could change the daemon itself: trusting them adds no one, and keeps a
// developer's build tree working under sudo). Writable by no one else: neither by the group
// nor by others; an ancestor directory others may write must be sticky (/tmp: only an entry's
// owner may replace it, and every entry on the way is checked in turn).
#pragma once

#include <sys/types.h>

#include <string>

#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

struct TrustedFile {
    UniqueFd fd;       // open for reading; the descriptor that was checked, the one to load
    std::string path;  // as resolved: absolute, no symlink, no "." or ".."
};

/// Resolves `path` one component at a time, each directory, symlink and the file itself
/// checked as above (symlinks followed and their targets checked the same way), then opens the
/// file and checks the open descriptor again, so what is loaded is what was checked. `dir` is
/// the directory the caller looks in (checked as a plugin directory: not even sticky may make
/// it writable by others). A refusal names the component and why.
Result<TrustedFile> open_trusted_file(const std::string& dir, const std::string& file_name);

}  // namespace mavbond
