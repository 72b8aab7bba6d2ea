// A bond's MAVLink 2 signing (`bonds: - {signing: {key_file, links}}`): the two gateways of a
// bond hold one key; each signs what it sends on the bond's signed links and requires a
// verified signature on what it receives on them. Plain MAVLink 2 signing on the wire: a stock
// stack with the key verifies it.
//
// Sending: a frame is signed once, before it fans out to the links (Router), so every link's
// copy is byte-identical; with link id kLinkId and a timestamp of its own that never goes
// below the newest the peer's frames carried (clocks that disagree catch up on the first
// frame heard, as the MAVLink stacks do). A frame signed already (by the autopilot or the GCS)
// goes as it is, and must verify with the same key on the other side. A MAVLink 1 frame
// cannot be signed: it is not sent on a signed link (counted, `refused_v1`).
//
// Receiving: every frame on a signed link goes through one SignatureVerifier for the whole
// bond, each member a link of its replay window: a frame is let in once per member (the late
// copy on the slow link too), never twice on one, never from older than the window. A frame
// this bond signed (its link id) has the signature taken off in place once verified: what
// the filters and the far side's GCS get is the frame as it was before this bond signed it,
// so dedup matches a signed link's copy with an unsigned link's (`key: frame` compares bytes),
// renumbering may number it, and a GCS with no key reads it. Frames others signed keep their
// signature. So the window and dedup work one after the other, each with its own identity:
// the window admits each link's copy of a signed frame once by its timestamp (the filters see
// every link's copy: dedup, stats and linkswitch judge the links by them), dedup then delivers
// one copy of the frame by its place in its source's stream. The window has the last word:
// the router delivers a frame whose timestamp was delivered before no more
// (first_delivery), so a copy brought by another link after dedup forgot the frame (a
// capture replayed on the other link, 10 s later) is not delivered twice.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "mavlink/frame.h"
#include "mavlink/signing.h"

namespace mavbond {

class BondSigning {
public:
    /// The link id of every signature a bond makes: its frames are one stream per source on
    /// the wire, apart from those their sources signed (ArduPilot signs with its channel
    /// number, MAVProxy and QGroundControl with small numbers).
    static constexpr uint8_t kLinkId = 0xBD;
    static constexpr unsigned kMaxMembers = ReplayWindow::kMaxLinks;

    struct Counters {
        uint64_t signed_frames = 0;  // frames this side signed for the bond
        uint64_t refused_v1 = 0;     // MAVLink 1 frames kept off its signed links
        uint64_t verified = 0;       // frames the peer signed that verified on a member
        uint64_t redelivered = 0;    // copies of a delivered frame the filters let through
                                     // (after dedup forgot it): not delivered again
    };

    explicit BondSigning(const SigningKey& key, WallClock clock = signing_timestamp_now);

    bool same_key(const BondSigning& other) const { return key_ == other.key_; }
    /// The place in the replay window of member endpoint `endpoint` (given the next free one
    /// the first time); nullopt beyond kMaxMembers (the config allows no more).
    std::optional<unsigned> member(const std::string& endpoint);
    /// Whether every one of `endpoints` has a place, or room for one.
    bool has_room_for(const std::vector<std::string>& endpoints) const;

    // --- sending -------------------------------------------------------------------------

    /// Writes `frame`, an unsigned MAVLink 2 frame, signed into `out` (room for
    /// kMaxFrameLen); returns its length. 0 for a MAVLink 1 frame (counted: it cannot be
    /// signed) and for a frame signed already (not counted: it goes as it is). For the
    /// router's once-per-frame path and for an endpoint's own frames alike. No allocation.
    size_t sign(std::span<const uint8_t> frame, std::span<uint8_t> out);

    // --- receiving -----------------------------------------------------------------------

    /// Checks `frame` as member `member` received it. On Accept of a frame the bond signed,
    /// its signature is taken off in place: `frame` (and the receive buffer it is a view
    /// over) becomes the unsigned frame it was. No allocation.
    SignatureVerifier::Verdict verify(Frame& frame, unsigned member, SignedId* id = nullptr);
    /// Whether the frame `id` names (verify() accepted it) may be delivered: not when a copy
    /// of it was (counted, `redelivered`).
    bool first_delivery(const SignedId& id);

    /// Whether `bytes` carry this bond's signature (a frame sign() made).
    static bool signed_by_bond(std::span<const uint8_t> bytes) {
        return bytes.size() > kHeaderLenV2 + kChecksumLen + kSignatureLen &&
               bytes[0] == kMagicV2 && (bytes[2] & kIncompatSigned) &&
               bytes[bytes.size() - kSignatureLen] == kLinkId;
    }

    const Counters& counters() const { return counters_; }

private:
    SigningKey key_;
    SignatureVerifier verifier_;
    FrameSigner signer_;
    std::vector<std::string> members_;
    Counters counters_;
};

/// Calls f(name, value) for each of a bond's signing counters, in one order: the status
/// socket and /metrics name them so.
template <typename F>
void for_each_counter(const BondSigning::Counters& c, F&& f) {
    f("signed", c.signed_frames);
    f("verified", c.verified);
    f("redelivered", c.redelivered);
    f("refused_v1", c.refused_v1);
}

/// Takes the signature off a signed MAVLink 2 frame in place: the flag cleared (the CRC
/// updated for it), the 13 bytes dropped from `frame`'s view.
void strip_signature(Frame& frame);

}  // namespace mavbond
