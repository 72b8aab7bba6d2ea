// X.25 CRC-16/MCRF4XX (reflected polynomial 0x8408, init 0xFFFF, no final xor), table-driven.
#include <array>

#include "mavlink/frame_parser.h"

namespace mavbond {

namespace {

constexpr std::array<uint16_t, 256> make_crc_table() {
    std::array<uint16_t, 256> table{};
    for (unsigned i = 0; i < 256; ++i) {
        uint16_t crc = static_cast<uint16_t>(i);
        for (int bit = 0; bit < 8; ++bit)
            crc = (crc & 1) ? static_cast<uint16_t>((crc >> 1) ^ 0x8408) : static_cast<uint16_t>(crc >> 1);
        table[i] = crc;
    }
    return table;
}

constexpr std::array<uint16_t, 256> kCrcTable = make_crc_table();

constexpr uint16_t step(uint8_t b, uint16_t crc) {
    return static_cast<uint16_t>((crc >> 8) ^ kCrcTable[(crc ^ b) & 0xFF]);
}

// The check value of CRC-16/MCRF4XX over "123456789".
static_assert([] {
    uint16_t crc = 0xFFFF;
    for (char c : {'1', '2', '3', '4', '5', '6', '7', '8', '9'})
        crc = step(static_cast<uint8_t>(c), crc);
    return crc;
}() == 0x6F91);

}  // namespace

uint16_t crc_x25_byte(uint8_t b, uint16_t crc) { return step(b, crc); }

uint16_t crc_x25(std::span<const uint8_t> data, uint16_t crc) {
    for (uint8_t b : data)
        crc = step(b, crc);
    return crc;
}

}  // namespace mavbond
