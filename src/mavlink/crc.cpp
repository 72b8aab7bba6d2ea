// X.25 CRC-16/MCRF4XX (reflected polynomial 0x8408, init 0xFFFF, no final xor), table-driven,
// four bytes a step ("slicing by 4"): every frame is checked, both copies of a bonded one, so
// this is a third of the parser's work.
#include <array>

#include "mavlink/frame_parser.h"

namespace mavbond {

namespace {

using Table = std::array<uint16_t, 256>;

/// kTables[0] is the classic byte table; kTables[k][i] is the CRC contribution of byte i
/// followed by k zero bytes, so four bytes fold in with four lookups.
constexpr std::array<Table, 4> make_crc_tables() {
    std::array<Table, 4> t{};
    for (unsigned i = 0; i < 256; ++i) {
        uint16_t crc = static_cast<uint16_t>(i);
        for (int bit = 0; bit < 8; ++bit)
            crc = (crc & 1) ? static_cast<uint16_t>((crc >> 1) ^ 0x8408) : static_cast<uint16_t>(crc >> 1);
        t[0][i] = crc;
    }
    for (size_t k = 1; k < 4; ++k) {
        for (unsigned i = 0; i < 256; ++i)
            t[k][i] = static_cast<uint16_t>((t[k - 1][i] >> 8) ^ t[0][t[k - 1][i] & 0xFF]);
    }
    return t;
}

constexpr std::array<Table, 4> kTables = make_crc_tables();

constexpr uint16_t step(uint8_t b, uint16_t crc) {
    return static_cast<uint16_t>((crc >> 8) ^ kTables[0][(crc ^ b) & 0xFF]);
}

constexpr uint16_t crc_bytes(const uint8_t* p, size_t n, uint16_t crc) {
    for (; n >= 4; p += 4, n -= 4) {
        // The CRC register is 16 bits: the first two bytes mix into it, the next two do not.
        const uint16_t x = static_cast<uint16_t>(crc ^ (p[0] | p[1] << 8));
        crc = static_cast<uint16_t>(kTables[3][x & 0xFF] ^ kTables[2][x >> 8] ^ kTables[1][p[2]] ^
                                    kTables[0][p[3]]);
    }
    for (; n > 0; ++p, --n)
        crc = step(*p, crc);
    return crc;
}

// The check value of CRC-16/MCRF4XX over "123456789", by both paths.
constexpr uint8_t kCheck[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
static_assert(crc_bytes(kCheck, sizeof kCheck, 0xFFFF) == 0x6F91);
static_assert([] {
    uint16_t crc = 0xFFFF;
    for (uint8_t c : kCheck)
        crc = step(c, crc);
    return crc;
}() == 0x6F91);

}  // namespace

uint16_t crc_x25_byte(uint8_t b, uint16_t crc) { return step(b, crc); }

uint16_t crc_x25(std::span<const uint8_t> data, uint16_t crc) {
    return crc_bytes(data.data(), data.size(), crc);
}

}  // namespace mavbond
