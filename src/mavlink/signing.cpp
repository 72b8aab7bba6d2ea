#include "mavlink/signing.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>

#include "core/unique_fd.h"
#include "mavlink/frame_writer.h"

namespace mavbond {
namespace {

constexpr int64_t kEpoch2015 = 1420070400;  // 2015-01-01 00:00:00 UTC in Unix seconds

int hex_value(char c) {
    if (c >= '0' && c <= '9')
        return c - '0';
    if (c >= 'a' && c <= 'f')
        return c - 'a' + 10;
    if (c >= 'A' && c <= 'F')
        return c - 'A' + 10;
    return -1;
}

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r'; }

}  // namespace

Result<SigningKey> load_signing_key(const std::string& path) {
    auto refuse = [&path](const std::string& why) { return make_error("key file " + path + ": " + why); };
    // open, then fstat the open file: what is checked is what is read.
    UniqueFd fd(open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY));
    if (!fd) {
        const int err = errno;
        return refuse(std::string("cannot open: ") + strerror(err) +
                      (err == ENOENT ? " (make one with: mavbondctl keygen " + path +
                                           "; then copy the same file to the other side)"
                                     : ""));
    }
    struct stat st {};
    if (fstat(fd.get(), &st) < 0)
        return refuse(std::string("cannot stat: ") + strerror(errno));
    if (!S_ISREG(st.st_mode))
        return refuse("not a regular file");
    if (st.st_mode & (S_IRWXG | S_IRWXO)) {
        char mode[8];
        snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(st.st_mode & 07777));
        return refuse(std::string("group or others may access it (mode ") + mode +
                      "): a secret must be readable by its owner only (chmod 600)");
    }
    // A key is 32 or 64 bytes; reading one byte more than the longest form tells "too long".
    char buf[256];
    size_t len = 0;
    while (len < sizeof buf) {
        ssize_t n = read(fd.get(), buf + len, sizeof buf - len);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            return refuse(std::string("cannot read: ") + strerror(errno));
        if (n == 0)
            break;
        len += static_cast<size_t>(n);
    }
    SigningKey key{};
    if (len == key.size()) {
        std::memcpy(key.data(), buf, key.size());
        return key;
    }
    std::string_view text(buf, len);
    while (!text.empty() && is_space(text.front()))
        text.remove_prefix(1);
    while (!text.empty() && is_space(text.back()))
        text.remove_suffix(1);
    if (text.size() != 2 * key.size())
        return refuse("holds " + std::to_string(len) + " bytes" + (len == sizeof buf ? " or more" : "") +
                      ": a key is 32 raw bytes or 64 hex digits");
    for (size_t i = 0; i < key.size(); i++) {
        int hi = hex_value(text[2 * i]);
        int lo = hex_value(text[2 * i + 1]);
        if (hi < 0 || lo < 0)
            return refuse("'" + std::string(1, text[hi < 0 ? 2 * i : 2 * i + 1]) +
                          "' at offset " + std::to_string(hi < 0 ? 2 * i : 2 * i + 1) +
                          " is not a hex digit: a key is 32 raw bytes or 64 hex digits");
        key[i] = static_cast<uint8_t>(hi << 4 | lo);
    }
    return key;
}

uint64_t signing_timestamp_now() {
    auto us = std::chrono::duration_cast<std::chrono::microseconds>(
                  std::chrono::system_clock::now().time_since_epoch())
                  .count();
    int64_t since_2015 = us - kEpoch2015 * 1'000'000;
    return since_2015 > 0 ? static_cast<uint64_t>(since_2015) / 10 : 0;
}

SignatureFields signature_fields(std::span<const uint8_t> signed_frame) {
    const uint8_t* sig = signed_frame.data() + signed_frame.size() - kSignatureLen;
    SignatureFields out;
    out.link_id = sig[0];
    for (int i = 6; i >= 1; i--)
        out.timestamp = out.timestamp << 8 | sig[i];
    return out;
}

std::array<uint8_t, 6> signature_of(const Sha256& keyed, std::span<const uint8_t> frame) {
    Sha256 h = keyed;
    h.update(frame);
    Sha256::Digest digest = h.finish();
    std::array<uint8_t, 6> out;
    std::copy_n(digest.begin(), out.size(), out.begin());
    return out;
}

SignatureVerifier::SignatureVerifier(const SigningKey& key, WallClock clock) : clock_(clock) {
    keyed_.update(key);
}

bool SignatureVerifier::signature_matches(std::span<const uint8_t> bytes) const {
    constexpr size_t kSigBytes = 6;
    const std::array<uint8_t, kSigBytes> want = signature_of(keyed_, bytes.first(bytes.size() - kSigBytes));
    // Every byte compared whatever the first difference: the time taken tells nothing.
    uint8_t diff = 0;
    for (size_t i = 0; i < kSigBytes; i++)
        diff |= static_cast<uint8_t>(want[i] ^ bytes[bytes.size() - kSigBytes + i]);
    return diff == 0;
}

SignatureVerifier::Stream* SignatureVerifier::find(uint32_t id) {
    if (last_ < count_ && streams_[last_].id == id)
        return &streams_[last_];
    for (size_t i = 0; i < count_; i++) {
        if (streams_[i].id == id) {
            last_ = i;
            return &streams_[i];
        }
    }
    return nullptr;
}

SignatureVerifier::Stream& SignatureVerifier::add(uint32_t id) {
    size_t slot = count_;
    if (count_ < streams_.size()) {
        count_++;
    } else {
        auto oldest = std::min_element(streams_.begin(), streams_.end(),
                                        [](const Stream& a, const Stream& b) { return a.heard < b.heard; });
        slot = static_cast<size_t>(oldest - streams_.begin());
    }
    Stream& s = streams_[slot];
    s.id = id;
    s.heard = 0;
    s.window.clear();
    last_ = slot;
    return s;
}

bool SignatureVerifier::first_delivery(const SignedId& id) {
    Stream* stream = id.known ? find(id.stream) : nullptr;
    return !stream || stream->window.first_delivery(id.timestamp);
}

SignatureVerifier::Verdict SignatureVerifier::check(const Frame& frame, unsigned link,
                                                    SignedId* out) {
    std::span<const uint8_t> bytes = frame.bytes;
    if (frame.version != 2 || !frame.is_signed())
        return Verdict::Unsigned;
    if (bytes.size() < kHeaderLenV2 + kChecksumLen + kSignatureLen)
        return Verdict::BadSignature;
    if (!signature_matches(bytes))
        return Verdict::BadSignature;

    const SignatureFields sig = signature_fields(bytes);
    uint32_t id = uint32_t{frame.sysid} << 16 | uint32_t{frame.compid} << 8 | sig.link_id;
    Stream* stream = find(id);
    if (!stream) {
        // A stream never heard may start up to a minute behind the local timestamp: a
        // capture older than that cannot be replayed as a "new" stream.
        local_ts_ = std::max(local_ts_, clock_());
        if (sig.timestamp + kNewStreamWindow < local_ts_)
            return Verdict::Replay;
        stream = &add(id);
    }
    const bool newest = stream->window.size() == 0 || sig.timestamp > stream->window.newest();
    if (!stream->window.admit(sig.timestamp, link))
        return Verdict::Replay;
    stream->heard = ++accepts_;
    local_ts_ = std::max(local_ts_, sig.timestamp);
    if (out)
        *out = SignedId{id, sig.timestamp, true, newest};
    return Verdict::Accept;
}

FrameSigner::FrameSigner(const SigningKey& key, uint8_t link_id, WallClock clock)
    : link_id_(link_id), clock_(clock) {
    keyed_.update(key);
}

size_t FrameSigner::sign(std::span<const uint8_t> frame, std::span<uint8_t> out,
                         uint64_t not_before) {
    if (frame.size() < kHeaderLenV2 + kChecksumLen || frame[0] != kMagicV2 ||
        (frame[2] & kIncompatSigned) || frame.size() + kSignatureLen > out.size())
        return 0;
    const size_t len = frame.size();
    uint8_t* p = out.data();
    std::memcpy(p, frame.data(), len);
    set_signed_flag_in_place(p, true);
    last_ = std::max({last_ + 1, clock_(), not_before});
    p[len] = link_id_;
    for (int i = 0; i < 6; i++)
        p[len + 1 + i] = static_cast<uint8_t>(last_ >> (8 * i));
    const std::array<uint8_t, 6> sig = signature_of(keyed_, std::span<const uint8_t>(p, len + 7));
    std::memcpy(p + len + 7, sig.data(), sig.size());
    return len + kSignatureLen;
}

}  // namespace mavbond
