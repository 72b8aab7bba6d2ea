// SHA-256 (FIPS 180-4), for MAVLink 2 message signing. Incremental, allocation-free: the state
// is a plain value, so a context primed with a key can be copied per frame.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>

namespace mavbond {

class Sha256 {
public:
    using Digest = std::array<uint8_t, 32>;

    Sha256();
    void update(std::span<const uint8_t> data);
    /// The digest of everything given to update(); the context is spent afterwards.
    Digest finish();

    static Digest hash(std::span<const uint8_t> data) {
        Sha256 h;
        h.update(data);
        return h.finish();
    }

private:
    void compress(const uint8_t* block);

    std::array<uint32_t, 8> state_;
    std::array<uint8_t, 64> block_{};
    uint64_t total_bytes_ = 0;
    size_t block_len_ = 0;
};

}  // namespace mavbond
