// Signing as a bond does it: FrameSigner against pymavlink's signatures (gen_signing_vectors.py),
// the replay window's rules, and BondSigning end to end (sign on one side, verify and take the
// signature off on the other), with no allocation per frame.
#include "mavlink/bond_signing.h"

#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "allocations.h"
#include "mavlink/frame_parser.h"
#include "mavlink/frame_writer.h"
#include "signing_vectors.h"

namespace mavbond {
namespace {

using Verdict = SignatureVerifier::Verdict;
using test::Bytes;

constexpr uint64_t kBaseTs = 300'000'000'000;  // gen_signing_vectors.py BASE_TS
uint64_t g_clock = kBaseTs;
uint64_t fake_clock() { return g_clock; }

SigningKey vector_key() {
    SigningKey key{};
    const Bytes& k = test::signing_vectors().key;
    std::copy(k.begin(), k.end(), key.begin());
    return key;
}

/// A frame parsed from `bytes` as the daemon parses what it receives (its spans into them).
Frame parse(std::span<const uint8_t> bytes) {
    ParserCounters counters;
    DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
    Frame frame;
    EXPECT_TRUE(parser.next(frame));
    return frame;
}

/// An unsigned ATTITUDE from (1, 1) with sequence number `seq`.
Bytes attitude(uint8_t seq) {
    std::array<uint8_t, kMaxFrameLen> buf{};
    std::vector<uint8_t> payload(28, static_cast<uint8_t>(seq + 1));
    size_t n = write_frame_v2(buf, FrameSource{1, 1, seq}, 30, payload);
    return Bytes(buf.begin(), buf.begin() + static_cast<ptrdiff_t>(n));
}

class BondSigningTest : public testing::Test {
protected:
    void SetUp() override { g_clock = kBaseTs; }
};

// --- FrameSigner: the same bytes pymavlink makes ------------------------------------------

TEST_F(BondSigningTest, SignsAsPymavlinkDoes) {
    // pymavlink's signed frames, the signature taken off, signed again with the same link id
    // at the same timestamp: byte for byte the same.
    for (const char* label : {"gcs0", "big"}) {
        const test::SignedFrame& v = test::signing_vectors().frame(label);
        Bytes bytes = v.bytes;
        Frame f = parse(bytes);
        strip_signature(f);
        ASSERT_FALSE(f.is_signed());
        EXPECT_EQ(f.bytes.size(), v.bytes.size() - kSignatureLen);
        EXPECT_TRUE(parse(f.bytes).crc_checked) << "the CRC fits the unsigned header";
        g_clock = v.timestamp;
        FrameSigner signer(vector_key(), static_cast<uint8_t>(v.link_id), fake_clock);
        std::array<uint8_t, kMaxFrameLen> out{};
        size_t n = signer.sign(f.bytes, out);
        ASSERT_EQ(n, v.bytes.size()) << label;
        EXPECT_EQ(Bytes(out.begin(), out.begin() + static_cast<ptrdiff_t>(n)), v.bytes) << label;
    }
}

TEST_F(BondSigningTest, TimestampsGrowAndNeverFallBehindWhatThePeerSays) {
    FrameSigner signer(vector_key(), 7, fake_clock);
    std::array<uint8_t, kMaxFrameLen> out{};
    Bytes a = attitude(0);
    std::vector<uint64_t> ts;
    for (int i = 0; i < 3; i++) {
        ASSERT_NE(0u, signer.sign(a, out));
        ts.push_back(signature_fields(std::span<const uint8_t>(out.data(), a.size() + 13)).timestamp);
    }
    EXPECT_EQ(ts, (std::vector<uint64_t>{kBaseTs, kBaseTs + 1, kBaseTs + 2})) << "a clock that stood";
    ASSERT_NE(0u, signer.sign(a, out, kBaseTs + 500));
    EXPECT_EQ(signer.last_timestamp(), kBaseTs + 500) << "the peer's clock is ahead: caught up";
    EXPECT_EQ(signature_fields(std::span<const uint8_t>(out.data(), a.size() + 13)).link_id, 7);
}

TEST_F(BondSigningTest, RefusesWhatCannotBeSigned) {
    FrameSigner signer(vector_key(), 7, fake_clock);
    std::array<uint8_t, kMaxFrameLen> out{};
    EXPECT_EQ(0u, signer.sign(test::signing_vectors().frame("gcs0").bytes, out)) << "signed already";
    const Bytes v1 = {0xFE, 9, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    EXPECT_EQ(0u, signer.sign(v1, out)) << "MAVLink 1 has no signature";
}

// --- ReplayWindow ----------------------------------------------------------------------------

TEST(ReplayWindow, OncePerLinkInAnyOrderWithinTheWindow) {
    ReplayWindow w;
    EXPECT_TRUE(w.admit(100, 0));
    EXPECT_TRUE(w.admit(300, 0));
    EXPECT_FALSE(w.admit(300, 0)) << "the same link again: a replay";
    EXPECT_TRUE(w.admit(300, 1)) << "the other link's copy";
    EXPECT_TRUE(w.admit(200, 1)) << "late, never seen: placed between";
    EXPECT_TRUE(w.admit(200, 0));
    EXPECT_FALSE(w.admit(200, 1));
    EXPECT_FALSE(w.admit(100, 0));
    EXPECT_TRUE(w.admit(100, 1));
    EXPECT_EQ(3u, w.size());
}

TEST(ReplayWindow, DeliveredOnceWhicheverLinkBroughtIt) {
    ReplayWindow w;
    ASSERT_TRUE(w.admit(100, 0));
    ASSERT_TRUE(w.admit(100, 1));
    EXPECT_TRUE(w.first_delivery(100));
    EXPECT_FALSE(w.first_delivery(100)) << "the other link's copy, past dedup";
    EXPECT_TRUE(w.admit(100, 2)) << "a third link's copy is still let in (the filters see it)";
    EXPECT_FALSE(w.first_delivery(100));
    EXPECT_TRUE(w.first_delivery(50)) << "not held: nothing to say against it";
}

TEST(ReplayWindow, RefusesWhatIsOlderThanTheSpan) {
    ReplayWindow w;
    ASSERT_TRUE(w.admit(1000, 0));
    ASSERT_TRUE(w.admit(1000 + ReplayWindow::kSpan, 0));
    EXPECT_TRUE(w.admit(1000, 1)) << "exactly kSpan behind: still in";
    ASSERT_TRUE(w.admit(1001 + ReplayWindow::kSpan, 0));
    EXPECT_FALSE(w.admit(1000, 1)) << "forgotten: older than the window";
    EXPECT_FALSE(w.admit(999, 1));
    EXPECT_TRUE(w.admit(1001, 1)) << "never seen, and kSpan behind the newest: in";
}

TEST(ReplayWindow, ACapacityOfTimestampsAndNoFurther) {
    ReplayWindow w;
    for (uint64_t t = 1; t <= ReplayWindow::kCapacity; t++)
        ASSERT_TRUE(w.admit(10 * t, 0));
    EXPECT_FALSE(w.admit(5, 0)) << "older than all kept, no room";
    EXPECT_TRUE(w.admit(15, 1)) << "between: the oldest goes for it";
    EXPECT_EQ(ReplayWindow::kCapacity, w.size());
    EXPECT_FALSE(w.admit(10, 1)) << "the forgotten one: refused, not let in again";
    EXPECT_FALSE(w.admit(15, 1));
    EXPECT_TRUE(w.admit(20, 1));
    // In order, the ring keeps the newest kCapacity.
    for (uint64_t t = 1; t <= 3 * ReplayWindow::kCapacity; t++)
        ASSERT_TRUE(w.admit(100'000 + t, 0));
    EXPECT_FALSE(w.admit(100'000 + 2 * ReplayWindow::kCapacity, 0));
    EXPECT_TRUE(w.admit(100'000 + 2 * ReplayWindow::kCapacity + 1, 1));
}

// --- BondSigning: both sides --------------------------------------------------------------

/// The air side signs, the ground side verifies, as two gateways of one bond would.
struct Pair {
    BondSigning air{vector_key(), fake_clock};
    BondSigning ground{vector_key(), fake_clock};
    unsigned radio = *ground.member("radio");
    unsigned lte = *ground.member("lte");
    /// `bytes` signed by the air side.
    Bytes sign(const Bytes& bytes) {
        std::array<uint8_t, kMaxFrameLen> out{};
        size_t n = air.sign(bytes, out);
        return Bytes(out.begin(), out.begin() + static_cast<ptrdiff_t>(n));
    }
    /// What the ground side makes of `bytes` (a copy: the verifier writes into it) on `member`.
    std::pair<Verdict, Bytes> receive(Bytes bytes, unsigned member) {
        Frame f = parse(bytes);
        Verdict v = ground.verify(f, member);
        return {v, Bytes(f.bytes.begin(), f.bytes.end())};
    }
};

TEST_F(BondSigningTest, WhatOneSideSignsTheOtherVerifiesAndGetsAsItWas) {
    Pair p;
    const Bytes plain = attitude(5);
    const Bytes s = p.sign(plain);
    ASSERT_EQ(s.size(), plain.size() + kSignatureLen);
    EXPECT_TRUE(BondSigning::signed_by_bond(s));
    EXPECT_TRUE(parse(s).crc_checked);
    Bytes first = s;
    Frame f = parse(first);
    SignedId first_id;
    EXPECT_EQ(p.ground.verify(f, p.lte, &first_id), Verdict::Accept);
    EXPECT_TRUE(first_id.newest);
    EXPECT_EQ(Bytes(f.bytes.begin(), f.bytes.end()), plain)
        << "the signature taken off: the frame as the air side was given it";
    // The radio's copy of the same frame (the same signed bytes): in once, as no newest
    // frame (it may be a capture from the other link); then never again.
    Bytes copy = s;
    Frame c = parse(copy);
    SignedId id;
    EXPECT_EQ(p.ground.verify(c, p.radio, &id), Verdict::Accept);
    EXPECT_TRUE(id.known);
    EXPECT_FALSE(id.newest);
    EXPECT_EQ(p.receive(s, p.radio).first, Verdict::Replay);
    EXPECT_EQ(p.receive(s, p.lte).first, Verdict::Replay);
    // Unsigned (a stranger's), and signed with another key.
    EXPECT_EQ(p.receive(plain, p.lte).first, Verdict::Unsigned);
    SigningKey other = vector_key();
    other[0] ^= 1;
    BondSigning stranger(other, fake_clock);
    std::array<uint8_t, kMaxFrameLen> out{};
    size_t n = stranger.sign(attitude(6), out);
    EXPECT_EQ(p.receive(Bytes(out.begin(), out.begin() + static_cast<ptrdiff_t>(n)), p.lte).first,
              Verdict::BadSignature);
    EXPECT_EQ(p.air.counters().signed_frames, 1u);
    EXPECT_EQ(p.ground.counters().verified, 2u);
}

TEST_F(BondSigningTest, FramesOthersSignedPassWithTheirSignature) {
    Pair p;
    const Bytes& gcs = test::signing_vectors().frame("gcs0").bytes;  // pymavlink, link id 3
    std::array<uint8_t, kMaxFrameLen> out{};
    EXPECT_EQ(0u, p.air.sign(gcs, out)) << "goes as it is";
    auto [v, got] = p.receive(gcs, p.lte);
    EXPECT_EQ(v, Verdict::Accept);
    EXPECT_EQ(got, gcs) << "kept whole: its source signed it";
    EXPECT_EQ(p.air.counters().signed_frames, 0u);
    EXPECT_EQ(p.air.counters().refused_v1, 0u);
    const Bytes v1 = {0xFE, 9, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    EXPECT_EQ(0u, p.air.sign(v1, out));
    EXPECT_EQ(p.air.counters().refused_v1, 1u);
}

TEST_F(BondSigningTest, ASideWhoseClockIsBehindCatchesUpOnWhatItHears) {
    // The ground's clock is right; the air side's is 70 s behind (a board without RTC). Its
    // first frame is a new stream over a minute old: refused. Once it heard the ground, its
    // timestamps are never behind the ground's: accepted.
    BondSigning ground(vector_key(), [] { return kBaseTs + 7'000'000; });
    BondSigning air(vector_key(), [] { return kBaseTs; });
    unsigned g = *ground.member("lte"), a = *air.member("lte");
    std::array<uint8_t, kMaxFrameLen> out{};
    auto send = [&](BondSigning& from, BondSigning& to, unsigned member, uint8_t seq) {
        Bytes b = attitude(seq);
        size_t n = from.sign(b, out);
        Bytes s(out.begin(), out.begin() + static_cast<ptrdiff_t>(n));
        Frame f = parse(s);
        return to.verify(f, member);
    };
    EXPECT_EQ(send(air, ground, g, 1), Verdict::Replay);
    EXPECT_EQ(send(ground, air, a, 2), Verdict::Accept);
    EXPECT_EQ(send(air, ground, g, 3), Verdict::Accept);
}

TEST_F(BondSigningTest, NothingAllocatedPerFrame) {
    Pair p;
    std::vector<Bytes> plain;
    for (uint8_t i = 0; i < 200; i++)
        plain.push_back(attitude(i));
    std::vector<Bytes> signed_(plain.size(), Bytes(kMaxFrameLen));
    p.receive(p.sign(plain[0]), p.lte);  // the stream's window: allocated with its first frame
    const uint64_t before = allocations();
    size_t accepted = 0;
    for (size_t i = 1; i < plain.size(); i++) {
        size_t n = p.air.sign(plain[i], signed_[i]);
        Frame f = parse(std::span<const uint8_t>(signed_[i].data(), n));
        accepted += p.ground.verify(f, p.lte) == Verdict::Accept;
    }
    EXPECT_EQ(allocations() - before, 0u);
    EXPECT_EQ(accepted, plain.size() - 1);
}

}  // namespace
}  // namespace mavbond
