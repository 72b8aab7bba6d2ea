// Metric sets in the Prometheus text format: escaping, numbers, families, what is refused.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "core/metric_set.h"

namespace mavbond {
namespace {

TEST(PrometheusText, CountersAreExactIntegersNamedTotal) {
    MetricSet set;
    ASSERT_TRUE(set.counter("frames", "Frames.", UINT64_MAX, {{"link", "a"}}));
    ASSERT_TRUE(set.counter("frames", "Frames.", (uint64_t{1} << 53) + 1, {{"link", "b"}}));
    EXPECT_EQ("# HELP frames_total Frames.\n"
              "# TYPE frames_total counter\n"
              "frames_total{link=\"a\"} 18446744073709551615\n"
              "frames_total{link=\"b\"} 9007199254740993\n",
              set.text());
}

TEST(PrometheusText, GaugesAreShortestRoundTripWithNanAndInfinities) {
    EXPECT_EQ("0", format_gauge(0.0));
    EXPECT_EQ("1", format_gauge(1.0));
    EXPECT_EQ("0.1", format_gauge(0.1));
    EXPECT_EQ("-2.5", format_gauge(-2.5));
    EXPECT_EQ("1e+100", format_gauge(1e100));
    EXPECT_EQ("123456789", format_gauge(123456789.0));
    EXPECT_EQ("NaN", format_gauge(std::numeric_limits<double>::quiet_NaN()));
    EXPECT_EQ("+Inf", format_gauge(std::numeric_limits<double>::infinity()));
    EXPECT_EQ("-Inf", format_gauge(-std::numeric_limits<double>::infinity()));
    // Every finite value reads back as itself.
    for (double v : {1.0 / 3, 2.0 / 3 * 1e-300, 6.02214076e23, 0.05, 1 - 1e-16}) {
        EXPECT_EQ(v, std::strtod(format_gauge(v).c_str(), nullptr)) << format_gauge(v);
    }
}

TEST(PrometheusText, LabelValuesEscapeBackslashQuoteAndNewline) {
    EXPECT_EQ(R"(a\\b\"c\nd)", escape_label_value("a\\b\"c\nd"));
    EXPECT_EQ("tab\tand unicode \xc3\xa9", escape_label_value("tab\tand unicode \xc3\xa9"));
    MetricSet set;
    ASSERT_TRUE(set.gauge("g", "G.", 1, {{"link", "gcs@127.0.0.1:5555"}, {"x", "\"q\"\n"}}));
    EXPECT_NE(std::string::npos, set.text().find("g{link=\"gcs@127.0.0.1:5555\",x=\"\\\"q\\\"\\n\"} 1\n"))
        << set.text();
}

TEST(PrometheusText, HelpEscapesBackslashAndNewlineOnly) {
    EXPECT_EQ(R"(one\ntwo \\ "three")", escape_help("one\ntwo \\ \"three\""));
    MetricSet set;
    ASSERT_TRUE(set.gauge("g", "line\nbreak", 2));
    EXPECT_EQ("# HELP g line\\nbreak\n# TYPE g gauge\ng 2\n", set.text());
}

TEST(PrometheusText, SamplesAreGroupedByFamilyInFirstSeenOrder) {
    MetricSet set;
    ASSERT_TRUE(set.counter("a", "A.", 1, {{"l", "1"}}));
    ASSERT_TRUE(set.gauge("b", "B.", 2));
    ASSERT_TRUE(set.counter("a", "A.", 3, {{"l", "2"}}));
    EXPECT_EQ("# HELP a_total A.\n# TYPE a_total counter\na_total{l=\"1\"} 1\na_total{l=\"2\"} 3\n"
              "# HELP b B.\n# TYPE b gauge\nb 2\n",
              set.text());
}

TEST(PrometheusText, DeclaredFamilyWithoutSamplesKeepsItsHeader) {
    MetricSet set;
    ASSERT_TRUE(set.declare("none", "Nothing yet.", MetricSet::Type::Counter));
    EXPECT_EQ("# HELP none_total Nothing yet.\n# TYPE none_total counter\n", set.text());
}

TEST(PrometheusText, RefusesWhatWouldMakeAnInvalidDocument) {
    MetricSet set;
    ASSERT_TRUE(set.gauge("ok", "Fine.", 1, {{"l", "x"}}));
    EXPECT_FALSE(set.gauge("ok", "Fine.", 2, {{"l", "x"}}));       // the same series twice
    EXPECT_FALSE(set.gauge("ok", "Other help.", 2, {{"l", "z"}}));  // help disagrees
    EXPECT_FALSE(set.gauge("9lives", "Bad name.", 1));
    EXPECT_FALSE(set.gauge("sp ace", "Bad name.", 1));
    EXPECT_FALSE(set.gauge("g", "Bad label.", 1, {{"__reserved", "x"}}));
    EXPECT_FALSE(set.gauge("g", "Bad label.", 1, {{"a-b", "x"}}));
    EXPECT_FALSE(set.gauge("g", "Twice.", 1, {{"a", "x"}, {"a", "y"}}));
    std::string text = set.text();
    EXPECT_EQ(std::string::npos, text.find("9lives"));
    EXPECT_EQ(std::string::npos, text.find("Other help"));
    EXPECT_NE(std::string::npos, text.find("ok{l=\"x\"} 1\n"));
    EXPECT_EQ(std::string::npos, text.find("ok{l=\"x\"} 2"));
}

TEST(PrometheusText, NameRules) {
    EXPECT_TRUE(valid_metric_name("mavbond_stats_link_frames"));
    EXPECT_TRUE(valid_metric_name("a:b_c"));
    EXPECT_FALSE(valid_metric_name(""));
    EXPECT_FALSE(valid_metric_name("1a"));
    EXPECT_FALSE(valid_metric_name("a-b"));
    EXPECT_TRUE(valid_label_name("link"));
    EXPECT_TRUE(valid_label_name("_x1"));
    EXPECT_FALSE(valid_label_name("a:b"));
    EXPECT_FALSE(valid_label_name("__name__"));
    EXPECT_FALSE(valid_label_name("1a"));
}

}  // namespace
}  // namespace mavbond
