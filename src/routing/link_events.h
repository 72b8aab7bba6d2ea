// Link events (`link_events:`): a bond member going silent, coming back, and a bond's active
// link switching are logged once each and told to the GCS as STATUSTEXT from mavbond's own
// identity, rate-limited so a flapping link never makes a storm.
//
// Everything is read from a 100 ms timer (when each member's last frame arrived, each bond's
// active link): nothing is added to the per-frame path. Silence is judged on the arrival clock
// (Router::arrival_clock), so a daemon that stalled finds the frames that came meanwhile, not
// a silent link.
//
// The rule for STATUSTEXT, per subject (a link, or a bond's active link):
// - a link heard for the first time, or a bond's first active link, is logged, not announced;
// - at most one message per subject per min_interval: a change within it waits, and when the
//   interval is over the subject's state *then* is sent if it differs from the one last sent
//   (lost-back-lost coalesces into nothing more; lost-back into one "back");
// - at most kGlobalBurst messages in any min_interval overall; the rest wait, oldest first.
//
// Severity: a link lost while others of its bond are up WARNING, the last one lost CRITICAL,
// a link back NOTICE, an active-link switch WARNING.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "config/config.h"
#include "core/clock.h"
#include "core/event_loop.h"
#include "routing/local_source.h"

namespace mavbond {

class Router;

/// The rules above, without a loop, a router or sockets (unit-tested on their own).
class LinkEvents {
public:
    static constexpr size_t kGlobalBurst = 5;

    struct Notice {
        Severity severity;
        std::string text;  // at most 50 characters (STATUSTEXT's text field)
    };
    struct Output {
        std::vector<std::string> events;  // every change seen, for the log
        std::vector<Notice> notices;      // the STATUSTEXTs due now
    };

    LinkEvents(Duration silent_after, Duration min_interval);

    uint32_t add_bond(std::string name);
    uint32_t add_link(uint32_t bond, std::string name);

    /// When a link's last frame arrived (epoch: never), as of `now` on the arrival clock
    /// (every tick): a stalled daemon finds its links' frames arrived, not silence.
    void observe_link(uint32_t link, TimePoint last_rx, TimePoint now);
    /// A bond's active link ("" when none is chosen) and its switch count.
    void observe_bond(uint32_t bond, std::string_view active, uint64_t switches, TimePoint now);
    /// The events seen since the last call and the notices the rate limit lets out now.
    Output poll(TimePoint now);

    /// "mavbond: link lte lost (bond telemetry, 1 of 2 up)", shortened to fit 50 characters.
    static std::string link_text(std::string_view link, bool up, std::string_view bond,
                                 unsigned up_count, unsigned members);

private:
    enum class State { Never, Up, Lost };
    struct Subject {
        std::optional<TimePoint> last_sent;
        TimePoint changed;  // when it last came to differ from what was reported
    };
    struct Link {
        std::string name;
        uint32_t bond;
        TimePoint last_heard;
        State state = State::Never;
        State reported = State::Never;
        Subject subject;
    };
    struct Bond {
        std::string name;
        std::string active;
        std::string reported;
        uint64_t switches = 0;
        Subject subject;
    };

    unsigned up_count(uint32_t bond, unsigned* members) const;
    bool may_send(const Subject& s, TimePoint now) const;
    void sent(Subject& s, TimePoint now);

    Duration silent_after_;
    Duration min_interval_;
    std::vector<Link> links_;
    std::vector<Bond> bonds_;
    std::deque<TimePoint> recent_;  // send times within the last min_interval (global cap)
    std::vector<std::string> events_;
};

/// Feeds LinkEvents from the router's bonds on a timer: when each member was last heard and
/// which link is active; logs the events and sends the notices through `source` (when
/// link_events.statustext is on).
class LinkEventMonitor {
public:
    static constexpr Duration kTick = milliseconds(100);

    LinkEventMonitor(const LinkEventsConfig& config, const Router& router, EventLoop& loop,
                     LocalSource& source);

private:
    void tick(TimePoint now);

    const LinkEventsConfig& config_;
    const Router& router_;
    LocalSource& source_;
    LinkEvents events_;
    std::vector<std::vector<uint32_t>> links_;  // per bond, per member: its id in events_
    EventLoop::Timer timer_;
};

}  // namespace mavbond
