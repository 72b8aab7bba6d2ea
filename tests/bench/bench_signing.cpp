// Signature check cost: ns per SignatureVerifier::check() on pymavlink-signed frames (a 57-byte
// COMMAND_LONG, a 279-byte FILE_TRANSFER_PROTOCOL). After the first Accept every check is a
// Replay, but the hash comes first, so what is timed is the hash plus the stream lookup.
// Usage: build/tests/bench/bench_signing [signing_vectors.txt]
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "../unit/mavlink/signing_vectors.h"
#include "mavlink/frame_parser.h"
#include "mavlink/signing.h"

using namespace mavbond;

int main(int argc, char** argv) {
    if (argc > 1)
        setenv("MAVBOND_SIGNING_VECTORS", argv[1], 1);
    const auto& v = test::signing_vectors();
    SigningKey key{};
    std::copy(v.key.begin(), v.key.end(), key.begin());
    for (const char* label : {"gcs0", "big"}) {
        test::Bytes bytes = v.frame(label).bytes;
        ParserCounters counters;
        DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
        Frame frame;
        if (!parser.next(frame))
            return 1;
        SignatureVerifier verifier(key, [] { return uint64_t{0}; });
        const int n = 200000;
        int accepted = 0;
        auto t0 = std::chrono::steady_clock::now();
        for (int i = 0; i < n; i++)
            accepted += verifier.check(frame) == SignatureVerifier::Verdict::Accept;
        auto t1 = std::chrono::steady_clock::now();
        double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() / n;
        printf("%s: %zu bytes, %.0f ns per check (%d accepted)\n", label, bytes.size(), ns, accepted);
    }
    return 0;
}
