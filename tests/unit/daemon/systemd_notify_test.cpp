// SystemdNotify against a real AF_UNIX datagram socket, bound where $NOTIFY_SOCKET says, as
// systemd's own: what arrives is what systemd would read.
#include "daemon/systemd_notify.h"

#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>

namespace mavbond {
namespace {

class NotifySocket : public ::testing::Test {
protected:
    void TearDown() override {
        for (const char* name : {"NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID"})
            unsetenv(name);
        if (fd_ >= 0)
            close(fd_);
        if (!path_.empty())
            std::filesystem::remove(path_);
    }
    /// Binds the receiving socket: a path, or with `abstract` a name in the abstract
    /// namespace ("@name" in $NOTIFY_SOCKET).
    void bind_socket(bool abstract) {
        fd_ = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        ASSERT_GE(fd_, 0);
        sockaddr_un addr{};
        addr.sun_family = AF_UNIX;
        const std::string name = "mavbond-notify-test-" + std::to_string(getpid());
        socklen_t len;
        if (abstract) {
            std::memcpy(addr.sun_path + 1, name.data(), name.size());
            len = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + 1 + name.size());
            setenv("NOTIFY_SOCKET", ("@" + name).c_str(), 1);
        } else {
            path_ = (std::filesystem::temp_directory_path() / name).string();
            std::filesystem::remove(path_);
            std::memcpy(addr.sun_path, path_.c_str(), path_.size() + 1);
            len = sizeof addr;
            setenv("NOTIFY_SOCKET", path_.c_str(), 1);
        }
        ASSERT_EQ(0, bind(fd_, reinterpret_cast<sockaddr*>(&addr), len)) << strerror(errno);
        timeval tv{2, 0};
        setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    }
    std::string receive() {
        char buf[4096];
        ssize_t n = recv(fd_, buf, sizeof buf, 0);
        return n < 0 ? "(nothing)" : std::string(buf, static_cast<size_t>(n));
    }
    std::unique_ptr<SystemdNotify> notifier() {
        auto n = SystemdNotify::from_environment();
        EXPECT_TRUE(n.has_value()) << n.error().message;
        return n ? std::move(n.value()) : nullptr;
    }

    int fd_ = -1;
    std::string path_;
};

TEST_F(NotifySocket, NothingWithoutNotifySocket) {
    unsetenv("NOTIFY_SOCKET");
    auto n = SystemdNotify::from_environment();
    ASSERT_TRUE(n.has_value());
    EXPECT_EQ(nullptr, n.value());
}

TEST_F(NotifySocket, ReadyReloadingStoppingAndStatusArriveAsSystemdReadsThem) {
    bind_socket(false);
    auto n = notifier();
    ASSERT_TRUE(n);
    n->ready("bond vehicle: 2 of 2 links up");
    EXPECT_EQ("READY=1\nSTATUS=bond vehicle: 2 of 2 links up", receive());
    timespec before{};
    clock_gettime(CLOCK_MONOTONIC, &before);
    n->reloading();
    const std::string reloading = receive();
    timespec after{};
    clock_gettime(CLOCK_MONOTONIC, &after);
    // MONOTONIC_USEC: CLOCK_MONOTONIC in microseconds, taken during the call.
    unsigned long long usec = 0;
    ASSERT_EQ(1, sscanf(reloading.c_str(), "RELOADING=1\nMONOTONIC_USEC=%llu\nSTATUS=reloading", &usec))
        << reloading;
    EXPECT_NE(std::string::npos, reloading.find("\nSTATUS=reloading")) << reloading;
    EXPECT_GE(usec, before.tv_sec * 1000000ull + before.tv_nsec / 1000);
    EXPECT_LE(usec, after.tv_sec * 1000000ull + after.tv_nsec / 1000);
    n->status("bond vehicle: 1 of 2 links up");
    EXPECT_EQ("STATUS=bond vehicle: 1 of 2 links up", receive());
    n->watchdog();
    EXPECT_EQ("WATCHDOG=1", receive());
    n->stopping();
    EXPECT_EQ("STOPPING=1\nSTATUS=stopping", receive());
}

TEST_F(NotifySocket, AnAbstractSocketIsReached) {
    bind_socket(true);
    auto n = notifier();
    ASSERT_TRUE(n);
    n->watchdog();
    EXPECT_EQ("WATCHDOG=1", receive());
}

TEST_F(NotifySocket, TheWatchdogIsFedAtHalfItsTimeoutForThisProcessOnly) {
    bind_socket(false);
    setenv("WATCHDOG_USEC", "3000000", 1);
    EXPECT_EQ(std::chrono::milliseconds(1500), notifier()->watchdog_period());
    setenv("WATCHDOG_PID", std::to_string(getpid()).c_str(), 1);
    EXPECT_EQ(std::chrono::milliseconds(1500), notifier()->watchdog_period());
    setenv("WATCHDOG_PID", std::to_string(getpid() + 1).c_str(), 1);  // another process's
    EXPECT_EQ(Duration::zero(), notifier()->watchdog_period());
    unsetenv("WATCHDOG_PID");
    setenv("WATCHDOG_USEC", "soon", 1);
    EXPECT_EQ(Duration::zero(), notifier()->watchdog_period());
}

TEST_F(NotifySocket, ASocketThatIsNoPathIsAnError) {
    setenv("NOTIFY_SOCKET", "relative/socket", 1);
    auto n = SystemdNotify::from_environment();
    ASSERT_FALSE(n.has_value());
    EXPECT_NE(std::string::npos, n.error().message.find("neither a path nor an abstract socket"));
}

}  // namespace
}  // namespace mavbond
