// Signing's cost per frame, on pymavlink-signed frames (a COMMAND_LONG and a 279-byte
// FILE_TRANSFER_PROTOCOL, gen_signing_vectors.py):
//   check   SignatureVerifier::check on one frame again and again: the hash, then the replay
//           window's lookup (every check after the first is a replay): an endpoint's check as
//           it was measured before bonds signed;
//   sign    BondSigning::sign, the sending side's once-per-frame cost (a new timestamp each);
//   verify  BondSigning::verify of frames signed so, in order, on one link: the hash, the
//           window (appended), the signature taken off;
//   copy    the same frames on a second link (the window's binary search, its bit set).
// Each figure is the median of 5 runs of 50,000 frames, in the thread's CPU time (a busy
// machine's other work does not count). scripts/bench prints them.
// Usage: build/tests/bench/bench_signing [signing_vectors.txt]
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "../unit/mavlink/signing_vectors.h"
#include "mavlink/bond_signing.h"
#include "mavlink/frame_parser.h"

using namespace mavbond;

namespace {

constexpr int kRuns = 5;
constexpr size_t kFrames = 50000;

Frame parse(std::span<const uint8_t> bytes) {
    ParserCounters counters;
    DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
    Frame frame;
    if (!parser.next(frame)) {
        fprintf(stderr, "bench_signing: a vector does not parse\n");
        std::exit(1);
    }
    return frame;
}

/// This thread's CPU time.
std::chrono::nanoseconds cpu_now() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return std::chrono::seconds(ts.tv_sec) + std::chrono::nanoseconds(ts.tv_nsec);
}

template <typename F>
double ns_per(size_t n, F&& f) {
    std::vector<double> runs;
    for (int r = 0; r < kRuns; r++) {
        auto t0 = cpu_now();
        f(r);
        auto t1 = cpu_now();
        runs.push_back(static_cast<double>((t1 - t0).count()) / static_cast<double>(n));
    }
    std::sort(runs.begin(), runs.end());
    return runs[kRuns / 2];
}

}  // namespace

int main(int argc, char** argv) {
    if (argc > 1)
        setenv("MAVBOND_SIGNING_VECTORS", argv[1], 1);
    const auto& v = test::signing_vectors();
    SigningKey key{};
    std::copy(v.key.begin(), v.key.end(), key.begin());
    printf("%-5s %6s %6s %9s %9s %9s %9s  (ns per frame, median of %d runs of %zu frames)\n",
           "frame", "bytes", "signed", "check", "sign", "verify", "copy", kRuns, kFrames);
    for (const char* label : {"gcs0", "big"}) {
        test::Bytes signed_vector = v.frame(label).bytes;
        Frame frame = parse(signed_vector);

        SignatureVerifier verifier(key, [] { return uint64_t{0}; });
        int accepted = 0;
        const double check = ns_per(kFrames, [&](int) {
            for (size_t i = 0; i < kFrames; i++)
                accepted += verifier.check(frame) == SignatureVerifier::Verdict::Accept;
        });

        // The unsigned frame, as the router has it before the bond signs.
        test::Bytes plain = signed_vector;
        Frame unsigned_frame = parse(plain);
        strip_signature(unsigned_frame);
        const std::span<const uint8_t> unsigned_bytes = unsigned_frame.bytes;
        const size_t signed_len = unsigned_bytes.size() + kSignatureLen;

        // Each run signs kFrames frames into its own buffer: the next measurements take them.
        std::vector<std::vector<uint8_t>> out(kRuns, std::vector<uint8_t>(kFrames * signed_len));
        BondSigning air(key);
        const double sign = ns_per(kFrames, [&](int r) {
            for (size_t i = 0; i < kFrames; i++)
                air.sign(unsigned_bytes, std::span<uint8_t>(out[r].data() + i * signed_len, signed_len));
        });

        std::vector<std::vector<Frame>> frames(kRuns);
        for (int r = 0; r < kRuns; r++) {
            for (size_t i = 0; i < kFrames; i++)
                frames[r].push_back(parse(std::span<const uint8_t>(out[r].data() + i * signed_len, signed_len)));
        }
        // Copies for the second link (verify takes the signature off the first link's).
        std::vector<std::vector<uint8_t>> copies = out;
        std::vector<std::vector<Frame>> copy_frames(kRuns);
        for (int r = 0; r < kRuns; r++) {
            for (size_t i = 0; i < kFrames; i++)
                copy_frames[r].push_back(parse(std::span<const uint8_t>(copies[r].data() + i * signed_len, signed_len)));
        }
        // Both links' copies, the second link's in blocks of 256 right after the first's (as
        // late copies come: the window keeps the newest 1,024 frames of the stream).
        constexpr size_t kBlock = 256;
        size_t ok = 0, copies_ok = 0;
        std::vector<double> verify_runs, copy_runs;
        for (int r = 0; r < kRuns; r++) {
            BondSigning ground(key);
            const unsigned lte = *ground.member("lte"), radio = *ground.member("radio");
            std::chrono::nanoseconds first{0}, second{0};
            for (size_t b = 0; b < kFrames; b += kBlock) {
                const size_t e = std::min(kFrames, b + kBlock);
                auto t0 = cpu_now();
                for (size_t i = b; i < e; i++)
                    ok += ground.verify(frames[r][i], lte) == SignatureVerifier::Verdict::Accept;
                auto t1 = cpu_now();
                for (size_t i = b; i < e; i++)
                    copies_ok += ground.verify(copy_frames[r][i], radio) == SignatureVerifier::Verdict::Accept;
                auto t2 = cpu_now();
                first += t1 - t0;
                second += t2 - t1;
            }
            verify_runs.push_back(static_cast<double>(first.count()) / kFrames);
            copy_runs.push_back(static_cast<double>(second.count()) / kFrames);
        }
        std::sort(verify_runs.begin(), verify_runs.end());
        std::sort(copy_runs.begin(), copy_runs.end());
        const double verify = verify_runs[kRuns / 2], copy = copy_runs[kRuns / 2];
        printf("%-5s %6zu %6zu %9.0f %9.0f %9.0f %9.0f  (accepted: %zu of %zu, copies %zu)\n",
               label, unsigned_bytes.size(), signed_len, check, sign, verify, copy, ok,
               kFrames * kRuns, copies_ok);
        (void)accepted;
    }
    return 0;
}
