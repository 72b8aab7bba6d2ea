// The message table, computed at compile time from c_library_v2's MAVLINK_MESSAGE_CRCS (CRC_EXTRA,
// lengths, target offsets), MAVLINK_MESSAGE_INFO (field names, types, wire offsets) and
// MAVLINK_MESSAGE_NAMES. Nothing is built at run time: lookups read constant arrays.
#include "mavlink/message_table.h"

#include <array>
#include <cstring>

#include <all/mavlink.h>

namespace mavbond {

namespace {

constexpr mavlink_msg_entry_t kCrcEntries[] = MAVLINK_MESSAGE_CRCS;
constexpr size_t kMessageCount = std::size(kCrcEntries);
constexpr uint32_t kDirectIds = 512;   // ids below this are looked up by index

struct NameEntry {
    const char* name;
    uint32_t msgid;
};
constexpr NameEntry kNames[] = MAVLINK_MESSAGE_NAMES;
static_assert(std::size(kNames) == kMessageCount);

constexpr bool str_equal(const char* a, const char* b) {
    while (*a != '\0' && *a == *b) {
        ++a;
        ++b;
    }
    return *a == *b;
}

constexpr int str_compare(std::string_view a, const char* b) {
    size_t i = 0;
    for (; i < a.size() && b[i] != '\0'; ++i) {
        if (a[i] != b[i])
            return static_cast<unsigned char>(a[i]) < static_cast<unsigned char>(b[i]) ? -1 : 1;
    }
    if (i == a.size())
        return b[i] == '\0' ? 0 : -1;
    return 1;
}

// find_message_id() bisects kNames: mavgen emits it sorted by name.
static_assert([] {
    for (size_t i = 1; i < kMessageCount; ++i) {
        if (str_compare(kNames[i - 1].name, kNames[i].name) >= 0)
            return false;
    }
    return true;
}());

// find_message() bisects the table above kDirectIds: mavgen emits the CRC entries sorted by id.
static_assert([] {
    for (size_t i = 1; i < kMessageCount; ++i) {
        if (kCrcEntries[i - 1].msgid >= kCrcEntries[i].msgid)
            return false;
    }
    return true;
}());

struct Timestamp {
    int16_t ofs = -1;
    uint8_t size = 0;
    bool us = false;
};

// The wire offset of a scalar time_boot_ms (uint32, ms) or time_usec (uint64, or uint32 as in
// SERVO_OUTPUT_RAW, us) field. Only samples of one message are ever compared, so a 32-bit
// microsecond clock is as good an order as any (its wrap every 71 minutes reads as a restart).
constexpr Timestamp find_timestamp(const mavlink_message_info_t& info) {
    for (unsigned f = 0; f < info.num_fields; ++f) {
        const mavlink_field_info_t& field = info.fields[f];
        if (field.array_length != 0)
            continue;
        if (field.type == MAVLINK_TYPE_UINT32_T && str_equal(field.name, "time_boot_ms"))
            return {static_cast<int16_t>(field.wire_offset), 4, false};
        if (str_equal(field.name, "time_usec") &&
            (field.type == MAVLINK_TYPE_UINT64_T || field.type == MAVLINK_TYPE_UINT32_T))
            return {static_cast<int16_t>(field.wire_offset),
                    static_cast<uint8_t>(field.type == MAVLINK_TYPE_UINT64_T ? 8 : 4), true};
    }
    return {};
}

struct Instance {
    int16_t ofs = -1;
    uint8_t size = 0;
};

// The field that tells a message's instances apart, when one source sends several (two
// batteries, every aircraft ADS-B hears, each distance sensor): a scalar integer of at most 4
// bytes by one of these names. A field so named that is not an instance only makes more
// instances than there are, never fewer.
constexpr Instance find_instance(const mavlink_message_info_t& info) {
    constexpr const char* kInstanceNames[] = {"id",         "instance",   "port",
                                              "index",      "sensor_id",  "compass_id",
                                              "gps_id",     "target_num", "camera_id",
                                              "ICAO_address"};
    for (unsigned f = 0; f < info.num_fields; ++f) {
        const mavlink_field_info_t& field = info.fields[f];
        if (field.array_length != 0)
            continue;
        uint8_t size = 0;
        switch (field.type) {
        case MAVLINK_TYPE_UINT8_T:
        case MAVLINK_TYPE_INT8_T:
            size = 1;
            break;
        case MAVLINK_TYPE_UINT16_T:
        case MAVLINK_TYPE_INT16_T:
            size = 2;
            break;
        case MAVLINK_TYPE_UINT32_T:
        case MAVLINK_TYPE_INT32_T:
            size = 4;
            break;
        default:
            continue;
        }
        for (const char* name : kInstanceNames) {
            if (str_equal(field.name, name))
                return {static_cast<int16_t>(field.wire_offset), size};
        }
    }
    return {};
}

struct Tables {
    std::array<MessageInfo, kMessageCount> messages{};
    std::array<int16_t, kDirectIds> direct{};   // index into messages, -1 when unknown
};

constexpr Tables build_tables() {
    // About 1 MB of field descriptions: it lives only inside this constant evaluation.
    constexpr mavlink_message_info_t infos[] = MAVLINK_MESSAGE_INFO;
    static_assert(std::size(infos) == kMessageCount);
    Tables t;
    for (auto& d : t.direct)
        d = -1;
    for (size_t i = 0; i < kMessageCount; ++i) {
        const mavlink_msg_entry_t& e = kCrcEntries[i];
        const mavlink_message_info_t* info = nullptr;
        for (const auto& candidate : infos) {
            if (candidate.msgid == e.msgid)
                info = &candidate;
        }
        if (info == nullptr)
            throw "MAVLINK_MESSAGE_INFO lacks a message of MAVLINK_MESSAGE_CRCS";
        const Timestamp ts = find_timestamp(*info);
        const Instance instance = find_instance(*info);
        t.messages[i] = MessageInfo{
            .msgid = e.msgid,
            .crc_extra = e.crc_extra,
            .min_len = e.min_msg_len,
            .max_len = e.max_msg_len,
            .target_system_ofs = e.target_system_ofs,
            .target_component_ofs = e.target_component_ofs,
            .has_target_system = (e.flags & 1) != 0,
            .has_target_component = (e.flags & 2) != 0,
            .timestamp_ofs = ts.ofs,
            .timestamp_size = ts.size,
            .timestamp_us = ts.us,
            .instance_ofs = instance.ofs,
            .instance_size = instance.size,
            .name = info->name,
        };
        if (e.msgid < kDirectIds)
            t.direct[e.msgid] = static_cast<int16_t>(i);
    }
    return t;
}

constexpr Tables kTables = build_tables();

}  // namespace

const MessageInfo* find_message(uint32_t msgid) {
    if (msgid < kDirectIds) {
        const int16_t i = kTables.direct[msgid];
        return i < 0 ? nullptr : &kTables.messages[static_cast<size_t>(i)];
    }
    size_t lo = 0;
    size_t hi = kMessageCount;
    while (lo < hi) {
        const size_t mid = lo + (hi - lo) / 2;
        const uint32_t id = kTables.messages[mid].msgid;
        if (id == msgid)
            return &kTables.messages[mid];
        if (id < msgid)
            lo = mid + 1;
        else
            hi = mid;
    }
    return nullptr;
}

std::optional<uint32_t> find_message_id(std::string_view name) {
    size_t lo = 0;
    size_t hi = kMessageCount;
    while (lo < hi) {
        const size_t mid = lo + (hi - lo) / 2;
        const int c = str_compare(name, kNames[mid].name);
        if (c == 0)
            return kNames[mid].msgid;
        if (c > 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return std::nullopt;
}

size_t message_count() { return kMessageCount; }

}  // namespace mavbond
