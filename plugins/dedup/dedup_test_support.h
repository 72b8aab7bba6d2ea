// What the dedup unit tests share: MAVLink frames built by hand, the fixture that drives the
// plugin through its C ABI (FakeHost: the daemon's real option validation) with explicit
// arrival times, and the link simulations judged by identity.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <initializer_list>
#include <random>
#include <string>
#include <vector>

#include "fake_host.h"
#include "mavbond/plugin.h"

extern "C" const mavbond_plugin_descriptor* mavbond_plugin_entry(void);

namespace mavbond::dedup_testing {

constexpr uint64_t kMs = 1'000'000;

using Bytes = std::vector<uint8_t>;

/// A frame of `header` then `payload` then `trailer` (built in place: GCC 12 reads an insert
/// after an initializer list as out of bounds).
inline Bytes frame_of(std::initializer_list<uint8_t> header, const Bytes& payload, size_t trailer) {
    Bytes f(header.size() + payload.size() + trailer);
    std::copy(header.begin(), header.end(), f.begin());
    std::copy(payload.begin(), payload.end(), f.begin() + static_cast<std::ptrdiff_t>(header.size()));
    return f;
}

/// A MAVLink v2 frame (the checksum bytes only need to be the same for the same content).
inline Bytes v2(uint8_t seq, uint32_t msgid, const Bytes& payload, uint8_t sysid = 1, uint8_t compid = 1) {
    Bytes f = frame_of({0xFD, static_cast<uint8_t>(payload.size()), 0, 0, seq, sysid, compid,
                        static_cast<uint8_t>(msgid), static_cast<uint8_t>(msgid >> 8),
                        static_cast<uint8_t>(msgid >> 16)},
                       payload, 2);
    uint16_t sum = 0;
    for (size_t i = 1; i + 2 < f.size(); i++)
        sum = static_cast<uint16_t>(sum * 31 + f[i]);
    f[f.size() - 2] = static_cast<uint8_t>(sum);
    f[f.size() - 1] = static_cast<uint8_t>(sum >> 8);
    return f;
}

inline Bytes v1(uint8_t seq, uint8_t msgid, const Bytes& payload, uint8_t sysid = 1, uint8_t compid = 1) {
    Bytes f = frame_of({0xFE, static_cast<uint8_t>(payload.size()), seq, sysid, compid, msgid}, payload, 2);
    f[f.size() - 2] = 0x55;
    f[f.size() - 1] = 0xAA;
    return f;
}

constexpr uint32_t kHeartbeat = 0;
constexpr uint32_t kAttitude = 30;  // time_boot_ms at payload offset 0

inline Bytes heartbeat_payload() { return {0, 0, 0, 0, 2, 3, 81, 4, 3}; }

inline Bytes attitude_payload(uint32_t time_boot_ms, uint8_t salt = 0) {
    Bytes p(28, 0);
    for (int i = 0; i < 4; i++)
        p[i] = static_cast<uint8_t>(time_boot_ms >> (8 * i));
    p[4] = salt;
    p[8] = 0x3f;
    return p;
}

class DedupTest : public ::testing::Test {
public:  // the simulations below feed through it
    void SetUp() override {
        plugin_ = mavbond_plugin_entry();
        a_ = &host_.add_link("a", "vehicle");
        b_ = &host_.add_link("b", "vehicle");
    }

    bool create(const std::string& options) {
        self_ = host_.create(plugin_, options);
        return self_ != nullptr;
    }

    /// Hands `raw` to the plugin as received on `link` at `t_ns` (0: the host's clock), as
    /// the daemon would: the link's stream position tracked by the host.
    mavbond_verdict feed(const mavbond_link& link, const Bytes& raw, uint64_t t_ns = 0,
                         mavbond_frame_notes* notes_out = nullptr, uint32_t note_flags = 0) {
        mavbond_frame f = host_.frame(raw, link, t_ns);
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = note_flags;
        mavbond_verdict v = host_.ingress(f, notes, link);
        if (notes_out)
            *notes_out = notes;
        return v;
    }

    std::string status() {
        size_t need = plugin_->status_json(self_, nullptr, 0);
        std::string s(need + 1, '\0');
        plugin_->status_json(self_, s.data(), s.size());
        s.resize(need);
        return s;
    }

    uint64_t now() { return host_.now_ns(); }

    FakeHost host_;
    const mavbond_plugin_descriptor* plugin_ = nullptr;
    const mavbond_link* a_ = nullptr;
    const mavbond_link* b_ = nullptr;
    void* self_ = nullptr;
};

// --- simulations ---------------------------------------------------------------------------

/// A source's frames: every 8th a HEARTBEAT whose bytes repeat every 256 frames (the sequence
/// byte wraps), the others a unique timestamped sample; `periodic`: every frame repeats every
/// 256 (no frame is unique: only positions tell instances apart).
inline std::vector<Bytes> source_stream(int count, bool periodic = false) {
    std::vector<Bytes> frames;
    frames.reserve(count);
    for (int i = 0; i < count; i++) {
        auto seq = static_cast<uint8_t>(i);
        if (periodic)
            frames.push_back(v2(seq, kHeartbeat, heartbeat_payload()));
        else if (i % 8 == 0)
            frames.push_back(v2(seq, kHeartbeat, heartbeat_payload()));
        else
            frames.push_back(v2(seq, kAttitude, attitude_payload(static_cast<uint32_t>(i))));
    }
    return frames;
}

struct Arrival {
    uint64_t t;
    int link;    // index into the links of the run
    int source;  // index of the source frame
};

struct LinkModel {
    uint64_t delay_ns;
    uint64_t jitter_ns;
    double loss;
    bool reorder = false;  // jitter may reorder (an LTE modem); else a link keeps its order
    std::pair<int, int> outage = {0, 0};  // frames [first, last) lost in a row
};

/// A stable sort: copies that arrive at one instant keep the order they were made in.
inline void in_time_order(std::vector<Arrival>& arrivals) {
    std::stable_sort(arrivals.begin(), arrivals.end(),
                     [](const Arrival& x, const Arrival& y) { return x.t < y.t; });
}

/// Arrivals of every source frame over each link, in time order.
inline std::vector<Arrival> simulate(int count, uint64_t start, uint64_t period_ns,
                              const std::vector<LinkModel>& links, uint32_t seed) {
    std::mt19937_64 rng(seed);
    std::vector<Arrival> out;
    for (int l = 0; l < static_cast<int>(links.size()); l++) {
        std::bernoulli_distribution lost(links[l].loss);
        std::uniform_int_distribution<uint64_t> jitter(0, links[l].jitter_ns);
        uint64_t last = 0;
        for (int i = 0; i < count; i++) {
            uint64_t t = start + i * period_ns + links[l].delay_ns + jitter(rng);
            bool gone = lost(rng);
            if (gone || (i >= links[l].outage.first && i < links[l].outage.second))
                continue;
            if (!links[l].reorder) {
                t = std::max(t, last);
                last = t;
            }
            out.push_back({t, l, i});
        }
    }
    in_time_order(out);
    return out;
}

struct Outcome {
    int sent = 0, arrivals = 0, lost_on_all = 0, expected = 0, delivered = 0;
    int legit_dropped = 0;      // frames some link brought that were not delivered
    int duplicates_passed = 0;  // deliveries beyond one per frame
    int wrong_verdicts = 0;     // arrivals whose verdict differs from first-copy-passes
};

/// Feeds the arrivals and judges by identity: frame i (an index, not its bytes) must be
/// delivered once if some link brought it, never otherwise.
inline Outcome run(const std::vector<Bytes>& frames, const std::vector<Arrival>& arrivals,
            const std::vector<const mavbond_link*>& links,
            const std::function<mavbond_verdict(const mavbond_link&, const Bytes&, uint64_t)>& feed) {
    Outcome o;
    o.sent = static_cast<int>(frames.size());
    o.arrivals = static_cast<int>(arrivals.size());
    std::vector<int> copies(frames.size(), 0), delivered(frames.size(), 0);
    for (const Arrival& a : arrivals) {
        bool first = copies[a.source]++ == 0;
        mavbond_verdict v = feed(*links[a.link], frames[a.source], a.t);
        if (v == MAVBOND_PASS) {
            delivered[a.source]++;
            o.delivered++;
        }
        if ((v == MAVBOND_PASS) != first) {
            // MAVBOND_TRACE=N prints the first N verdicts that are off, for a closer look.
            static const int trace = std::getenv("MAVBOND_TRACE") ? std::atoi(std::getenv("MAVBOND_TRACE")) : 0;
            if (o.wrong_verdicts < trace)
                std::printf("off: frame %d seq %d on link %d at %.3f ms: %s (copy %d)\n", a.source,
                            frames[a.source][4], a.link, static_cast<double>(a.t % 100000000000ull) / 1e6,
                            v == MAVBOND_PASS ? "passed" : "dropped", copies[a.source]);
            o.wrong_verdicts++;
        }
    }
    for (size_t i = 0; i < frames.size(); i++) {
        o.lost_on_all += copies[i] == 0;
        o.expected += copies[i] > 0;
        o.legit_dropped += copies[i] > 0 && delivered[i] == 0;
        o.duplicates_passed += std::max(0, delivered[i] - 1);
    }
    return o;
}

/// Feeds the copies of `sent` (anything with a .frame) in time order to the fixture's links a
/// and b: every frame some link brought is delivered once.
template <typename Sent>
void expect_each_frame_once(DedupTest& t, const std::vector<Sent>& sent,
                            std::vector<Arrival> arrivals) {
    in_time_order(arrivals);
    std::vector<Bytes> frames;
    for (const Sent& x : sent)
        frames.push_back(x.frame);
    Outcome o = run(frames, arrivals, {t.a_, t.b_},
                    [&t](const mavbond_link& l, const Bytes& f, uint64_t at) { return t.feed(l, f, at); });
    EXPECT_EQ(0, o.legit_dropped);
    EXPECT_EQ(0, o.duplicates_passed);
}

inline Outcome simulate_and_run(DedupTest& t, int count, const std::vector<LinkModel>& models,
                         std::vector<const mavbond_link*> links, uint32_t seed,
                         bool periodic = false) {
    auto frames = source_stream(count, periodic);
    auto arrivals = simulate(count, t.now(), kMs, models, seed);
    return run(frames, arrivals, links, [&t](const mavbond_link& l, const Bytes& f, uint64_t at) {
        return t.feed(l, f, at);
    });
}

/// Arrivals of `count` frames `period_ns` apart over a link whose delay is delay(i) for frame i,
/// keeping its order (a radio's queue).
inline std::vector<Arrival> over_link(int link, int count, uint64_t start, uint64_t period_ns,
                               const std::function<uint64_t(int)>& delay) {
    std::vector<Arrival> out;
    uint64_t last = 0;
    for (int i = 0; i < count; i++) {
        uint64_t t = std::max(last, start + i * period_ns + delay(i));
        last = t;
        out.push_back({t, link, i});
    }
    return out;
}

}  // namespace mavbond::dedup_testing
