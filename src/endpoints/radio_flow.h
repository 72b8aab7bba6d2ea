// A radio's own word on what its line carries. SiK radios (3DR, RFD900) put a RADIO_STATUS into
// the serial stream towards the device they are attached to, about once a second, from system
// 51 ('3'), component 68 ('D'); its `txbuf` is the share of the radio's transmit buffer still
// free. ArduPilot slows its streams when it reads a low txbuf and speeds up on a high one
// (GCS_MAVLINK::handle_radio_status). mavbond reads the reports instead, where it can act on
// them per link:
//
//   - RadioFlow sets one link's budget from its radio's reports, additive increase and
//     multiplicative decrease (as TCP does, and for the same reason: a buffer that fills says
//     the rate is too high by an unknown amount, one that stays empty says there is room):
//       txbuf < 20   the rate halves          (the buffer is nearly full)
//       txbuf < 50   the rate loses a quarter
//       txbuf > 90   the rate gains a tenth of the ceiling, up to the ceiling, when the rate
//                    held the stream back since the last report (an empty buffer says
//                    nothing of a rate the sender never used: as TCP's window does not grow
//                    while the application sends less than it allows, RFC 7661)
//       otherwise    it stays
//     never below a sixteenth of the ceiling (control frames go regardless: tx_budget.h). The
//     ceiling is the configured tx_rate (a UART's baud without one). The rate starts at half
//     the ceiling: a line's rate says nothing of the air behind it (a SiK radio on a 57600-baud
//     line airs some 3,600 B/s), and a burst at the line's rate (the first parameter download)
//     overflowed the radio's buffer before its reports could slow it; the reports raise it
//     from there within seconds where the radio has room. A radio that never reports (kStale
//     from the start) and reports that stop for kStale put the rate at the ceiling: nothing is
//     known then, and the line's own rate is what mavbond knows.
//   - bond_report() makes the report the autopilot gets for a whole bond: the bond is
//     redundant, so it can carry the stream while its best member can. See its comment. A
//     member with a budget has a say of its own beside its radio's (budget_room): a radio
//     whose buffer mavbond keeps from filling always looks free, while the budget thins what
//     the autopilot sends beyond it; only the autopilot, slowed, can send less.
#pragma once

#include <cstdint>
#include <optional>
#include <span>

#include "config/config.h"
#include "core/clock.h"
#include "mavlink/frame.h"
#include "mavlink/radio_status.h"

namespace mavbond {

/// Whether `frame` is a report of the radio `source` names (a RADIO_STATUS or RADIO from its
/// system and component).
bool is_radio_report(const Frame& frame, RadioStatusSource source);

class RadioFlow {
public:
    static constexpr Duration kStale = seconds(5);  // as ArduPilot treats a report as stale

    struct Counters {
        uint64_t reports = 0;    // taken from the radio
        uint64_t decreases = 0;  // reports that lowered the rate
        uint64_t increases = 0;  // reports that raised it
        uint64_t stale = 0;      // times the reports stopped and the rate went back up
    };

    /// `ceiling`: the configured rate, bytes a second; `started`: when the link began.
    RadioFlow(uint64_t ceiling, TimePoint started);

    /// A new configured rate (a reload): the rate keeps what the reports made it, within it.
    void set_ceiling(uint64_t ceiling);
    /// Takes a report; `rate_was_limit`: the budget held the stream back since the last one
    /// (thinned samples, a queue waiting). Returns the rate now.
    uint64_t report(const RadioReport& r, TimePoint now, bool rate_was_limit = true);
    /// Puts the rate at the ceiling when no report came for kStale (since the last one, or
    /// since the start); returns the rate now.
    uint64_t check(TimePoint now);

    uint64_t rate() const { return rate_; }
    uint64_t ceiling() const { return ceiling_; }
    uint64_t floor() const;
    /// Whether a report came in the last kStale.
    bool fresh(TimePoint now) const { return counters_.reports != 0 && now - last_at_ < kStale; }
    const RadioReport& last() const { return last_; }
    TimePoint last_at() const { return last_at_; }
    const Counters& counters() const { return counters_; }

private:
    uint64_t ceiling_;
    uint64_t rate_;
    RadioReport last_;
    TimePoint last_at_{};  // the last report's arrival (the start, before the first)
    bool stale_ = false;   // the rate is at the ceiling for want of reports
    Counters counters_;
};

/// A bond member as the bond's report sees it.
struct RadioVote {
    bool reports = false;  // its endpoint has `radio_status`
    bool fresh = false;    // ... and its radio reported within RadioFlow::kStale
    RadioReport last;      // ... what it said last
    bool alive = false;    // a member without reports: it heard its peer lately
    bool standby = false;  // a metered member in standby: control only, no room for streams
    uint8_t room = 100;    // what its budget says, as a txbuf (budget_room); 100 without one
};

/// What a member's budget says of the room for the autopilot's stream, as a RADIO_STATUS
/// txbuf, from what the budget was offered and did over the last report's interval (`load`
/// its TxBudget::Load there, `rate` bytes a second, `span_s` its length in seconds): ArduPilot slows its streams
/// below 50 and speeds them up above 90 (a step of 20 to 60 ms per stream per report), so
///   frames lost (thinned, dropped)  more than a tenth 10, else 40: slow down
///   offered 85 % of the rate or more                    70: hold (one step up would overflow)
///   offered 70 % or more                                92: a small step up
///   less                                               100
/// Every step keeps clear of the next, so the autopilot settles below the rate, not around it.
uint8_t budget_room(uint64_t offered_frames, uint64_t offered_bytes, uint64_t lost, uint64_t rate,
                    double span_s);

/// The report for a whole bond, or nullopt when no member can say. `txbuf` is the best
/// member's: a redundant bond carries the stream while one member can, so the autopilot slows
/// only when none can, and a slow member with a fast partner does not throttle it. A member
/// without radio reports (an LTE link) has no buffer mavbond knows of: it counts as free while
/// it hears its peer, and not at all when it does not, nor while it stands by (a metered
/// member in standby carries control only: the autopilot must slow to what the radio
/// carries, and speeds up again when the metered member is active). The signal fields come from the radio
/// with the most free buffer (ties: the stronger rssi), the error counts are summed over the
/// radios that report.
std::optional<RadioReport> bond_report(std::span<const RadioVote> members);

}  // namespace mavbond
