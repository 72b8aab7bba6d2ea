// The exact account of one link between two mavbond gateways: how many frames the far side
// wrote on it against how many arrived.
//
// A receiver cannot tell a frame lost on a link from one the sender never put on it: on a bond
// the sender decides what each link carries (a budget thins telemetry, standby keeps a metered
// link to control, block_out), and a sequence gap looks the same either way. So each side
// tells the other, in band, how many frames it has written on the link: a count marker, a
// frame of its own that the endpoint writes at the moment it goes on the wire, ahead of
// everything not yet begun there, carrying the number of frames written whole before it. On a
// FIFO link, when the marker arrives everything written before it has arrived or been lost:
// frames written minus frames received is the link's loss at that instant, exactly, with no
// timing to guess. (A link that reorders, as UDP over the internet may, moves a frame from one
// marker's interval to the next: the running totals stay exact within the frames in flight.)
//
// The marker is a NAMED_VALUE_INT (common.xml; no target, so stock routers pass it on, and it
// means nothing to an autopilot or a GCS):
//   time_boot_ms  the sending link's session: fixed for the life of the link that counts (a new
//                 value: its count started again from 0)
//   value         frames written on the link before the marker, modulo 2^32 (markers included)
//   name          "mbw:" + the first 6 characters of the sender's endpoint name while it sends
//                 the link everything routed to it, "mbs:" while it keeps the link in standby
// A receiving mavbond consumes it on the link it came on (it is never routed). A radio's own
// RADIO_STATUS (a SiK radio's, system 51 component 68) is counted on neither side: the
// receiver's radio puts it into the stream, the far side never wrote it.
#pragma once

#include <algorithm>
#include <cstdint>
#include <span>
#include <string_view>

#include "core/clock.h"
#include "mavlink/frame.h"
#include "mavlink/frame_writer.h"
#include "mavlink/radio_status.h"

namespace mavbond {

/// What one count marker says.
struct CountMarker {
    uint32_t written = 0;   // frames written on the link before it, modulo 2^32
    uint32_t session = 0;   // fixed for the life of the sending link
    bool standby = false;   // the sender keeps the link in standby (control only)
    std::string_view link;  // the sender's endpoint name, its first 6 characters (read only)

    /// Whether it is a marker of the link named `endpoint` (its first 6 characters): a
    /// marker counts only on the link it was written for, so one captured on another link of
    /// the bond and sent again here, signed as it is, moves no figure.
    bool names(std::string_view endpoint) const {
        return link == endpoint.substr(0, std::min<size_t>(endpoint.size(), 6));
    }
};

/// How often a link writes a marker while it writes frames (none while it writes nothing).
constexpr Duration kCountMarkerEvery = seconds(1);

/// Whether `frame` is a count marker; its fields in `out`.
bool read_count_marker(const Frame& frame, CountMarker& out);

/// Writes `marker` as a whole MAVLink 2 frame from `source` into `out` (at least kMaxFrameLen
/// bytes); `link`: the sender's endpoint name. Returns its length, the same for every marker of
/// one link (only the counts change).
size_t write_count_marker(std::span<uint8_t> out, FrameSource source, std::string_view link,
                          const CountMarker& marker);

/// The length write_count_marker gives the markers of endpoint `link`.
size_t count_marker_length(std::string_view link);

/// Whether the bytes of a whole frame are a radio's own RADIO_STATUS (neither side counts it).
bool is_radio_own_report(const uint8_t* frame);
/// The same of a parsed frame (its header, not its bytes, is read).
inline bool is_radio_own_report(const Frame& frame) {
    return frame.sysid == kSikSysid && frame.compid == kSikCompid && is_radio_status(frame.msgid);
}

/// The receiving side of one link's account: the frames that came in, against what the far
/// side's markers say it wrote. Counts only grow; a new session of the sender (its link
/// restarted its count) goes on from where the last one's figures stood.
///
/// Two readings: at the last marker (expected, received: what standby compares from marker to
/// marker), and now (expected_now, received_now: what the operator is shown). A frame that came
/// in after the last marker was written and arrived; left out, a second of a lossy link's
/// frames was missing from what it was expected to bring (a radio losing 18 % read 18.56 %
/// where it had lost 18.27 % of what it was given). A loss among them is only known at the
/// next marker: the loss now is the loss at the last marker.
class LinkAccount {
public:
    /// A frame came in on the link (the far side's: not a radio's own report).
    void frame_in() { received_++; }
    /// A count marker came in at `arrival` (it is one of the frames the far side counts).
    void take_marker(const CountMarker& marker, TimePoint arrival);
    /// This link carries on `older`'s (a UDP peer whose NAT gave it a new port): what `older`
    /// counted goes on here, followed by what this one counted so far (its frames, and the
    /// markers it took while the move was being judged: the far side's count, if the same,
    /// goes on across the move, so what was lost in it is counted), and `older` is marked
    /// moved.
    void continue_from(LinkAccount& older);
    /// Whether another link carries this one's account on (continue_from): its figures are
    /// that one's, not to be summed with them.
    bool moved() const { return moved_; }

    /// Whether the far side counts: a marker came, the figures below are exact.
    bool exact() const { return markers_ != 0; }
    /// Frames the far side wrote on the link, as far as its markers tell, since the first.
    uint64_t expected() const { return expected_done_ + (written_ - session_written_); }
    /// Of them, the frames that arrived before the marker that told (every later marker
    /// included, so it only grows).
    uint64_t received() const { return received_done_ + (at_marker_ - session_received_); }
    /// expected - received: below 0 while a frame written after a marker overtook it.
    int64_t lost() const {
        return static_cast<int64_t>(expected()) - static_cast<int64_t>(received());
    }
    /// As expected() and received(), and every frame that came in since the last marker.
    uint64_t expected_now() const { return expected() + since_marker(); }
    uint64_t received_now() const { return received() + since_marker(); }
    /// When the last marker arrived (epoch: never).
    TimePoint last_marker() const { return last_marker_at_; }
    /// What the last marker said of the far side's use of the link.
    bool peer_standby() const { return peer_standby_; }
    uint64_t markers() const { return markers_; }
    /// Markers the far side wrote that came after a later one (a reordering link): not taken.
    uint64_t markers_late() const { return markers_late_; }
    /// Times the far side's count started again (its link restarted).
    uint64_t sessions() const { return sessions_; }

private:
    uint64_t since_marker() const { return received_ - at_marker_; }

    uint64_t received_ = 0;          // every frame in, markers included
    uint64_t markers_ = 0;
    uint64_t markers_late_ = 0;
    uint64_t sessions_ = 0;
    uint32_t session_ = 0;
    uint64_t written_ = 0;           // the session's count, unwrapped
    uint64_t session_written_ = 0;   // ... at its first marker
    uint64_t session_received_ = 0;  // received_ at the session's first marker
    uint64_t at_marker_ = 0;         // received_ at the last marker
    uint64_t expected_done_ = 0;     // of the sessions before this one
    uint64_t received_done_ = 0;
    uint32_t first_session_ = 0;     // the first marker's session and count
    uint32_t first_written_ = 0;
    uint64_t before_first_ = 0;      // received_ at the first marker
    TimePoint last_marker_at_{};
    bool peer_standby_ = false;
    bool moved_ = false;
};

}  // namespace mavbond
