// MurmurHash3 against SMHasher's verification values and the mmh3 package's hashes.
#include "murmur3.h"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace mavbond::dedup {
namespace {

void put_le(uint8_t* out, uint64_t v, int bytes) {
    for (int i = 0; i < bytes; i++)
        out[i] = static_cast<uint8_t>(v >> (8 * i));
}

// SMHasher's VerificationTest: hash the keys {}, {0}, {0,1}, ... {0..254} with seeds 256-i,
// hash the concatenated digests with seed 0, and read its first 4 bytes little-endian.
template <typename HashFn>
uint32_t verification(int hash_bytes, HashFn fn) {
    std::vector<uint8_t> key(256), digests(256 * hash_bytes), final_digest(hash_bytes);
    for (int i = 0; i < 256; i++) {
        key[i] = static_cast<uint8_t>(i);
        fn(key.data(), static_cast<size_t>(i), static_cast<uint32_t>(256 - i),
           digests.data() + i * hash_bytes);
    }
    fn(digests.data(), digests.size(), 0, final_digest.data());
    return uint32_t{final_digest[0]} | uint32_t{final_digest[1]} << 8 |
           uint32_t{final_digest[2]} << 16 | uint32_t{final_digest[3]} << 24;
}

void x86_32_bytes(const uint8_t* key, size_t len, uint32_t seed, uint8_t* out) {
    put_le(out, murmur3_x86_32(key, len, seed), 4);
}

void x64_128_bytes(const uint8_t* key, size_t len, uint32_t seed, uint8_t* out) {
    Hash128 h = murmur3_x64_128(key, len, seed);
    put_le(out, h.h1, 8);
    put_le(out + 8, h.h2, 8);
}

TEST(Murmur3, SmhasherVerificationX86_32) {
    EXPECT_EQ(0xB0F57EE3u, verification(4, x86_32_bytes));
}

TEST(Murmur3, SmhasherVerificationX64_128) {
    EXPECT_EQ(0x6384BA69u, verification(16, x64_128_bytes));
}

TEST(Murmur3, UnalignedKeysHashAlike) {
    // Frames start anywhere in a receive buffer.
    std::vector<uint8_t> buf(300);
    for (size_t i = 0; i < buf.size(); i++)
        buf[i] = static_cast<uint8_t>(i * 7 + 3);
    std::vector<uint8_t> aligned(buf.begin() + 1, buf.begin() + 1 + 280);
    EXPECT_EQ(murmur3_x86_32(aligned.data(), 280, 9), murmur3_x86_32(buf.data() + 1, 280, 9));
    EXPECT_EQ(murmur3_x64_128(aligned.data(), 280, 9).h1,
              murmur3_x64_128(buf.data() + 1, 280, 9).h1);
    EXPECT_EQ(murmur3_x64_128(aligned.data(), 280, 9).h2,
              murmur3_x64_128(buf.data() + 1, 280, 9).h2);
}

std::vector<uint8_t> from_hex(const std::string& hex) {
    std::vector<uint8_t> out;
    if (hex == "-")
        return out;
    for (size_t i = 0; i + 1 < hex.size(); i += 2)
        out.push_back(static_cast<uint8_t>(std::stoul(hex.substr(i, 2), nullptr, 16)));
    return out;
}

TEST(Murmur3, MatchesMmh3OnRandomInputs) {
    std::ifstream in(MAVBOND_DEDUP_HASH_VECTORS);
    ASSERT_TRUE(in) << "no vectors at " << MAVBOND_DEDUP_HASH_VECTORS;
    int checked = 0;
    for (std::string line; std::getline(in, line);) {
        std::istringstream fields(line);
        std::string seed_hex, key_hex, h32_hex, h1_hex, h2_hex;
        ASSERT_TRUE(fields >> seed_hex >> key_hex >> h32_hex >> h1_hex >> h2_hex) << line;
        auto seed = static_cast<uint32_t>(std::stoul(seed_hex, nullptr, 16));
        std::vector<uint8_t> key = from_hex(key_hex);
        EXPECT_EQ(std::stoul(h32_hex, nullptr, 16), murmur3_x86_32(key.data(), key.size(), seed))
            << "x86_32 of " << key.size() << " bytes, seed " << seed;
        Hash128 h = murmur3_x64_128(key.data(), key.size(), seed);
        EXPECT_EQ(std::stoull(h1_hex, nullptr, 16), h.h1) << "x64_128 of " << key.size() << " bytes";
        EXPECT_EQ(std::stoull(h2_hex, nullptr, 16), h.h2) << "x64_128 of " << key.size() << " bytes";
        checked++;
    }
    EXPECT_GT(checked, 400);
}

}  // namespace
}  // namespace mavbond::dedup
