// MAVLink 2 message signing (mavlink.io "Message Signing"): the signature is the first 48 bits
// of SHA-256(key + header + payload + CRC + link_id + timestamp); the timestamp (10 us units
// since 2015-01-01 UTC) identifies the frame on its logical stream, a stream being (sysid,
// compid, link_id). Checking: SignatureVerifier, with a replay window per stream
// (mavlink/replay_window.h). Signing: FrameSigner. A bond's signing, both: bond_signing.h.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <string>

#include "core/result.h"
#include "mavlink/frame.h"
#include "mavlink/replay_window.h"
#include "mavlink/sha256.h"

namespace mavbond {

using SigningKey = std::array<uint8_t, 32>;

/// Reads a key file: 32 raw bytes, or 64 hex digits (whitespace around them allowed). Like
/// ssh with a private key, refuses a file that group or others may access. Errors name the
/// path.
Result<SigningKey> load_signing_key(const std::string& path);

/// The signing clock now: 10 us units since 2015-01-01 UTC from the wall clock (0 before).
uint64_t signing_timestamp_now();
using WallClock = uint64_t (*)();

/// A signed frame's signature: the link id and the timestamp it was signed with.
struct SignatureFields {
    uint8_t link_id = 0;
    uint64_t timestamp = 0;
};
/// Reads them from the last 13 bytes of a signed frame's bytes.
SignatureFields signature_fields(std::span<const uint8_t> signed_frame);

/// A signed frame's identity: its stream and its timestamp.
struct SignedId {
    uint32_t stream = 0;     // sysid << 16 | compid << 8 | link_id
    uint64_t timestamp = 0;
    bool known = false;      // false: no signed frame's (or not verified)
    /// Newer than every frame of its stream let in before, on any link: no late copy of a
    /// frame another link brought (which a stranger may have captured there and replayed
    /// here). What may move a peer's address (admission, a NAT rebinding) on a signed link.
    bool newest = false;
};

class SignatureVerifier {
public:
    enum class Verdict {
        Accept,
        Unsigned,      // no signature (a MAVLink 1 frame, or a v2 frame without the flag)
        BadSignature,  // does not verify against the key
        Replay,        // its link brought it already, it is older than its stream's window,
                       // or a new stream over a minute old
    };
    /// Streams remembered at most; the least recently heard one makes room for a new one.
    /// Only frames that verified create streams, so without the key nobody can churn them.
    static constexpr size_t kMaxStreams = 64;
    /// How far behind the local timestamp a new stream may start: one minute.
    static constexpr uint64_t kNewStreamWindow = 6'000'000;

    explicit SignatureVerifier(const SigningKey& key, WallClock clock = signing_timestamp_now);

    /// Checks one frame that link `link` (< ReplayWindow::kMaxLinks) brought, and on Accept
    /// records its timestamp in its stream's window. The links that share a verifier (a
    /// bond's members; a server's peers are one link) each get a frame once. No allocation
    /// but a new stream's window.
    Verdict check(const Frame& frame, unsigned link = 0, SignedId* id = nullptr);
    /// Whether the frame `id` names (one check() accepted) is delivered for the first time
    /// now (ReplayWindow::first_delivery).
    bool first_delivery(const SignedId& id);

    size_t stream_count() const { return count_; }
    /// The largest of the wall clock read last and every accepted timestamp.
    uint64_t local_timestamp() const { return local_ts_; }

private:
    struct Stream {
        uint32_t id = 0;     // sysid << 16 | compid << 8 | link_id
        uint64_t heard = 0;  // verifier-wide accept count when last heard, for eviction
        ReplayWindow window;
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

/// Signs MAVLink 2 frames with one key and link id, each with a timestamp of its own: the
/// larger of the wall clock and one past the last (so a stream's timestamps always grow), and
/// never below what the caller says the time is (the newest timestamp heard from the peer).
class FrameSigner {
public:
    FrameSigner(const SigningKey& key, uint8_t link_id, WallClock clock = signing_timestamp_now);

    /// Writes the unsigned MAVLink 2 frame `frame` signed into `out` (room for kMaxFrameLen):
    /// the signed flag set (its CRC updated), the link id, the timestamp and the signature
    /// after it. Returns the signed length; 0 for a frame that cannot be signed (MAVLink 1, a
    /// frame signed already), `out` untouched. No allocation.
    size_t sign(std::span<const uint8_t> frame, std::span<uint8_t> out, uint64_t not_before = 0);

    uint8_t link_id() const { return link_id_; }
    uint64_t last_timestamp() const { return last_; }

private:
    Sha256 keyed_;
    uint8_t link_id_;
    WallClock clock_;
    uint64_t last_ = 0;
};

/// The bytes of one signature: the first 48 bits of SHA-256 over `keyed` (a context that has
/// hashed the key) and everything of `frame` before them. Verifying and signing share it.
std::array<uint8_t, 6> signature_of(const Sha256& keyed, std::span<const uint8_t> frame);

}  // namespace mavbond
