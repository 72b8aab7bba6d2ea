// Link events (`link_events:`): a bond member going silent, coming back, and a bond's active
// link switching are logged once each and told to the GCS as STATUSTEXT from mavbond's own
// identity, rate-limited so a flapping link never makes a storm.
//
// Everything is read from a 100 ms timer (when each member's last frame arrived, what the far
// side reports, each bond's active link): nothing is added to the per-frame path. Silence is
// judged on the arrival clock (Router::arrival_clock), so a daemon that stalled finds the
// frames that came meanwhile, not a silent link, and by routing/link_silence.h, the rule
// standby's reports follow too: a link is silent when it brought nothing for three of its
// usual gaps (never less than silent_after, at most kMaxSilence) while its far side
// evidently wrote on it (a report of the far side's came on another link, not on this one);
// with nothing to go by, the gaps alone.
//
// A link has two directions. This side's reception it judges itself ("downlink" on the side
// facing the ground station, the one that hears the vehicle through the bond; "uplink" on the
// vehicle's); the far side's it knows from the far side's standby reports (a bond with a
// metered member), while they come. Every change of either direction is logged. The GCS is
// told of the link as a whole, once per real change: a radio that dies dies both ways, and
// the far side's report of it comes a moment after this side's own finding, so a link lost
// (or back) one way only is told only once that has held for kSettle: "mavbond: link sik
// lost (bond vehicle, 1 of 2 up)", one way "mavbond: sik uplink lost (vehicle 1/2 up)". With
// no report from the far side (none for kReportTimeout, or a far side that sends none), the
// other direction is taken to go with this one.
//
// The rule for STATUSTEXT, per subject (a link, or a bond's active link):
// - a link heard for the first time, or a bond's first active link, is logged, not announced;
// - at most one message per subject per min_interval: a change within it waits, and when the
//   interval is over the subject's state *then* is sent if it differs from the one last sent
//   (lost-back-lost coalesces into nothing more; lost-back into one "back");
// - at most kGlobalBurst messages in any min_interval overall; the rest wait, oldest first.
//
// Severity: a link lost (either way) while others of its bond are up WARNING, the last one
// lost CRITICAL, a link back (or back one way) NOTICE, an active-link switch WARNING.
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
#include "routing/link_silence.h"
#include "routing/local_source.h"

namespace mavbond {

class Router;

/// The rules above, without a loop, a router or sockets (unit-tested on their own).
class LinkEvents {
public:
    static constexpr size_t kGlobalBurst = 5;
    static constexpr Duration kMaxSilence = seconds(10);
    // A one-way change waits this long for the other way's (the far side's standby judges
    // within 3 s of the report it missed, and reports at once).
    static constexpr Duration kSettle = seconds(5);

    struct Notice {
        Severity severity;
        std::string text;  // at most 50 characters (STATUSTEXT's text field)
        uint32_t bond = 0;
    };
    struct Output {
        std::vector<std::string> events;  // every change seen, for the log
        std::vector<Notice> notices;      // the STATUSTEXTs due now
    };

    LinkEvents(Duration silent_after, Duration min_interval);

    uint32_t add_bond(std::string name);
    uint32_t add_link(uint32_t bond, std::string name);

    /// The silence bounds a link is judged within (LinkSilence::judge): silent_after, and
    /// kMaxSilence or silent_after if that is more.
    Duration least_silence() const { return silent_after_; }
    Duration most_silence() const { return std::max(silent_after_, Duration(kMaxSilence)); }

    /// What this side receives on `link`: its last frame (epoch: never) and whether it is
    /// silent now (LinkSilence), `why` for the log.
    void observe_link(uint32_t link, TimePoint last_rx, bool silent, TimePoint now,
                      const std::string& why = "");
    /// What the far side receives on it, as its standby reports say: up, silent, or nothing
    /// known (no report lately).
    void observe_reported(uint32_t link, std::optional<bool> up, TimePoint now);
    /// Which way the frames this side receives go: "downlink" (from the vehicle), "uplink", or
    /// "" while unknown; the far side's are the other way.
    void set_direction(std::string_view own);
    /// A bond's active link ("" when none is chosen) and its switch count.
    void observe_bond(uint32_t bond, std::string_view active, uint64_t switches, TimePoint now);
    /// The events seen since the last call and the notices the rate limit lets out now.
    Output poll(TimePoint now);

    /// "mavbond: link lte lost (bond telemetry, 1 of 2 up)", shortened to "mavbond: lte lost
    /// (telemetry 1/2 up)" and then cut to fit 50 characters; `what`: "lost", "back",
    /// "uplink lost", ...
    static std::string link_text(std::string_view link, std::string_view what,
                                 std::string_view bond, unsigned up_count, unsigned members);

private:
    enum class State { Never, Up, Lost };
    // The link as a whole: both ways up, both lost, or lost one way only.
    enum class Whole { Never, Up, Lost, OwnLost, FarLost };
    struct Subject {
        std::optional<TimePoint> last_sent;
        TimePoint changed;  // when it last came to differ from what was reported
    };
    struct Link {
        std::string name;
        uint32_t bond;
        State own = State::Never;    // this side's reception
        State far = State::Never;    // the far side's, as it reports (Never: no report lately)
        State far_known = State::Never;  // what its last report said (Never: none came)
        Whole whole = Whole::Never;
        Whole reported = Whole::Never;  // last told the GCS (first heard: as if told Up)
        TimePoint since{};           // when `whole` last changed
        Subject subject;
    };
    struct Bond {
        std::string name;
        std::string active;
        std::string reported;
        uint64_t switches = 0;
        Subject subject;
    };

    static Whole whole_of(const Link& l);
    static bool one_way(Whole w) { return w == Whole::OwnLost || w == Whole::FarLost; }
    unsigned up_count(uint32_t bond, unsigned* members) const;
    /// Follows the whole link after a change of one direction.
    void follow(Link& l, TimePoint now);
    /// Logs a direction's change (`far`: the far side's) from `was` to `state`.
    void log_change(const Link& l, bool far, State was, State state, const std::string& why);
    std::string_view own_direction() const;
    std::string_view far_direction() const;
    /// What a notice says has become of the link: "lost", "back", "uplink lost", ...;
    /// `back`: it (or one way of it) came back.
    std::string what_of(const Link& l, bool* back) const;
    bool may_send(const Subject& s, TimePoint now) const;
    void sent(Subject& s, TimePoint now);

    Duration silent_after_;
    Duration min_interval_;
    std::string direction_;  // of what this side receives
    std::vector<Link> links_;
    std::vector<Bond> bonds_;
    std::deque<TimePoint> recent_;  // send times within the last min_interval (global cap)
    std::vector<std::string> events_;
};

/// Feeds LinkEvents from the router's bonds on a timer: whether each member is silent (by its
/// bond's standby's LinkSilence, which has the far side's reports to go by, or one of its own
/// for a bond without), what the far side reports, which link is active; logs the events and,
/// on the side that
/// announces, sends the notices: as the vehicle's autopilot, numbered into its renumbered
/// stream, where the bond renumbers and its autopilot is heard through it (MAVProxy shows only
/// its target's texts, and a GCS counts the frame in sequence, no gap); else from `identity`
/// through `source`.
class LinkEventMonitor {
public:
    static constexpr Duration kTick = milliseconds(100);

    LinkEventMonitor(const LinkEventsConfig& config, Router& router, EventLoop& loop,
                     LocalSource& source);

    /// Whether this side announces now: link_events.statustext, or when it says nothing,
    /// unless this is the vehicle's side (its autopilot heard outside the bonds): the ground
    /// side announces for both.
    static bool announces(const LinkEventsConfig& config, const Router& router);

private:
    void tick(TimePoint now);
    /// Sends a notice about bond `bond`'s links.
    void announce(uint32_t bond, const LinkEvents::Notice& notice);

    const LinkEventsConfig& config_;
    Router& router_;
    LocalSource& source_;
    LinkEvents events_;
    struct BondLinks {
        std::vector<uint32_t> members;          // per member: its id in events_
        std::unique_ptr<LinkSilence> silence;   // a bond without standby: its own judge
    };
    std::vector<BondLinks> links_;
    EventLoop::Timer timer_;
};

}  // namespace mavbond
