#include "mavlink/bond_signing.h"

#include <algorithm>

#include "mavlink/frame_writer.h"

namespace mavbond {

BondSigning::BondSigning(const SigningKey& key, WallClock clock)
    : key_(key), verifier_(key, clock), signer_(key, kLinkId, clock) {}

std::optional<unsigned> BondSigning::member(const std::string& endpoint) {
    auto it = std::find(members_.begin(), members_.end(), endpoint);
    if (it != members_.end())
        return static_cast<unsigned>(it - members_.begin());
    if (members_.size() >= kMaxMembers)
        return std::nullopt;
    members_.push_back(endpoint);
    return static_cast<unsigned>(members_.size() - 1);
}

bool BondSigning::has_room_for(const std::vector<std::string>& endpoints) const {
    size_t places = members_.size();
    for (const std::string& e : endpoints)
        places += std::find(members_.begin(), members_.end(), e) == members_.end() ? 1 : 0;
    return places <= kMaxMembers;
}

size_t BondSigning::sign(std::span<const uint8_t> frame, std::span<uint8_t> out) {
    if (!frame.empty() && frame[0] == kMagicV1) {
        counters_.refused_v1++;
        return 0;
    }
    // Never behind the peer's clock: its window refuses a new stream a minute older.
    size_t n = signer_.sign(frame, out, verifier_.local_timestamp());
    if (n != 0)
        counters_.signed_frames++;
    return n;
}

bool BondSigning::first_delivery(const SignedId& id) {
    if (verifier_.first_delivery(id))
        return true;
    counters_.redelivered++;
    return false;
}

SignatureVerifier::Verdict BondSigning::verify(Frame& frame, unsigned member, SignedId* id) {
    SignatureVerifier::Verdict v = verifier_.check(frame, member, id);
    if (v == SignatureVerifier::Verdict::Accept && signed_by_bond(frame.bytes)) {
        strip_signature(frame);
        counters_.verified++;
    }
    return v;
}

void strip_signature(Frame& frame) {
    // The receiver's buffer is writable; Frame only promises the routing code it will not be.
    set_signed_flag_in_place(const_cast<uint8_t*>(frame.bytes.data()), false);
    frame.incompat_flags &= static_cast<uint8_t>(~kIncompatSigned);
    frame.bytes = frame.bytes.first(kHeaderLenV2 + frame.payload.size() + kChecksumLen);
}

}  // namespace mavbond
