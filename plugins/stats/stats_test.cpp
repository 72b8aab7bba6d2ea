// stats against FakeHost: sequence-gap loss (wrap, reordering, per source), the bond figures
// read from dedup's notes, the CSV time series, and the status JSON the host shows.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
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
    EXPECT_TRUE(has(radio, "\"bond\":\"vehicle\",\"frames\":10,\"bytes\":210,\"lost\":2,"
                           "\"loss_pct\":16.667"))
        << radio;
}

TEST_F(StatsTest, ReorderingDoesNotInflateLoss) {
    create();
    for (int s : {0, 1, 3, 2, 4, 6, 5, 7})
        send("radio", static_cast<uint8_t>(s));
    EXPECT_TRUE(has(object("links", "radio"), "\"frames\":8,\"bytes\":168,\"lost\":0,"))
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
    EXPECT_TRUE(has(object("links", "radio"), "\"frames\":19,\"bytes\":399,\"lost\":1,"))
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
    EXPECT_TRUE(has(object("links", "lte"), "\"frames\":11,\"bytes\":231,\"lost\":0,"))
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
    create("interval: 1s");
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
    EXPECT_TRUE(has(radio, "\"frames\":19,\"bytes\":399,\"lost\":1,")) << radio;
    EXPECT_TRUE(has(radio, "\"interval\":{\"frames\":10,\"bytes\":210,\"lost\":0,")) << radio;
    EXPECT_TRUE(has(status(), "\"intervals\":2,")) << status();
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
