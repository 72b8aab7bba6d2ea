// MAVLink framing: datagram mode (one UDP datagram may hold several frames) and stream mode
// (UART/TCP: frames split across reads, garbage between frames). Both check the CRC with
// CRC_EXTRA from c_library_v2 and resync after garbage by retrying from the next start byte
// inside a rejected span, within the same call.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "mavlink/frame.h"

namespace mavbond {

/// What happens to frames whose msgid c_library_v2 does not know (their CRC cannot be checked).
/// Such a frame is believed only when no CRC-valid known frame starts inside it and a frame
/// boundary follows it (a start byte, or the end of the datagram); otherwise it is garbage.
/// Forward yields it with crc_checked = false; Drop skips it. Both count unknown_ids.
enum class UnknownIdPolicy { Forward, Drop };

struct ParserCounters {
    uint64_t frames = 0;          // frames yielded (checked + unknown forwarded)
    uint64_t bytes = 0;           // bytes of the yielded frames
    uint64_t crc_errors = 0;      // candidates failing the integrity check: bad CRC, or a
                                  // length impossible for their (known) msgid
    uint64_t bad_lengths = 0;     // the part of crc_errors rejected by length alone
    uint64_t garbage_bytes = 0;   // bytes skipped that were not part of a yielded or dropped
                                  // frame (a rejected candidate's bytes become garbage)
    uint64_t unknown_ids = 0;     // frames with an unknown msgid (forwarded or dropped)
    uint64_t bad_flags = 0;       // v2 frames with incompat flag bits we do not understand

    ParserCounters& operator+=(const ParserCounters& o) {
        frames += o.frames;
        bytes += o.bytes;
        crc_errors += o.crc_errors;
        bad_lengths += o.bad_lengths;
        garbage_bytes += o.garbage_bytes;
        unknown_ids += o.unknown_ids;
        bad_flags += o.bad_flags;
        return *this;
    }
};

/// Parses the frames of one datagram in place. Frames are views into `datagram`.
class DatagramParser {
public:
    DatagramParser(std::span<const uint8_t> datagram, UnknownIdPolicy policy, ParserCounters& counters);
    /// Fills `frame` with the next frame; false when the datagram is exhausted (trailing
    /// garbage and incomplete frames are counted as garbage).
    bool next(Frame& frame);

private:
    std::span<const uint8_t> data_;
    size_t pos_ = 0;
    UnknownIdPolicy policy_;
    ParserCounters& counters_;
};

/// Accumulates a byte stream and yields frames. Frames are views into the parser's buffer,
/// valid until the next call to write_area()/commit().
class StreamParser {
public:
    explicit StreamParser(UnknownIdPolicy policy, size_t capacity = 4096);
    /// Space to read() into (compacts consumed bytes first). Never empty.
    std::span<uint8_t> write_area();
    /// Marks n bytes of write_area() as filled.
    void commit(size_t n);
    /// Next complete frame in the buffered bytes; false when more bytes are needed. Rejected
    /// candidates are retried from the next start byte within the same call. A possible
    /// known-id frame waits for its bytes; an unknown-id frame waits for the next start byte.
    bool next(Frame& frame);
    /// Drops buffered bytes (e.g. after a UART reopen); counts them as garbage.
    void reset();
    const ParserCounters& counters() const { return counters_; }
    ParserCounters& counters() { return counters_; }

private:
    std::vector<uint8_t> buf_;
    size_t begin_ = 0;   // first unconsumed byte
    size_t end_ = 0;     // one past the last filled byte
    UnknownIdPolicy policy_;
    ParserCounters counters_;
};

/// X.25 CRC-16/MCRF4XX as MAVLink uses it.
uint16_t crc_x25(std::span<const uint8_t> data, uint16_t crc = 0xFFFF);
uint16_t crc_x25_byte(uint8_t b, uint16_t crc);

}  // namespace mavbond
