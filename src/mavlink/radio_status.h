// RADIO_STATUS: what a telemetry radio says of its link (src/endpoints/radio_flow.h reads it).
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <span>

namespace mavbond {

constexpr uint32_t kMsgRadioStatus = 109;  // RADIO_STATUS (common.xml)
constexpr uint32_t kMsgRadio = 166;        // RADIO (ardupilotmega.xml): its older twin, same fields
constexpr uint8_t kSikSysid = 51;          // '3'
constexpr uint8_t kSikCompid = 68;         // 'D'

inline bool is_radio_status(uint32_t msgid) {
    return msgid == kMsgRadioStatus || msgid == kMsgRadio;
}

/// A RADIO_STATUS's fields. 255 in the signal fields: unknown (as the message defines it).
struct RadioReport {
    static constexpr size_t kPayloadLen = 9;
    uint16_t rxerrors = 0;
    uint16_t fixed = 0;
    uint8_t rssi = 255;
    uint8_t remrssi = 255;
    uint8_t txbuf = 100;
    uint8_t noise = 255;
    uint8_t remnoise = 255;

    /// From a payload in wire order (a MAVLink 2 payload may end early: its zeros trimmed).
    static RadioReport decode(std::span<const uint8_t> payload) {
        std::array<uint8_t, kPayloadLen> p{};
        std::copy_n(payload.begin(), std::min(payload.size(), p.size()), p.begin());
        return RadioReport{static_cast<uint16_t>(p[0] | p[1] << 8),
                           static_cast<uint16_t>(p[2] | p[3] << 8), p[4], p[5], p[6], p[7], p[8]};
    }
    /// Its payload in wire order.
    std::array<uint8_t, kPayloadLen> encode() const {
        return {static_cast<uint8_t>(rxerrors), static_cast<uint8_t>(rxerrors >> 8),
                static_cast<uint8_t>(fixed), static_cast<uint8_t>(fixed >> 8),
                rssi, remrssi, txbuf, noise, remnoise};
    }
    bool operator==(const RadioReport&) const = default;
};

}  // namespace mavbond
