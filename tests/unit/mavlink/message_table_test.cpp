#include <gtest/gtest.h>

#include <array>
#include <cstring>
#include <string>

#include "mavlink/frame_parser.h"
#include "mavlink/message_table.h"

namespace mavbond {
namespace {

TEST(MessageTable, Heartbeat) {
    const MessageInfo* hb = find_message(0);
    ASSERT_NE(hb, nullptr);
    EXPECT_EQ(hb->msgid, 0u);
    EXPECT_STREQ(hb->name, "HEARTBEAT");
    EXPECT_EQ(hb->crc_extra, 50);
    EXPECT_EQ(hb->min_len, 9);
    EXPECT_EQ(hb->max_len, 9);
    EXPECT_FALSE(hb->has_target_system);
    EXPECT_FALSE(hb->has_target_component);
    EXPECT_EQ(hb->timestamp_ofs, -1);
    EXPECT_EQ(hb->timestamp_size, 0);
    EXPECT_EQ(find_message_id("HEARTBEAT"), 0u);
}

TEST(MessageTable, AttitudeTimestamp) {
    const MessageInfo* att = find_message(30);
    ASSERT_NE(att, nullptr);
    EXPECT_STREQ(att->name, "ATTITUDE");
    EXPECT_EQ(att->crc_extra, 39);
    EXPECT_EQ(att->timestamp_ofs, 0);
    EXPECT_EQ(att->timestamp_size, 4);
    EXPECT_FALSE(att->timestamp_us);
    EXPECT_EQ(find_message_id("ATTITUDE"), 30u);
}

TEST(MessageTable, TimeUsec) {
    const MessageInfo* gps = find_message(24);   // GPS_RAW_INT: uint64 time_usec first on the wire
    ASSERT_NE(gps, nullptr);
    EXPECT_EQ(gps->timestamp_ofs, 0);
    EXPECT_EQ(gps->timestamp_size, 8);
    // SERVO_OUTPUT_RAW's time_usec is a uint32 microsecond clock: still a sample order.
    const MessageInfo* servo = find_message(36);
    ASSERT_NE(servo, nullptr);
    EXPECT_EQ(servo->timestamp_ofs, 0);
    EXPECT_EQ(servo->timestamp_size, 4);
    EXPECT_TRUE(servo->timestamp_us);
    EXPECT_TRUE(gps->timestamp_us);
    // SYSTEM_TIME: time_unix_usec (uint64) comes first on the wire, time_boot_ms at 8.
    const MessageInfo* st = find_message(2);
    ASSERT_NE(st, nullptr);
    EXPECT_EQ(st->timestamp_ofs, 8);
    EXPECT_EQ(st->timestamp_size, 4);
}

TEST(MessageTable, Targets) {
    const MessageInfo* cmd = find_message(76);   // COMMAND_LONG
    ASSERT_NE(cmd, nullptr);
    EXPECT_TRUE(cmd->has_target_system);
    EXPECT_TRUE(cmd->has_target_component);
    EXPECT_EQ(cmd->target_system_ofs, 30);
    EXPECT_EQ(cmd->target_component_ofs, 31);
    EXPECT_EQ(cmd->min_len, 33);
    const MessageInfo* prr = find_message(20);   // PARAM_REQUEST_READ
    ASSERT_NE(prr, nullptr);
    EXPECT_EQ(prr->target_system_ofs, 2);
    EXPECT_EQ(prr->target_component_ofs, 3);
    const MessageInfo* gpo = find_message(48);   // SET_GPS_GLOBAL_ORIGIN: target_system only
    ASSERT_NE(gpo, nullptr);
    EXPECT_TRUE(gpo->has_target_system);
    EXPECT_FALSE(gpo->has_target_component);
}

TEST(MessageTable, Instances) {
    // BATTERY_STATUS: int32 x2, int16, uint16[10], int16 before it: id at 32.
    const MessageInfo* battery = find_message(147);
    ASSERT_NE(nullptr, battery);
    EXPECT_EQ(32, battery->instance_ofs);
    EXPECT_EQ(1, battery->instance_size);
    const MessageInfo* adsb = find_message(246);  // ADSB_VEHICLE: ICAO_address first
    ASSERT_NE(nullptr, adsb);
    EXPECT_EQ(0, adsb->instance_ofs);
    EXPECT_EQ(4, adsb->instance_size);
    const MessageInfo* attitude = find_message(30);
    EXPECT_EQ(-1, attitude->instance_ofs);
    EXPECT_EQ(0, attitude->instance_size);
}

TEST(MessageTable, HighIdsUseTheSearchPath) {
    const MessageInfo* odid = find_message(12900);   // OPEN_DRONE_ID_BASIC_ID
    ASSERT_NE(odid, nullptr);
    EXPECT_STREQ(odid->name, "OPEN_DRONE_ID_BASIC_ID");
    EXPECT_TRUE(odid->has_target_system);
    EXPECT_EQ(find_message_id("OPEN_DRONE_ID_BASIC_ID"), 12900u);
}

TEST(MessageTable, Unknown) {
    EXPECT_EQ(find_message(8), nullptr);
    EXPECT_EQ(find_message(411), nullptr);
    EXPECT_EQ(find_message(15000), nullptr);
    EXPECT_EQ(find_message(0xFFFFFF), nullptr);
    EXPECT_EQ(find_message_id("NO_SUCH_MESSAGE"), std::nullopt);
    EXPECT_EQ(find_message_id("heartbeat"), std::nullopt);   // case-sensitive
    EXPECT_EQ(find_message_id(""), std::nullopt);
    EXPECT_EQ(find_message_id("HEARTBEATS"), std::nullopt);
    EXPECT_EQ(find_message_id("HEARTBEA"), std::nullopt);
}

TEST(MessageTable, EveryEntryIsConsistent) {
    size_t seen = 0;
    for (uint32_t id = 0; id < (1u << 16); ++id) {
        const MessageInfo* m = find_message(id);
        if (m == nullptr)
            continue;
        ++seen;
        EXPECT_EQ(m->msgid, id);
        ASSERT_NE(m->name, nullptr);
        EXPECT_EQ(find_message_id(m->name), id) << m->name;
        EXPECT_LE(m->min_len, m->max_len) << m->name;
        if (m->has_target_system) {
            EXPECT_LT(m->target_system_ofs, m->max_len) << m->name;
        }
        if (m->has_target_component) {
            EXPECT_LT(m->target_component_ofs, m->max_len) << m->name;
        }
        if (m->timestamp_ofs >= 0) {
            EXPECT_LE(m->timestamp_ofs + m->timestamp_size, m->max_len) << m->name;
        }
    }
    EXPECT_EQ(seen, message_count());
    EXPECT_GT(message_count(), 300u);
}

TEST(Crc, CheckValue) {
    const char* s = "123456789";
    const auto* p = reinterpret_cast<const uint8_t*>(s);
    EXPECT_EQ(crc_x25({p, std::strlen(s)}), 0x6F91);
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < 9; ++i)
        crc = crc_x25_byte(p[i], crc);
    EXPECT_EQ(crc, 0x6F91);
    EXPECT_EQ(crc_x25({}), 0xFFFF);
}

}  // namespace
}  // namespace mavbond
