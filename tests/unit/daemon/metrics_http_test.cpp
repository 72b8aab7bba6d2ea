// The metrics endpoint's HTTP request classifier.
#include <gtest/gtest.h>

#include "daemon/metrics_http.h"

namespace mavbond {
namespace {

int classify(const std::string& head, bool* head_only = nullptr) {
    bool h = false;
    int status = classify_http_request(head, h);
    if (head_only)
        *head_only = h;
    return status;
}

TEST(MetricsHttpRequest, GetAndHeadOfMetrics) {
    bool head = true;
    EXPECT_EQ(200, classify("GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n", &head));
    EXPECT_FALSE(head);
    EXPECT_EQ(200, classify("HEAD /metrics HTTP/1.1\r\nHost: x\r\n\r\n", &head));
    EXPECT_TRUE(head);
    EXPECT_EQ(200, classify("GET /metrics?name[]=x HTTP/1.1\r\nHost: x\r\nAccept: */*\r\n\r\n"));
    EXPECT_EQ(200, classify("GET /metrics HTTP/1.0\r\n\r\n"));  // 1.0 needs no Host
    EXPECT_EQ(200, classify("GET /metrics HTTP/1.1\nHost: x\n\n"));  // bare LF ends lines too
}

TEST(MetricsHttpRequest, OtherPathsAndMethods) {
    EXPECT_EQ(404, classify("GET / HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(404, classify("GET /metricsx HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(404, classify("GET /metrics/ HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(405, classify("POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n"));
    EXPECT_EQ(405, classify("DELETE /metrics HTTP/1.1\r\nHost: x\r\n\r\n"));
}

TEST(MetricsHttpRequest, MalformedIs400) {
    EXPECT_EQ(400, classify("\r\n\r\n"));
    EXPECT_EQ(400, classify("HELLO\r\n\r\n"));
    EXPECT_EQ(400, classify("GET /metrics\r\n\r\n"));
    EXPECT_EQ(400, classify("GET  /metrics HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(400, classify("GET /metrics HTTP/1.1 extra\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(400, classify("GET /metrics HTTP/2.0\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(400, classify("GET metrics HTTP/1.1\r\nHost: x\r\n\r\n"));
    EXPECT_EQ(400, classify("G(T /metrics HTTP/1.1\r\nHost: x\r\n\r\n"));
    const char nul[] = "GET /met\0rics HTTP/1.1\r\nHost: x\r\n\r\n";
    EXPECT_EQ(400, classify(std::string(nul, sizeof nul - 1)));
    EXPECT_EQ(400, classify("GET /metrics HTTP/1.1\r\n\r\n"));  // 1.1 without Host
    EXPECT_EQ(400, classify("GET /metrics HTTP/1.1\r\nHost: x\r\nno colon here\r\n\r\n"));
    EXPECT_EQ(400, classify("GET /metrics HTTP/1.1\r\nHost: x\r\nBad Name: y\r\n\r\n"));
}

}  // namespace
}  // namespace mavbond
