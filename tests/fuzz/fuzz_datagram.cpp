// Fuzz target: the datagram parser (UDP: one datagram, several frames, garbage anywhere).
// Beyond "no crash", for any input:
//  - every frame lies inside the datagram, after the previous one, and checks out against its
//    own bytes (parser_checks.h); parsed alone, it is the same frame;
//  - the counters account for every byte: when a frame is yielded, the bytes up to its end are
//    exactly the yielded frames' bytes plus the garbage; at the end, bytes + garbage_bytes is
//    the datagram's size (unknown-id frames included: the policy is Forward);
//  - the Drop policy yields the same frames less the unknown-id ones, judging every byte alike.
#include <cstdint>
#include <span>

#include "fuzz_check.h"
#include "parser_checks.h"

namespace mavbond::fuzz {
namespace {

ParseRun parse(std::span<const uint8_t> datagram, UnknownIdPolicy policy) {
    ParseRun run;
    DatagramParser parser(datagram, policy, run.counters);
    const auto base = reinterpret_cast<uintptr_t>(datagram.data());
    size_t previous_end = 0;
    Frame f;
    while (parser.next(f)) {
        const auto at = reinterpret_cast<uintptr_t>(f.bytes.data());
        FUZZ_CHECK(at >= base && at - base + f.bytes.size() <= datagram.size(),
                   "a frame outside the datagram");
        const size_t offset = at - base;
        FUZZ_CHECK(offset >= previous_end, "a frame at %zu overlaps or precedes the one ending at %zu",
                   offset, previous_end);
        previous_end = offset + f.bytes.size();
        if (policy == UnknownIdPolicy::Forward) {
            const ParserCounters& c = run.counters;
            FUZZ_CHECK(c.bytes + c.garbage_bytes == previous_end,
                       "frame ending at %zu: %zu yielded + %zu garbage bytes before it",
                       previous_end, static_cast<size_t>(c.bytes),
                       static_cast<size_t>(c.garbage_bytes));
        }
        run.frames.push_back(check_frame(f));
    }
    FUZZ_CHECK(!parser.next(f), "an exhausted datagram yields again");
    return run;
}

}  // namespace
}  // namespace mavbond::fuzz

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    using namespace mavbond;
    using namespace mavbond::fuzz;
    const std::span<const uint8_t> datagram(data, size);

    const ParseRun forward = parse(datagram, UnknownIdPolicy::Forward);
    const ParserCounters& c = forward.counters;
    FUZZ_CHECK(c.bytes + c.garbage_bytes == size, "%zu bytes in, %zu yielded + %zu garbage",
               size, static_cast<size_t>(c.bytes), static_cast<size_t>(c.garbage_bytes));
    FUZZ_CHECK(c.frames == forward.frames.size(), "counted %zu frames, yielded %zu",
               static_cast<size_t>(c.frames), forward.frames.size());
    FUZZ_CHECK(c.bad_lengths <= c.crc_errors, "bad_lengths is a part of crc_errors");
    size_t unknown = 0;
    for (const FrameRecord& r : forward.frames) {
        unknown += r.crc_checked ? 0 : 1;
        check_reparses(r);
    }
    FUZZ_CHECK(c.unknown_ids == unknown, "counted %zu unknown ids, forwarded %zu",
               static_cast<size_t>(c.unknown_ids), unknown);

    check_drop_matches_forward(parse(datagram, UnknownIdPolicy::Drop), forward);
    return 0;
}
