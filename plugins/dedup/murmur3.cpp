#include "murmur3.h"

#include <bit>
#include <cstring>

namespace mavbond::dedup {
namespace {

// Loads through memcpy: frames sit at any offset in a receive buffer, and unaligned pointer
// casts are undefined (and trap on some ARM cores). Compilers turn this into one load.
uint32_t load_le32(const uint8_t* p) {
    return uint32_t{p[0]} | uint32_t{p[1]} << 8 | uint32_t{p[2]} << 16 | uint32_t{p[3]} << 24;
}

uint64_t load_le64(const uint8_t* p) {
    if constexpr (std::endian::native == std::endian::little) {
        uint64_t v;
        std::memcpy(&v, p, sizeof v);
        return v;
    }
    return uint64_t{load_le32(p)} | uint64_t{load_le32(p + 4)} << 32;
}

constexpr uint32_t rotl32(uint32_t x, int r) { return (x << r) | (x >> (32 - r)); }
constexpr uint64_t rotl64(uint64_t x, int r) { return (x << r) | (x >> (64 - r)); }

// The finalisers spread every input bit over the whole word (avalanche).
constexpr uint32_t fmix32(uint32_t h) {
    h ^= h >> 16;
    h *= 0x85ebca6bu;
    h ^= h >> 13;
    h *= 0xc2b2ae35u;
    h ^= h >> 16;
    return h;
}

constexpr uint64_t fmix64(uint64_t k) {
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdull;
    k ^= k >> 33;
    k *= 0xc4ceb9fe1a85ec53ull;
    k ^= k >> 33;
    return k;
}

constexpr uint32_t kC1_32 = 0xcc9e2d51u;
constexpr uint32_t kC2_32 = 0x1b873593u;
constexpr uint64_t kC1_64 = 0x87c37b91114253d5ull;
constexpr uint64_t kC2_64 = 0x4cf5ad432745937full;

constexpr uint32_t scramble32(uint32_t k) { return rotl32(k * kC1_32, 15) * kC2_32; }
constexpr uint64_t scramble64_1(uint64_t k) { return rotl64(k * kC1_64, 31) * kC2_64; }
constexpr uint64_t scramble64_2(uint64_t k) { return rotl64(k * kC2_64, 33) * kC1_64; }

}  // namespace

uint32_t murmur3_x86_32(const void* key, size_t len, uint32_t seed) {
    const auto* p = static_cast<const uint8_t*>(key);
    const size_t blocks = len / 4;
    uint32_t h = seed;
    for (size_t i = 0; i < blocks; i++) {
        h ^= scramble32(load_le32(p + 4 * i));
        h = rotl32(h, 13) * 5 + 0xe6546b64u;
    }
    // The 1 to 3 bytes left over form one more little-endian word, without the mixing step.
    const uint8_t* tail = p + 4 * blocks;
    uint32_t k = 0;
    for (size_t i = len & 3; i > 0; i--)
        k |= uint32_t{tail[i - 1]} << (8 * (i - 1));
    if (len & 3)
        h ^= scramble32(k);
    // The length is folded in as 32 bits, as the reference does (keys here are < 4 GiB).
    h ^= static_cast<uint32_t>(len);
    return fmix32(h);
}

Hash128 murmur3_x64_128(const void* key, size_t len, uint32_t seed) {
    const auto* p = static_cast<const uint8_t*>(key);
    const size_t blocks = len / 16;
    uint64_t h1 = seed;
    uint64_t h2 = seed;
    for (size_t i = 0; i < blocks; i++) {
        h1 ^= scramble64_1(load_le64(p + 16 * i));
        h1 = (rotl64(h1, 27) + h2) * 5 + 0x52dce729u;
        h2 ^= scramble64_2(load_le64(p + 16 * i + 8));
        h2 = (rotl64(h2, 31) + h1) * 5 + 0x38495ab5u;
    }
    // Up to 15 bytes left: bytes 8.. feed the second lane, bytes 0..7 the first.
    const uint8_t* tail = p + 16 * blocks;
    const size_t rest = len & 15;
    uint64_t k1 = 0;
    uint64_t k2 = 0;
    for (size_t i = 0; i < rest; i++) {
        if (i < 8)
            k1 |= uint64_t{tail[i]} << (8 * i);
        else
            k2 |= uint64_t{tail[i]} << (8 * (i - 8));
    }
    if (rest > 8)
        h2 ^= scramble64_2(k2);
    if (rest > 0)
        h1 ^= scramble64_1(k1);
    h1 ^= len;
    h2 ^= len;
    h1 += h2;
    h2 += h1;
    h1 = fmix64(h1);
    h2 = fmix64(h2);
    h1 += h2;
    h2 += h1;
    return {h1, h2};
}

}  // namespace mavbond::dedup
