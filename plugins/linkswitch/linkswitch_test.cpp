// linkswitch against FakeHost: a manual clock drives the silence timer, frames are built with
// chosen sequence numbers so loss is exact, and the host's active-link map shows each switch.
#include <gtest/gtest.h>

#include <cstdlib>
#include <regex>
#include <string>
#include <vector>

#include "fake_host.h"
#include "mavbond/plugin.h"

extern "C" const mavbond_plugin_descriptor* mavbond_plugin_entry(void);

namespace mavbond {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

/// A minimal MAVLink v2 frame (header, empty HEARTBEAT-sized payload, dummy CRC): the plugin
/// reads the fields from mavbond_frame, the bytes only have to exist.
std::vector<uint8_t> raw_frame(uint8_t seq, uint8_t sysid, uint8_t compid, uint32_t msgid) {
    std::vector<uint8_t> raw = {0xFD,   9,      0,
                                0,      seq,    sysid,
                                compid, static_cast<uint8_t>(msgid),
                                static_cast<uint8_t>(msgid >> 8),
                                static_cast<uint8_t>(msgid >> 16)};
    raw.resize(raw.size() + 9 + 2, 0);
    return raw;
}

/// One source sending on one link: seq counts up every frame; every `drop_every`th frame is
/// lost in the air (its seq is used but nothing arrives).
struct Sender {
    std::string link;
    int drop_every = 0;
    bool on = true;
    uint8_t seq = 0;
    uint64_t sent = 0;
};

class LinkSwitchTest : public testing::Test {
protected:
    const mavbond_plugin_descriptor* plugin_ = mavbond_plugin_entry();
    FakeHost host_;
    void* self_ = nullptr;

    void create(const std::string& options) {
        self_ = host_.create(plugin_, options);
        ASSERT_NE(self_, nullptr) << host_.last_error();
    }

    mavbond_verdict send(const std::string& link, uint8_t seq, uint32_t note_flags = 0) {
        auto raw = raw_frame(seq, 1, 1, 0);
        mavbond_frame f = host_.frame(raw);
        f.version = 2;
        f.seq = seq;
        f.sysid = 1;
        f.compid = 1;
        f.crc_checked = 1;
        mavbond_frame_notes notes{};
        notes.struct_size = sizeof notes;
        notes.flags = note_flags;
        return plugin_->on_ingress(self_, &f, &notes, &host_.link(link));
    }

    /// 50 frames/s from each sender that is on, for `total`.
    void run(Duration total, std::vector<Sender*> senders) {
        for (Duration t{}; t < total; t += milliseconds(20)) {
            for (Sender* s : senders) {
                if (!s->on)
                    continue;
                s->sent++;
                uint8_t seq = s->seq++;
                if (s->drop_every && s->sent % s->drop_every == 0)
                    continue;
                send(s->link, seq);
            }
            host_.advance(milliseconds(20));
        }
    }

    std::string active(const std::string& bond = "vehicle") {
        uint32_t id = 0;
        EXPECT_EQ(host_.bond_by_name(bond, &id), 0);
        auto it = host_.active_link.find(id);
        if (it == host_.active_link.end())
            return "";
        const mavbond_link* links[16];
        size_t n = host_.links(links, 16);
        return it->second < n ? links[it->second]->name : "?";
    }

    uint64_t switches(const std::string& bond = "vehicle") {
        uint32_t id = 0;
        EXPECT_EQ(host_.bond_by_name(bond, &id), 0);
        return host_.switches[id];
    }

    std::string status() {
        char buf[4096];
        size_t n = plugin_->status_json(self_, buf, sizeof buf);
        EXPECT_LT(n, sizeof buf);
        return std::string(buf, n);
    }

    /// The loss_pct status_json shows for a link (-1 when absent or null).
    double loss_pct(const std::string& link) {
        std::string s = status();
        size_t at = s.find("\"name\":\"" + link + "\",\"heard\"");
        if (at == std::string::npos)
            return -1;
        at = s.find("\"loss_pct\":", at);
        if (at == std::string::npos || s.compare(at + 11, 4, "null") == 0)
            return -1;
        return std::strtod(s.c_str() + at + 11, nullptr);
    }

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
};

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
    EXPECT_NE(s.find("\"passed\":1,\"dropped\":0"), std::string::npos) << s;
    EXPECT_NE(s.find("\"passed\":0,\"dropped\":2"), std::string::npos) << s;
    EXPECT_EQ(s.find("gcs"), std::string::npos) << s;
}

TEST_F(LinkSwitchTest, SilenceSwitchesWithinSwitchAfterPlusOneTick) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("switch_after: 1s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(2), {&radio, &lte});
    ASSERT_EQ(active(), "radio");
    radio.on = false;
    uint64_t last_radio = host_.now_ns() - 20'000'000;  // run() advanced after the last frame
    while (active() == "radio" && host_.now_ns() - last_radio < 3'000'000'000ull)
        run(milliseconds(20), {&lte});
    ASSERT_EQ(active(), "lte");
    uint64_t took = host_.now_ns() - last_radio;
    EXPECT_GE(took, 1'000'000'000ull);
    EXPECT_LE(took, 1'100'000'000ull);
    EXPECT_TRUE(logged("active link radio -> lte: radio silent for 1.0")) << host_.logs.back();
    EXPECT_EQ(send("lte", lte.seq++), MAVBOND_PASS);
    EXPECT_EQ(switches(), 2u);  // the initial choice and the switch
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

TEST_F(LinkSwitchTest, LossAboveMaxSwitchesToABetterBackup) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("max_loss: 5%\nloss_window: 5s");
    Sender radio{"radio", 10}, lte{"lte"};  // radio loses 10%
    run(seconds(3), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
    // The switch comes as soon as the window holds enough frames to judge, so the figure is
    // near, not exactly, the 10% sent.
    EXPECT_TRUE(logged_like(R"(^active link radio -> lte: loss [0-9]+\.[0-9]% over 5s > 5%$)"))
        << testing::PrintToString(host_.logs);
    EXPECT_EQ(switch_lines(), 1u);
}

TEST_F(LinkSwitchTest, NoLossSwitchWhenTheBackupIsWorse) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("max_loss: 5%");
    Sender radio{"radio", 10}, lte{"lte", 4};  // 10% against 25%
    run(seconds(10), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 0u);
    EXPECT_NEAR(loss_pct("radio"), 10.0, 0.5) << status();
    EXPECT_NEAR(loss_pct("lte"), 25.0, 0.5) << status();
}

TEST_F(LinkSwitchTest, ReorderingIsNotLoss) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("max_loss: 5%");
    Sender lte{"lte"};
    // Radio delivers every pair swapped: 1,0,3,2,... — nothing is lost.
    for (int i = 0; i < 200; i++) {
        send("radio", static_cast<uint8_t>(i ^ 1));
        if (i % 2)
            run(milliseconds(40), {&lte});
    }
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(loss_pct("radio"), 0.0) << status();
}

TEST_F(LinkSwitchTest, HoldDownPreventsFlapping) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("max_loss: 5%\nloss_window: 2s\nhold_down: 10s");
    Sender radio{"radio", 10}, lte{"lte"};
    run(seconds(2), {&radio, &lte});
    ASSERT_EQ(active(), "lte");
    // Now the roles swap: lte gets bad, radio clean. Within hold_down nothing moves.
    radio.drop_every = 0;
    lte.drop_every = 5;
    run(seconds(7), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
    EXPECT_EQ(switch_lines(), 1u);
    run(seconds(3), {&radio, &lte});  // hold_down (10s after the switch) has passed
    EXPECT_EQ(active(), "radio");
    EXPECT_EQ(switch_lines(), 2u);
    EXPECT_TRUE(logged_like(R"(^active link lte -> radio: loss (19|20)\.[0-9]% over 2s > 5%$)"))
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

TEST_F(LinkSwitchTest, FailbackAfterTheMostPreferredLinkIsHealthyLongEnough) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("failback_after: 3s\nhold_down: 1s");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    ASSERT_EQ(active(), "lte");
    radio.on = true;
    radio.seq += 100;  // the frames sent into the outage: not charged as loss on return
    run(milliseconds(2900), {&radio, &lte});
    EXPECT_EQ(active(), "lte");  // healthy, but not yet for 3s
    run(milliseconds(300), {&radio, &lte});
    EXPECT_EQ(active(), "radio");
    EXPECT_TRUE(logged("active link lte -> radio: failback to radio after 3s healthy"));
}

TEST_F(LinkSwitchTest, NoFailbackByDefault) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    create("");
    Sender radio{"radio"}, lte{"lte"};
    run(seconds(1), {&radio, &lte});
    radio.on = false;
    run(seconds(2), {&lte});
    radio.on = true;
    run(seconds(60), {&radio, &lte});
    EXPECT_EQ(active(), "lte");
}

TEST_F(LinkSwitchTest, ThreeLinksFollowThePriorityList) {
    host_.add_link("a", "vehicle");
    host_.add_link("b", "vehicle");
    host_.add_link("c", "vehicle");
    create("priority: [c, a, b]\nswitch_after: 500ms");
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

TEST_F(LinkSwitchTest, OptionErrorsNameFileLineAndColumn) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    EXPECT_EQ(host_.create(plugin_, "switch_after: 1"), nullptr);
    EXPECT_NE(host_.last_error().find("test.yaml:"), std::string::npos) << host_.last_error();
    EXPECT_NE(host_.last_error().find("option 'switch_after' must be a duration"),
              std::string::npos)
        << host_.last_error();
}

TEST_F(LinkSwitchTest, RepeatedPriorityLinkIsAnError) {
    host_.add_link("radio", "vehicle");
    host_.add_link("lte", "vehicle");
    EXPECT_EQ(host_.create(plugin_, "priority: [radio, lte, radio]"), nullptr);
    const std::string& e = host_.last_error();
    EXPECT_NE(e.find("test.yaml:"), std::string::npos) << e;
    EXPECT_NE(e.find("option 'priority': 'radio' is listed twice"), std::string::npos) << e;
}

TEST_F(LinkSwitchTest, LearnedPeersRankAsTheirEndpointAndMayAppearLater) {
    // As in the daemon: filters exist before the links; a UDP server's peers are the links,
    // named after their endpoint, and the less preferred one may send first.
    host_.add_link("lte", "vehicle");
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

}  // namespace
}  // namespace mavbond
