#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

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
    EXPECT_NE(std::string::npos, e.find("this mavbond speaks version " +
                                        std::to_string(MAVBOND_PLUGIN_ABI_VERSION) +
                                        ": rebuild the plugin")) << e;
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
    chmod(dir.c_str(), 0755);
    std::filesystem::copy_file(kDir + "/good_plugin.so", dir / "good_plugin.so",
                               std::filesystem::copy_options::overwrite_existing);
    for (mode_t mode : {0666, 0664, 0646}) {
        chmod((dir / "good_plugin.so").c_str(), mode);
        std::string e = load_error("good_plugin", dir.string());
        char want[80];
        snprintf(want, sizeof want, "may be written by others than its owner (mode %04o)", mode);
        EXPECT_NE(std::string::npos, e.find(want)) << e;
    }
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
    // Sticky or not: the plugin directory is where names are looked up, so no one else may
    // add one.
    for (mode_t mode : {0777, 0775, 0757, 01777}) {
        chmod(dir.c_str(), mode);
        std::string e = load_error("good_plugin", dir.string());
        char want[80];
        snprintf(want, sizeof want, "may be written by others than its owner (mode %04o)", mode);
        EXPECT_NE(std::string::npos, e.find("plugin directory " + dir.string())) << e;
        EXPECT_NE(std::string::npos, e.find(want)) << e;
    }
    chmod(dir.c_str(), 0755);
    EXPECT_TRUE(LoadedPlugin::load(dir.string(), "good_plugin").has_value());
    std::filesystem::remove_all(dir);
}

/// Plugin files laid out as a test needs them, under a private directory; the trace file
/// the test plugins' constructors write to (tests/abi/test_plugin.cpp) tells which of them ran.
class PluginFiles : public ::testing::Test {
protected:
    void SetUp() override {
        root_ = std::filesystem::temp_directory_path() /
                ("mavbond-trust-" + std::to_string(getpid()) + "-" +
                 ::testing::UnitTest::GetInstance()->current_test_info()->name());
        std::filesystem::remove_all(root_);
        std::filesystem::create_directories(root_);
        chmod(root_.c_str(), 0755);
        trace_ = root_ / "ran.txt";
        setenv("MAVBOND_ABI_TEST_RAN", trace_.c_str(), 1);
    }
    void TearDown() override {
        unsetenv("MAVBOND_ABI_TEST_RAN");
        std::filesystem::remove_all(root_);
    }
    /// A directory under the root, made with `mode` (mkdir's mode is cut by the umask).
    std::filesystem::path dir(const std::string& rel, mode_t mode = 0755) {
        auto p = root_ / rel;
        std::filesystem::create_directories(p);
        chmod(p.c_str(), mode);
        return p;
    }
    /// A fresh copy (its own inode: the dynamic loader runs its constructor anew) of the
    /// test plugin `plugin`, as `to`.
    std::filesystem::path copy(const std::string& plugin, const std::filesystem::path& to) {
        std::filesystem::copy_file(kDir + "/" + plugin + ".so", to,
                                   std::filesystem::copy_options::overwrite_existing);
        chmod(to.c_str(), 0644);
        return to;
    }
    std::string ran() const {
        std::ifstream in(trace_);
        std::stringstream text;
        text << in.rdbuf();
        return text.str();
    }
    static bool as_root() { return geteuid() == 0; }

    std::filesystem::path root_;
    std::filesystem::path trace_;
};

constexpr uid_t kNobody = 65534;

TEST_F(PluginFiles, AGoodPluginRunsAndSaysSo) {
    // The trace works: what the tests below find absent would be there had the code run.
    auto plugins = dir("plugins");
    copy("good_plugin", plugins / "good_plugin.so");
    auto p = LoadedPlugin::load(plugins.string(), "good_plugin");
    ASSERT_TRUE(p.has_value()) << p.error().message;
    EXPECT_EQ("good_plugin\n", ran());
}

TEST_F(PluginFiles, WhatTheFileSaysIsCheckedBeforeAnyOfItRuns) {
    auto plugins = dir("plugins");
    const std::pair<const char*, std::string> cases[] = {
        {"abi_version", "built for plugin ABI version " + std::to_string(MAVBOND_PLUGIN_ABI_VERSION + 41) +
                        ", this mavbond speaks version " + std::to_string(MAVBOND_PLUGIN_ABI_VERSION)},
        {"wrong_name", "calls itself 'somebody_else', but was loaded as 'wrong_name'"},
        {"no_entry", "no entry symbol mavbond_plugin_entry"},
        {"no_abi_data", "no mavbond_plugin_abi_version symbol: built for plugin ABI version 4 or older"},
    };
    for (const auto& [name, why] : cases) {
        copy(name, plugins / (std::string(name) + ".so"));
        std::string e = load_error(name, plugins.string());
        EXPECT_NE(std::string::npos, e.find((plugins / name).string() + ".so: " + why)) << e;
    }
    EXPECT_EQ("", ran()) << "a refused plugin's constructor ran";
}

TEST_F(PluginFiles, AFileForAnotherMachineIsNamedAsSuch) {
    auto plugins = dir("plugins");
    auto path = copy("good_plugin", plugins / "good_plugin.so");
    auto patch = [&](long offset, std::initializer_list<unsigned char> bytes) {
        copy("good_plugin", path);
        std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
        f.seekp(offset);
        for (unsigned char b : bytes)
            f.put(static_cast<char>(b));
    };
    // e_machine: another machine than this build's (EM_AARCH64, or EM_X86_64 on arm64)
#if defined(__aarch64__)
    patch(18, {62, 0});
    const char* other = "built for x86-64 (amd64), this mavbond runs on";
#else
    patch(18, {183, 0});
    const char* other = "built for AArch64 (arm64), this mavbond runs on";
#endif
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find(other)) << e;
    patch(4, {sizeof(void*) == 8 ? 1 : 2});  // EI_CLASS: the other one
    e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find(sizeof(void*) == 8 ? "built for 32-bit, this mavbond is 64-bit"
                                                            : "built for 64-bit, this mavbond is 32-bit"))
        << e;
    std::ofstream(path, std::ios::trunc) << "not a shared object\n";
    e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find("good_plugin.so: not an ELF file")) << e;
    EXPECT_EQ("", ran());
}

TEST_F(PluginFiles, ADescriptorThatContradictsTheFileIsRefused) {
    auto plugins = dir("plugins");
    copy("descriptor_abi", plugins / "descriptor_abi.so");
    std::string e = load_error("descriptor_abi", plugins.string());
    EXPECT_NE(std::string::npos, e.find("built for plugin ABI version " +
                                        std::to_string(MAVBOND_PLUGIN_ABI_VERSION + 41)))
        << e;
}

// The files root does not own (issue 22, item 4): each one refused, naming the file, the
// directory or the symlink and its owner, and none of its code run.
TEST_F(PluginFiles, RefusesAPluginFileAnotherUserOwns) {
    if (!as_root())
        GTEST_SKIP() << "needs root to give a file to uid 65534";
    auto plugins = dir("plugins");
    auto path = copy("good_plugin", plugins / "good_plugin.so");
    ASSERT_EQ(0, chown(path.c_str(), kNobody, kNobody));
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find("plugin " + path.string() + " is owned by uid 65534")) << e;
    EXPECT_NE(std::string::npos, e.find("may run code in mavbond")) << e;
    EXPECT_EQ("", ran());
}

TEST_F(PluginFiles, RefusesAPluginDirectoryAnotherUserOwns) {
    if (!as_root())
        GTEST_SKIP() << "needs root to give a directory to uid 65534";
    auto plugins = dir("plugins");
    copy("good_plugin", plugins / "good_plugin.so");
    ASSERT_EQ(0, chown(plugins.c_str(), kNobody, kNobody));
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find("directory " + plugins.string() + " is owned by uid 65534")) << e;
    EXPECT_EQ("", ran());
}

TEST_F(PluginFiles, RefusesAPluginDirectoryWhoseParentOthersMayWrite) {
    // A 0777 parent: anyone may swap its plugins/ for their own.
    auto parent = dir("open", 0777);
    auto plugins = dir("open/plugins");
    copy("good_plugin", plugins / "good_plugin.so");
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos,
              e.find("directory " + parent.string() + " may be written by others than its owner (mode 0777)"))
        << e;
    EXPECT_EQ("", ran());
    // Sticky, as /tmp: an entry may be replaced by its owner only, and the next one is checked.
    chmod(parent.c_str(), 01777);
    EXPECT_TRUE(LoadedPlugin::load(plugins.string(), "good_plugin").has_value());
}

TEST_F(PluginFiles, RefusesASymlinkToAFileAnotherUserOwns) {
    if (!as_root())
        GTEST_SKIP() << "needs root to give a file to uid 65534";
    auto plugins = dir("plugins");
    auto elsewhere = dir("elsewhere");
    auto target = copy("good_plugin", elsewhere / "good_plugin.so");
    ASSERT_EQ(0, chown(target.c_str(), kNobody, kNobody));
    std::filesystem::create_symlink("../elsewhere/good_plugin.so", plugins / "good_plugin.so");
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find("plugin " + target.string() + " is owned by uid 65534")) << e;
    EXPECT_EQ("", ran());
}

TEST_F(PluginFiles, RefusesASymlinkAnotherUserOwns) {
    if (!as_root())
        GTEST_SKIP() << "needs root to give a symlink to uid 65534";
    auto plugins = dir("plugins");
    auto real = dir("real");
    copy("good_plugin", real / "good_plugin.so");
    auto link = plugins / "good_plugin.so";
    std::filesystem::create_symlink(real / "good_plugin.so", link);
    ASSERT_EQ(0, lchown(link.c_str(), kNobody, kNobody));
    std::string e = load_error("good_plugin", plugins.string());
    EXPECT_NE(std::string::npos, e.find("symlink " + link.string() + " is owned by uid 65534")) << e;
    // A plugin directory that is a symlink to another user's directory.
    auto theirs = dir("theirs");
    copy("good_plugin", theirs / "good_plugin.so");
    ASSERT_EQ(0, chown(theirs.c_str(), kNobody, kNobody));
    std::filesystem::create_symlink(theirs, root_ / "linked");
    e = load_error("good_plugin", (root_ / "linked").string());
    EXPECT_NE(std::string::npos, e.find("directory " + theirs.string() + " is owned by uid 65534")) << e;
    EXPECT_EQ("", ran());
}

TEST_F(PluginFiles, FollowsSymlinksItTrustsAndNamesWhereTheyLed) {
    auto real = dir("lib/real");
    copy("good_plugin", real / "good_plugin.so");
    auto plugins = dir("plugins");
    std::filesystem::create_symlink("../lib/./real/../real/good_plugin.so", plugins / "good_plugin.so");
    std::filesystem::create_symlink("plugins", root_ / "current");
    auto p = LoadedPlugin::load((root_ / "current").string(), "good_plugin");
    ASSERT_TRUE(p.has_value()) << p.error().message;
    EXPECT_EQ((real / "good_plugin.so").string(), p.value()->path());
    EXPECT_EQ("good_plugin\n", ran());
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
    void expect_needs(const std::string& bonds, const std::string& provider,
                      const std::string& why);

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

// A bond setting that needs something of its filters, declared by them (provides): refused
// without an instance of `provider` on the bond (another plugin, a disabled one, one scoped
// elsewhere), accepted with one scoped to it or unscoped.
void ChainTest::expect_needs(const std::string& bonds, const std::string& provider,
                             const std::string& why) {
    for (const std::string& filters :
         {std::string("  - {plugin: good_plugin, bonds: [b]}\n"),
          "  - {plugin: " + provider + ", enabled: false}\n",
          "  - {plugin: " + provider + ", endpoints: [a]}\n"}) {
        auto chain = build(filters, bonds);
        ASSERT_FALSE(chain.has_value()) << filters;
        EXPECT_EQ(why, chain.error().message) << filters;
    }
    for (const std::string& filters : {"  - {plugin: " + provider + ", bonds: [b]}\n",
                                       "  - {plugin: " + provider + "}\n"}) {
        auto chain = build(filters, bonds);
        EXPECT_TRUE(chain.has_value()) << filters << chain.error().message;
    }
}

// `renumber: true` needs a filter on the bond that provides the bond's positions of copies
// (dedup declares it); the host checks the declaration, never a plugin's options. Without the
// key, a bond renumbers wherever such a filter is.
TEST_F(ChainTest, RenumberingNeedsAFilterThatAlignsTheBondsNumberings) {
    expect_needs("bonds:\n  - {name: b, renumber: true}\n", "aligning_plugin",
                 "t.yaml:4:25: bond 'b': 'renumber' needs a dedup filter on this bond, enabled "
                 "and scoped to it by 'bonds:' or unscoped");
    // Not said: derived from the chain; said false: off whatever the chain gives.
    BondConfig unsaid{"b"}, off{"b"};
    off.renumber = false;
    auto with = build("  - {plugin: aligning_plugin}\n", "bonds:\n  - {name: b}\n");
    ASSERT_TRUE(with.has_value()) << with.error().message;
    EXPECT_TRUE(with.value()->renumbers(unsaid));
    EXPECT_FALSE(with.value()->renumbers(off));
    auto without = build("  - {plugin: good_plugin}\n", "bonds:\n  - {name: b}\n");
    ASSERT_TRUE(without.has_value()) << without.error().message;
    EXPECT_FALSE(without.value()->renumbers(unsaid));
}

// `tx: active` sends on the link a filter chooses: with none that declares it chooses one (as
// linkswitch does), the bond would send on every link, so the config is refused.
TEST_F(ChainTest, ActiveTxNeedsAFilterThatChoosesTheActiveLink) {
    expect_needs("bonds:\n  - {name: b, tx: active}\n", "choosing_plugin",
                 "t.yaml:4:19: bond 'b': 'tx: active' needs a linkswitch filter on this bond, "
                 "enabled and scoped to it by 'bonds:' or unscoped, to choose the active link "
                 "(without one the bond would send on every link: that is 'tx: broadcast')");
    auto broadcast = build("  - {plugin: good_plugin}\n", "bonds:\n  - {name: b, tx: broadcast}\n");
    EXPECT_TRUE(broadcast.has_value()) << broadcast.error().message;
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
