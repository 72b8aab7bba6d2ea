#include "core/event_loop.h"

#include <sys/signalfd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <csignal>
#include <cstring>

#include "core/log.h"

namespace mavbond {

// --- Watch ---------------------------------------------------------------------------------

EventLoop::Watch::Watch(Watch&& other) noexcept
    : loop_(std::exchange(other.loop_, nullptr)), record_(std::exchange(other.record_, nullptr)) {}

EventLoop::Watch& EventLoop::Watch::operator=(Watch&& other) noexcept {
    if (this != &other) {
        reset();
        loop_ = std::exchange(other.loop_, nullptr);
        record_ = std::exchange(other.record_, nullptr);
    }
    return *this;
}

void EventLoop::Watch::set_events(uint32_t events) {
    if (record_ && record_->events != events)
        loop_->modify_watch(record_, events);
}

uint32_t EventLoop::Watch::events() const { return record_ ? record_->events : 0; }

int64_t EventLoop::wall_minus_monotonic_ns() const {
    if (wall_round_ != round_) {
        timespec wall{}, mono{};
        clock_gettime(CLOCK_REALTIME, &wall);
        clock_gettime(CLOCK_MONOTONIC, &mono);
        wall_minus_monotonic_ = (wall.tv_sec - mono.tv_sec) * 1'000'000'000LL + wall.tv_nsec - mono.tv_nsec;
        wall_round_ = round_;
    }
    return wall_minus_monotonic_;
}

bool EventLoop::Watch::ready_this_round() const {
    return record_ && record_->ready_round == loop_->round_;
}

void EventLoop::Watch::reset() {
    if (record_)
        loop_->remove_watch(record_);
    record_ = nullptr;
    loop_ = nullptr;
}

// --- Timer ---------------------------------------------------------------------------------

EventLoop::Timer::Timer(Timer&& other) noexcept
    : loop_(std::exchange(other.loop_, nullptr)), id_(std::exchange(other.id_, 0)) {}

EventLoop::Timer& EventLoop::Timer::operator=(Timer&& other) noexcept {
    if (this != &other) {
        cancel();
        loop_ = std::exchange(other.loop_, nullptr);
        id_ = std::exchange(other.id_, 0);
    }
    return *this;
}

void EventLoop::Timer::cancel() {
    // The heap entry stays and is skipped when it comes due: erasing from the middle of a
    // binary heap is not worth it for the few timers a gateway has.
    if (loop_)
        loop_->timers_.erase(id_);
    loop_ = nullptr;
    id_ = 0;
}

bool EventLoop::Timer::active() const { return loop_ && loop_->timers_.count(id_) != 0; }

// --- EventLoop -----------------------------------------------------------------------------

Result<std::unique_ptr<EventLoop>> EventLoop::create() {
    UniqueFd fd(epoll_create1(EPOLL_CLOEXEC));
    if (!fd)
        return make_error(std::string("epoll_create1: ") + strerror(errno));
    return std::unique_ptr<EventLoop>(new EventLoop(std::move(fd)));
}

EventLoop::EventLoop(UniqueFd epoll_fd) : epoll_fd_(std::move(epoll_fd)) {}

EventLoop::~EventLoop() {
    signal_watch_.reset();
    round_hooks_.clear();
    after_io_hooks_.clear();
}

Result<EventLoop::Watch> EventLoop::watch(int fd, uint32_t events, IoHandler handler) {
    auto record = std::make_unique<WatchRecord>(WatchRecord{fd, events, std::move(handler)});
    epoll_event ev{};
    ev.events = events;
    ev.data.ptr = record.get();
    if (epoll_ctl(epoll_fd_.get(), EPOLL_CTL_ADD, fd, &ev) < 0)
        return make_error(std::string("epoll_ctl(ADD): ") + strerror(errno));
    WatchRecord* raw = record.get();
    watches_.push_back(std::move(record));
    return Watch(this, raw);
}

void EventLoop::modify_watch(WatchRecord* record, uint32_t events) {
    epoll_event ev{};
    ev.events = events;
    ev.data.ptr = record;
    if (epoll_ctl(epoll_fd_.get(), EPOLL_CTL_MOD, record->fd, &ev) < 0) {
        log_error("epoll_ctl(MOD, fd %d): %s", record->fd, strerror(errno));
        return;
    }
    record->events = events;
}

void EventLoop::remove_watch(WatchRecord* record) {
    // The fd may already be closed by its owner; EPOLL_CTL_DEL then fails harmlessly.
    epoll_ctl(epoll_fd_.get(), EPOLL_CTL_DEL, record->fd, nullptr);
    record->dead = true;
    auto it = std::find_if(watches_.begin(), watches_.end(),
                           [record](const auto& r) { return r.get() == record; });
    if (it != watches_.end()) {
        // Events already fetched this round may still point at it: free after the round.
        graveyard_.push_back(std::move(*it));
        watches_.erase(it);
    }
}

EventLoop::Timer EventLoop::schedule(Duration delay, TimerHandler handler) {
    uint64_t id = next_timer_id_++;
    timers_.emplace(id, std::move(handler));
    timer_heap_.push(TimerEntry{Clock::now() + delay, id});
    return Timer(this, id);
}

Result<void> EventLoop::on_signal(int signo, SignalHandler handler) {
    signal_handlers_[signo] = std::move(handler);
    sigset_t mask;
    sigemptyset(&mask);
    for (const auto& [sig, _] : signal_handlers_)
        sigaddset(&mask, sig);
    if (sigprocmask(SIG_BLOCK, &mask, nullptr) < 0)
        return make_error(std::string("sigprocmask: ") + strerror(errno));
    int fd = signalfd(signal_fd_ ? signal_fd_.get() : -1, &mask, SFD_NONBLOCK | SFD_CLOEXEC);
    if (fd < 0)
        return make_error(std::string("signalfd: ") + strerror(errno));
    if (!signal_fd_) {
        signal_fd_.reset(fd);
        auto w = watch(fd, EPOLLIN, [this](uint32_t) { handle_signals(); });
        if (!w)
            return w.error();
        signal_watch_ = std::move(w.value());
    }
    return {};
}

void EventLoop::handle_signals() {
    signalfd_siginfo info;
    while (read(signal_fd_.get(), &info, sizeof info) == static_cast<ssize_t>(sizeof info)) {
        auto it = signal_handlers_.find(static_cast<int>(info.ssi_signo));
        if (it != signal_handlers_.end())
            it->second(static_cast<int>(info.ssi_signo));
    }
}

void EventLoop::add_round_hook(std::function<void()> hook) { round_hooks_.push_back(std::move(hook)); }

void EventLoop::add_after_io_hook(std::function<void()> hook) {
    after_io_hooks_.push_back(std::move(hook));
}

void EventLoop::request_exit(int code) {
    exit_requested_ = true;
    exit_code_ = code;
}

int EventLoop::timeout_ms() const {
    if (timer_heap_.empty())
        return -1;
    // The round that just ended read the clock; its work took microseconds, so a timer may
    // fire that much late, but a wakeup costs one clock read instead of two.
    auto wait = timer_heap_.top().due - now_;
    if (wait <= Duration::zero())
        return 0;
    // Round up so a timer never fires early and spins.
    return static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(wait).count());
}

void EventLoop::run_due_timers() {
    while (!timer_heap_.empty() && timer_heap_.top().due <= now_) {
        TimerEntry entry = timer_heap_.top();
        timer_heap_.pop();
        auto it = timers_.find(entry.id);
        if (it == timers_.end())
            continue;  // cancelled
        // Move the handler out: it may cancel its own Timer (erasing the map entry).
        TimerHandler handler = std::move(it->second);
        Duration next = handler();
        it = timers_.find(entry.id);
        if (it == timers_.end())
            continue;
        if (next <= Duration::zero()) {
            timers_.erase(it);
            continue;
        }
        it->second = std::move(handler);
        timer_heap_.push(TimerEntry{entry.due + next > now_ ? entry.due + next : now_ + next, entry.id});
    }
}

bool EventLoop::run_once(Duration max_wait) {
    if (exit_requested_)
        return false;
    int timeout = timeout_ms();
    int cap = static_cast<int>(std::chrono::ceil<std::chrono::milliseconds>(max_wait).count());
    if (max_wait >= Duration::zero() && (timeout < 0 || timeout > cap))
        timeout = cap;
    if (std::exchange(prompt_round_, false))
        timeout = 0;
    std::array<epoll_event, 64> events;
    polled_after_ = now_;
    const TimePoint waited_from = Clock::now();  // the previous round's end
    if (round_ > 0)
        note_stall(waited_from - now_, false, waited_from);
    int n = epoll_wait(epoll_fd_.get(), events.data(), static_cast<int>(events.size()), timeout);
    if (n < 0) {
        if (errno != EINTR) {
            log_error("epoll_wait: %s", strerror(errno));
            request_exit(1);
        }
        n = 0;
    }
    now_ = Clock::now();
    const Duration late = now_ - (waited_from + milliseconds(timeout));
    if (timeout >= 0 && late > Duration::zero())
        note_stall(late, true, now_);
    // Woken that late (stopped, or held in the kernel), the process may not have what came in
    // meanwhile yet: an epoll_wait resumed after its timeout can return before the sockets'
    // readiness. Timers wait for one more poll, at once, so none judges a link silent that
    // only this process did not hear (the air gateway, held 5.8 s, called LTE lost and back
    // 0.1 s later). Once only: a machine that keeps it that late must not starve its timers.
    const bool timers_wait = timeout >= 0 && late >= kStall && !timers_waited_;
    round_++;
    // A full event array may have left ready fds out: their data waits for the next round,
    // which must come at once.
    all_reported_ = n < static_cast<int>(events.size());
    if (!all_reported_)
        prompt_round_ = true;
    for (int i = 0; i < n; i++)
        static_cast<WatchRecord*>(events[i].data.ptr)->ready_round = round_;
    for (int i = 0; i < n; i++) {
        auto* record = static_cast<WatchRecord*>(events[i].data.ptr);
        if (!record->dead)
            record->handler(events[i].events);
    }
    for (auto& hook : after_io_hooks_)
        hook();
    timers_waited_ = timers_wait;
    if (timers_wait)
        prompt_round_ = true;
    else
        run_due_timers();
    for (auto& hook : round_hooks_)
        hook();
    while (!deferred_.empty()) {
        auto work = std::move(deferred_);
        deferred_.clear();
        for (auto& fn : work)
            fn();
    }
    graveyard_.clear();
    return !exit_requested_;
}

void EventLoop::note_stall(Duration took, bool woke, TimePoint at) {
    Duration& longest = woke ? stalls_.latest_wakeup : stalls_.longest_round;
    longest = std::max(longest, took);
    if (took < kStall)
        return;
    (woke ? stalls_.late_wakeups : stalls_.long_rounds)++;
    if (took < kStallLogged)
        return;
    long_stalls_++;
    if (stall_logged_ != TimePoint{} && at - stall_logged_ < kStallLogEvery)
        return;
    stall_logged_ = at;
    log_warning("event loop %s %.2f s %s; %llu such stall%s of 1 s or more in all",
                woke ? "woke" : "ran one round for", std::chrono::duration<double>(took).count(),
                woke ? "later than its next timer (no CPU, stopped, or held in the kernel: a "
                       "tty's poll waits for its flush worker)"
                     : "(a handler waited in a syscall or work piled up; every frame waited "
                       "behind it)",
                static_cast<unsigned long long>(long_stalls_), long_stalls_ == 1 ? "" : "s");
}

int EventLoop::run() {
    while (run_once(Duration(-1))) {
    }
    return exit_code_;
}

}  // namespace mavbond
