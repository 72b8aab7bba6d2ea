#include "parser_checks.h"

#include <cinttypes>
#include <cstdio>

#include "fuzz_check.h"
#include "mavlink/message_table.h"

namespace mavbond::fuzz {

namespace {

/// CRC-16/MCRF4XX one bit at a time: the definition, independent of the parser's tables.
uint16_t reference_crc(const uint8_t* p, size_t n, uint8_t crc_extra) {
    uint16_t crc = 0xFFFF;
    auto fold = [&crc](uint8_t b) {
        crc ^= b;
        for (int bit = 0; bit < 8; ++bit)
            crc = (crc & 1) != 0 ? static_cast<uint16_t>((crc >> 1) ^ 0x8408) : crc >> 1;
    };
    for (size_t i = 0; i < n; ++i)
        fold(p[i]);
    fold(crc_extra);
    return crc;
}

/// A target field as the frame must report it: -1 when the message has none, 0 when a
/// truncated v2 payload cut it off (MAVLink v2 drops trailing zero bytes).
int16_t expected_target(std::span<const uint8_t> payload, bool present, uint8_t ofs) {
    if (!present)
        return -1;
    return ofs < payload.size() ? payload[ofs] : 0;
}

}  // namespace

FrameRecord check_frame(const Frame& f) {
    const std::span<const uint8_t> b = f.bytes;
    FUZZ_CHECK(b.size() >= kHeaderLenV1 + kChecksumLen, "a frame of %zu bytes", b.size());
    const bool v2 = b[0] == kMagicV2;
    FUZZ_CHECK(v2 || b[0] == kMagicV1, "start byte 0x%02x", b[0]);
    const size_t header = v2 ? kHeaderLenV2 : kHeaderLenV1;
    FUZZ_CHECK(b.size() >= header, "a v2 frame of %zu bytes", b.size());
    const bool is_signed = v2 && (b[2] & kIncompatSigned) != 0;
    const size_t payload_len = b[1];
    FUZZ_CHECK(b.size() == header + payload_len + kChecksumLen + (is_signed ? kSignatureLen : 0),
               "%zu bytes for a v%d frame with a %zu-byte payload%s", b.size(), v2 ? 2 : 1,
               payload_len, is_signed ? ", signed" : "");
    FUZZ_CHECK(f.payload.data() == b.data() + header && f.payload.size() == payload_len,
               "the payload view is not the frame's payload");
    FUZZ_CHECK(f.version == (v2 ? 2 : 1), "version %d", f.version);

    uint32_t msgid = 0;
    if (v2) {
        FUZZ_CHECK((b[2] & ~kIncompatSigned) == 0, "yielded with incompat flags 0x%02x", b[2]);
        FUZZ_CHECK(f.incompat_flags == b[2], "incompat_flags %d, header %d", f.incompat_flags, b[2]);
        FUZZ_CHECK(f.seq == b[4] && f.sysid == b[5] && f.compid == b[6], "header fields");
        msgid = b[7] | (b[8] << 8) | (static_cast<uint32_t>(b[9]) << 16);
    } else {
        FUZZ_CHECK(f.incompat_flags == 0, "a v1 frame with incompat_flags %d", f.incompat_flags);
        FUZZ_CHECK(f.seq == b[2] && f.sysid == b[3] && f.compid == b[4], "header fields");
        msgid = b[5];
    }
    FUZZ_CHECK(f.msgid == msgid, "msgid %" PRIu32 ", header %" PRIu32, f.msgid, msgid);

    const MessageInfo* info = find_message(msgid);
    FUZZ_CHECK(f.info == info, "msgid %" PRIu32 ": the frame's table entry is not the table's",
               msgid);
    FUZZ_CHECK(f.crc_checked == (info != nullptr), "msgid %" PRIu32 " crc_checked %d", msgid,
               f.crc_checked);
    if (info != nullptr) {
        FUZZ_CHECK(payload_len <= info->max_len && (v2 || payload_len >= info->min_len),
                   "msgid %" PRIu32 " yielded with a %zu-byte payload (allowed %d..%d)", msgid,
                   payload_len, v2 ? 0 : info->min_len, info->max_len);
        const size_t ck = header + payload_len;
        const auto sent = static_cast<uint16_t>(b[ck] | (b[ck + 1] << 8));
        const uint16_t crc = reference_crc(b.data() + 1, ck - 1, info->crc_extra);
        FUZZ_CHECK(crc == sent, "msgid %" PRIu32 " yielded with CRC 0x%04x, computed 0x%04x",
                   msgid, sent, crc);
        FUZZ_CHECK(f.target_system ==
                           expected_target(f.payload, info->has_target_system,
                                           info->target_system_ofs) &&
                       f.target_component == expected_target(f.payload,
                                                             info->has_target_component,
                                                             info->target_component_ofs),
                   "msgid %" PRIu32 " targets %d/%d", msgid, f.target_system, f.target_component);
    } else {
        FUZZ_CHECK(f.target_system == -1 && f.target_component == -1,
                   "unknown msgid %" PRIu32 " with targets %d/%d", msgid, f.target_system,
                   f.target_component);
    }
    return FrameRecord{{b.begin(), b.end()}, f.msgid,  f.version,       f.incompat_flags,
                       f.seq,                f.sysid,  f.compid,        f.target_system,
                       f.target_component,   f.crc_checked};
}

void check_reparses(const FrameRecord& record) {
    ParserCounters c;
    DatagramParser parser(record.bytes, UnknownIdPolicy::Forward, c);
    Frame f;
    FUZZ_CHECK(parser.next(f), "msgid %" PRIu32 ": its %zu bytes alone yield no frame",
               record.msgid, record.bytes.size());
    FUZZ_CHECK(check_frame(f) == record, "msgid %" PRIu32 ": alone it parses differently",
               record.msgid);
    FUZZ_CHECK(!parser.next(f), "msgid %" PRIu32 ": alone it yields a second frame",
               record.msgid);
    ParserCounters want;
    want.frames = 1;
    want.bytes = record.bytes.size();
    want.unknown_ids = record.crc_checked ? 0 : 1;
    if (!same_counters(c, want)) {
        print_counters("alone", c);
        print_counters("expected", want);
        FUZZ_CHECK(false, "msgid %" PRIu32 ": parsed alone, its counters are off", record.msgid);
    }
}

void check_drop_matches_forward(const ParseRun& drop, const ParseRun& forward) {
    std::vector<FrameRecord> checked;
    uint64_t unknown_bytes = 0;
    for (const auto& r : forward.frames) {
        if (r.crc_checked)
            checked.push_back(r);
        else
            unknown_bytes += r.bytes.size();
    }
    FUZZ_CHECK(drop.frames == checked, "Drop yielded %zu frames, Forward %zu of known ids",
               drop.frames.size(), checked.size());
    ParserCounters want = forward.counters;
    want.frames -= forward.frames.size() - checked.size();
    want.bytes -= unknown_bytes;
    if (!same_counters(drop.counters, want)) {
        print_counters("drop", drop.counters);
        print_counters("forward minus unknown ids", want);
        FUZZ_CHECK(false, "the unknown-id policy changed how bytes were judged");
    }
}

bool same_counters(const ParserCounters& a, const ParserCounters& b) {
    return a.frames == b.frames && a.bytes == b.bytes && a.crc_errors == b.crc_errors &&
           a.bad_lengths == b.bad_lengths && a.garbage_bytes == b.garbage_bytes &&
           a.unknown_ids == b.unknown_ids && a.bad_flags == b.bad_flags;
}

void print_counters(const char* label, const ParserCounters& c) {
    std::fprintf(stderr,
                 "%s: frames=%" PRIu64 " bytes=%" PRIu64 " crc_errors=%" PRIu64
                 " bad_lengths=%" PRIu64 " garbage_bytes=%" PRIu64 " unknown_ids=%" PRIu64
                 " bad_flags=%" PRIu64 "\n",
                 label, c.frames, c.bytes, c.crc_errors, c.bad_lengths, c.garbage_bytes,
                 c.unknown_ids, c.bad_flags);
}

}  // namespace mavbond::fuzz
