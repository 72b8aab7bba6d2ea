// MurmurHash3 (Austin Appleby's design, placed in the public domain), written here from the
// algorithm's description: the 32-bit x86 variant (the paper's) and the 128-bit x64 variant.
// Both read the key as little-endian words whatever the host's byte order, so hashes are the
// same on every machine and match SMHasher's verification values and the mmh3 package.
#pragma once

#include <cstddef>
#include <cstdint>

namespace mavbond::dedup {

struct Hash128 {
    uint64_t h1;  // the first 8 bytes of the 16-byte digest, little-endian
    uint64_t h2;  // the last 8
};

uint32_t murmur3_x86_32(const void* key, size_t len, uint32_t seed);
Hash128 murmur3_x64_128(const void* key, size_t len, uint32_t seed);

}  // namespace mavbond::dedup
