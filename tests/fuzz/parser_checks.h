// What the two frame-parser fuzz targets check about every frame they are given, re-derived
// from the frame's own bytes rather than trusted from the parser (the CRC with a bitwise
// reference, not the parser's table-driven one), and how their runs are compared.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "mavlink/frame.h"
#include "mavlink/frame_parser.h"

namespace mavbond::fuzz {

/// A yielded frame copied out of the parser (a stream parser's frames die with its buffer),
/// so that runs over the same input can be compared.
struct FrameRecord {
    std::vector<uint8_t> bytes;
    uint32_t msgid = 0;
    uint8_t version = 0;
    uint8_t incompat_flags = 0;
    uint8_t seq = 0;
    uint8_t sysid = 0;
    uint8_t compid = 0;
    int16_t target_system = -1;
    int16_t target_component = -1;
    bool crc_checked = false;

    bool operator==(const FrameRecord&) const = default;
};

/// The frames and final counters of one parse.
struct ParseRun {
    std::vector<FrameRecord> frames;
    ParserCounters counters;
};

/// Checks every field of `f` against its bytes and the message table (a known msgid's CRC
/// verified, its length allowed; an unknown one yielded unchecked), aborting on any mismatch.
FrameRecord check_frame(const Frame& f);

/// A frame's bytes parsed alone as a datagram yield that very frame and nothing else: no
/// garbage, no error. (What a router forwarding it in its own datagram relies on.)
void check_reparses(const FrameRecord& record);

/// The unknown-id policy decides only whether an unknown-id frame is yielded, never how the
/// bytes are judged: a Drop run is the Forward run without its unknown-id frames, with the
/// same garbage and error counts, and the dropped frames' bytes make up the difference.
void check_drop_matches_forward(const ParseRun& drop, const ParseRun& forward);

bool same_counters(const ParserCounters& a, const ParserCounters& b);
void print_counters(const char* label, const ParserCounters& c);

}  // namespace mavbond::fuzz
