#include "core/event_loop.h"

#include <gtest/gtest.h>
#include <sys/socket.h>

#include <csignal>

namespace mavbond {
namespace {

std::unique_ptr<EventLoop> make_loop() {
    auto loop = EventLoop::create();
    EXPECT_TRUE(loop.has_value());
    return std::move(loop.value());
}

TEST(EventLoop, TimersFireInDeadlineOrderAndRearm) {
    auto loop = make_loop();
    std::vector<int> fired;
    int periodic = 0;
    auto t1 = loop->schedule(milliseconds(30), [&] { fired.push_back(30); return Duration::zero(); });
    auto t2 = loop->schedule(milliseconds(10), [&] { fired.push_back(10); return Duration::zero(); });
    auto t3 = loop->schedule(milliseconds(5), [&] {
        ++periodic;
        return periodic < 3 ? Duration(milliseconds(5)) : Duration::zero();
    });
    TimePoint until = Clock::now() + milliseconds(500);
    while (Clock::now() < until && (fired.size() < 2 || periodic < 3))
        loop->run_once(milliseconds(50));
    EXPECT_EQ((std::vector<int>{10, 30}), fired);
    EXPECT_EQ(3, periodic);
    EXPECT_FALSE(t1.active());
}

TEST(EventLoop, CancelledTimerNeverFires) {
    auto loop = make_loop();
    bool fired = false;
    {
        auto t = loop->schedule(milliseconds(1), [&] { fired = true; return Duration::zero(); });
    }  // destroyed: cancelled
    loop->run_once(milliseconds(20));
    EXPECT_FALSE(fired);
}

TEST(EventLoop, TimerMayCancelItself) {
    auto loop = make_loop();
    int count = 0;
    EventLoop::Timer t;
    t = loop->schedule(milliseconds(1), [&] {
        ++count;
        t.cancel();
        return Duration(milliseconds(1));  // ignored: cancelled
    });
    for (int i = 0; i < 5; i++)
        loop->run_once(milliseconds(5));
    EXPECT_EQ(1, count);
}

TEST(EventLoop, WatchDeliversReadableAndRemovalDuringDispatchIsSafe) {
    auto loop = make_loop();
    int fds_a[2], fds_b[2];
    ASSERT_EQ(0, socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK, 0, fds_a));
    ASSERT_EQ(0, socketpair(AF_UNIX, SOCK_DGRAM | SOCK_NONBLOCK, 0, fds_b));
    UniqueFd a0(fds_a[0]), a1(fds_a[1]), b0(fds_b[0]), b1(fds_b[1]);
    int a_calls = 0, b_calls = 0;
    EventLoop::Watch wb;
    auto wa = loop->watch(a0.get(), EPOLLIN, [&](uint32_t) {
        ++a_calls;
        char buf[8];
        (void)!read(a0.get(), buf, sizeof buf);
        wb.reset();  // removes the other watch, whose event may already be fetched
    });
    ASSERT_TRUE(wa.has_value());
    auto w = loop->watch(b0.get(), EPOLLIN, [&](uint32_t) { ++b_calls; });
    ASSERT_TRUE(w.has_value());
    wb = std::move(w.value());
    ASSERT_EQ(1, write(a1.get(), "x", 1));
    ASSERT_EQ(1, write(b1.get(), "y", 1));
    loop->run_once(milliseconds(50));
    loop->run_once(milliseconds(10));
    EXPECT_EQ(1, a_calls);
    // b ran at most in the first round before a removed it (epoll order), never after.
    EXPECT_LE(b_calls, 1);
    int b_before = b_calls;
    loop->run_once(milliseconds(10));
    EXPECT_EQ(b_before, b_calls);
}

TEST(EventLoop, SignalStopsTheLoopWithItsCode) {
    auto loop = make_loop();
    ASSERT_TRUE(loop->on_signal(SIGUSR2, [&](int) { loop->request_exit(7); }).has_value());
    auto t = loop->schedule(milliseconds(5), [] {
        raise(SIGUSR2);
        return Duration::zero();
    });
    EXPECT_EQ(7, loop->run());
}

TEST(EventLoop, DeferredWorkRunsAfterTheRound) {
    auto loop = make_loop();
    std::vector<int> order;
    auto t = loop->schedule(milliseconds(1), [&] {
        loop->defer([&] { order.push_back(2); });
        order.push_back(1);
        return Duration::zero();
    });
    loop->add_round_hook([&] { order.push_back(order.empty() ? 0 : 3); });
    for (int i = 0; i < 5 && order.size() < 3; i++)
        loop->run_once(milliseconds(10));
    ASSERT_GE(order.size(), 3u);
    EXPECT_EQ(1, order[0]);
    EXPECT_EQ(3, order[1]);  // round hook
    EXPECT_EQ(2, order[2]);  // then deferred work
}

}  // namespace
}  // namespace mavbond
