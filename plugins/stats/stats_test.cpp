// stats against FakeHost: sequence-gap loss (wrap, reordering, per source), the bond figures
// read from dedup's notes, the CSV time series, and the status JSON the host shows.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <map>
#include <string>
#include <vector>

#include "fake_host.h"
#include "mavbond/plugin.h"
#include "seq_loss.h"

extern "C" const mavbond_plugin_descriptor* mavbond_plugin_entry(void);

namespace mavbond {
namespace {

using mavbond_plugins::SeqTracker;
using std::chrono::milliseconds;
using std::chrono::seconds;


/// Just enough of a JSON parser to prove the status text is well formed.
class JsonCheck {
public:
    explicit JsonCheck(const std::string& s) : s_(s) {}
    bool valid() {
        ws();
        if (!value())
            return false;
        ws();
        return i_ == s_.size();
    }

private:
    void ws() {
        while (i_ < s_.size() && isspace(static_cast<unsigned char>(s_[i_])))
            i_++;
    }
    bool lit(const char* w) {
        size_t n = strlen(w);
        if (s_.compare(i_, n, w) != 0)
            return false;
        i_ += n;
        return true;
    }
    bool string() {
        if (s_[i_] != '"')
            return false;
        for (i_++; i_ < s_.size(); i_++) {
            if (s_[i_] == '\\')
                i_++;
            else if (s_[i_] == '"')
                return ++i_, true;
        }
        return false;
    }
    bool number() {
        size_t start = i_;
        char* end = nullptr;
        strtod(s_.c_str() + i_, &end);
        i_ = static_cast<size_t>(end - s_.c_str());
        return i_ > start;
    }
    template <typename F>
    bool list(char close, F item) {
        i_++;
        ws();
        if (s_[i_] == close)
            return ++i_, true;
        for (;;) {
            ws();
            if (!item())
                return false;
            ws();
            if (s_[i_] == close)
                return ++i_, true;
            if (s_[i_++] != ',')
                return false;
        }
    }
    bool value() {
        if (i_ >= s_.size())
            return false;
        switch (s_[i_]) {
        case '{':
            return list('}', [this] {
                if (!string())
                    return false;
                ws();
                if (s_[i_++] != ':')
                    return false;
                ws();
                return value();
            });
        case '[': return list(']', [this] { return value(); });
        case '"': return string();
        case 't': return lit("true");
        case 'f': return lit("false");
        case 'n': return lit("null");
        default: return number();
        }
    }
    const std::string& s_;
    size_t i_ = 0;
};

// --- the sequence tracker on its own ----------------------------------------------------------

int64_t lost_over(std::initializer_list<int> seqs, int64_t* received = nullptr) {
    SeqTracker t;
    int64_t lost = 0, rx = 0;
    for (int s : seqs) {
        auto step = t.step(static_cast<uint8_t>(s));
        lost += step.lost;
        rx += step.received;
    }
    if (received)
        *received = rx;
    return lost;
}

TEST(SeqTracker, CountsGapsAcrossTheWrap) {
    int64_t rx = 0;
    EXPECT_EQ(lost_over({250, 251, 252, 253, 255, 0, 1, 2, 4, 5}, &rx), 2);  // 254 and 3
    EXPECT_EQ(rx, 10);
    EXPECT_EQ(lost_over({254, 255, 0, 1}), 0);
    EXPECT_EQ(lost_over({255, 1}), 1);
}

TEST(SeqTracker, LateFrameFillsItsGapAndRepeatsAreNotLoss) {
    int64_t rx = 0;
    EXPECT_EQ(lost_over({0, 1, 3, 2, 4, 5}, &rx), 0);
    EXPECT_EQ(rx, 6);
    EXPECT_EQ(lost_over({254, 0, 255, 1}, &rx), 0);  // reordered across the wrap
    EXPECT_EQ(rx, 4);
    EXPECT_EQ(lost_over({0, 1, 1, 2}, &rx), 0);  // a repeat counts neither way
    EXPECT_EQ(rx, 3);
    EXPECT_EQ(lost_over({0, 5, 3, 3, 6}, &rx), 3);  // 1, 2, 4 lost; 3 filled once
    EXPECT_EQ(rx, 4);
}

TEST(SeqTracker, FollowsASourceThatRestarts) {
    // The counter jumps back (autopilot reboot): a short run of odd frames, then normal counting
    // resumes without charging the jump as loss.
    EXPECT_EQ(lost_over({100, 101, 102, 103, 0, 1, 2, 3, 4, 6}), 1);
}

// --- the plugin -------------------------------------------------------------------------------

class StatsTest : public testing::Test {
protected:
    const mavbond_plugin_descriptor* plugin_ = mavbond_plugin_entry();
    FakeHost host_;
    void* self_ = nullptr;

    void SetUp() override {
        host_.add_link("radio", "vehicle");
        host_.add_link("lte", "vehicle");
        host_.add_link("gcs");
    }

    void create(const std::string& options = "") {
        self_ = host_.create(plugin_, options);
        ASSERT_NE(self_, nullptr) << host_.last_error();
    }

    mavbond_verdict send(const std::string& link, uint8_t seq, uint8_t sysid = 1,
                         uint8_t compid = 1, uint32_t flags = 0, int64_t skew_ns = 0,
                         const std::string& first = "") {
        auto raw = test_frame(seq, sysid, compid, 0);
        mavbond_frame f = host_.frame(raw, host_.link(link));  // positions tracked by the host
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = flags;
        notes.skew_ns = skew_ns;
        notes.first_link_id = first.empty() ? 0 : host_.link(first).id;
        return host_.ingress(f, notes, host_.link(link));
    }

    std::string status() {
        char small[16];
        size_t need = plugin_->status_json(self_, small, sizeof small);
        std::string buf(need + 1, '\0');
        size_t n = plugin_->status_json(self_, buf.data(), buf.size());
        EXPECT_EQ(n, need);
        buf.resize(n);
        EXPECT_TRUE(JsonCheck(buf).valid()) << buf;
        return buf;
    }

    /// The object of `kind` ("links" or "bonds") named `name`, as text.
    std::string object(const std::string& kind, const std::string& name) {
        std::string s = status();
        size_t list = s.find("\"" + kind + "\":[");
        size_t at = s.find("{\"name\":\"" + name + "\"", list);
        if (list == std::string::npos || at == std::string::npos)
            return "";
        int depth = 0;
        for (size_t i = at; i < s.size(); i++) {
            depth += s[i] == '{' ? 1 : s[i] == '}' ? -1 : 0;
            if (depth == 0)
                return s.substr(at, i - at + 1);
        }
        return "";
    }

    static bool has(const std::string& text, const std::string& part) {
        return text.find(part) != std::string::npos;
    }
};

TEST_F(StatsTest, AlwaysPasses) {
    create();
    EXPECT_EQ(send("radio", 0), MAVBOND_PASS);
    EXPECT_EQ(send("lte", 0, 1, 1, MAVBOND_NOTE_DROPPED | MAVBOND_NOTE_DUPLICATE), MAVBOND_PASS);
    EXPECT_EQ(send("gcs", 0), MAVBOND_PASS);
}

TEST_F(StatsTest, LinkLossFromSequenceGapsWithWrap) {
    create();
    for (int s : {250, 251, 252, 253, 255, 0, 1, 2, 4, 5})
        send("radio", static_cast<uint8_t>(s));
    std::string radio = object("links", "radio");
    EXPECT_TRUE(has(radio, "\"bond\":\"vehicle\",\"frames\":10,\"bytes\":210,\"basis\":\"sequence\","
                           "\"expected\":12,\"lost\":2,\"loss_pct\":16.667"))
        << radio;
}

TEST_F(StatsTest, ReorderingDoesNotInflateLoss) {
    create();
    for (int s : {0, 1, 3, 2, 4, 6, 5, 7})
        send("radio", static_cast<uint8_t>(s));
    EXPECT_TRUE(has(object("links", "radio"), "\"frames\":8,\"bytes\":168,\"basis\":\"sequence\",\"expected\":8,\"lost\":0,"))
        << object("links", "radio");
}

TEST_F(StatsTest, SourcesAreCountedSeparately) {
    create();
    // Autopilot (1,1) and gimbal (1,154) interleaved on one link, each with its own counter;
    // only the gimbal loses one frame.
    for (int i = 0; i < 10; i++) {
        send("radio", static_cast<uint8_t>(i), 1, 1);
        if (i != 4)
            send("radio", static_cast<uint8_t>(100 + i), 1, 154);
    }
    EXPECT_TRUE(has(object("links", "radio"), "\"frames\":19,\"bytes\":399,\"basis\":\"sequence\",\"expected\":20,"
                                          "\"lost\":1,"))
        << object("links", "radio");
}

TEST_F(StatsTest, BondFiguresComeFromTheNotes) {
    create();
    constexpr uint32_t kDup = MAVBOND_NOTE_DROPPED | MAVBOND_NOTE_DUPLICATE;
    constexpr uint32_t kStale = MAVBOND_NOTE_DROPPED | MAVBOND_NOTE_STALE;
    // Radio delivers 0..9 except 3; lte's copies of them are duplicates 10/30 ms late; lte
    // alone delivers 3; one stale frame on lte.
    for (int i = 0; i < 10; i++) {
        if (i != 3)
            send("radio", static_cast<uint8_t>(i));
        if (i == 3)
            send("lte", 3);
        else
            send("lte", static_cast<uint8_t>(i), 1, 1, kDup, (i % 2 ? 30 : 10) * 1'000'000,
                 "radio");
    }
    send("lte", 10, 1, 1, kStale);
    // A frame from a source the bond lost in the delivered stream: 11 never arrives.
    send("radio", 12);
    std::string bond = object("bonds", "vehicle");
    EXPECT_TRUE(has(bond, "\"frames\":21,\"delivered\":11,\"duplicates\":9,\"stale\":1,"
                          "\"delivered_lost\":2,"))
        << bond;
    // Mean of five 10 ms and four 30 ms skews.
    EXPECT_TRUE(has(bond, "\"skew_ms\":{\"count\":9,\"mean\":18.889,\"max\":30.000,"
                          "\"pairs\":[{\"first\":\"radio\",\"late\":\"lte\",\"count\":9,"
                          "\"mean\":18.889,\"p50\":10.000,\"max\":30.000}]}"))
        << bond;
    // Per link, lte lost nothing by sequence (its dropped copies still arrived).
    EXPECT_TRUE(has(object("links", "lte"), "\"frames\":11,\"bytes\":231,\"basis\":\"sequence\",\"expected\":11,\"lost\":0,"))
        << object("links", "lte");
}

// Found with MAVSDK through a bond whose second link is 300 ms behind: in a burst (a
// parameter list) a frame the fast link lost comes by the slow one hundreds of positions
// later. Counted by dedup's positions, it fills its hole; by 8-bit sequence numbers the late
// copies looked like restarts and 40 % of the stream was counted lost.
TEST_F(StatsTest, DeliveredLossByPositionTakesLateCopiesBehindABurst) {
    create("log: false");
    auto deliver = [this](const std::string& link, int64_t pos, uint64_t t_ns) {
        auto raw = test_frame(static_cast<uint8_t>(pos), 1, 1, 22);
        mavbond_frame f = host_.frame(raw, host_.link(link), t_ns);
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = MAVBOND_NOTE_POSITION;
        notes.bond_pos = pos;
        host_.ingress(f, notes, host_.link(link));
    };
    uint64_t t = host_.now_ns();
    for (int64_t p = 0; p < 100; p++, t += 10'000'000)
        deliver("radio", p, t);
    for (int64_t p = 100; p < 400; p++) {  // the burst; 150 lost on the radio
        if (p != 150)
            deliver("radio", p, t);
    }
    deliver("lte", 150, t + 300'000'000);
    for (int64_t p = 400; p < 500; p++, t += 10'000'000)
        deliver("radio", p, t + 310'000'000);
    host_.advance(seconds(3));  // every hole has waited long enough
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered\":500,\"duplicates\":0,\"stale\":0,"
                                                "\"delivered_lost\":0,"))
        << object("bonds", "vehicle");
}

// Found with two gateways and a GCS that reconnected (its counter from 0 again): dedup placed
// the new numbering's first frames a turn of 256 ahead, then back when the host saw the
// numbering restart; each reconnect was ~255 "lost" in the delivered stream.
TEST_F(StatsTest, ASourceThatStartsItsNumberingAgainIsNoLoss) {
    create("log: false");
    auto deliver = [&](int64_t pos, uint32_t stream_flags) {
        auto raw = test_frame(static_cast<uint8_t>(pos), 255, 190);
        mavbond_frame f = host_.frame(raw, host_.link("radio"));
        f.stream_flags = stream_flags;
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = MAVBOND_NOTE_POSITION;
        notes.bond_pos = pos;
        host_.ingress(f, notes, host_.link("radio"));
        host_.advance(milliseconds(200));  // a HEARTBEAT at 5 Hz
    };
    for (int64_t p = 0; p < 70; p++)
        deliver(p, 0);
    deliver(256, 0);  // the new numbering's seq 0, placed a turn ahead
    deliver(257, 0);
    deliver(258, 0);
    for (int64_t p = 3; p < 40; p++)  // the host saw the restart: dedup places it anew
        deliver(p + 70, p == 3 ? MAVBOND_STREAM_RESYNC : 0);
    host_.advance(seconds(3));  // every hole has waited long enough
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered\":110,\"duplicates\":0,\"stale\":0,"
                                                "\"delivered_lost\":0,"))
        << object("bonds", "vehicle");
    // Yet a frame lost after the restart is loss.
    deliver(111, 0);
    host_.advance(seconds(3));
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered_lost\":1,")) << object("bonds", "vehicle");
}

// Found with two links cut together for a second of a 124 frames/s stream: the link that came
// back first stepped further than its numbers could tell, the host flagged its numbering
// restarted, and dedup placed its frames right, one step on from the newest. Read as a
// restart, the second's 124 frames lost on both links were not counted.
TEST_F(StatsTest, AFramePlacedOneStepOnIsNoRestartWhateverTheLinkSaw) {
    create("log: false");
    auto deliver = [&](int64_t pos, uint32_t stream_flags) {
        auto raw = test_frame(static_cast<uint8_t>(pos), 1, 1);
        mavbond_frame f = host_.frame(raw, host_.link("radio"));
        f.stream_flags = stream_flags;
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = MAVBOND_NOTE_POSITION;
        notes.bond_pos = pos;
        host_.ingress(f, notes, host_.link("radio"));
        host_.advance(milliseconds(8));
    };
    for (int64_t p = 0; p < 300; p++)
        deliver(p, 0);
    host_.advance(seconds(1));  // both links cut: 124 frames lost on both
    deliver(424, 0);            // dedup placed the first one back by time
    deliver(425, MAVBOND_STREAM_RESYNC);  // and the host saw the radio's numbering anew
    for (int64_t p = 426; p < 500; p++)
        deliver(p, 0);
    host_.advance(seconds(3));
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered_lost\":124,")) << object("bonds", "vehicle");
}

// Found with MAVProxy through the shipped pair: it quit at sequence 192 and a new one
// started 11 s later at 0, a step of 64 forward, and the air side counted 63 frames lost on
// every link while both links brought the ground's reports all along.
TEST_F(StatsTest, ASourceThatWentQuietWhileItsLinksWereHeardIsNoLoss) {
    create("log: false");
    auto deliver = [&](const std::string& link, uint8_t sysid, uint8_t compid, int64_t pos) {
        auto raw = test_frame(static_cast<uint8_t>(pos), sysid, compid);
        mavbond_frame f = host_.frame(raw, host_.link(link));
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = MAVBOND_NOTE_POSITION;
        notes.bond_pos = pos;
        host_.ingress(f, notes, host_.link(link));
    };
    int64_t report = 0;  // the far gateway's own frames, a second apart on each link
    auto second = [&](bool radio_heard) {
        if (radio_heard)
            deliver("radio", 1, 192, report++);
        deliver("lte", 1, 192, report++);
        host_.advance(seconds(1));
    };
    for (int64_t p = 0; p <= 192; p++) {  // the first GCS: 193 frames, on the radio
        deliver("radio", 255, 230, p);
        if (p % 10 == 0)
            second(true);
    }
    for (int i = 0; i < 11; i++)  // no GCS: the links are heard
        second(true);
    for (int64_t p = 256; p < 266; p++)  // the next GCS at 0: dedup continues a step of 64
        deliver("radio", 255, 230, p);
    host_.advance(seconds(3));
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered_lost\":0,")) << object("bonds", "vehicle");
    // Quiet while the one link that brought it was silent too: what it sent meanwhile was lost.
    for (int i = 0; i < 11; i++)
        second(false);
    for (int64_t p = 276; p < 280; p++)  // 10 frames on from the last
        deliver("radio", 255, 230, p);
    host_.advance(seconds(3));
    EXPECT_TRUE(has(object("bonds", "vehicle"), "\"delivered_lost\":10,")) << object("bonds", "vehicle");
}

TEST_F(StatsTest, ActiveLinkAndSwitchesFromTheHost) {
    create();
    std::string bond = object("bonds", "vehicle");
    EXPECT_TRUE(has(bond, "\"active\":\"\",\"switches\":0")) << bond;
    uint32_t id = 0;
    ASSERT_EQ(host_.bond_by_name("vehicle", &id), 0);
    host_.set_active_link(id, host_.link("radio").id);
    host_.set_active_link(id, host_.link("lte").id);
    bond = object("bonds", "vehicle");
    EXPECT_TRUE(has(bond, "\"active\":\"lte\",\"switches\":2")) << bond;
}

TEST_F(StatsTest, CrcErrorsFromTheHostCounters) {
    create("interval: 1s");
    host_.counters[host_.link("radio").id].crc_errors = 3;
    host_.counters[host_.link("radio").id].garbage_bytes = 17;
    host_.advance(seconds(1));
    host_.counters[host_.link("radio").id].crc_errors = 5;
    std::string radio = object("links", "radio");
    EXPECT_TRUE(has(radio, "\"crc_errors\":5,\"garbage_bytes\":17")) << radio;
    EXPECT_TRUE(has(radio, "\"interval\":{\"frames\":0,\"bytes\":0,\"lost\":0,\"loss_pct\":0.000,"
                           "\"crc_errors\":3}"))
        << radio;
}

TEST_F(StatsTest, IntervalFiguresAndOneLogLinePerInterval) {
    create("interval: 1s\nlog: true");
    for (int i = 0; i < 10; i++) {
        if (i != 5)
            send("radio", static_cast<uint8_t>(i));
    }
    host_.advance(seconds(1));
    ASSERT_EQ(host_.logs.size(), 1u);
    EXPECT_EQ(host_.logs[0],
              "vehicle: delivered 9 loss 10.0% dup 0 stale 0 (radio 9 loss 10.0%, lte 0 loss "
              "0.0%); gcs 0 loss 0.0%");
    for (int i = 10; i < 20; i++)
        send("radio", static_cast<uint8_t>(i));
    host_.advance(seconds(1));
    ASSERT_EQ(host_.logs.size(), 2u);
    std::string radio = object("links", "radio");
    EXPECT_TRUE(has(radio, "\"frames\":19,\"bytes\":399,\"basis\":\"sequence\",\"expected\":20,"
                           "\"lost\":1,"))
        << radio;
    EXPECT_TRUE(has(radio, "\"interval\":{\"frames\":10,\"bytes\":210,\"lost\":0,")) << radio;
    EXPECT_TRUE(has(status(), "\"intervals\":2,")) << status();
}

TEST_F(StatsTest, NoLogLineUnlessAskedFor) {
    // A line a second by default filled a Pi's journal (issue 21, item 14).
    create("interval: 1s");
    host_.advance(seconds(5));
    EXPECT_TRUE(host_.logs.empty()) << host_.logs.size() << " lines";
    EXPECT_TRUE(has(status(), "\"intervals\":5,")) << status();
}

/// The samples a metrics scrape gives, by "name{label=value,...}" (labels in their order).
std::map<std::string, double> scrape(const mavbond_plugin_descriptor* plugin, void* self) {
    std::map<std::string, double> out;
    plugin->metrics(self, [](void* ctx, const mavbond_metric_sample* m) {
        std::string key = m->name;
        key += "{";
        for (uint32_t i = 0; i < m->label_count; i++)
            key += std::string(i ? "," : "") + m->labels[i].name + "=" + m->labels[i].value;
        key += "}";
        (*static_cast<std::map<std::string, double>*>(ctx))[key] =
            m->type == MAVBOND_METRIC_COUNTER ? static_cast<double>(m->count) : m->value;
    }, &out);
    return out;
}

TEST_F(StatsTest, AFarSideThatCountsMakesALinksLossExact) {
    create("interval: 1s");
    // Ten frames of a source with a gap: by sequence 1 lost of 11.
    for (int i = 0; i < 12; i++) {
        if (i != 5)
            send("radio", static_cast<uint8_t>(i));
    }
    host_.advance(seconds(1));
    EXPECT_TRUE(has(object("links", "radio"), "\"basis\":\"sequence\",\"expected\":12,\"lost\":1,"))
        << object("links", "radio");
    // The far side's markers: it wrote 200 frames on the link (the gap was its budget's
    // choice), 198 arrived; it keeps the link in standby.
    mavbond_link_counters& c = host_.counters[host_.link("radio").id];
    c.account_flags = MAVBOND_ACCOUNT_EXACT | MAVBOND_ACCOUNT_PEER_STANDBY;
    c.account_expected = 200;
    c.account_received = 198;
    std::string radio = object("links", "radio");
    EXPECT_TRUE(has(radio, "\"basis\":\"markers\",\"expected\":200,\"lost\":2,\"loss_pct\":1.000,"
                           "\"peer_standby\":true"))
        << radio;
    // The switch makes no interval of its own: the next one is the markers' alone.
    host_.advance(seconds(1));
    c.account_expected = 300;
    c.account_received = 297;
    host_.advance(seconds(1));
    EXPECT_TRUE(has(object("links", "radio"), "\"interval\":{\"frames\":0,\"bytes\":0,\"lost\":1,"
                                              "\"loss_pct\":1.000"))
        << object("links", "radio");
    auto m = scrape(plugin_, self_);
    EXPECT_EQ(300, m["link_expected_frames{link=radio,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(297, m["link_received_frames{link=radio,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(0.01, m["link_loss_ratio{link=radio,bond=vehicle,basis=markers}"]);
    // The sequence figures before the markers came stay, and grow no more.
    send("radio", 20);
    m = scrape(plugin_, self_);
    EXPECT_EQ(12, m["link_expected_frames{link=radio,bond=vehicle,basis=sequence}"]);
    EXPECT_EQ(11, m["link_received_frames{link=radio,bond=vehicle,basis=sequence}"]);
    EXPECT_EQ(0u, m.count("link_loss_ratio{link=radio,bond=vehicle,basis=sequence}"));
}

TEST(StatsPeers, APeerThatMovesToANewPortStaysOneSeries) {
    const mavbond_plugin_descriptor* plugin = mavbond_plugin_entry();
    FakeHost host;
    host.declare_endpoint("lte", "vehicle");  // a UDP server: its peers are the links
    void* self = host.create(plugin, "log: false");
    ASSERT_NE(self, nullptr) << host.last_error();
    const mavbond_link& first = host.add_link("lte@192.0.2.7:40001", "vehicle");
    plugin->on_link(self, &first, MAVBOND_LINK_ADDED);
    host.counters[first.id] = mavbond_link_counters{};
    host.counters[first.id].account_flags = MAVBOND_ACCOUNT_EXACT;
    host.counters[first.id].account_expected = 100;
    host.counters[first.id].account_received = 90;
    for (uint8_t i = 0; i < 5; i++) {
        auto raw = test_frame(i, 1, 1);
        mavbond_frame f = host.frame(raw, first);
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        host.ingress(f, notes, first);
    }
    plugin->on_link(self, &first, MAVBOND_LINK_REMOVED);  // the NAT moved the vehicle's port
    const mavbond_link& second = host.add_link("lte@192.0.2.7:40002", "vehicle");
    plugin->on_link(self, &second, MAVBOND_LINK_ADDED);
    host.counters[second.id].account_flags = MAVBOND_ACCOUNT_EXACT;
    host.counters[second.id].account_expected = 50;
    host.counters[second.id].account_received = 50;
    auto m = scrape(plugin, self);
    EXPECT_EQ(150, m["link_expected_frames{link=lte,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(140, m["link_received_frames{link=lte,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(5, m["link_frames{link=lte,bond=vehicle}"]);
    for (const auto& [key, v] : m)
        EXPECT_EQ(std::string::npos, key.find("192.0.2.7")) << key << ": an address in a label";
}

// A signed peer's new port is taken at once and carries the old one's account on: the old
// link's figures are then the new one's, counted once.
TEST(StatsPeers, AnAccountCarriedOnByTheNewPeerIsCountedOnce) {
    const mavbond_plugin_descriptor* plugin = mavbond_plugin_entry();
    FakeHost host;
    host.declare_endpoint("lte", "vehicle");
    void* self = host.create(plugin, "log: false");
    ASSERT_NE(self, nullptr) << host.last_error();
    const mavbond_link& first = host.add_link("lte@192.0.2.7:40001", "vehicle");
    plugin->on_link(self, &first, MAVBOND_LINK_ADDED);
    host.counters[first.id] = mavbond_link_counters{};
    host.counters[first.id].account_flags = MAVBOND_ACCOUNT_EXACT;
    host.counters[first.id].account_expected = 100;
    host.counters[first.id].account_received = 90;
    EXPECT_EQ(100, scrape(plugin, self)["link_expected_frames{link=lte,bond=vehicle,basis=markers}"]);
    const mavbond_link& second = host.add_link("lte@192.0.2.7:40002", "vehicle");
    plugin->on_link(self, &second, MAVBOND_LINK_ADDED);
    host.counters[first.id].account_flags |= MAVBOND_ACCOUNT_MOVED;
    host.counters[second.id].account_flags = MAVBOND_ACCOUNT_EXACT;
    host.counters[second.id].account_expected = 130;  // the old one's 100 and 30 since
    host.counters[second.id].account_received = 118;
    auto m = scrape(plugin, self);  // both present, as for a moment they are
    EXPECT_EQ(130, m["link_expected_frames{link=lte,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(118, m["link_received_frames{link=lte,bond=vehicle,basis=markers}"]);
    plugin->on_link(self, &first, MAVBOND_LINK_REMOVED);
    m = scrape(plugin, self);
    EXPECT_EQ(130, m["link_expected_frames{link=lte,bond=vehicle,basis=markers}"]);
    EXPECT_EQ(118, m["link_received_frames{link=lte,bond=vehicle,basis=markers}"]);
}

TEST_F(StatsTest, LogCanBeTurnedOff) {
    create("log: false");
    host_.advance(seconds(5));
    EXPECT_TRUE(host_.logs.empty());
}

TEST_F(StatsTest, ScopeLimitsWhatIsReported) {
    create("bonds: [vehicle]");
    std::string s = status();
    EXPECT_TRUE(has(s, "\"name\":\"radio\"")) << s;
    EXPECT_FALSE(has(s, "\"name\":\"gcs\"")) << s;
}

class StatsCsvTest : public StatsTest {
protected:
    std::string dir_;
    void SetUp() override {
        StatsTest::SetUp();
        char tmpl[] = "/tmp/mavbond-stats-XXXXXX";
        ASSERT_NE(mkdtemp(tmpl), nullptr);
        dir_ = tmpl;
    }
    void TearDown() override {
        std::remove((dir_ + "/stats.csv").c_str());
        rmdir(dir_.c_str());
    }
    std::vector<std::string> lines() {
        std::ifstream in(dir_ + "/stats.csv");
        std::vector<std::string> out;
        for (std::string line; std::getline(in, line);)
            out.push_back(line);
        return out;
    }
};

TEST_F(StatsCsvTest, HeaderOnceAndARowPerLinkAndBondEachInterval) {
    create("csv: " + dir_ + "/stats.csv\nlog: false");
    uint32_t id = 0;
    ASSERT_EQ(host_.bond_by_name("vehicle", &id), 0);
    host_.set_active_link(id, host_.link("radio").id);
    for (int i = 0; i < 10; i++) {
        if (i != 5)
            send("radio", static_cast<uint8_t>(i));
        send("lte", static_cast<uint8_t>(i), 1, 1, MAVBOND_NOTE_DROPPED | MAVBOND_NOTE_DUPLICATE,
             4'000'000, "radio");
    }
    host_.advance(seconds(1));
    auto rows = lines();
    ASSERT_EQ(rows.size(), 5u);  // header, 3 links, 1 bond; flushed without closing
    EXPECT_EQ(rows[0],
              "time_s,kind,name,frames,bytes,lost,loss_pct,delivered,duplicates,stale,crc_errors,"
              "skew_ms_mean,active");
    EXPECT_EQ(rows[1], "1.000,link,radio,9,189,1,10.000,,,,0,,1");
    EXPECT_EQ(rows[2], "1.000,link,lte,10,210,0,0.000,,,,0,,0");
    EXPECT_EQ(rows[3], "1.000,link,gcs,0,0,0,0.000,,,,0,,");
    EXPECT_EQ(rows[4], "1.000,bond,vehicle,19,399,1,10.000,9,10,0,0,4.000,radio");
    host_.advance(seconds(1));
    rows = lines();
    ASSERT_EQ(rows.size(), 9u);
    EXPECT_EQ(rows[8], "2.000,bond,vehicle,0,0,0,0.000,0,0,0,0,,radio");

    // A second run appends to the series without another header (the first instance stays
    // idle: its host's clock no longer moves).
    FakeHost again;
    again.add_link("radio", "vehicle");
    ASSERT_NE(again.create(plugin_, "csv: " + dir_ + "/stats.csv\nlog: false"), nullptr)
        << again.last_error();
    again.advance(seconds(1));
    rows = lines();
    ASSERT_EQ(rows.size(), 11u);
    EXPECT_EQ(rows[9].rfind("1.000,link,radio,", 0), 0u) << rows[9];
}

TEST_F(StatsCsvTest, UnwritableCsvIsAConfigError) {
    EXPECT_EQ(host_.create(plugin_, "csv: " + dir_ + "/missing/stats.csv"), nullptr);
    const std::string& e = host_.last_error();
    EXPECT_TRUE(has(e, "test.yaml:")) << e;
    EXPECT_TRUE(has(e, "option 'csv': cannot open")) << e;
}

TEST_F(StatsTest, BadIntervalIsAConfigError) {
    EXPECT_EQ(host_.create(plugin_, "interval: soon"), nullptr);
    EXPECT_TRUE(has(host_.last_error(), "test.yaml:")) << host_.last_error();
    EXPECT_TRUE(has(host_.last_error(), "option 'interval' must be a duration"))
        << host_.last_error();
    EXPECT_EQ(host_.create(plugin_, "interval: 0s"), nullptr);
    EXPECT_TRUE(has(host_.last_error(), "option 'interval': must be greater than 0"))
        << host_.last_error();
}

}  // namespace
}  // namespace mavbond
