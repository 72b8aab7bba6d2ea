#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "config/config.h"
#include "core/event_loop.h"
#include "routing/filter_chain.h"
#include "routing/plugin_loader.h"
#include "routing/router.h"
#include "endpoints/endpoint_types.h"

namespace mavbond {
namespace {

const std::string kDir = MAVBOND_ABI_PLUGIN_DIR;

std::string load_error(const std::string& name, const std::string& dir = kDir) {
    auto p = LoadedPlugin::load(dir, name);
    EXPECT_FALSE(p.has_value()) << name << " loaded";
    return p ? "" : p.error().message;
}

TEST(PluginLoader, LoadsAGoodPlugin) {
    auto p = LoadedPlugin::load(kDir, "good_plugin");
    ASSERT_TRUE(p.has_value()) << p.error().message;
    EXPECT_STREQ("good_plugin", p.value()->descriptor().name);
    EXPECT_EQ(kDir + "/good_plugin.so", p.value()->path());
}

TEST(PluginLoader, RefusesAMissingFileNamingIt) {
    std::string e = load_error("no_such_plugin");
    EXPECT_NE(std::string::npos, e.find(kDir + "/no_such_plugin.so")) << e;
    EXPECT_NE(std::string::npos, e.find("No such file")) << e;
}

TEST(PluginLoader, RefusesAnotherAbiVersion) {
    std::string e = load_error("abi_version");
    EXPECT_NE(std::string::npos, e.find("abi_version.so")) << e;
    EXPECT_NE(std::string::npos, e.find("ABI version " + std::to_string(MAVBOND_PLUGIN_ABI_VERSION + 41))) << e;
}

TEST(PluginLoader, RefusesATooSmallDescriptor) {
    EXPECT_NE(std::string::npos, load_error("small_struct").find("descriptor of 16 bytes"));
}

TEST(PluginLoader, RefusesANameMismatch) {
    EXPECT_NE(std::string::npos, load_error("wrong_name").find("calls itself 'somebody_else'"));
}

TEST(PluginLoader, RefusesAMissingEntrySymbol) {
    EXPECT_NE(std::string::npos, load_error("no_entry").find("no entry symbol mavbond_plugin_entry"));
}

TEST(PluginLoader, RefusesMissingCreate) {
    EXPECT_NE(std::string::npos, load_error("no_create").find("lacks create or destroy"));
}

TEST(PluginLoader, RefusesAFileOthersMayWrite) {
    auto dir = std::filesystem::temp_directory_path() / ("mavbond-abi-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    std::filesystem::copy_file(kDir + "/good_plugin.so", dir / "good_plugin.so",
                               std::filesystem::copy_options::overwrite_existing);
    chmod((dir / "good_plugin.so").c_str(), 0666);
    std::string e = load_error("good_plugin", dir.string());
    EXPECT_NE(std::string::npos, e.find("others than its owner may write (mode 666)")) << e;
    chmod((dir / "good_plugin.so").c_str(), 0644);
    EXPECT_TRUE(LoadedPlugin::load(dir.string(), "good_plugin").has_value());
    std::filesystem::remove_all(dir);
}

TEST(PluginLoader, RefusesADirectoryOthersMayWrite) {
    auto dir = std::filesystem::temp_directory_path() / ("mavbond-abi-dir-" + std::to_string(getpid()));
    std::filesystem::create_directories(dir);
    std::filesystem::copy_file(kDir + "/good_plugin.so", dir / "good_plugin.so",
                               std::filesystem::copy_options::overwrite_existing);
    chmod((dir / "good_plugin.so").c_str(), 0644);
    for (mode_t mode : {0777, 0775, 0757, 01777}) {
        chmod(dir.c_str(), mode);
        std::string e = load_error("good_plugin", dir.string());
        char want[80];
        snprintf(want, sizeof want, "that others than its owner may write (mode %04o)", mode);
        EXPECT_NE(std::string::npos, e.find(want)) << e;
        EXPECT_NE(std::string::npos, e.find("plugin_dir " + dir.string())) << e;
    }
    chmod(dir.c_str(), 0755);
    EXPECT_TRUE(LoadedPlugin::load(dir.string(), "good_plugin").has_value());
    std::filesystem::remove_all(dir);
}

TEST(PluginLoader, RefusesNamesThatLeaveTheDirectory) {
    // good_plugin.so one level up, reachable as "../abi/good_plugin" if names were paths.
    for (const char* name : {"../abi/good_plugin", "/tmp/good_plugin", "good_plugin/", "..",
                             "good.plugin", "Good_plugin", "good-plugin", ""}) {
        std::string e = load_error(name);
        EXPECT_NE(std::string::npos, e.find("invalid plugin name")) << name << ": " << e;
    }
}

TEST(PluginConfig, NamesOutsideAToZDigitsUnderscoreAreConfigErrors) {
    for (const char* name : {"../evil", "/usr/lib/evil", "a/b", "..", "dedup.so", "De-dup", "x y"}) {
        auto cfg = parse_config(std::string("endpoints:\n"
                                            "  - {name: a, type: udp, mode: server, address: 127.0.0.1:9}\n"
                                            "filters:\n  - plugin: \"") + name + "\"\n", "t.yaml", endpoint_schemas());
        ASSERT_FALSE(cfg.has_value()) << name;
        EXPECT_EQ(0u, cfg.error().message.find("t.yaml:4:13: filter #1: invalid plugin name '" +
                                              std::string(name) + "'"))
            << cfg.error().message;
    }
}

/// The chain builds from a real config: its errors carry the filter's file:line:column.
class ChainTest : public ::testing::Test {
protected:
    Result<std::unique_ptr<FilterChain>> build(const std::string& filters,
                                               const std::string& bonds = "") {
        auto cfg = parse_config("endpoints:\n"
                                "  - {name: a, type: udp, mode: server, address: 127.0.0.1:9" +
                                    std::string(bonds.empty() ? "" : ", bond: b") + "}\n" + bonds +
                                    "filters:\n" + filters,
                                "t.yaml", endpoint_schemas());
        EXPECT_TRUE(cfg.has_value()) << cfg.error().message;
        config_ = std::make_unique<Config>(std::move(cfg.value()));
        router_ = std::make_unique<Router>(*loop_, seconds(10));
        router_->replace_bonds(*config_);
        return FilterChain::create(*config_, kDir, *loop_, *router_);
    }
    std::unique_ptr<EventLoop> loop_ = std::move(EventLoop::create().value());
    std::unique_ptr<Config> config_;
    std::unique_ptr<Router> router_;
};

TEST_F(ChainTest, BuildsAGoodPluginWithItsOptions) {
    auto chain = build("  - {plugin: good_plugin, label: hello, period: 250ms}\n");
    ASSERT_TRUE(chain.has_value()) << chain.error().message;
    EXPECT_EQ(1u, chain.value()->size());
}

TEST_F(ChainTest, DisabledFiltersAreNotLoaded) {
    auto chain = build("  - {plugin: no_such_plugin, enabled: false}\n");
    ASSERT_TRUE(chain.has_value()) << chain.error().message;
    EXPECT_EQ(0u, chain.value()->size());
}

TEST_F(ChainTest, UnknownOptionNamesItsPlace) {
    auto chain = build("  - plugin: good_plugin\n    lable: x\n");
    ASSERT_FALSE(chain.has_value());
    EXPECT_EQ("t.yaml:5:5: filter 'good_plugin': unknown option 'lable' (it takes: label, period)",
              chain.error().message);
}

TEST_F(ChainTest, WrongOptionTypeNamesItsPlace) {
    auto chain = build("  - plugin: good_plugin\n    period: 5\n");
    ASSERT_FALSE(chain.has_value());
    EXPECT_EQ("t.yaml:5:13: filter 'good_plugin': option 'period' must be a duration with a unit "
              "(250ms, 2s), not '5'",
              chain.error().message);
}

TEST_F(ChainTest, FailedCreateNamesTheEntryTheFileAndTheReason) {
    auto chain = build("  - {plugin: failing_create}\n");
    ASSERT_FALSE(chain.has_value());
    const std::string& e = chain.error().message;
    EXPECT_EQ(0u, e.find("t.yaml:4:5: filter 'failing_create': ")) << e;
    EXPECT_NE(std::string::npos, e.find("failing_create.so: create failed")) << e;
    EXPECT_NE(std::string::npos, e.find("this plugin always refuses")) << e;
}

TEST_F(ChainTest, PluginCheckOfAnOptionValueNamesItsPlace) {
    auto chain = build("  - plugin: good_plugin\n    label: bad\n");
    ASSERT_FALSE(chain.has_value());
    EXPECT_NE(std::string::npos,
              chain.error().message.find("t.yaml:5:12: filter 'good_plugin': option 'label': must not be 'bad'"))
        << chain.error().message;
}

TEST_F(ChainTest, LoadErrorsCarryTheConfigPlace) {
    auto chain = build("  - {plugin: abi_version}\n");
    ASSERT_FALSE(chain.has_value());
    EXPECT_EQ(0u, chain.error().message.find("t.yaml:4:5: filter 'abi_version': " + kDir)) << chain.error().message;
}

// `renumber: true` needs a filter on the bond that provides the bond's positions of copies
// numbered each their own way (dedup with key: content declares it); the host checks the
// declaration, never a plugin's options.
TEST_F(ChainTest, RenumberingNeedsAFilterThatAlignsTheBondsNumberings) {
    const std::string bonds = "bonds:\n  - {name: b, renumber: true}\n";
    const std::string why =
        "t.yaml:4:25: bond 'b': 'renumber' needs a dedup filter with 'key: content' on this bond, "
        "enabled and scoped to it by 'bonds:' or unscoped (with key: frame the copies already "
        "share one numbering)";
    for (const char* filters : {"  - {plugin: good_plugin, bonds: [b]}\n",
                                "  - {plugin: aligning_plugin, enabled: false}\n",
                                "  - {plugin: aligning_plugin, endpoints: [a]}\n"}) {
        auto chain = build(filters, bonds);
        ASSERT_FALSE(chain.has_value()) << filters;
        EXPECT_EQ(why, chain.error().message) << filters;
    }
    for (const char* filters : {"  - {plugin: aligning_plugin, bonds: [b]}\n",
                                "  - {plugin: aligning_plugin}\n"}) {
        auto chain = build(filters, bonds);
        EXPECT_TRUE(chain.has_value()) << filters << chain.error().message;
    }
}

TEST_F(ChainTest, PluginMetricsAreNamedLabelledAndChecked) {
    auto chain = build("  - {plugin: good_plugin}\n  - {plugin: good_plugin, label: two}\n");
    ASSERT_TRUE(chain.has_value()) << chain.error().message;
    MetricSet set;
    for (const FilterReport& f : chain.value()->report()) {
        for (const MetricSample& s : f.samples)
            ASSERT_TRUE(set.add(s).has_value()) << s.name;
    }
    std::string text = set.text();
    // Named mavbond_PLUGIN_NAME, counters _total, one family for both instances, the
    // instance in `filter`, the plugin's label value escaped, the count exact.
    EXPECT_NE(std::string::npos,
              text.find("# HELP mavbond_good_plugin_frames_total Frames seen.\n"
                        "# TYPE mavbond_good_plugin_frames_total counter\n"
                        "mavbond_good_plugin_frames_total{filter=\"good_plugin\",link=\"a\\\"b\\\\c\\nd\"} "
                        "18446744073709551000\n"
                        "mavbond_good_plugin_frames_total{filter=\"good_plugin#2\",link=\"a\\\"b\\\\c\\nd\"} "
                        "18446744073709551000\n"))
        << text;
    EXPECT_NE(std::string::npos, text.find("mavbond_good_plugin_ratio{filter=\"good_plugin\"} NaN\n"))
        << text;
    EXPECT_NE(std::string::npos,
              text.find("mavbond_filter_dropped_total{filter=\"good_plugin#2\",plugin=\"good_plugin\"} 0\n"))
        << text;
    // The host's label is not the plugin's to set, and a name must be a name.
    EXPECT_EQ(std::string::npos, text.find("stolen")) << text;
    EXPECT_EQ(std::string::npos, text.find("bad-name")) << text;
    EXPECT_EQ(std::string::npos, text.find("mine")) << text;
}

}  // namespace
}  // namespace mavbond
