// The mavlink-router importer, in-process: each sample main.conf gives its expected YAML, and
// that YAML loads by the endpoint types' tables (what an imported key means is theirs to say).
// A unit test, so that every build runs it: the armhf one found a 32-bit bug here (a baud
// range limit that did not fit a 32-bit long).
#include "daemon/import_mavlink_router.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

#include "config/config.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {
namespace {

std::string read(const std::string& path) {
    std::ifstream in(path);
    EXPECT_TRUE(in) << path;
    std::stringstream text;
    text << in.rdbuf();
    return text.str();
}

class ImportSample : public ::testing::TestWithParam<const char*> {};

TEST_P(ImportSample, GivesItsYamlWhichLoads) {
    const char* root = std::getenv("MAVBOND_SOURCE_ROOT");
    ASSERT_NE(nullptr, root) << "MAVBOND_SOURCE_ROOT is not set (run via meson test)";
    const std::string base = std::string(root) + "/tests/integration/data/mavlink-router/" + GetParam();
    auto imported = import_mavlink_router(read(base + ".conf"), std::string(GetParam()) + ".conf");
    ASSERT_TRUE(imported.has_value()) << imported.error().message;
    EXPECT_EQ(read(base + ".yaml"), imported->yaml);
    auto config = parse_config(imported->yaml, std::string(GetParam()) + ".yaml", endpoint_schemas());
    EXPECT_TRUE(config.has_value()) << config.error().message;
}

INSTANTIATE_TEST_SUITE_P(Samples, ImportSample, ::testing::Values("companion", "redundant", "sample"));

TEST(Import, BaudRatesUpToTheLargestAUartTakes) {
    auto imported = import_mavlink_router("[UartEndpoint fc]\nDevice = /dev/ttyS0\nBaud = 4000000\n",
                                          "fc.conf");
    ASSERT_TRUE(imported.has_value()) << imported.error().message;
    EXPECT_NE(std::string::npos, imported->yaml.find("baud: 4000000")) << imported->yaml;
    auto too_big = import_mavlink_router(
        "[UartEndpoint fc]\nDevice = /dev/ttyS0\nBaud = 4294967296\n", "fc.conf");
    ASSERT_FALSE(too_big.has_value());
    EXPECT_EQ("fc.conf:3: Baud: '4294967296' is not an integer in 1..4294967295",
              too_big.error().message);
}

}  // namespace
}  // namespace mavbond
