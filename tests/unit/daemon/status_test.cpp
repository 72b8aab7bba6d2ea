// The status model's renderers: one Status, four views that agree.
#include "daemon/status.h"

#include <gtest/gtest.h>

#include <regex>

namespace mavbond {
namespace {

Status sample() {
    Status s;
    s.taken = TimePoint(seconds(100));
    s.uptime = seconds(42);
    s.status_refused = 1;
    Status::Endpoint radio{"radio", "udp-server", "vehicle", false, {}};
    radio.counters.rx.frames = 7;
    radio.counters.tx_dropped = 2;
    radio.counters.last_rx = TimePoint(seconds(99));
    radio.state = "standby";
    radio.peer_standby = true;
    Status::Endpoint gcs{"gcs", "udp-client", "", true, {}};
    gcs.open_error = "cannot connect: \"gcs\" said no";
    gcs.state = "closed";
    s.endpoints = {radio, gcs};
    Status::Bond bond;
    bond.name = "vehicle";
    bond.tx_active = true;
    bond.active = "radio@127.0.0.1:9";
    bond.switches = 3;
    bond.links = {{"radio", true}, {"lte", false}};
    bond.renumber = {{"renumbered", 5}, {"gaps", 1}};
    s.bonds = {bond};
    s.frames_routed = 11;
    FilterReport f;
    f.name = "dedup";
    f.plugin = "dedup";
    f.dropped = 4;
    f.status_json = "{\"window_ms\":1000.0}";
    f.samples = {{MetricSet::Type::Counter, kFilterDroppedMetric, kFilterDroppedHelp,
                  {{"filter", "dedup"}, {"plugin", "dedup"}}, 4, 0}};
    s.filters = {f};
    return s;
}

TEST(Status, JsonCarriesEveryPart) {
    std::string j = status_json(sample());
    EXPECT_EQ(0u, j.find("{\"version\":\"")) << j;
    EXPECT_NE(std::string::npos, j.find("\"uptime_s\":42,\"status_refused\":1,")) << j;
    EXPECT_NE(std::string::npos,
              j.find("{\"name\":\"radio\",\"kind\":\"udp-server\",\"bond\":\"vehicle\","
                     "\"state\":\"standby\",\"open\":true,\"standby\":false,\"peer_standby\":true,"
                     "\"rx_frames\":7,"))
        << j;
    EXPECT_NE(std::string::npos,
              j.find("\"state\":\"closed\",\"open\":false,\"open_error\":\"cannot connect: "
                     "\\\"gcs\\\" said no\",\"standby\":false,"))
        << j;
    EXPECT_NE(std::string::npos, j.find("\"tx_dropped\":2,")) << j;
    EXPECT_NE(std::string::npos, j.find("\"last_rx_ms_ago\":1000}")) << j;
    EXPECT_NE(std::string::npos, j.find("\"last_rx_ms_ago\":-1}")) << j;  // gcs: never heard
    EXPECT_NE(std::string::npos,
              j.find("{\"name\":\"vehicle\",\"tx\":\"active\",\"active\":\"radio@127.0.0.1:9\","
                     "\"switches\":3,\"numbering\":{\"numbered\":0,\"expired\":0,\"untracked\":0,\"superseded\":0},"
                     "\"renumber\":{\"renumbered\":5,\"gaps\":1}}"))
        << j;
    EXPECT_NE(std::string::npos,
              j.find("\"filters\":[{\"name\":\"dedup\",\"plugin\":\"dedup\",\"dropped\":4,"
                     "\"status\":{\"window_ms\":1000.0}}]}"))
        << j;
}

TEST(Status, MetricsCarryTheSameFigures) {
    std::string m = status_metrics(sample()).text();
    EXPECT_NE(std::string::npos,
              m.find("mavbond_endpoint_rx_frames_total{endpoint=\"radio\",kind=\"udp-server\","
                     "bond=\"vehicle\"} 7\n"))
        << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_endpoint_last_rx_age_seconds{endpoint=\"radio\",kind=\"udp-server\","
                     "bond=\"vehicle\"} 1\n"))
        << m;
    EXPECT_NE(std::string::npos, m.find("mavbond_bond_switches_total{bond=\"vehicle\"} 3\n")) << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_bond_active_link{bond=\"vehicle\",link=\"radio\"} 1\n"))
        << m;
    EXPECT_NE(std::string::npos, m.find("mavbond_bond_active_link{bond=\"vehicle\",link=\"lte\"} 0\n"))
        << m;
    EXPECT_NE(std::string::npos, m.find("mavbond_renumber_gaps_total{bond=\"vehicle\"} 1\n")) << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_filter_dropped_total{filter=\"dedup\",plugin=\"dedup\"} 4\n"))
        << m;
    EXPECT_NE(std::string::npos, m.find("mavbond_router_frames_routed_total 11\n")) << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_endpoint_open{endpoint=\"gcs\",kind=\"udp-client\",bond=\"\"} 0\n"))
        << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_endpoint_state{endpoint=\"radio\",kind=\"udp-server\",bond=\"vehicle\","
                     "state=\"standby\"} 1\n"))
        << m;
    EXPECT_NE(std::string::npos,
              m.find("mavbond_endpoint_state{endpoint=\"radio\",kind=\"udp-server\",bond=\"vehicle\","
                     "state=\"up\"} 0\n"))
        << m;
}

TEST(Status, CountersLineAndProblemReport) {
    Status s = sample();
    EXPECT_EQ(0u, counters_line(s.endpoints[0]).find("stats endpoint=radio kind=udp-server rx_frames=7 "))
        << counters_line(s.endpoints[0]);
    ProblemReport report;
    testing::internal::CaptureStderr();
    report.run(s, seconds(10));  // the first report counts from zero: 2 dropped
    s.endpoints[0].counters.tx_dropped = 5;
    report.run(s, seconds(10));  // then the difference: 3
    report.run(s, seconds(10));  // nothing new: no line
    std::string err = testing::internal::GetCapturedStderr();
    // Each line stamped with the time (not the journal's stream here): the time left out.
    const std::string stamp = R"(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d{3} )";
    EXPECT_TRUE(std::regex_match(
        err, std::regex(stamp + R"(mavbond: notice: \[radio\] 2 frames dropped on transmit in the last 10s\n)" +
                        stamp + R"(mavbond: notice: \[radio\] 3 frames dropped on transmit in the last 10s\n)")))
        << err;
}

}  // namespace
}  // namespace mavbond
