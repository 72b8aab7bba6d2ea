// linkswitch against FakeHost: a manual clock drives the silence timer, frames are built with
// chosen sequence numbers so loss is exact, each link's stream positions are tracked by the
// host's own StreamPositions (as the filter chain does), and the host's active-link map shows
// each switch.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <functional>
#include <map>
#include <random>
#include <regex>
#include <string>
#include <vector>

#include "allocations.h"
#include "fake_host.h"
#include "mavbond/plugin.h"
#include "routing/stream_positions.h"

extern "C" const mavbond_plugin_descriptor* mavbond_plugin_entry(void);

namespace mavbond {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using std::chrono::seconds;

constexpr uint64_t kMsNs = 1'000'000;
constexpr uint64_t kSecondNs = 1'000'000'000;


/// One source sending on one link with its own numbering: seq counts up every frame; every
/// `drop_every`th frame, or each frame with probability `loss`, is lost in the air (its seq is
/// used but nothing arrives).
struct Sender {
    std::string link;
    int drop_every = 0;
    bool on = true;
    uint8_t seq = 0;
    uint64_t sent = 0;
    double loss = 0;
    std::mt19937 rng{1};
};

/// One path of a stream fanned out over the bond's links by the gateway on the other side:
/// frame k (seq k % 256) arrives `lag` frames later than it was sent, unless the path loses it.
struct Path {
    std::string link;
    int64_t lag = 0;
    std::function<bool(int64_t)> loses = [](int64_t) { return false; };
    bool on = true;
};

struct Delivery {
    int64_t frame;
    std::string link;
};

class LinkSwitchTest : public testing::Test {
protected:
    const mavbond_plugin_descriptor* plugin_ = mavbond_plugin_entry();
    FakeHost host_;
    void* self_ = nullptr;
    std::map<std::string, StreamPositions> positions_;  // what the host tracks per link
    int64_t next_frame_ = 0;                            // fan_out's stream
    std::vector<Delivery> delivered_;                   // what fan_out saw passed
    std::string last_active_;
    std::vector<std::pair<int64_t, std::string>> switched_at_;  // (frame, new active link)

    void create(const std::string& options) {
        self_ = host_.create(plugin_, options);
        ASSERT_NE(self_, nullptr) << host_.last_error();
    }

    mavbond_verdict send(const std::string& link, uint8_t seq, uint32_t note_flags = 0,
                         uint8_t sysid = 1, uint8_t compid = 1, bool track = true) {
        auto raw = test_frame(seq, sysid, compid, 0);
        mavbond_frame f = host_.frame(raw);
        f.version = 2;
        f.seq = seq;
        f.sysid = sysid;
        f.compid = compid;
        f.crc_checked = 1;
        StreamStep step =
            track ? positions_[link].track(sysid, compid, seq) : StreamStep{seq, 0, 0};
        f.stream_pos = step.pos;
        f.stream_lost = step.lost;
        f.stream_flags = step.flags;
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = note_flags;
        return host_.ingress(f, notes, host_.link(link));
    }

    /// A frame from each sender that is on every `period` (50 frames/s by default).
    void run(Duration total, std::vector<Sender*> senders, Duration period = milliseconds(20)) {
        for (Duration t{}; t < total; t += period) {
            for (Sender* s : senders) {
                if (!s->on)
                    continue;
                s->sent++;
                uint8_t seq = s->seq++;
                if (s->drop_every && s->sent % s->drop_every == 0)
                    continue;
                if (s->loss > 0 && std::bernoulli_distribution(s->loss)(s->rng))
                    continue;
                send(s->link, seq);
            }
            host_.advance(period);
        }
    }

    /// Runs until `link` is active or `limit` has passed; the time it took.
    uint64_t run_until_active(const std::string& link, Duration limit, std::vector<Sender*> senders,
                              Duration period = milliseconds(20)) {
        uint64_t start = host_.now_ns();
        while (active() != link && host_.now_ns() - start < static_cast<uint64_t>(limit.count()))
            run(period, senders, period);
        return host_.now_ns() - start;
    }

    /// `frames` frames of one stream, one every `period`, on every path that is on. Notes in
    /// switched_at_ the first frame sent after each change of the active link.
    void fan_out(int64_t frames, std::vector<Path*> paths, Duration period = milliseconds(20)) {
        for (int64_t i = 0; i < frames; i++, next_frame_++) {
            std::string now_active = active();
            if (now_active != last_active_) {
                if (!last_active_.empty())
                    switched_at_.emplace_back(next_frame_, now_active);
                last_active_ = now_active;
            }
            for (Path* p : paths) {
                int64_t k = next_frame_ - p->lag;
                if (!p->on || k < 0 || p->loses(k))
                    continue;
                if (send(p->link, static_cast<uint8_t>(k)) == MAVBOND_PASS)
                    delivered_.push_back({k, p->link});
            }
            host_.advance(period);
        }
    }

    /// After a loss switch from radio (every 4th frame lost) to lte, which carries the same
    /// stream `lag` frames later: each frame delivered once, radio's up to the switch, lte's
    /// from its first frame after the switch, the copies among them dropped and what radio
    /// lost among them delivered.
    void expect_clean_loss_switch(int64_t lag) {
        ASSERT_EQ(switched_at_.size(), 1u);
        ASSERT_EQ(switched_at_[0].second, "lte");
        int64_t first_lte = switched_at_[0].first - lag;  // the first frame lte brought after
        int64_t last_radio = switched_at_[0].first - 1;
        std::map<int64_t, int> times;
        for (const Delivery& d : delivered_) {
            times[d.frame]++;
            if (d.frame < first_lte || d.frame > last_radio) {
                EXPECT_EQ(d.link, d.frame < first_lte ? "radio" : "lte") << d.frame;
            }
        }
        for (const auto& [k, n] : times)
            EXPECT_EQ(n, 1) << "frame " << k << " delivered " << n << " times";
        int64_t copies = 0, filled = 0;
        for (int64_t k = 0; k < next_frame_ - lag; k++) {
            bool radio_had = k % 4 != 3;
            bool want = (k <= last_radio && radio_had) || k >= first_lte;
            EXPECT_EQ(times.count(k), want ? 1u : 0u) << "frame " << k;
            if (k >= first_lte && k <= last_radio)
                (radio_had ? copies : filled)++;
        }
        EXPECT_GT(filled, 0);  // frames radio lost and lte delivered late
        EXPECT_EQ(link_field("lte", "already_delivered"), copies) << status();
    }

    std::string active(const std::string& bond = "vehicle") {
        uint32_t id = 0;
        EXPECT_EQ(host_.bond_by_name(bond, &id), 0);
        auto it = host_.active_link.find(id);
        if (it == host_.active_link.end())
            return "";
        return host_.link_name(it->second);
    }

    std::string status() {
        char buf[8192];
        size_t n = plugin_->status_json(self_, buf, sizeof buf);
        EXPECT_LT(n, sizeof buf);
        return std::string(buf, n);
    }

    /// A number status_json shows in a link's object (-1 when absent or null).
    double link_field(const std::string& link, const std::string& key) {
        std::string s = status();
        size_t at = s.find("{\"name\":\"" + link + "\",\"heard\"");
        if (at == std::string::npos)
            return -1;
        at = s.find("\"" + key + "\":", at);
        size_t value = at + key.size() + 3;
        if (at == std::string::npos || s.compare(value, 4, "null") == 0)
            return -1;
        return std::strtod(s.c_str() + value, nullptr);
    }
    double loss_pct(const std::string& link) { return link_field(link, "loss_pct"); }

    bool logged(const std::string& text) const {
        for (const auto& line : host_.logs) {
            if (line.find(text) != std::string::npos)
                return true;
        }
        return false;
    }

    bool logged_like(const std::string& pattern) const {
        std::regex re(pattern);
        for (const auto& line : host_.logs) {
            if (std::regex_search(line, re))
                return true;
        }
        return false;
    }

    size_t switch_lines() const {
        size_t n = 0;
        for (const auto& line : host_.logs)
            n += line.rfind("active link ", 0) == 0 && line.find(" -> ") != std::string::npos;
        return n;
    }

    /// The plugin's metric samples as "name{label=value,...}" -> value (counters as numbers).
    std::map<std::string, double> metrics() {
        std::map<std::string, double> out;
        plugin_->metrics(
            self_,
            [](void* ctx, const mavbond_metric_sample* s) {
                std::string key = std::string(s->name) + "{";
                for (uint32_t i = 0; i < s->label_count; i++)
                    key += std::string(i ? "," : "") + s->labels[i].name + "=" + s->labels[i].value;
                key += "}";
                (*static_cast<std::map<std::string, double>*>(ctx))[key] =
                    s->type == MAVBOND_METRIC_COUNTER ? static_cast<double>(s->count) : s->value;
            },
            &out);
        return out;
    }
};

// --- the basics -----------------------------------------------------------------------------

TEST_F(LinkSwitchTest, FirstLinkIsActiveAndOthersAreDroppedAndCounted) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    host_.add_link("gcs");
    create("switch_after: 1s");
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(send("radio", 0), MAVBOND_PASS);
    EXPECT_EQ(send("lte", 0), MAVBOND_DROP);
    EXPECT_EQ(send("lte", 1), MAVBOND_DROP);
    EXPECT_EQ(send("gcs", 0), MAVBOND_PASS);  // not in a bond
    // Dropped by an earlier filter: only observed, neither passed nor dropped again.
    EXPECT_EQ(send("lte", 2, MAVBOND_NOTE_DROPPED), MAVBOND_PASS);
    std::string s = status();
    EXPECT_NE(s.find("\"active\":\"radio\""), std::string::npos) << s;
    EXPECT_NE(s.find("\"name\":\"radio\",\"heard\":true"), std::string::npos) << s;
    EXPECT_NE(s.find("\"passed\":1,\"dropped\":0,\"already_delivered\":0"), std::string::npos) << s;
    EXPECT_NE(s.find("\"passed\":0,\"dropped\":2,\"already_delivered\":0"), std::string::npos) << s;
    EXPECT_EQ(s.find("gcs"), std::string::npos) << s;
}

// Found on the air side of a bond between MAVSDK peers: between transfers it hears only the
// GCS's HEARTBEAT, 1 Hz on each link. One lost HEARTBEAT was a second's silence: the bond
// switched to the 300 ms link, and never came back, as a link carrying one frame a second has
// too few frames to judge its loss. A lost HEARTBEAT is no silence now (three usual gaps), and
// a preferred link too thin to judge may take its place back once healthy for failback_after.
TEST_F(LinkSwitchTest, AOneHertzLinkLosingAHeartbeatStaysAndThinLinksFailBack) {
    host_.add_link("fast", "vehicle");
    host_.add_link("slow", "vehicle");
    create("switch_after: 1s\nfailback_after: 10s");
    Sender fast{"fast"}, slow{"slow"};
    run(seconds(10), {&fast, &slow}, seconds(1));
    ASSERT_EQ(active(), "fast");
    fast.sent++;  // one HEARTBEAT lost on fast: 2 s between two of its frames
    fast.seq++;
    run(seconds(1), {&slow}, seconds(1));
    run(seconds(5), {&fast, &slow}, seconds(1));
    EXPECT_EQ(active(), "fast") << "one lost HEARTBEAT is no silence";
    // fast really goes silent: the bond moves to slow, and back once fast is heard again and
    // healthy for failback_after, though its window never holds enough frames to judge.
    fast.on = false;
    run_until_active("slow", seconds(10), {&fast, &slow}, seconds(1));
    ASSERT_EQ(active(), "slow");
    fast.on = true;
    uint64_t took = run_until_active("fast", seconds(60), {&fast, &slow}, seconds(1));
    EXPECT_EQ(active(), "fast");
    EXPECT_GE(took, 10'000'000'000u) << "not before failback_after";
    EXPECT_LT(took, 20'000'000'000u);
}

TEST_F(LinkSwitchTest, SilenceSwitchesWithinSwitchAfterPlusOneTick) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(2), {&radio, &lte});
    ASSERT_EQ(active(), "radio");
    radio.on = false;
    uint64_t last_radio = host_.now_ns() - 20 * kMsNs;  // run() advanced after the last frame
    run_until_active("lte", seconds(3), {&lte});
    ASSERT_EQ(active(), "lte");
    uint64_t took = host_.now_ns() - last_radio;
    EXPECT_GE(took, 1'000'000'000ull);
    EXPECT_LE(took, 1'100'000'000ull);
    EXPECT_TRUE(logged("active link radio -> lte: radio silent for 1.0")) << host_.logs.back();
    EXPECT_EQ(send("lte", lte.seq++), MAVBOND_PASS);
    EXPECT_EQ(host_.switches[0], 2u);  // the initial choice and the switch
}

TEST_F(LinkSwitchTest, NoSwitchWhenNoOtherLinkIsHeard) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1s");
    Sender radio{"radio"};
    run(seconds(1), {&radio});
    host_.advance(seconds(5));
    EXPECT_EQ(active(), "radio");
    EXPECT_TRUE(logged("active link radio silent for"));
    EXPECT_EQ(switch_lines(), 0u);
}

TEST_F(LinkSwitchTest, NoSwitchWhenTheVehicleStopsSending) {
    // Every link falls silent, lte 200 ms after radio (its latency): lte is not "alive" for
    // long enough to be worth a switch.
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1s");
    Path radio{"radio"}, lte{"lte", 10};  // 10 frames of 20 ms behind
    fan_out(200, {&radio, &lte});
    radio.on = false;
    fan_out(10, {&radio, &lte});  // lte brings the last 10 frames
    lte.on = false;
    fan_out(150, {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u) << testing::PrintToString(host_.logs);
    EXPECT_TRUE(logged("active link radio silent for 1.0"));
}

TEST_F(LinkSwitchTest, ReorderingIsNotLoss) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 3s");
    Sender lte{"lte"};
    // Radio delivers every pair swapped: 1,0,3,2,... — nothing is lost, and all of it passes.
    int passed = 0;
    for (int i = 0; i < 400; i++) {
        passed += send("radio", static_cast<uint8_t>(i ^ 1)) == MAVBOND_PASS;
        if (i % 2)
            run(milliseconds(40), {&lte});
    }
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(passed, 400);
    EXPECT_EQ(loss_pct("radio"), 0.0) << status();
    EXPECT_EQ(link_field("radio", "already_delivered"), 0) << status();
}

TEST_F(LinkSwitchTest, RepeatsAreNoFramesForLoss) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 3s");
    // Radio brings every frame twice and loses every 5th: 20% loss, not 11%.
    Sender lte{"lte"};
    for (int i = 0; i < 250; i++) {
        if (i % 5 != 4) {
            send("radio", static_cast<uint8_t>(i));
            send("radio", static_cast<uint8_t>(i));
        }
        run(milliseconds(20), {&lte});
    }
    EXPECT_NEAR(loss_pct("radio"), 20.0, 0.5) << status();
}

TEST_F(LinkSwitchTest, NoAllocationPerFrame) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 1s");
    // The frames are built once, the positions tracked as the host does: only the plugin's
    // own work (ingress on both links, the timer's checks) is counted.
    auto raw = test_frame(0, 1, 1, 0);
    mavbond_frame f = host_.frame(raw);
    f.version = 2;
    f.sysid = f.compid = f.crc_checked = 1;
    const mavbond_link* links[] = {&host_.link("radio"), &host_.link("lte")};
    StreamPositions positions[2];
    auto frames = [&](int from, int to) {
        for (int i = from; i < to; i++) {
            for (int l = 0; l < 2; l++) {
                if (l == 0 && i % 10 == 9)
                    continue;  // radio loses 10%: gaps, late frames never
                f.seq = static_cast<uint8_t>(i);
                f.rx_time_ns = host_.now_ns();
                StreamStep step = positions[l].track(1, 1, f.seq);
                f.stream_pos = step.pos;
                f.stream_lost = step.lost;
                f.stream_flags = step.flags;
                mavbond_frame_notes notes{};
                notes.struct_size = sizeof notes;
                host_.ingress(f, notes, *links[l]);
            }
            host_.advance(milliseconds(5));
        }
    };
    frames(0, 1000);  // sources learned, the loss switch to lte made (and logged) once judged
    ASSERT_EQ(active(), "lte");
    uint64_t before = allocations();
    frames(1000, 11000);  // 50 s, 20,000 frames, 1,000 timer ticks
    EXPECT_EQ(allocations() - before, 0u);
    EXPECT_EQ(switch_lines(), 1u) << testing::PrintToString(host_.logs);
}

// --- 1. a loss figure is judged only over a whole window with enough frames ----------------

TEST_F(LinkSwitchTest, NoLossSwitchBeforeTheLinkIsHeardForAWholeWindow) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("max_loss: 5%\nloss_window: 5s");
    Sender radio{"radio", 5}, lte{"lte"};  // radio loses 20% from the first frame
    uint64_t first = host_.now_ns();
    run(milliseconds(4900), {&radio, &lte});
    // 245 frames expected by now, 49 lost: far over max_loss, but not a whole window yet.
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(loss_pct("radio"), -1) << status();
    EXPECT_GE(link_field("radio", "expected_frames"), 240) << status();
    run_until_active("lte", seconds(1), {&radio, &lte});
    uint64_t took = host_.now_ns() - first;
    EXPECT_EQ(active(), "lte");
    EXPECT_GE(took, 5 * kSecondNs);
    EXPECT_LE(took, 5 * kSecondNs + 70 * kMsNs);  // the next tick (50 ms) and a frame step
    EXPECT_TRUE(logged_like(R"(^active link radio -> lte: loss (19|20)\.[0-9]%)"
                            R"( over 5s > 5%, lte 0\.0%$)"))
        << testing::PrintToString(host_.logs);
    EXPECT_EQ(switch_lines(), 1u);
}

TEST_F(LinkSwitchTest, TooFewFramesInTheWindowAreNeverJudged) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 5s");
    Sender radio{"radio", 2}, lte{"lte"};  // 10 frames/s: 50 expected per window, radio half lost
    run(seconds(30), {&radio, &lte}, milliseconds(100));
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u);
    EXPECT_EQ(loss_pct("radio"), -1) << status();
    EXPECT_TRUE(logged_like("^link radio: (4[5-9]|50) frames expected over 5s, fewer than the 100 "
                            "needed to judge its loss"))
        << testing::PrintToString(host_.logs);
    EXPECT_TRUE(logged_like("^link lte: (4[5-9]|50) frames expected over 5s"));
}

TEST_F(LinkSwitchTest, ALongerWindowJudgesASlowLink) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 20s");
    Sender radio{"radio", 2}, lte{"lte"};  // the same 10 frames/s: 200 expected per window
    run(milliseconds(19900), {&radio, &lte}, milliseconds(100));
    EXPECT_EQ(active(), "radio");
    run_until_active("lte", seconds(1), {&radio, &lte}, milliseconds(100));
    EXPECT_EQ(active(), "lte");
    EXPECT_TRUE(logged_like(R"(^active link radio -> lte: loss (49|50)\.[0-9]%)"
                            R"( over 20s > 5%, lte 0\.0%$)"))
        << testing::PrintToString(host_.logs);
    EXPECT_FALSE(logged("fewer than the 100 needed"));
}

// --- 2. no flapping between links of similar loss -------------------------------------------

TEST_F(LinkSwitchTest, TwoLinksOfEqualLossStayPut) {
    // As a new user tried it: two links losing 5% each at random, the ArduPilot rate (124
    // frames/s), defaults. A plain "the backup does better" switched 10 times in 50 s.
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    Sender radio{"radio"}, lte{"lte"};
    radio.loss = lte.loss = 0.05;
    radio.rng.seed(7);
    lte.rng.seed(8);
    Duration period(kSecondNs / 124);
    for (int i = 0; i < 60; i++) {  // 300 s, checking the figures are judged on the way
        run(seconds(5), {&radio, &lte}, period);
        if (i > 0) {
            ASSERT_GT(loss_pct("radio"), 2.0) << status();
            ASSERT_LT(loss_pct("radio"), 9.0) << status();
            ASSERT_GT(loss_pct("lte"), 2.0) << status();
        }
    }
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u) << testing::PrintToString(host_.logs);
}

TEST_F(LinkSwitchTest, NoLossSwitchToABackupBetterByLessThanTheMargin) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_margin: 15%");
    Sender radio{"radio", 4}, lte{"lte", 8};  // 25% against 12.5%: 12.5 points better
    run(seconds(30), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u);
    EXPECT_NEAR(loss_pct("radio"), 25.0, 0.5) << status();
    EXPECT_NEAR(loss_pct("lte"), 12.5, 0.5) << status();
}

TEST_F(LinkSwitchTest, LossSwitchToABackupBetterByTheMargin) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");  // switch_margin 5%
    Sender radio{"radio", 4}, lte{"lte", 8};  // the same 25% against 12.5%
    run(seconds(6), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
    EXPECT_TRUE(logged_like(R"(^active link radio -> lte: loss 2[45]\.[0-9]%)"
                            R"( over 5s > 5%, lte 1[23]\.[0-9]%$)"))
        << testing::PrintToString(host_.logs);
}

TEST_F(LinkSwitchTest, ADifferenceWithinChanceIsNoReasonToSwitch) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    // No margin at all: 12.5% against 10% over 250 frames is 0.9 standard errors apart.
    create("switch_margin: 0%");
    Sender radio{"radio", 8}, lte{"lte", 10};
    run(seconds(60), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u);
    EXPECT_NEAR(loss_pct("radio"), 12.5, 0.5) << status();
    EXPECT_NEAR(loss_pct("lte"), 10.0, 0.5) << status();
}

TEST_F(LinkSwitchTest, NoLossSwitchWhenTheBackupIsWorse) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_margin: 0%");
    Sender radio{"radio", 10}, lte{"lte", 4};  // 10% against 25%
    run(seconds(20), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u);
    EXPECT_NEAR(loss_pct("radio"), 10.0, 0.5) << status();
    EXPECT_NEAR(loss_pct("lte"), 25.0, 0.5) << status();
}

TEST_F(LinkSwitchTest, HoldDownPreventsAnEarlySecondLossSwitch) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 4s\nhold_down: 10s");
    Sender radio{"radio", 5}, lte{"lte"};
    run_until_active("lte", seconds(5), {&radio, &lte});
    ASSERT_EQ(active(), "lte");
    uint64_t switched = host_.now_ns();
    // Now the roles swap: lte gets bad, radio clean. Within hold_down nothing moves.
    radio.drop_every = 0;
    lte.drop_every = 5;
    run(milliseconds(9900), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
    EXPECT_EQ(switch_lines(), 1u);
    run_until_active("radio", milliseconds(500), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_LE(host_.now_ns() - switched, 10 * kSecondNs + 100 * kMsNs);
    EXPECT_EQ(switch_lines(), 2u);
    EXPECT_TRUE(logged_like(R"(^active link lte -> radio: loss (19|20)\.[0-9]%)"
                            R"( over 4s > 5%, radio 0\.0%$)"))
        << testing::PrintToString(host_.logs);
}

TEST_F(LinkSwitchTest, SilenceSwitchesEvenDuringHoldDown) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("hold_down: 30s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    lte.on = false;
    run(seconds(2), {&radio});
    EXPECT_EQ(active(), "radio");
    EXPECT_TRUE(logged("active link lte -> radio: lte silent for"));
}

// --- 3. failback with hysteresis, probation after silence ----------------------------------

TEST_F(LinkSwitchTest, FailbackByDefaultAfter30sHealthy) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    radio.seq += 100;  // the frames sent into the outage: not charged as loss on return
    uint64_t back = host_.now_ns();
    run(milliseconds(29900), {&radio, &lte});
    EXPECT_EQ(active(), "lte");  // healthy, but not yet for 30s
    EXPECT_NE(status().find("\"probation\":true"), std::string::npos) << status();
    run_until_active("radio", milliseconds(500), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_LE(host_.now_ns() - back, 30 * kSecondNs + 100 * kMsNs);
    EXPECT_TRUE(logged("active link lte -> radio: failback to radio after 30s healthy"));
    EXPECT_EQ(loss_pct("radio"), 0.0) << status();  // the jump over the outage is no loss
    EXPECT_EQ(status().find("\"probation\":true"), std::string::npos) << status();
}

TEST_F(LinkSwitchTest, FailbackWaitsForAnUnbrokenHealthyStretch) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("failback_after: 30s\nloss_window: 4s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    run(seconds(20), {&radio, &lte});
    radio.drop_every = 4;  // a bad spell: its clock starts again
    run(seconds(6), {&radio, &lte});
    radio.drop_every = 0;
    run(seconds(30), {&radio, &lte});  // 56 s after its return, < 30 s after it was bad
    EXPECT_EQ(active(), "lte");
    run_until_active("radio", seconds(10), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_TRUE(logged("active link lte -> radio: failback to radio after 30s healthy"));
}

TEST_F(LinkSwitchTest, NoFailbackWithFailbackAfterZero) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("failback_after: 0s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    radio.on = true;
    run(seconds(90), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
    EXPECT_EQ(switch_lines(), 1u);
}

TEST_F(LinkSwitchTest, ALinkBackFromSilenceIsNoLossTargetUntilHealthyForFailbackAfter) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 2s\nfailback_after: 20s\nhold_down: 1s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(3), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    lte.drop_every = 4;  // the active link turns bad (25%) as the clean radio returns
    uint64_t back = host_.now_ns();
    run(milliseconds(19900), {&radio, &lte});
    // Radio is clean and judged, lte clearly worse: only probation holds the switch back.
    EXPECT_EQ(active(), "lte");
    EXPECT_EQ(loss_pct("radio"), 0.0) << status();
    EXPECT_NEAR(loss_pct("lte"), 25.0, 1.0) << status();
    run_until_active("radio", milliseconds(500), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_GE(host_.now_ns() - back, 20 * kSecondNs);
    EXPECT_LE(host_.now_ns() - back, 20 * kSecondNs + 100 * kMsNs);
    EXPECT_TRUE(logged_like(R"(^active link lte -> radio: loss 2[45]\.[0-9]%)"
                            R"( over 2s > 5%, radio 0\.0%$)"))
        << testing::PrintToString(host_.logs);
}

TEST_F(LinkSwitchTest, ASilenceSwitchPassesOverABackupJudgedLossy) {
    host_.add_link("c", "vehicle");
    host_.add_link("a", "vehicle");
    host_.add_link("b", "vehicle");
    create("priority: [c, a, b]\nloss_window: 3s");
    Sender a{"a", 4}, b{"b"}, c{"c"};  // a, the next preferred, loses 25%
    run(seconds(4), {&a, &b, &c});
    ASSERT_EQ(active(), "c");
    c.on = false;
    run(milliseconds(1200), {&a, &b});
    EXPECT_EQ(active(), "b");
    EXPECT_TRUE(logged("active link c -> b: c silent for 1.0"));
}

TEST_F(LinkSwitchTest, ASilenceSwitchMayTakeALinkOnProbation) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("failback_after: 30s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(2), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    run(seconds(3), {&radio, &lte});
    ASSERT_NE(status().find("\"probation\":true"), std::string::npos) << status();
    lte.on = false;
    run(milliseconds(1200), {&radio});
    EXPECT_EQ(active(), "radio");
    EXPECT_TRUE(logged("active link lte -> radio: lte silent for 1.0"));
}

// --- 4. no frame delivered twice at a switch -------------------------------------------------

TEST_F(LinkSwitchTest, LossSwitchDeliversNoCopyTwiceAndWhatTheOldLinkLost) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 2s");
    Path radio{"radio", 0, [](int64_t k) { return k % 4 == 3; }}, lte{"lte", 10};
    fan_out(600, {&radio, &lte});  // 12 s at 50 frames/s, past two wraps of the seq byte
    ASSERT_EQ(active(), "lte");
    expect_clean_loss_switch(10);
}

TEST_F(LinkSwitchTest, ACopy120FramesBehindIsStillRecognised) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 2s");
    // 200 frames/s, lte 120 frames (0.6 s) behind: within both limits (128 frames, switch_after).
    Path radio{"radio", 0, [](int64_t k) { return k % 4 == 3; }}, lte{"lte", 120};
    fan_out(1600, {&radio, &lte}, milliseconds(5));
    ASSERT_EQ(active(), "lte");
    expect_clean_loss_switch(120);
}

TEST_F(LinkSwitchTest, ACopyMoreThan128FramesBehindIsDeliveredAgainNeverLost) {
    // The documented limit: 150 frames behind, a copy looks like a frame 106 ahead.
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 2s");
    Path radio{"radio", 0, [](int64_t k) { return k % 4 == 3; }}, lte{"lte", 150};
    fan_out(1600, {&radio, &lte}, milliseconds(5));
    ASSERT_EQ(active(), "lte");
    std::map<int64_t, int> times;
    int64_t last_radio = -1, first_lte = -1;
    for (const Delivery& d : delivered_) {
        times[d.frame]++;
        if (d.link == "radio")
            last_radio = std::max(last_radio, d.frame);
        else if (first_lte < 0)
            first_lte = d.frame;
    }
    ASSERT_EQ(first_lte, last_radio - 149);
    int64_t twice = 0;
    for (int64_t k = first_lte; k < 1600 - 150; k++) {
        ASSERT_GE(times[k], 1) << "frame " << k << " lost";
        twice += times[k] - 1;
    }
    int64_t radio_had = 0;
    for (int64_t k = first_lte; k <= last_radio; k++)
        radio_had += k % 4 != 3;
    EXPECT_EQ(twice, radio_had);
    EXPECT_EQ(link_field("lte", "already_delivered"), 0) << status();
}

TEST_F(LinkSwitchTest, SilenceSwitchAfterMoreThan128FramesLosesNothing) {
    // 400 frames/s: when radio is overdue (half of switch_after), lte's frames are about 190
    // ahead of the last one delivered, which modulo 256 reads as 66 behind. 128 frames at the
    // source's rate is shorter than that silence, so the history is forgotten: they are new.
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1s");
    Path radio{"radio"}, lte{"lte", 10};
    fan_out(800, {&radio, &lte}, microseconds(2500));
    radio.on = false;
    fan_out(1200, {&radio, &lte}, microseconds(2500));
    ASSERT_EQ(active(), "lte");
    std::map<int64_t, int> times;
    int64_t last_radio = -1, first_lte = -1;
    for (const Delivery& d : delivered_) {
        times[d.frame]++;
        if (d.link == "radio")
            last_radio = std::max(last_radio, d.frame);
        else if (first_lte < 0)
            first_lte = d.frame;
    }
    EXPECT_EQ(last_radio, 799);
    EXPECT_GT(first_lte, last_radio + 128);
    for (int64_t k = 0; k < 2000 - 10; k++)
        EXPECT_EQ(times[k], k <= last_radio || k >= first_lte ? 1 : 0) << "frame " << k;
    EXPECT_EQ(link_field("lte", "already_delivered"), 0) << status();
    EXPECT_GT(link_field("lte", "stood_in"), 0) << status();  // before the switch
}

TEST_F(LinkSwitchTest, AFrameBothLinksBroughtIsNotLostToTheSwitchBetweenThem) {
    // The real-peers case (tests/peers): a side that hears the GCS's few frames a second.
    // radio, the active link, is 500 ms behind lte and loses frames 40..42: it is overdue once
    // silent for twice its usual gap (1 s), dead after switch_after (1.7 s). lte brings frame
    // 43 before the switch, radio brings it after: without lte standing in for the overdue
    // radio, each copy came on a link that was not active, and the frame was lost on both.
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1700ms");
    Path radio{"radio", 1}, lte{"lte", 0};
    radio.loses = [](int64_t k) { return k >= 40 && k < 43; };
    fan_out(60, {&radio, &lte}, milliseconds(500));
    ASSERT_EQ(switched_at_.size(), 1u);
    EXPECT_EQ(switched_at_[0].second, "lte");
    std::map<int64_t, int> times;
    for (const Delivery& d : delivered_)
        times[d.frame]++;
    for (int64_t k = 0; k < 59; k++) {
        if (k < 40 || k >= 42)  // both brought it (42: lte, while radio was overdue)
            EXPECT_EQ(times[k], 1) << "frame " << k;
        else
            EXPECT_EQ(times[k], 0) << "frame " << k << ": lte's, while radio was active";
    }
    EXPECT_EQ(link_field("lte", "stood_in"), 2) << status();  // 42 and 43
}

TEST_F(LinkSwitchTest, ARepeatOnTheActiveLinkIsDroppedAndALateFrameDelivered) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    for (int seq = 0; seq < 10; seq++)
        ASSERT_EQ(send("radio", static_cast<uint8_t>(seq)), MAVBOND_PASS);
    EXPECT_EQ(send("radio", 9), MAVBOND_DROP);   // the newest again
    EXPECT_EQ(send("radio", 4), MAVBOND_DROP);   // delivered before
    EXPECT_EQ(send("radio", 12), MAVBOND_PASS);  // 10 and 11 lost ...
    EXPECT_EQ(send("radio", 10), MAVBOND_PASS);  // ... or late: delivered once
    EXPECT_EQ(send("radio", 10), MAVBOND_DROP);
    EXPECT_EQ(send("radio", 11), MAVBOND_PASS);
    // Another source's numbers are its own.
    EXPECT_EQ(send("radio", 4, 0, 1, 2), MAVBOND_PASS);
    EXPECT_EQ(link_field("radio", "already_delivered"), 3) << status();
    EXPECT_EQ(link_field("radio", "passed"), 14) << status();
}

TEST_F(LinkSwitchTest, TheHistorySpansLongGaps) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    // The bond's history alone: the host's tracker would take this many frames from far
    // behind for a restarted counter.
    auto on_radio = [this](uint8_t seq) { return send("radio", seq, 0, 1, 1, false); };
    for (int seq = 0; seq < 10; seq++)
        ASSERT_EQ(on_radio(static_cast<uint8_t>(seq)), MAVBOND_PASS);
    EXPECT_EQ(on_radio(80), MAVBOND_PASS);  // 70 ahead: the bitmap moves across its words
    EXPECT_EQ(on_radio(9), MAVBOND_DROP);   // 71 behind, delivered
    EXPECT_EQ(on_radio(0), MAVBOND_DROP);   // 80 behind, delivered
    EXPECT_EQ(on_radio(50), MAVBOND_PASS);  // 30 behind, never delivered
    EXPECT_EQ(on_radio(50), MAVBOND_DROP);
    EXPECT_EQ(on_radio(180), MAVBOND_PASS);  // 100 ahead
    EXPECT_EQ(on_radio(80), MAVBOND_DROP);   // 100 behind
    EXPECT_EQ(on_radio(60), MAVBOND_PASS);   // 120 behind, never delivered
    EXPECT_EQ(on_radio(60), MAVBOND_DROP);
    EXPECT_EQ(on_radio(52), MAVBOND_PASS);   // 128 behind, the oldest place
    EXPECT_EQ(on_radio(52), MAVBOND_DROP);
    EXPECT_EQ(on_radio(181), MAVBOND_PASS);
    EXPECT_EQ(on_radio(180), MAVBOND_DROP);
}

TEST_F(LinkSwitchTest, ARestartedCounterIsDeliveredOnceTheHostSeesTheRestart) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    for (int seq = 0; seq < 100; seq++)
        ASSERT_EQ(send("radio", static_cast<uint8_t>(seq)), MAVBOND_PASS);
    // The source restarts at 0 at once: 0 and 1 were delivered moments ago, so they are taken
    // for repeats until the host flags the restart (MAVBOND_STREAM_RESYNC, the third frame).
    EXPECT_EQ(send("radio", 0), MAVBOND_DROP);
    EXPECT_EQ(send("radio", 1), MAVBOND_DROP);
    EXPECT_EQ(send("radio", 2), MAVBOND_PASS);
    for (int seq = 3; seq < 60; seq++)
        ASSERT_EQ(send("radio", static_cast<uint8_t>(seq)), MAVBOND_PASS) << seq;
    // After a silence (a reboot takes seconds) the history is forgotten: nothing is lost.
    host_.advance(seconds(3));
    for (int seq = 0; seq < 60; seq++)
        ASSERT_EQ(send("radio", static_cast<uint8_t>(seq)), MAVBOND_PASS) << seq;
}

TEST_F(LinkSwitchTest, SourcesBeyondTheHistoryPassUncheckedAndCounted) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    // 60 sources, each frame twice: the history holds 48 (3/4 of its 64 places).
    for (int round = 0; round < 2; round++) {
        for (int c = 0; c < 60; c++) {
            mavbond_verdict v = send("radio", 7, 0, 1, static_cast<uint8_t>(c));
            EXPECT_EQ(v, round == 0 || c >= 48 ? MAVBOND_PASS : MAVBOND_DROP) << round << " " << c;
        }
    }
    EXPECT_NE(status().find("\"untracked_frames\":24"), std::string::npos) << status();
    EXPECT_EQ(metrics()["untracked_frames{bond=vehicle}"], 24);
}

// --- 5. priority names ----------------------------------------------------------------------

TEST_F(LinkSwitchTest, ThreeLinksFollowThePriorityList) {
    host_.add_link("a", "vehicle");
    host_.add_link("b", "vehicle");
    host_.add_link("c", "vehicle");
    create("bonds: [vehicle]\npriority: [c, a, b]\nswitch_after: 500ms");
    EXPECT_EQ(active(), "c");
    Sender a{"a"}, b{"b"}, c{"c"};
    run(seconds(1), {&a, &b, &c});
    EXPECT_EQ(send("c", c.seq++), MAVBOND_PASS);
    EXPECT_EQ(send("a", a.seq++), MAVBOND_DROP);
    c.on = false;
    run(seconds(1), {&a, &b});
    EXPECT_EQ(active(), "a");  // the next preferred live link, not just "the other one"
    a.on = false;
    run(seconds(1), {&b});
    EXPECT_EQ(active(), "b");
    EXPECT_TRUE(logged("active link c -> a: c silent for"));
    EXPECT_TRUE(logged("active link a -> b: a silent for"));
}

TEST_F(LinkSwitchTest, DefaultOrderIsBondMemberOrderAndBondsAreIndependent) {
    host_.add_link("a1", "one");
    host_.add_link("b1", "two");
    host_.add_link("a2", "one");
    host_.add_link("b2", "two");
    create("bonds: [one]");
    EXPECT_EQ(active("one"), "a1");
    EXPECT_EQ(active("two"), "");  // out of scope: untouched
    EXPECT_EQ(send("a2", 0), MAVBOND_DROP);
    EXPECT_EQ(send("b2", 0), MAVBOND_PASS);
}

TEST_F(LinkSwitchTest, UnknownPriorityNameIsAnErrorAtTheItem) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    // The document FakeHost writes: endpoints (lines 1-3), bonds (4-5), filters (6-7), then
    // the options from line 8, indented by 4. (Below: 3 endpoints and 2 bonds, 2 lines more.)
    EXPECT_EQ(host_.create(plugin_, "bonds: [vehicle]\npriority: [radio, lte, radoi]"), nullptr);
    std::string line = "    priority: [radio, lte, radoi]";
    EXPECT_EQ(host_.last_error(),
              "test.yaml:9:" + std::to_string(line.find("radoi") + 1) +
                  ": filter 'linkswitch': option 'priority': 'radoi' is not an endpoint of bond "
                  "vehicle (radio, lte)");
}

TEST_F(LinkSwitchTest, AnEndpointOfABondOutOfScopeIsAnError) {
    host_.add_link("a1", "one");
    host_.add_link("b1", "two");
    host_.add_link("a2", "one");
    EXPECT_EQ(host_.create(plugin_, "bonds: [one]\npriority: [b1, a1]"), nullptr);
    std::string line = "    priority: [b1, a1]";
    EXPECT_EQ(host_.last_error(),
              "test.yaml:11:" + std::to_string(line.find("b1") + 1) +
                  ": filter 'linkswitch': option 'priority': 'b1' is not an endpoint of bond one "
                  "(a1, a2)");
}

TEST_F(LinkSwitchTest, PriorityMayNameEndpointsOfEveryBondInScope) {
    host_.add_link("a1", "one");
    host_.add_link("b1", "two");
    host_.add_link("a2", "one");
    host_.add_link("b2", "two");
    create("bonds: [one, two]\npriority: [b2, a2]");
    EXPECT_EQ(active("one"), "a2");
    EXPECT_EQ(active("two"), "b2");
    EXPECT_EQ(send("a1", 0), MAVBOND_DROP);
    EXPECT_EQ(send("b2", 0), MAVBOND_PASS);
}

TEST_F(LinkSwitchTest, OptionErrorsNameFileLineAndColumn) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    EXPECT_EQ(host_.create(plugin_, "switch_after: 1"), nullptr);
    EXPECT_NE(host_.last_error().find("test.yaml:"), std::string::npos) << host_.last_error();
    EXPECT_NE(host_.last_error().find("option 'switch_after' must be a duration"),
              std::string::npos)
        << host_.last_error();
    EXPECT_EQ(host_.create(plugin_, "switch_margin: 5"), nullptr);
    EXPECT_NE(host_.last_error().find("option 'switch_margin' must be a percentage"),
              std::string::npos)
        << host_.last_error();
}

TEST_F(LinkSwitchTest, RepeatedPriorityLinkIsAnError) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    EXPECT_EQ(host_.create(plugin_, "bonds: [vehicle]\npriority: [radio, lte, radio]"), nullptr);
    const std::string& e = host_.last_error();
    EXPECT_NE(e.find("test.yaml:9:"), std::string::npos) << e;
    EXPECT_NE(e.find("option 'priority': 'radio' is listed twice"), std::string::npos) << e;
}

TEST_F(LinkSwitchTest, LearnedPeersRankAsTheirEndpointAndMayAppearLater) {
    // As in the daemon: filters exist before the links; a UDP server's peers are the links,
    // named after their endpoint, and the less preferred one may send first.
    host_.add_link("lte", "vehicle");
    host_.declare_endpoint("radio", "vehicle");  // a UDP server: its peer is the link
    create("priority: [radio, lte]\nswitch_after: 500ms");
    EXPECT_EQ(active(), "lte");
    const mavbond_link& radio = host_.add_link("radio@10.0.0.2:14550", "vehicle");
    plugin_->on_link(self_, &radio, MAVBOND_LINK_ADDED);
    EXPECT_EQ(active(), "radio@10.0.0.2:14550");  // no switch has happened: take the preferred
    Sender r{"radio@10.0.0.2:14550"}, l{"lte"};
    run(seconds(1), {&r, &l});
    EXPECT_EQ(send("lte", l.seq++), MAVBOND_DROP);
    plugin_->on_link(self_, &radio, MAVBOND_LINK_REMOVED);  // the peer timed out
    EXPECT_EQ(active(), "lte");
    EXPECT_TRUE(logged("active link radio@10.0.0.2:14550 -> lte: "
                       "radio@10.0.0.2:14550 was removed"));
    // Once a switch happened, a returning preferred link waits for failback (never, here).
    plugin_->on_link(self_, &radio, MAVBOND_LINK_ADDED);
    run(seconds(3), {&r, &l});
    EXPECT_EQ(active(), "lte");
}

TEST_F(LinkSwitchTest, ZeroSwitchAfterIsAnError) {
    host_.add_link("radio", "vehicle");
    EXPECT_EQ(host_.create(plugin_, "switch_after: 0s"), nullptr);
    EXPECT_NE(host_.last_error().find("option 'switch_after': must be greater than 0"),
              std::string::npos)
        << host_.last_error();
}

// --- 6. what it did, in status_json and metrics ---------------------------------------------

TEST_F(LinkSwitchTest, SwitchesAreCountedByReason) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 3s\nfailback_after: 5s\nhold_down: 1s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(3), {&radio, &lte});
    radio.on = false;
    run_until_active("lte", seconds(2), {&radio, &lte});  // silence
    radio.on = true;
    run_until_active("radio", seconds(8), {&radio, &lte});  // failback
    radio.drop_every = 4;
    run_until_active("lte", seconds(5), {&radio, &lte});  // loss
    radio.drop_every = 0;
    plugin_->on_link(self_, &host_.link("lte"), MAVBOND_LINK_REMOVED);  // removed
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 4u) << testing::PrintToString(host_.logs);
    EXPECT_NE(status().find("\"switches\":4,\"switches_by_reason\":{\"silence\":1,\"loss\":1,"
                            "\"failback\":1,\"removed\":1}"),
              std::string::npos)
        << status();
    auto m = metrics();
    EXPECT_EQ(m["switches{bond=vehicle}"], 4);
    for (const char* reason : {"silence", "loss", "failback", "removed"})
        EXPECT_EQ(m[std::string("switches_by_reason{bond=vehicle,reason=") + reason + "}"], 1)
            << reason;
}

TEST_F(LinkSwitchTest, MetricsShowWhatStatusShows) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("loss_window: 2s");
    Path radio{"radio", 0, [](int64_t k) { return k % 4 == 3; }}, lte{"lte", 10};
    fan_out(400, {&radio, &lte});
    ASSERT_EQ(active(), "lte");
    auto m = metrics();
    for (const char* link : {"radio", "lte"}) {
        std::string labels = std::string("{bond=vehicle,link=") + link + "}";
        EXPECT_EQ(m["already_delivered_frames" + labels], link_field(link, "already_delivered"))
            << link;
        EXPECT_EQ(m["passed_frames" + labels], link_field(link, "passed")) << link;
        EXPECT_EQ(m["dropped_frames" + labels], link_field(link, "dropped")) << link;
        EXPECT_NEAR(m["loss_ratio" + labels] * 100, loss_pct(link), 1e-9) << link;
    }
    EXPECT_GT(m["already_delivered_frames{bond=vehicle,link=lte}"], 0);
    EXPECT_EQ(m["active{bond=vehicle,link=lte}"], 1);
    EXPECT_EQ(m["active{bond=vehicle,link=radio}"], 0);
    EXPECT_EQ(m["switches_by_reason{bond=vehicle,reason=loss}"], 1);
}

}  // namespace
}  // namespace mavbond
