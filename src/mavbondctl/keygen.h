// `mavbondctl keygen PATH`: a new signing key for a bond (or an endpoint), as a file both
// gateways read.
#pragma once

#include <string>

namespace mavbond {

/// The user the service runs as (conf/mavbond.service.in): the key file's owner by default.
constexpr const char* kServiceUser = "mavbond";

/// Writes 32 random bytes as 64 hex digits and a newline to a new file `path`, mode 0600,
/// owned by `owner` when that user exists (the service reads it; `owner` given explicitly must
/// exist); never over an existing file. Prints what it did, or why not, and returns the exit
/// code: 0, 64 (usage), 67 (no such user), 73 (cannot create).
int keygen(const std::string& path, const std::string& owner, bool owner_given);

}  // namespace mavbond
