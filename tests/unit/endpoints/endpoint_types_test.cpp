// The endpoint types' tables are the one place their options are declared: the loader reads
// endpoints by them, and the manual's list is made from them.
#include "endpoints/endpoint_types.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

namespace mavbond {
namespace {

TEST(EndpointTypes, EachTypeAndModeOnceWithAnOpener) {
    std::set<std::string> seen;
    for (const EndpointType& t : endpoint_types()) {
        EXPECT_TRUE(seen.insert(t.schema.title()).second) << t.schema.title();
        EXPECT_NE(nullptr, t.open) << t.schema.title();
        for (const EndpointOption& o : t.schema.options) {
            EXPECT_NE(nullptr, o.help) << o.key;
            EXPECT_FALSE(o.required && o.default_value) << o.key << ": required with a default";
        }
    }
    EXPECT_EQ(endpoint_types().size(), endpoint_schemas().size());
}

TEST(EndpointTypes, DefaultsReadAsTheirKindSays) {
    // Every type's defaults, loaded as if written: a table with a bad default cannot start.
    std::string yaml = "endpoints:\n";
    int n = 0;
    for (const EndpointType& t : endpoint_types()) {
        yaml += "  - {name: e" + std::to_string(n++) + ", type: " + t.schema.type;
        if (t.schema.mode)
            yaml += std::string(", mode: ") + t.schema.mode;
        for (const EndpointOption& o : t.schema.options) {
            if (o.required)
                yaml += std::string(", ") + o.key + ": " +
                        (o.kind == OptionKind::Address ? "127.0.0.1:9" : "/tmp");
        }
        yaml += "}\n";
    }
    auto config = parse_config(yaml, "t.yaml", endpoint_schemas());
    ASSERT_TRUE(config.has_value()) << config.error().message << "\n" << yaml;
    for (const EndpointConfig& ep : config->endpoints) {
        for (const EndpointOption& o : ep.schema->options)
            EXPECT_EQ(o.default_value != nullptr || o.required, ep.options.has(o.key)) << o.key;
    }
}

TEST(EndpointTypes, TheManualListsEveryTypesOptionsAsTheTablesSay) {
    const char* root = std::getenv("MAVBOND_SOURCE_ROOT");
    ASSERT_NE(nullptr, root) << "MAVBOND_SOURCE_ROOT is not set (run via meson test)";
    const std::string path = std::string(root) + "/conf/man/mavbond.yaml.5.in";
    std::ifstream in(path);
    ASSERT_TRUE(in) << path;
    std::stringstream text;
    text << in.rdbuf();
    const std::string page = text.str();
    const std::string begin = ".\\\" BEGIN endpoint types", end = ".\\\" END endpoint types";
    size_t b = page.find(begin), e = page.find(end);
    ASSERT_NE(std::string::npos, b) << path << ": no '" << begin << "' line";
    ASSERT_NE(std::string::npos, e) << path << ": no '" << end << "' line";
    b = page.find('\n', b) + 1;
    const std::string expected = endpoint_options_manual(endpoint_schemas());
    EXPECT_EQ(expected, page.substr(b, e - b))
        << path << ": the lines between the BEGIN and END markers must be, from the tables:\n"
        << expected;
}

}  // namespace
}  // namespace mavbond
