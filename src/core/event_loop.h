// One thread, one epoll loop: fd watches, timers on the monotonic clock (a min-heap that sets
// epoll_wait's timeout, no timerfd per timer) and signals through signalfd. No singleton: main
// owns the loop and hands out references.
#pragma once

#include <sys/epoll.h>

#include <cstdint>
#include <functional>
#include <memory>
#include <queue>
#include <unordered_map>
#include <vector>

#include "core/clock.h"
#include "core/result.h"
#include "core/unique_fd.h"

namespace mavbond {

class EventLoop {
    struct WatchRecord;

public:
    using IoHandler = std::function<void(uint32_t events)>;
    /// Returns the delay until the next run, or Duration::zero() to stop.
    using TimerHandler = std::function<Duration()>;
    using SignalHandler = std::function<void(int signo)>;

    /// RAII registration of an fd; the destructor removes it (safe inside its own handler).
    class Watch {
    public:
        Watch() = default;
        Watch(Watch&& other) noexcept;
        Watch& operator=(Watch&& other) noexcept;
        Watch(const Watch&) = delete;
        Watch& operator=(const Watch&) = delete;
        ~Watch() { reset(); }
        /// Changes the epoll event mask (e.g. adds EPOLLOUT while a tx queue is non-empty).
        void set_events(uint32_t events);
        uint32_t events() const;
        bool active() const { return record_ != nullptr; }
        /// Whether epoll reported the fd in this round (it may hold data the round began with).
        bool ready_this_round() const;
        void reset();

    private:
        friend class EventLoop;
        Watch(EventLoop* loop, WatchRecord* record) : loop_(loop), record_(record) {}
        EventLoop* loop_ = nullptr;
        WatchRecord* record_ = nullptr;
    };

    /// RAII timer; the destructor cancels it (safe inside its own handler).
    class Timer {
    public:
        Timer() = default;
        Timer(Timer&& other) noexcept;
        Timer& operator=(Timer&& other) noexcept;
        Timer(const Timer&) = delete;
        Timer& operator=(const Timer&) = delete;
        ~Timer() { cancel(); }
        void cancel();
        bool active() const;

    private:
        friend class EventLoop;
        Timer(EventLoop* loop, uint64_t id) : loop_(loop), id_(id) {}
        EventLoop* loop_ = nullptr;
        uint64_t id_ = 0;
    };

    static Result<std::unique_ptr<EventLoop>> create();
    ~EventLoop();
    EventLoop(const EventLoop&) = delete;
    EventLoop& operator=(const EventLoop&) = delete;

    [[nodiscard]] Result<Watch> watch(int fd, uint32_t events, IoHandler handler);
    /// Runs `handler` after `delay`, then again after whatever delay it returns.
    [[nodiscard]] Timer schedule(Duration delay, TimerHandler handler);
    /// Blocks `signo` and delivers it through signalfd to `handler` on the loop thread.
    Result<void> on_signal(int signo, SignalHandler handler);
    /// Runs after every dispatch round, before the loop sleeps (batch flushes).
    void add_round_hook(std::function<void()> hook);
    /// Runs after the fd handlers of every round, before the timers: work that the timers of
    /// the round must find done (the frames a round received, merged in arrival order).
    void add_after_io_hook(std::function<void()> hook);
    /// The next round polls instead of sleeping (work was held back for it).
    void request_prompt_round() { prompt_round_ = true; }
    /// Runs `fn` once after this dispatch round: for destroying an object from inside one of
    /// its own handlers.
    void defer(std::function<void()> fn) { deferred_.push_back(std::move(fn)); }

    /// Runs until request_exit(); returns the code given to it.
    int run();
    /// One round: waits at most max_wait for events (for tests). False once exit was requested.
    bool run_once(Duration max_wait);
    void request_exit(int code = 0);

    /// The time cached at the start of this round (one clock read per batch).
    TimePoint now() const { return now_; }
    /// A time before epoll looked at the fds for this round (the previous round's start): an
    /// fd it did not report had nothing then. (epoll looked later, maybe much later when the
    /// process was stopped in between: a data point that bounds it better is the arrival of
    /// what a reported fd held, see Router::Input.)
    TimePoint polled_after() const { return polled_after_; }
    /// The number of this round.
    uint64_t round() const { return round_; }
    /// Whether epoll reported every ready fd in this round (its event array was not full).
    bool all_reported() const { return all_reported_; }
    /// The wall clock (CLOCK_REALTIME, which the kernel stamps arrivals with) minus the
    /// monotonic, in ns: read once per round, when first asked.
    int64_t wall_minus_monotonic_ns() const;

    /// How the loop kept time, the daemon's own evidence of a stall: a round that ran long (a
    /// handler that blocked in a syscall, or work piled up) held every frame behind it; a
    /// wakeup later than epoll_wait was asked for means the process had no CPU (a busy
    /// machine), was stopped, or the kernel held epoll_wait itself (a tty's poll waits for
    /// the tty's flush worker, which a saturated machine can starve for seconds). One clock
    /// read per round buys it.
    struct Stalls {
        Duration longest_round{};   // handlers, hooks and timers of one round
        uint64_t long_rounds = 0;   // rounds of kStall or more
        Duration latest_wakeup{};   // beyond the timeout epoll_wait was given
        uint64_t late_wakeups = 0;  // of kStall or more
    };
    static constexpr Duration kStall = milliseconds(100);
    /// A stall this long is logged (at most once per kStallLogEvery, with how many there were).
    static constexpr Duration kStallLogged = seconds(1);
    static constexpr Duration kStallLogEvery = seconds(10);
    const Stalls& stalls() const { return stalls_; }

private:
    struct WatchRecord {
        int fd;
        uint32_t events;
        IoHandler handler;
        bool dead = false;
        uint64_t ready_round = 0;  // the last round epoll reported it
    };
    struct TimerEntry {
        TimePoint due;
        uint64_t id;
        bool operator>(const TimerEntry& o) const { return due > o.due; }
    };

    explicit EventLoop(UniqueFd epoll_fd);
    void remove_watch(WatchRecord* record);
    void modify_watch(WatchRecord* record, uint32_t events);
    void run_due_timers();
    int timeout_ms() const;
    void handle_signals();
    /// Counts a round that took `took`, or (`woke`) a wakeup `took` after the timeout asked
    /// for, either ending `at`.
    void note_stall(Duration took, bool woke, TimePoint at);

    UniqueFd epoll_fd_;
    std::vector<std::unique_ptr<WatchRecord>> watches_;
    std::vector<std::unique_ptr<WatchRecord>> graveyard_;  // freed after the round
    std::priority_queue<TimerEntry, std::vector<TimerEntry>, std::greater<>> timer_heap_;
    std::unordered_map<uint64_t, TimerHandler> timers_;
    uint64_t next_timer_id_ = 1;
    UniqueFd signal_fd_;
    Watch signal_watch_;
    std::unordered_map<int, SignalHandler> signal_handlers_;
    std::vector<std::function<void()>> round_hooks_;
    std::vector<std::function<void()>> after_io_hooks_;
    uint64_t round_ = 0;
    bool prompt_round_ = false;
    bool timers_waited_ = false;  // the last round woke late and left its timers to this one
    std::vector<std::function<void()>> deferred_;
    TimePoint now_ = Clock::now();
    TimePoint polled_after_ = now_;
    bool all_reported_ = true;
    mutable int64_t wall_minus_monotonic_ = 0;
    mutable uint64_t wall_round_ = UINT64_MAX;  // the round wall_minus_monotonic_ was read in
    Stalls stalls_;
    TimePoint stall_logged_{};  // when a stall was last logged
    uint64_t long_stalls_ = 0;  // stalls of kStallLogged or more
    bool exit_requested_ = false;
    int exit_code_ = 0;
};

}  // namespace mavbond
