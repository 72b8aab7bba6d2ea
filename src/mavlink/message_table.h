// What c_library_v2 knows about each message id: CRC_EXTRA, lengths, target field offsets,
// names, a timestamp field and an instance field. Built from the generated library's tables at compile time.
#pragma once

#include <cstdint>
#include <optional>
#include <string_view>

namespace mavbond {

struct MessageInfo {
    uint32_t msgid;
    uint8_t crc_extra;
    uint8_t min_len;                // payload length without extension fields (a v1 frame's)
    uint8_t max_len;                // payload length with every extension field
    uint8_t target_system_ofs;      // valid when has_target_system
    uint8_t target_component_ofs;   // valid when has_target_component
    bool has_target_system;
    bool has_target_component;
    int16_t timestamp_ofs;          // wire offset of time_boot_ms / time_usec, -1 if none
    uint8_t timestamp_size;         // its size in bytes (4 or 8); 0 if none
    bool timestamp_us;              // time_usec (microseconds), else time_boot_ms (milliseconds)
    int16_t instance_ofs;           // wire offset of the field telling instances apart (a
                                    // battery's id, an aircraft's ICAO_address), -1 if none
    uint8_t instance_size;          // its size in bytes (1 to 4); 0 if none
    const char* name;
};

/// The entry for msgid, or nullptr when c_library_v2 does not define it. O(1) for the
/// common ids (below 512), a binary search above.
const MessageInfo* find_message(uint32_t msgid);

/// msgid for a message name such as "HEARTBEAT" (case-sensitive), if known.
std::optional<uint32_t> find_message_id(std::string_view name);

/// Number of messages in the table.
size_t message_count();

}  // namespace mavbond
