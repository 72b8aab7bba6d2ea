// SHA-256: the FIPS 180-4 examples, hashlib's digests of random inputs of every length around
// the block edges, and any split of the input into update() calls.
#include "mavlink/sha256.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

#include "signing_vectors.h"

namespace mavbond {
namespace {

std::string hex(const Sha256::Digest& d) {
    static const char* digits = "0123456789abcdef";
    std::string out;
    for (uint8_t b : d) {
        out += digits[b >> 4];
        out += digits[b & 15];
    }
    return out;
}

std::string hash_text(const std::string& text) {
    return hex(Sha256::hash({reinterpret_cast<const uint8_t*>(text.data()), text.size()}));
}

// FIPS 180-4 / NIST CSRC "Example Algorithm Implementations", SHA-256.
TEST(Sha256, NistExamples) {
    EXPECT_EQ(hash_text(""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    EXPECT_EQ(hash_text("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    EXPECT_EQ(hash_text("abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
              "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1");
    EXPECT_EQ(hash_text("abcdefghbcdefghicdefghijdefghijkefghijklfghijklmghijklmnhijklmnoijklmnopjklm"
                        "nopqklmnopqrlmnopqrsmnopqrstnopqrstu"),
              "cf5b16a778af8380036ce59e7b0492370b249b11e8f07a51afac45037afee9d1");
}

TEST(Sha256, OneMillionA) {
    Sha256 h;
    std::string chunk(1000, 'a');
    for (int i = 0; i < 1000; i++)
        h.update({reinterpret_cast<const uint8_t*>(chunk.data()), chunk.size()});
    EXPECT_EQ(hex(h.finish()), "cdc76e5c9914fb9281a1c7e284d73e67f1809a48a497200e046d39ccc7112cd0");
}

TEST(Sha256, MatchesHashlibOnRandomInputs) {
    const auto& v = test::signing_vectors();
    ASSERT_GE(v.sha.size(), 140u);
    for (const auto& [input, digest] : v.sha) {
        SCOPED_TRACE("length " + std::to_string(input.size()));
        Sha256::Digest d = Sha256::hash(input);
        EXPECT_EQ(test::Bytes(d.begin(), d.end()), digest);
    }
}

TEST(Sha256, AnySplitGivesTheSameDigest) {
    const auto& v = test::signing_vectors();
    std::mt19937 rng(5);
    for (const auto& [input, digest] : v.sha) {
        Sha256 h;
        size_t pos = 0;
        while (pos < input.size()) {
            size_t n = std::min<size_t>(input.size() - pos, rng() % 130);
            h.update(std::span(input).subspan(pos, n));
            pos += n;
        }
        Sha256::Digest d = h.finish();
        ASSERT_EQ(test::Bytes(d.begin(), d.end()), digest) << "length " << input.size();
    }
}

TEST(Sha256, CopiedContextContinuesIndependently) {
    Sha256 base;
    const std::string prefix(40, 'k');
    base.update({reinterpret_cast<const uint8_t*>(prefix.data()), prefix.size()});
    Sha256 a = base, b = base;
    const std::string x = "abc", y = "abd";
    a.update({reinterpret_cast<const uint8_t*>(x.data()), x.size()});
    b.update({reinterpret_cast<const uint8_t*>(y.data()), y.size()});
    EXPECT_EQ(hex(a.finish()), hash_text(prefix + x));
    EXPECT_EQ(hex(b.finish()), hash_text(prefix + y));
}

}  // namespace
}  // namespace mavbond
