// MAVLink 2 message signing, the receiving side (mavlink.io "Message Signing"): the signature
// is the first 48 bits of SHA-256(key + header + payload + CRC + link_id + timestamp); the
// timestamp (10 us units since 2015-01-01 UTC) must grow on every logical stream, a stream
// being (sysid, compid, link_id).
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "core/result.h"
#include "mavlink/frame.h"
#include "mavlink/sha256.h"

namespace mavbond {

using SigningKey = std::array<uint8_t, 32>;

/// Reads a key file: 32 raw bytes, or 64 hex digits (whitespace around them allowed). Like
/// ssh with a private key, refuses a file that group or others may access. Errors name the
/// path.
Result<SigningKey> load_signing_key(const std::string& path);

/// The signing clock now: 10 us units since 2015-01-01 UTC from the wall clock (0 before).
uint64_t signing_timestamp_now();

class SignatureVerifier {
public:
    enum class Verdict {
        Accept,
        Unsigned,      // no signature (a MAVLink 1 frame, or a v2 frame without the flag)
        BadSignature,  // does not verify against the key
        Replay,        // not newer than its stream's last, or a new stream over a minute old
    };
    using WallClock = uint64_t (*)();
    /// Streams remembered at most; the least recently heard one makes room for a new one.
    /// Only frames that verified create streams, so without the key nobody can churn them.
    static constexpr size_t kMaxStreams = 64;
    /// How far behind the local timestamp a new stream may start: one minute.
    static constexpr uint64_t kNewStreamWindow = 6'000'000;

    explicit SignatureVerifier(const SigningKey& key, WallClock clock = signing_timestamp_now);

    /// Checks one frame, and on Accept records its timestamp. No allocation.
    Verdict check(const Frame& frame);

    size_t stream_count() const { return count_; }
    /// The largest of the wall clock read last and every accepted timestamp.
    uint64_t local_timestamp() const { return local_ts_; }

private:
    struct Stream {
        uint32_t id = 0;         // sysid << 16 | compid << 8 | link_id
        uint64_t timestamp = 0;  // the last accepted one
        uint64_t heard = 0;      // verifier-wide accept count when last heard, for eviction
    };
    bool signature_matches(std::span<const uint8_t> bytes) const;
    Stream* find(uint32_t id);
    Stream& add(uint32_t id);

    Sha256 keyed_;  // has hashed the key: every frame's hash starts from a copy
    WallClock clock_;
    std::array<Stream, kMaxStreams> streams_{};
    size_t count_ = 0;
    size_t last_ = 0;  // the stream found last: most frames come from the same one
    uint64_t local_ts_ = 0;
    uint64_t accepts_ = 0;
};

}  // namespace mavbond
