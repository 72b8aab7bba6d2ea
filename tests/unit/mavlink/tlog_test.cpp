// The parser against recorded telemetry (see /work/shared/data/tlogs/README.md for the figures).
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "mavlink/frame_parser.h"

namespace mavbond {
namespace {

using Bytes = std::vector<uint8_t>;

std::filesystem::path tlog_dir() {
    const char* env = std::getenv("MAVBOND_TLOG_DIR");
    return env != nullptr ? env : "/work/shared/data/tlogs";
}

Bytes read_file(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    return Bytes(std::istreambuf_iterator<char>(in), {});
}

/// What a tlog holds once its 8-byte timestamps are stripped: each record is a frame (framed
/// from its header alone, CRC not checked) or one non-MAVLink byte; a final record cut short
/// is left out.
struct TlogStream {
    Bytes bytes;
    size_t records = 0;    // MAVLink frames
    size_t other = 0;      // non-MAVLink bytes
};

TlogStream strip_timestamps(const Bytes& file) {
    TlogStream s;
    size_t pos = 0;
    while (pos + 8 < file.size()) {
        const uint8_t* r = file.data() + pos + 8;
        const size_t left = file.size() - pos - 8;
        size_t len = 1;
        if (r[0] == kMagicV1 && left >= 2)
            len = kHeaderLenV1 + r[1] + kChecksumLen;
        else if (r[0] == kMagicV2 && left >= 3)
            len = kHeaderLenV2 + r[1] + kChecksumLen + ((r[2] & kIncompatSigned) ? kSignatureLen : 0);
        if (len > left)
            break;   // truncated final record
        s.bytes.insert(s.bytes.end(), r, r + len);
        if (len == 1)
            ++s.other;
        else
            ++s.records;
        pos += 8 + len;
    }
    return s;
}

struct Result {
    ParserCounters counters;
    size_t frames = 0;
};

Result stream(const Bytes& data, UnknownIdPolicy policy) {
    StreamParser p(policy);
    Result r;
    const size_t chunks[] = {1, 4096, 17, 300, 2, 1000, 63, 280};
    size_t pos = 0;
    size_t i = 0;
    Frame f;
    while (pos < data.size()) {
        auto area = p.write_area();
        const size_t n = std::min({chunks[i++ % std::size(chunks)], area.size(), data.size() - pos});
        std::memcpy(area.data(), data.data() + pos, n);
        p.commit(n);
        pos += n;
        while (p.next(f))
            ++r.frames;
    }
    r.counters = p.counters();
    return r;
}

struct Expect {
    const char* file;
    bool raw;              // a raw byte stream, not a tlog
    size_t frames;         // README "Frames"
    size_t bad_crc;        // frames failing the CRC
    size_t unknown;        // frames with an msgid the table lacks
    size_t non_mavlink;    // non-MAVLink records (one byte each)
    // What the parser must count, derived from the data (see the comments in the table):
    size_t crc_errors;     // the failing frames plus false starts inside them
    size_t bad_flags;      // false v2 starts inside failing frames
    size_t garbage;        // bytes of the failing frames + non-MAVLink bytes
};

class Tlog : public ::testing::TestWithParam<Expect> {};

TEST_P(Tlog, FramesAndErrorsMatchTheRecording) {
    const Expect& e = GetParam();
    const auto path = tlog_dir() / e.file;
    if (!std::filesystem::exists(path))
        GTEST_SKIP() << "no " << path << " (set MAVBOND_TLOG_DIR to the recorded tlogs)";
    const Bytes file = read_file(path);
    TlogStream s;
    if (e.raw) {
        s.bytes = file;
    } else {
        s = strip_timestamps(file);
        EXPECT_EQ(s.records, e.frames);
        EXPECT_EQ(s.other, e.non_mavlink);
    }
    const size_t good = e.frames - e.bad_crc;

    const Result fwd = stream(s.bytes, UnknownIdPolicy::Forward);
    const auto& c = fwd.counters;
    std::printf("%s: frames %zu bytes %zu crc_errors %zu (bad_lengths %zu) bad_flags %zu "
                "unknown_ids %zu garbage %zu\n", e.file, size_t(c.frames), size_t(c.bytes),
                size_t(c.crc_errors), size_t(c.bad_lengths), size_t(c.bad_flags),
                size_t(c.unknown_ids), size_t(c.garbage_bytes));
    EXPECT_EQ(fwd.frames, good);
    EXPECT_EQ(fwd.counters.frames, good);
    EXPECT_EQ(fwd.counters.unknown_ids, e.unknown);
    EXPECT_EQ(fwd.counters.crc_errors, e.crc_errors);
    EXPECT_EQ(fwd.counters.bad_flags, e.bad_flags);
    EXPECT_EQ(fwd.counters.garbage_bytes, e.garbage);
    EXPECT_EQ(fwd.counters.bytes + fwd.counters.garbage_bytes, s.bytes.size());

    const Result drop = stream(s.bytes, UnknownIdPolicy::Drop);
    EXPECT_EQ(drop.frames, good - e.unknown);
    EXPECT_EQ(drop.counters.unknown_ids, e.unknown);

    if (!e.raw) {
        // The whole file, timestamps and all: 8 bytes of garbage before every frame, some of
        // them start bytes. Not one good frame may be lost to a false start.
        const Result whole = stream(file, UnknownIdPolicy::Drop);
        EXPECT_EQ(whole.frames, good - e.unknown);
        EXPECT_EQ(whole.counters.unknown_ids, e.unknown);
    }
}

INSTANTIATE_TEST_SUITE_P(
    Recorded, Tlog,
    ::testing::Values(
        // 1,314 v1 frames (255,0) msgid 142 with a 5-byte payload (13 bytes each: 17,082 bytes
        // of garbage); RESOURCE_REQUEST is 243 bytes, so each is rejected by its length. Inside
        // them are 19 start bytes: 0xFE as seq (5, len 255, msgid 255 unknown: the next frame
        // starts inside their span) or as the last CRC byte (4: the next frame's 0xFE becomes a
        // 254-byte length, impossible for msgid 1 (3 times) so 3 more crc_errors; compid 68 is
        // unknown), 0xFD as seq (4, unknown ids) or as the last CRC byte (6: the next frame's
        // length byte is read as incompat flags: 6 bad_flags).
        Expect{"ardupilot-copter-real-2015-dronekit-flight.tlog", false, 76791, 1314, 0, 0,
               1317, 6, 1314 * 13},
        Expect{"ardupilot-plane-quadplane-sitl-2018-uavlogviewer-vtol.tlog", false, 23894, 0, 0, 0,
               0, 0, 0},
        // 285 one-byte records of SITL console text.
        Expect{"ardupilot-rover-boat-sitl-autotest-2025.tlog", false, 96646, 0, 0, 285, 0, 0, 285},
        // 4 camera frames (v2) from older definitions: msgid 259 len 139, 260 len 5, 262 len 16
        // and 269 len 75: each within max_len, so rejected by the CRC; 12 + len bytes each.
        Expect{"ardupilot-sub-real-2023-qgc-small.tlog", false, 35916, 4, 0, 0, 4, 0,
               (12 + 139) + (12 + 5) + (12 + 16) + (12 + 75)},
        // 14 frames with ids all.xml lacks: msgid 8 (x10) and 411 (x4).
        Expect{"px4-plane-raw-v2-3412-packets.mavlink", true, 3412, 0, 14, 0, 0, 0, 0}),
    [](const auto& param_info) {
        std::string name = param_info.param.file;
        name = name.substr(0, name.find('-', name.find('-') + 1));
        for (auto& ch : name) {
            if (ch == '-')
                ch = '_';
        }
        return name;
    });

}  // namespace
}  // namespace mavbond
