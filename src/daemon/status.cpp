#include "daemon/status.h"

#include <chrono>

#include "core/log.h"
#include "mavbond_build_config.h"

namespace mavbond {
namespace {

/// Help texts of the endpoint counters, in for_each_counter's names.
const std::map<std::string, const char*>& counter_help() {
    static const std::map<std::string, const char*> help = {
        {"rx_frames", "Frames received whole (CRC checked, or of an unknown id when forwarded)."},
        {"rx_bytes", "Bytes received."},
        {"crc_errors", "Frames received with a bad CRC (dropped)."},
        {"garbage_bytes", "Received bytes that were not part of any frame."},
        {"unknown_ids", "Frames received with a message id the daemon does not know."},
        {"bad_flags", "Frames received with unknown incompatibility flags (dropped)."},
        {"rx_filtered", "Received frames dropped by allow_in/block_in."},
        {"rx_overflows", "Datagrams the kernel dropped because the receive buffer was full."},
        {"tx_frames", "Frames sent."},
        {"tx_bytes", "Bytes sent."},
        {"tx_filtered", "Frames not sent because of allow_out/block_out."},
        {"tx_dropped", "Frames dropped on transmit: queue full, link down or a write error."},
        {"tx_errors", "Hard write errors (ICMP unreachable, EIO, ...)."},
        {"sig_unsigned", "Unsigned frames on a signing endpoint (dropped when signing is required)."},
        {"sig_bad", "Frames dropped because their signature does not verify."},
        {"sig_replay", "Signed frames dropped as replayed or too old."},
        {"tx_signed", "Frames sent with the bond's signature (13 bytes more each)."},
        {"resolve_failures", "Lookups of a client's host name that failed (retried with backoff)."},
        {"address_changes", "Lookups of a client's host name that gave a new address."},
        {"peer_rebinds", "UDP peers that went on from a new address (a NAT rebinding): the old one forgotten."},
        {"stranger_datagrams", "Datagrams to a UDP server from an address that is no peer, with no frame that passed the checks (dropped; the sender stays no peer)."},
        {"peers_evicted", "UDP peers forgotten to make room for a new one (a full peer table: the least recently heard)."},
        {"clients_refused", "TCP connections refused: max_clients_per_address or 32 clients reached."},
        {"clients_idle_closed", "TCP clients closed for bringing no valid frame for idle_timeout."},
        {"routes_evicted", "Routes learned on the endpoint's links forgotten to make room (the per-link cap)."},
        {"markers_foreign", "Count markers that named another link (captured there and replayed, or a far side that names the link otherwise): not counted."},
    };
    return help;
}

/// Help texts of the renumbering counters, in Bond::renumber_counters' names.
const std::map<std::string, const char*>& renumber_help() {
    static const std::map<std::string, const char*> help = {
        {"renumbered", "Frames the bond delivered with a new sequence number."},
        {"gaps", "Sequence numbers skipped on output: frames lost on every link of the bond."},
        {"late_filled", "Frames delivered after a later one, given the number they had kept."},
        {"unplaced", "Frames delivered before dedup could place them in the stream (given the next number)."},
        {"untracked", "Frames of sources beyond the renumbering table (left as they were)."},
        {"signed_left_alone", "Signed frames passed with their own number (the signature covers it)."},
        {"added", "Frames mavbond added to a source's numbering (link events told as the vehicle)."},
    };
    return help;
}

/// Help texts of a signed bond's counters, in their for_each_counter names.
const std::map<std::string, const char*>& signing_help() {
    static const std::map<std::string, const char*> help = {
        {"signed", "Frames this side signed for a bond's signed links."},
        {"verified", "Frames the peer signed for the bond that verified on a member."},
        {"redelivered", "Copies of a signed frame delivered before that the filters let through "
                        "(dedup had forgotten it): not delivered again."},
        {"refused_v1", "MAVLink 1 frames kept off a bond's signed links (they cannot be signed)."},
    };
    return help;
}

/// Help texts of a budget's per-class counters (label `class`), in their for_each_counter names.
const std::map<std::string, const char*>& tx_class_help() {
    static const std::map<std::string, const char*> help = {
        {"frames", "Frames of the class a budgeted endpoint (tx_rate) handed to its line."},
        {"bytes", "Bytes of them, with the link's framing (IP and UDP headers) charged."},
        {"waited", "Of those frames, the ones held for the budget or a cap first."},
        {"thinned", "Telemetry replaced, while held, by a newer sample of the same message."},
        {"dropped", "Bulk dropped (oldest first) from a full queue; telemetry without a slot."},
    };
    return help;
}

/// `text` as a JSON string: quoted, with quotes, backslashes and control characters escaped.
std::string json_string(const std::string& text) {
    std::string out = "\"";
    for (char c : text) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += c;
        } else if (static_cast<unsigned char>(c) < 0x20) {
            char esc[8];
            snprintf(esc, sizeof esc, "\\u%04x", static_cast<unsigned>(c));
            out += esc;
        } else {
            out += c;
        }
    }
    return out + "\"";
}

/// The states an endpoint may be in (Status::Endpoint::state), for /metrics' state set.
constexpr const char* kEndpointStates[] = {"up", "standby", "down", "closed"};

int64_t ms_since(TimePoint t, TimePoint now) {
    return std::chrono::duration_cast<milliseconds>(now - t).count();
}

/// Calls f(name, value) for each field of a RADIO_STATUS, in one order.
template <typename F>
void for_each_field(const RadioReport& r, F&& f) {
    f("txbuf", r.txbuf);
    f("rssi", r.rssi);
    f("remrssi", r.remrssi);
    f("noise", r.noise);
    f("remnoise", r.remnoise);
    f("rxerrors", r.rxerrors);
    f("fixed", r.fixed);
}

std::string report_json(const RadioReport& r) {
    std::string out = "{";
    for_each_field(r, [&out](const char* name, uint64_t v) {
        out += std::string(out.size() == 1 ? "\"" : ",\"") + name + "\":" + std::to_string(v);
    });
    return out + "}";
}

/// An endpoint's `radio_status` object: its radio's last report and what the reports made of
/// its budget.
std::string radio_json(const RadioFlow& r, TimePoint now) {
    const RadioFlow::Counters& c = r.counters();
    return ",\"radio_status\":{\"reports\":" + std::to_string(c.reports) +
           ",\"decreases\":" + std::to_string(c.decreases) +
           ",\"increases\":" + std::to_string(c.increases) +
           ",\"stale\":" + std::to_string(c.stale) + ",\"rate\":" + std::to_string(r.rate()) +
           ",\"ceiling\":" + std::to_string(r.ceiling()) + ",\"floor\":" +
           std::to_string(r.floor()) + ",\"age_ms\":" +
           std::to_string(c.reports ? ms_since(r.last_at(), now) : -1) + ",\"last\":" +
           (c.reports ? report_json(r.last()) : "null") + "}";
}

int64_t whole_ms(Duration d) { return std::chrono::duration_cast<milliseconds>(d).count(); }

}  // namespace

Status::Endpoint endpoint_status(const Endpoint& e, TimePoint now, Duration silent_after) {
    Status::Endpoint out{e.name(), e.kind(), e.config().bond,
                         e.config().signing.enabled && e.config().signing.require,
                         e.budget() ? e.budget()->bytes_per_s() : 0, e.total_counters(), {},
                         e.open_error()};
    if (e.radio())
        out.radio = *e.radio();
    e.for_each_link([&out](const Link& link) {
        out.standby = out.standby || link.standby();
        out.peer_standby = out.peer_standby || (link.account().exact() && link.account().peer_standby());
    });
    const TimePoint last = out.counters.last_rx;
    out.state = !out.open_error.empty()                                         ? "closed"
                : !out.bond.empty() && (last == TimePoint{} || now - last > silent_after) ? "down"
                : out.standby || out.peer_standby                               ? "standby"
                                                                                : "up";
    return out;
}

std::string status_json(const Status& s) {
    std::string out = "{\"version\":\"" MAVBOND_VERSION "\",\"uptime_s\":" +
                      std::to_string(std::chrono::duration_cast<seconds>(s.uptime).count()) +
                      ",\"status_refused\":" + std::to_string(s.status_refused) + ",\"event_loop\":{" +
                      "\"longest_round_ms\":" + std::to_string(whole_ms(s.stalls.longest_round)) +
                      ",\"long_rounds\":" + std::to_string(s.stalls.long_rounds) +
                      ",\"latest_wakeup_ms\":" + std::to_string(whole_ms(s.stalls.latest_wakeup)) +
                      ",\"late_wakeups\":" + std::to_string(s.stalls.late_wakeups) +
                      "},\"endpoints\":[";
    for (size_t i = 0; i < s.endpoints.size(); i++) {
        const Status::Endpoint& e = s.endpoints[i];
        out += std::string(i ? "," : "") + "{\"name\":\"" + e.name + "\",\"kind\":\"" + e.kind +
               "\",\"bond\":\"" + e.bond + "\",\"state\":\"" + e.state + "\",\"open\":" +
               (e.open_error.empty() ? "true" : "false");
        if (!e.open_error.empty())
            out += ",\"open_error\":" + json_string(e.open_error);
        out += std::string(",\"standby\":") + (e.standby ? "true" : "false") +
               ",\"peer_standby\":" + (e.peer_standby ? "true" : "false");
        for_each_counter(e.counters, [&out](const char* name, uint64_t value) {
            out += std::string(",\"") + name + "\":" + std::to_string(value);
        });
        // Milliseconds since a frame last came in; -1: never.
        TimePoint last = e.counters.last_rx;
        out += ",\"last_rx_ms_ago\":" +
               std::to_string(last == TimePoint{} ? -1 : ms_since(last, s.taken));
        if (e.tx_rate) {
            out += ",\"tx_budget\":{\"rate\":" + std::to_string(e.tx_rate);
            for (size_t c = 0; c < kTxClassCount; c++) {
                out += std::string(",\"") + kTxClassNames[c] + "\":{";
                for_each_counter(e.counters.tx_class[c], [&out](const char* name, uint64_t v) {
                    out += std::string(out.back() == '{' ? "\"" : ",\"") + name + "\":" +
                           std::to_string(v);
                });
                out += "}";
            }
            out += "}";
        }
        if (e.radio)
            out += radio_json(*e.radio, s.taken);
        out += "}";
    }
    out += "],\"bonds\":[";
    for (size_t i = 0; i < s.bonds.size(); i++) {
        const Status::Bond& b = s.bonds[i];
        out += std::string(i ? "," : "") + "{\"name\":\"" + b.name + "\",\"tx\":\"" +
               (b.tx_active ? "active" : "broadcast") + "\",\"active\":\"" + b.active +
               "\",\"switches\":" + std::to_string(b.switches);
        out += ",\"numbering\":{\"numbered\":" + std::to_string(b.numbering.numbered) +
               ",\"expired\":" + std::to_string(b.numbering.expired) +
               ",\"untracked\":" + std::to_string(b.numbering.untracked) +
               ",\"superseded\":" + std::to_string(b.numbering.superseded) + "}";
        if (!b.renumber.empty()) {
            out += ",\"renumber\":{";
            for (const auto& [name, value] : b.renumber)
                out += std::string(out.back() == '{' ? "\"" : ",\"") + name + "\":" +
                       std::to_string(value);
            out += "}";
        }
        if (b.reports_radio_status)
            out += ",\"radio_status\":{\"sent\":" + std::to_string(b.radio_status_sent) +
                   ",\"foreign\":" + std::to_string(b.foreign_radio_status) + ",\"last\":" +
                   (b.radio_status_last ? report_json(*b.radio_status_last) : "null") + "}";
        if (b.has_standby) {
            const Standby::Counters& c = b.standby;
            out += std::string(",\"standby\":{\"state\":\"") +
                   (b.standby_active ? "active" : "standby") +
                   "\",\"metered_tx_bytes\":" + std::to_string(b.metered_tx_bytes) +
                   ",\"to_active\":" + std::to_string(c.to_active) +
                   ",\"to_standby\":" + std::to_string(c.to_standby) +
                   ",\"withheld\":" + std::to_string(c.withheld) +
                   ",\"resent\":" + std::to_string(c.resent) +
                   ",\"resend_skipped\":" + std::to_string(c.resend_skipped) +
                   ",\"reports_sent\":" + std::to_string(c.reports_sent) +
                   ",\"reports_received\":" + std::to_string(c.reports_received) +
                   ",\"reports_ignored\":" + std::to_string(c.reports_ignored) +
                   ",\"peer_loss_permille\":{";
            for (size_t k = 0; k < b.peer_loss.size(); k++)
                out += std::string(k ? "," : "") + "\"" + b.peer_loss[k].first +
                       "\":" + std::to_string(b.peer_loss[k].second);
            out += "}}";
        }
        if (!b.signed_links.empty()) {
            out += ",\"signing\":{\"links\":[";
            for (size_t k = 0; k < b.signed_links.size(); k++)
                out += std::string(k ? "," : "") + "\"" + b.signed_links[k] + "\"";
            out += "]";
            for_each_counter(b.signing, [&out](const char* name, uint64_t v) {
                out += std::string(",\"") + name + "\":" + std::to_string(v);
            });
            out += "}";
        }
        out += "}";
    }
    out += "],\"standby_reports_dropped\":" + std::to_string(s.standby_reports_dropped) +
           ",\"filters\":[";
    for (size_t i = 0; i < s.filters.size(); i++) {
        const FilterReport& f = s.filters[i];
        out += std::string(i ? "," : "") + "{\"name\":\"" + f.name + "\",\"plugin\":\"" + f.plugin +
               "\",\"dropped\":" + std::to_string(f.dropped);
        if (!f.status_json.empty())
            out += ",\"status\":" + f.status_json;
        out += "}";
    }
    return out + "]}";
}

MetricSet status_metrics(const Status& s) {
    MetricSet set;
    set.gauge("mavbond_build_info", "Always 1; the version in a label.", 1,
              {{"version", MAVBOND_VERSION}});
    set.gauge("mavbond_uptime_seconds", "Seconds since the daemon started.",
              std::chrono::duration<double>(s.uptime).count());
    // One family per counter, one sample per configured endpoint (a server's with every peer
    // or connection it has had).
    for (const Status::Endpoint& e : s.endpoints) {
        MetricLabels labels{{"endpoint", e.name}, {"kind", e.kind}, {"bond", e.bond}};
        set.gauge("mavbond_endpoint_open",
                  "1 while the endpoint is open (a UART opened, a TCP client connected, a name "
                  "resolved); the status socket says why not.",
                  e.open_error.empty() ? 1 : 0, labels);
        for (const char* state : kEndpointStates) {
            MetricLabels with_state = labels;
            with_state.emplace_back("state", state);
            set.gauge("mavbond_endpoint_state",
                      "1 for the state an endpoint is in: up, standby (either side keeps it to "
                      "control), down (a bond member its far side is not heard on), closed.",
                      e.state == state ? 1 : 0, with_state);
        }
        for_each_counter(e.counters, [&](const char* name, uint64_t value) {
            auto help = counter_help().find(name);
            set.counter(std::string("mavbond_endpoint_") + name,
                        help == counter_help().end() ? name : help->second, value, labels);
        });
        if (e.tx_rate) {
            set.gauge("mavbond_endpoint_tx_rate_bytes",
                      "The endpoint's transmit budget (tx_rate), bytes a second.",
                      static_cast<double>(e.tx_rate), labels);
            for (size_t c = 0; c < kTxClassCount; c++) {
                MetricLabels with_class = labels;
                with_class.emplace_back("class", kTxClassNames[c]);
                for_each_counter(e.counters.tx_class[c], [&](const char* name, uint64_t v) {
                    set.counter(std::string("mavbond_endpoint_tx_class_") + name,
                                tx_class_help().at(name), v, with_class);
                });
            }
        }
        if (e.radio) {
            const RadioFlow& r = *e.radio;
            set.counter("mavbond_endpoint_radio_reports",
                        "RADIO_STATUS reports taken from the radio on the endpoint.",
                        r.counters().reports, labels);
            set.gauge("mavbond_endpoint_radio_rate_bytes",
                      "The budget the radio's reports set (radio_status), bytes a second.",
                      static_cast<double>(r.rate()), labels);
            set.gauge("mavbond_endpoint_radio_ceiling_bytes",
                      "The rate the radio's reports set the budget below, bytes a second.",
                      static_cast<double>(r.ceiling()), labels);
            if (r.counters().reports != 0) {
                for_each_field(r.last(), [&](const char* name, uint64_t v) {
                    set.gauge(std::string("mavbond_endpoint_radio_") + name,
                              "A field of the radio's last RADIO_STATUS.", static_cast<double>(v),
                              labels);
                });
            }
        }
        // "Last heard" for alerts on a silent link; absent until the first frame.
        if (e.counters.last_rx != TimePoint{})
            set.gauge("mavbond_endpoint_last_rx_age_seconds",
                      "Seconds since a frame last came in on the endpoint.",
                      std::chrono::duration<double>(s.taken - e.counters.last_rx).count(), labels);
    }
    set.counter("mavbond_router_frames_routed", "Frames the router handled (after ingress filters).",
                s.frames_routed);
    set.counter("mavbond_router_frames_without_destination",
                "Frames that had nowhere to go (no other endpoint, or an unknown target).",
                s.frames_without_destination);
    set.counter("mavbond_router_frames_held_back",
                "Frames of a bond's link that waited for its other links to be read up to "
                "their arrival (arrival order): most frames of a UART or TCP member, for one "
                "loop round; a datagram only after a stall or a burst.",
                s.frames_held_back);
    const char* active_help = "1 for the active link of a bond (tx: active), 0 for its others.";
    set.declare("mavbond_bond_active_link", active_help, MetricSet::Type::Gauge);
    for (const Status::Bond& b : s.bonds) {
        set.counter("mavbond_bond_switches", "Changes of a bond's active link.", b.switches,
                    {{"bond", b.name}});
        set.gauge("mavbond_bond_tx_active", "1 when the bond sends on its active link only.",
                  b.tx_active ? 1 : 0, {{"bond", b.name}});
        for (const Status::BondLink& l : b.links)
            set.gauge("mavbond_bond_active_link", active_help, l.active ? 1 : 0,
                      {{"bond", b.name}, {"link", l.name}});
        for (const auto& [name, value] : b.renumber)
            set.counter(std::string("mavbond_renumber_") + name, renumber_help().at(name), value,
                        {{"bond", b.name}});
        set.counter("mavbond_bond_numbered",
                    "Frames the bond numbered as their first copy went (frames it never sent take "
                    "no number).", b.numbering.numbered, {{"bond", b.name}});
        set.counter("mavbond_bond_numbering_expired",
                    "Frames that waited so long their ticket was reused: given a fresh number.",
                    b.numbering.expired, {{"bond", b.name}});
        set.counter("mavbond_bond_numbering_untracked",
                    "Frames of sources beyond the bond's numbering table: sent as they came.",
                    b.numbering.untracked, {{"bond", b.name}});
        set.counter("mavbond_bond_numbering_superseded",
                    "Held copies not sent: another link carried their frame so long before that "
                    "the far side could not place them.", b.numbering.superseded, {{"bond", b.name}});
        if (b.reports_radio_status) {
            set.counter("mavbond_bond_radio_status_sent",
                        "RADIO_STATUS frames mavbond sent the local side for the bond.",
                        b.radio_status_sent, {{"bond", b.name}});
            set.counter("mavbond_bond_radio_status_foreign",
                        "RADIO_STATUS frames not from a member's own radio, dropped.",
                        b.foreign_radio_status, {{"bond", b.name}});
            if (b.radio_status_last)
                set.gauge("mavbond_bond_radio_txbuf",
                          "The txbuf of the last RADIO_STATUS sent for the bond, percent.",
                          b.radio_status_last->txbuf, {{"bond", b.name}});
        }
        if (b.has_standby) {
            const Standby::Counters& c = b.standby;
            const MetricLabels bond{{"bond", b.name}};
            set.gauge("mavbond_standby_active",
                      "1 while a bond's metered links carry everything, 0 in standby.",
                      b.standby_active ? 1 : 0, bond);
            set.counter("mavbond_standby_metered_tx_bytes",
                        "Bytes sent on a bond's metered links (cost: metered).", b.metered_tx_bytes,
                        bond);
            set.counter("mavbond_standby_to_active",
                        "Times a bond's metered links left standby (the free links failing).",
                        c.to_active, bond);
            set.counter("mavbond_standby_to_standby",
                        "Times a bond's metered links went back to standby.", c.to_standby, bond);
            set.counter("mavbond_standby_withheld",
                        "Frames standby kept off a metered link.", c.withheld, bond);
            set.counter("mavbond_standby_resent",
                        "Frames standby held back and sent on a metered link when it went active.",
                        c.resent, bond);
            set.counter("mavbond_standby_resend_skipped",
                        "Frames standby held back and did not resend: further back than the "
                        "metered link's numbering of their source can place.",
                        c.resend_skipped, bond);
            set.counter("mavbond_standby_reports_sent",
                        "Link loss reports sent to the peer (NAMED_VALUE_INT).", c.reports_sent, bond);
            set.counter("mavbond_standby_reports_received",
                        "Link loss reports received from the peer.", c.reports_received, bond);
            set.counter("mavbond_standby_reports_ignored",
                        "Reports received that named no free link of the bond (ignored).",
                        c.reports_ignored, bond);
            for (const auto& [link, permille] : b.peer_loss)
                set.gauge("mavbond_standby_peer_loss_ratio",
                          "A free link's loss as the peer last reported it (1: silent).",
                          permille / 1000.0, {{"bond", b.name}, {"link", link}});
        }
    }
    for (const Status::Bond& b : s.bonds) {
        if (b.signed_links.empty())
            continue;
        for_each_counter(b.signing, [&](const char* name, uint64_t v) {
            set.counter(std::string("mavbond_bond_") + name, signing_help().at(name), v,
                        {{"bond", b.name}});
        });
    }
    set.gauge("mavbond_event_loop_longest_round_seconds",
              "The longest round of the event loop (its handlers, hooks and timers): a handler "
              "that waited in a syscall held every frame behind it that long.",
              std::chrono::duration<double>(s.stalls.longest_round).count());
    set.counter("mavbond_event_loop_long_rounds",
                "Rounds of the event loop that took 100 ms or more.", s.stalls.long_rounds);
    set.gauge("mavbond_event_loop_latest_wakeup_seconds",
              "How much later than its next timer the event loop woke at worst: the process "
              "had no CPU (a busy machine), was stopped, or the kernel held it in a UART's poll.",
              std::chrono::duration<double>(s.stalls.latest_wakeup).count());
    set.counter("mavbond_event_loop_late_wakeups",
                "Wakeups of the event loop 100 ms or more later than its next timer.",
                s.stalls.late_wakeups);
    set.counter("mavbond_standby_reports_dropped",
                "Standby reports (mbl:) no bond took: from outside every bond, or on a bond "
                "without a metered link. Never routed on.",
                s.standby_reports_dropped);
    set.declare(kFilterDroppedMetric, kFilterDroppedHelp, MetricSet::Type::Counter);
    // The chain checked its samples against one another; one that clashes with a family of
    // the host's (a plugin named like one) is left out.
    for (const FilterReport& f : s.filters) {
        for (const MetricSample& sample : f.samples) {
            if (auto r = set.add(sample); !r)
                log_debug("metrics: %s", r.error().message.c_str());
        }
    }
    return set;
}

std::string counters_line(const Status::Endpoint& e, const char* what) {
    std::string line = std::string(what) + " endpoint=" + e.name + " kind=" + e.kind;
    for_each_counter(e.counters, [&line](const char* name, uint64_t value) {
        line += std::string(" ") + name + "=" + std::to_string(value);
    });
    if (e.tx_rate) {
        line += " tx_rate=" + std::to_string(e.tx_rate);
        for (size_t c = 0; c < kTxClassCount; c++) {
            for_each_counter(e.counters.tx_class[c], [&](const char* name, uint64_t value) {
                line += std::string(" ") + kTxClassNames[c] + "_" + name + "=" +
                        std::to_string(value);
            });
        }
    }
    return line;
}

void ProblemReport::run(const Status& status, Duration interval) {
    double secs = std::chrono::duration<double>(interval).count();
    for (const Status::Endpoint& e : status.endpoints) {
        const LinkCounters& now = e.counters;
        LinkCounters& was = last_[e.name];
        std::string what;
        auto add = [&what](uint64_t delta, const char* label) {
            if (delta == 0)
                return;
            if (!what.empty())
                what += ", ";
            what += std::to_string(delta) + " " + label;
        };
        add(now.rx.crc_errors - was.rx.crc_errors, "CRC errors");
        add(now.rx.garbage_bytes - was.rx.garbage_bytes, "garbage bytes");
        add(now.rx.unknown_ids - was.rx.unknown_ids, "unknown message ids");
        add(now.rx.bad_flags - was.rx.bad_flags, "frames with unknown incompat flags");
        add(now.rx_overflows - was.rx_overflows,
            "datagrams dropped by the kernel (receive buffer full: raise rx_buffer)");
        add(now.tx_dropped - was.tx_dropped, "frames dropped on transmit");
        add(now.tx_errors - was.tx_errors, "write errors");
        add(now.sig_unsigned - was.sig_unsigned,
            e.signing_required ? "unsigned frames dropped" : "unsigned frames let through");
        add(now.sig_bad - was.sig_bad, "frames with a bad signature dropped");
        add(now.sig_replay - was.sig_replay, "replayed or stale signed frames dropped");
        add(now.stranger_datagrams - was.stranger_datagrams,
            "datagrams from strangers dropped (no frame that passed the checks)");
        add(now.peers_evicted - was.peers_evicted, "peers forgotten to make room for new ones");
        add(now.clients_refused - was.clients_refused,
            "connections refused (max_clients_per_address or 32 clients)");
        add(now.clients_idle_closed - was.clients_idle_closed,
            "clients closed for bringing no valid frame (idle_timeout)");
        add(now.routes_evicted - was.routes_evicted,
            "routes forgotten to make room (more than 128 systems and components on one link)");
        add(now.markers_foreign - was.markers_foreign,
            "count markers naming another link ignored (name the bond's links alike on both "
            "sides; else one captured on another link)");
        if (!what.empty())
            log_notice("[%s] %s in the last %.0fs", e.name.c_str(), what.c_str(), secs);
        was = now;
    }
}

}  // namespace mavbond
