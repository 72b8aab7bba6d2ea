// Signature verification against frames pymavlink signed (gen_signing_vectors.py): good,
// bad signature, replay, old timestamp, new stream, the bounded stream table; and key files.
#include "mavlink/signing.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

#include "mavlink/frame_parser.h"
#include "mavlink/message_table.h"
#include "signing_vectors.h"

namespace mavbond {
namespace {

using Verdict = SignatureVerifier::Verdict;
using test::Bytes;

constexpr uint64_t kBaseTs = 300'000'000'000;  // gen_signing_vectors.py BASE_TS

/// The wall clock the verifier reads, set by each test.
uint64_t g_wall_clock = 0;
uint64_t fake_clock() { return g_wall_clock; }

SigningKey vector_key() {
    SigningKey key{};
    const Bytes& k = test::signing_vectors().key;
    std::copy(k.begin(), k.end(), key.begin());
    return key;
}

/// Checks one frame as the daemon does: parsed from its bytes by the real parser.
Verdict check(SignatureVerifier& v, const Bytes& bytes, unsigned link = 0) {
    ParserCounters counters;
    DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
    Frame frame;
    EXPECT_TRUE(parser.next(frame));
    EXPECT_EQ(frame.bytes.size(), bytes.size());
    return v.check(frame, link);
}

Verdict check(SignatureVerifier& v, const std::string& label, unsigned link = 0) {
    return check(v, test::signing_vectors().frame(label).bytes, link);
}

class Verifier : public testing::Test {
protected:
    void SetUp() override { g_wall_clock = kBaseTs; }
    SignatureVerifier verifier{vector_key(), fake_clock};
};

TEST_F(Verifier, AcceptsPymavlinkSignedFramesInOrder) {
    for (const char* label : {"gcs0", "gcs1", "gcs2", "gcs3", "big"})
        EXPECT_EQ(check(verifier, label), Verdict::Accept) << label;
    EXPECT_EQ(verifier.local_timestamp(), kBaseTs + 50);
}

/// An attacker's edit: bytes changed, then the CRC made valid again (it is no secret).
Bytes tamper(const Bytes& frame, size_t at) {
    Bytes bad = frame;
    bad[at] ^= 0x10;
    size_t payload_len = bad[1];
    size_t crc_at = kHeaderLenV2 + payload_len;
    if (at < crc_at) {
        uint32_t msgid = bad[7] | bad[8] << 8 | bad[9] << 16;
        uint16_t crc = crc_x25(std::span(bad).subspan(1, crc_at - 1));
        crc = crc_x25_byte(find_message(msgid)->crc_extra, crc);
        bad[crc_at] = static_cast<uint8_t>(crc);
        bad[crc_at + 1] = static_cast<uint8_t>(crc >> 8);
    }
    return bad;
}

TEST_F(Verifier, RejectsWrongKeyAndAlteredBytes) {
    EXPECT_EQ(check(verifier, "wrong_key"), Verdict::BadSignature);
    const Bytes& good = test::signing_vectors().frame("gcs0").bytes;
    // Any byte changed, header, payload, link id, timestamp or signature, breaks it.
    for (size_t i : {size_t{4}, size_t{5}, size_t{6}, size_t{12}, good.size() - 16,
                     good.size() - 13, good.size() - 8, good.size() - 6, good.size() - 1}) {
        SignatureVerifier fresh(vector_key(), fake_clock);
        EXPECT_EQ(check(fresh, tamper(good, i)), Verdict::BadSignature) << "byte " << i;
    }
    // A bad signature teaches nothing: the good frame is still new.
    EXPECT_EQ(check(verifier, "gcs0"), Verdict::Accept);
    EXPECT_EQ(verifier.stream_count(), 1u);
}

TEST_F(Verifier, ReportsUnsigned) {
    EXPECT_EQ(check(verifier, "unsigned"), Verdict::Unsigned);
    EXPECT_EQ(verifier.stream_count(), 0u);
}

TEST_F(Verifier, RejectsReplaysButLetsALateFrameInOnce) {
    EXPECT_EQ(check(verifier, "gcs0"), Verdict::Accept);
    EXPECT_EQ(check(verifier, "gcs2"), Verdict::Accept);
    EXPECT_EQ(check(verifier, "gcs2"), Verdict::Replay) << "the same frame again";
    EXPECT_EQ(check(verifier, "gcs0"), Verdict::Replay);
    // Older than the stream's last but never seen: it came late (a budget held it, the
    // network reordered it), within the window. Once.
    EXPECT_EQ(check(verifier, "gcs1"), Verdict::Accept) << "late, within the window";
    EXPECT_EQ(check(verifier, "gcs1"), Verdict::Replay);
    EXPECT_EQ(check(verifier, "gcs3"), Verdict::Accept);
}

TEST_F(Verifier, EachLinkSharingTheVerifierGetsAFrameOnce) {
    // A bond's two members bring one frame each: both copies in (dedup keeps one), neither
    // twice.
    EXPECT_EQ(check(verifier, "gcs2"), Verdict::Accept);
    EXPECT_EQ(check(verifier, "gcs2", 1), Verdict::Accept) << "the other link's copy";
    EXPECT_EQ(check(verifier, "gcs2", 1), Verdict::Replay);
    EXPECT_EQ(check(verifier, "gcs1", 1), Verdict::Accept) << "late on the slow link only";
    EXPECT_EQ(check(verifier, "gcs1", 0), Verdict::Accept);
    EXPECT_EQ(check(verifier, "gcs1", 0), Verdict::Replay);
}

TEST_F(Verifier, StreamsAreSystemComponentAndLinkId) {
    EXPECT_EQ(check(verifier, "gcs3"), Verdict::Accept);
    // Same sysid/compid, another link id, an older timestamp: its own stream, accepted.
    EXPECT_EQ(check(verifier, "gcs_link9"), Verdict::Accept);
    EXPECT_EQ(check(verifier, "big"), Verdict::Accept);  // system 1
    EXPECT_EQ(verifier.stream_count(), 3u);
}

TEST_F(Verifier, NewStreamUpToOneMinuteBehindTheWallClock) {
    g_wall_clock = kBaseTs + SignatureVerifier::kNewStreamWindow;
    EXPECT_EQ(check(verifier, "gcs0"), Verdict::Accept) << "exactly a minute behind";
    SignatureVerifier late(vector_key(), fake_clock);
    g_wall_clock = kBaseTs + SignatureVerifier::kNewStreamWindow + 1;
    EXPECT_EQ(check(late, "gcs0"), Verdict::Replay) << "more than a minute behind";
    EXPECT_EQ(late.stream_count(), 0u);
}

TEST_F(Verifier, NewStreamJudgedByTheNewestAcceptedTimestampWithoutAClock) {
    g_wall_clock = 0;  // a board without RTC, just booted: the clock says 1970
    EXPECT_EQ(check(verifier, "late"), Verdict::Accept);
    EXPECT_EQ(verifier.local_timestamp(), kBaseTs + 7'000'000);
    // gcs0 is 70 s older than what was accepted: a capture, not a live stream.
    EXPECT_EQ(check(verifier, "gcs0"), Verdict::Replay);
    EXPECT_EQ(check(verifier, "stream60"), Verdict::Replay);
}

TEST_F(Verifier, StreamTableIsBoundedAndForgetsTheLeastRecentlyHeard) {
    for (int s = 1; s <= 64; s++)
        ASSERT_EQ(check(verifier, "stream" + std::to_string(s)), Verdict::Accept) << s;
    EXPECT_EQ(verifier.stream_count(), SignatureVerifier::kMaxStreams);
    EXPECT_EQ(check(verifier, "stream65"), Verdict::Accept);
    EXPECT_EQ(verifier.stream_count(), SignatureVerifier::kMaxStreams);
    // Streams 2..65 are remembered: their frames again are replays.
    for (int s = 2; s <= 65; s++)
        EXPECT_EQ(check(verifier, "stream" + std::to_string(s)), Verdict::Replay) << s;
    // Stream 1 was the least recently heard and made room: its frame is a new stream again,
    // fresh enough (the documented cost of a bounded table; only keyed senders fill it).
    EXPECT_EQ(check(verifier, "stream1"), Verdict::Accept);
    EXPECT_EQ(verifier.stream_count(), SignatureVerifier::kMaxStreams);
}

// --- key files -----------------------------------------------------------------------------

class KeyFile : public testing::Test {
protected:
    void SetUp() override {
        char tmpl[] = "/tmp/mavbond-key-XXXXXX";
        ASSERT_NE(mkdtemp(tmpl), nullptr);
        dir_ = tmpl;
    }
    void TearDown() override {
        std::string cmd = "rm -rf '" + dir_ + "'";
        ASSERT_EQ(std::system(cmd.c_str()), 0);
    }
    std::string write(const std::string& name, const std::string& content, mode_t mode = 0600) {
        std::string path = dir_ + "/" + name;
        std::ofstream(path, std::ios::binary) << content;
        EXPECT_EQ(chmod(path.c_str(), mode), 0);
        return path;
    }
    std::string dir_;
};

const char* kHex = "000102030405060708090a0b0c0d0e0f101112131415161718191A1B1C1D1E1F";

SigningKey counting_key() {
    SigningKey k{};
    for (size_t i = 0; i < k.size(); i++)
        k[i] = static_cast<uint8_t>(i);
    return k;
}

TEST_F(KeyFile, ReadsRawBytesAndHex) {
    std::string raw(32, '\0');
    for (size_t i = 0; i < raw.size(); i++)
        raw[i] = static_cast<char>(i);
    auto a = load_signing_key(write("raw.key", raw));
    ASSERT_TRUE(a.has_value()) << a.error().message;
    EXPECT_EQ(a.value(), counting_key());
    auto b = load_signing_key(write("hex.key", std::string(kHex) + "\n"));
    ASSERT_TRUE(b.has_value()) << b.error().message;
    EXPECT_EQ(b.value(), counting_key());
    // 32 raw bytes that happen to end in a newline byte stay raw.
    raw[31] = '\n';
    auto c = load_signing_key(write("raw2.key", raw));
    ASSERT_TRUE(c.has_value());
    EXPECT_EQ(c.value()[31], '\n');
}

TEST_F(KeyFile, RefusesWhatIsNotAKey) {
    struct Case {
        std::string name, content, error;
    };
    const Case cases[] = {
        {"short.key", std::string(31, 'x'), "holds 31 bytes: a key is 32 raw bytes or 64 hex digits"},
        {"empty.key", "", "holds 0 bytes"},
        {"long.key", std::string(33, 'x'), "holds 33 bytes"},
        {"huge.key", std::string(5000, 'a'), "holds 256 bytes or more"},
        {"hex63.key", std::string(kHex).substr(0, 63), "holds 63 bytes"},
        {"badhex.key", std::string(kHex).substr(0, 10) + "g" + std::string(kHex).substr(11),
         "'g' at offset 10 is not a hex digit"},
    };
    for (const auto& c : cases) {
        auto r = load_signing_key(write(c.name, c.content));
        ASSERT_FALSE(r.has_value()) << c.name;
        EXPECT_NE(r.error().message.find(c.error), std::string::npos) << r.error().message;
        EXPECT_NE(r.error().message.find(dir_ + "/" + c.name), std::string::npos);
    }
}

TEST_F(KeyFile, RefusesAKeyOthersMayAccess) {
    for (mode_t mode : {0640, 0604, 0620, 0602, 0610, 0644}) {
        auto r = load_signing_key(write("open.key", kHex, mode));
        ASSERT_FALSE(r.has_value()) << std::oct << mode;
        EXPECT_NE(r.error().message.find("group or others may access it"), std::string::npos)
            << r.error().message;
    }
    EXPECT_TRUE(load_signing_key(write("ok.key", kHex, 0400)).has_value());
}

TEST_F(KeyFile, RefusesMissingFilesAndDirectories) {
    auto missing = load_signing_key(dir_ + "/none.key");
    ASSERT_FALSE(missing.has_value());
    EXPECT_NE(missing.error().message.find("cannot open: No such file or directory"), std::string::npos);
    ASSERT_EQ(chmod(dir_.c_str(), 0700), 0);
    auto directory = load_signing_key(dir_);
    ASSERT_FALSE(directory.has_value());
    EXPECT_NE(directory.error().message.find("not a regular file"), std::string::npos)
        << directory.error().message;
}

}  // namespace
}  // namespace mavbond
