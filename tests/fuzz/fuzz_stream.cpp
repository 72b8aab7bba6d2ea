// Fuzz target: the stream parser (UART/TCP: frames split across reads, noise between them).
// The input is a byte stream, fed the way the daemon feeds it (read into write_area(), commit,
// drain next()) through the smallest buffer the parser accepts. For any input:
//  - every frame is the input's bytes at the offset the counters imply, checks out against its
//    own bytes (parser_checks.h) and, parsed alone as a datagram, is the same frame;
//  - the counters account for every byte: fed = yielded bytes + garbage + still buffered, after
//    every read; and a drained parser never has to give up a buffered byte to make room;
//  - how the stream is split into reads changes nothing: whole, byte by byte and in random
//    chunks give the same frames, counters and leftover;
//  - the stream's frames are the first frames the datagram parser finds in the same bytes
//    (a stream only waits where a datagram, knowing nothing follows, decides);
//  - the Drop policy yields the same frames less the unknown-id ones, judging every byte alike.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <functional>
#include <span>

#include "fuzz_check.h"
#include "parser_checks.h"

namespace mavbond::fuzz {
namespace {

// The smallest buffer StreamParser accepts (two largest frames: an unknown-id candidate and a
// known frame that may start inside it), so waiting is exercised at its limit.
constexpr size_t kCapacity = 2 * kMaxFrameLen;

struct StreamRun : ParseRun {
    size_t buffered = 0;   // bytes still waiting for more input at the end
};

/// Feeds `input` in reads of chunk() bytes (at most what write_area() offers), draining the
/// parser after each, checking the byte accounting all along.
StreamRun feed(std::span<const uint8_t> input, UnknownIdPolicy policy,
               const std::function<size_t()>& chunk) {
    StreamParser parser(policy, kCapacity);
    const ParserCounters& c = parser.counters();
    const bool forward = policy == UnknownIdPolicy::Forward;
    StreamRun run;
    size_t fed = 0;
    size_t previous_end = 0;
    Frame f;
    for (;;) {
        const uint64_t garbage_before = c.garbage_bytes;
        const std::span<uint8_t> area = parser.write_area();
        FUZZ_CHECK(c.garbage_bytes == garbage_before,
                   "after %zu bytes, a drained parser gave up a buffered byte to make room", fed);
        FUZZ_CHECK(!area.empty() && area.size() <= kCapacity, "write area of %zu bytes",
                   area.size());
        const size_t buffered = kCapacity - area.size();
        if (forward) {
            FUZZ_CHECK(fed == c.bytes + c.garbage_bytes + buffered,
                       "%zu bytes fed, %zu yielded + %zu garbage + %zu buffered", fed,
                       static_cast<size_t>(c.bytes), static_cast<size_t>(c.garbage_bytes),
                       buffered);
        }
        if (fed == input.size()) {
            run.buffered = buffered;
            break;
        }
        const size_t n = std::max<size_t>(1, std::min({chunk(), area.size(), input.size() - fed}));
        std::memcpy(area.data(), input.data() + fed, n);
        parser.commit(n);
        fed += n;
        while (parser.next(f)) {
            run.frames.push_back(check_frame(f));
            if (!forward)
                continue;
            // Every byte before the frame's end was yielded or skipped as garbage.
            const size_t end = c.bytes + c.garbage_bytes;
            FUZZ_CHECK(end >= previous_end + f.bytes.size() && end <= fed,
                       "a frame of %zu bytes ending at %zu (previous end %zu, fed %zu)",
                       f.bytes.size(), end, previous_end, fed);
            FUZZ_CHECK(std::memcmp(input.data() + end - f.bytes.size(), f.bytes.data(),
                                   f.bytes.size()) == 0,
                       "the frame ending at %zu is not the input's bytes there", end);
            previous_end = end;
        }
    }
    // reset() drops what was buffered, as garbage, and empties the buffer.
    const uint64_t garbage_before = c.garbage_bytes;
    parser.reset();
    FUZZ_CHECK(c.garbage_bytes == garbage_before + run.buffered, "reset() lost count of %zu bytes",
               run.buffered);
    FUZZ_CHECK(parser.write_area().size() == kCapacity, "reset() left bytes behind");
    run.counters = c;
    run.counters.garbage_bytes = garbage_before;   // as before reset(), to compare runs
    return run;
}

/// Same frames, counters and leftover.
void check_same_run(const StreamRun& a, const StreamRun& b, const char* how) {
    FUZZ_CHECK(a.frames == b.frames, "fed %s: %zu frames, whole: %zu", how, b.frames.size(),
               a.frames.size());
    if (!same_counters(a.counters, b.counters)) {
        print_counters("whole", a.counters);
        print_counters(how, b.counters);
        FUZZ_CHECK(false, "fed %s, the counters differ", how);
    }
    FUZZ_CHECK(a.buffered == b.buffered, "fed %s: %zu bytes left buffered, whole: %zu", how,
               b.buffered, a.buffered);
}

/// Read sizes from 1 to a bit over a largest frame, from a generator seeded by the input, so
/// that each input has its own split (xorshift64: deterministic, for replays).
class RandomChunks {
public:
    explicit RandomChunks(std::span<const uint8_t> input) {
        for (uint8_t b : input)
            state_ = (state_ ^ b) * 0x100000001B3ull;   // FNV-1a
        state_ |= 1;
    }
    size_t operator()() {
        state_ ^= state_ << 13;
        state_ ^= state_ >> 7;
        state_ ^= state_ << 17;
        return 1 + state_ % (kMaxFrameLen + 20);
    }

private:
    uint64_t state_ = 0xCBF29CE484222325ull;
};

std::vector<FrameRecord> datagram_frames(std::span<const uint8_t> input) {
    ParserCounters c;
    DatagramParser parser(input, UnknownIdPolicy::Forward, c);
    std::vector<FrameRecord> out;
    Frame f;
    while (parser.next(f))
        out.push_back(check_frame(f));
    return out;
}

}  // namespace
}  // namespace mavbond::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    using namespace mavbond;
    using namespace mavbond::fuzz;
    const std::span<const uint8_t> input(data, size);
    const auto whole = [] { return SIZE_MAX; };

    const StreamRun run = feed(input, UnknownIdPolicy::Forward, whole);
    const ParserCounters& c = run.counters;
    FUZZ_CHECK(c.frames == run.frames.size(), "counted %zu frames, yielded %zu",
               static_cast<size_t>(c.frames), run.frames.size());
    FUZZ_CHECK(c.bad_lengths <= c.crc_errors, "bad_lengths is a part of crc_errors");
    size_t unknown = 0;
    for (const FrameRecord& r : run.frames) {
        unknown += r.crc_checked ? 0 : 1;
        check_reparses(r);
    }
    FUZZ_CHECK(c.unknown_ids == unknown, "counted %zu unknown ids, forwarded %zu",
               static_cast<size_t>(c.unknown_ids), unknown);

    check_same_run(run, feed(input, UnknownIdPolicy::Forward, [] { return size_t{1}; }),
                   "byte by byte");
    RandomChunks random(input);
    check_same_run(run, feed(input, UnknownIdPolicy::Forward, std::ref(random)),
                   "in random chunks");

    const std::vector<FrameRecord> datagram = datagram_frames(input);
    FUZZ_CHECK(run.frames.size() <= datagram.size() &&
                   std::equal(run.frames.begin(), run.frames.end(), datagram.begin()),
               "the stream's %zu frames are not the first of the datagram parser's %zu",
               run.frames.size(), datagram.size());

    const StreamRun drop = feed(input, UnknownIdPolicy::Drop, whole);
    check_drop_matches_forward(drop, run);
    FUZZ_CHECK(drop.buffered == run.buffered, "Drop left %zu bytes buffered, Forward %zu",
               drop.buffered, run.buffered);
    return 0;
}
