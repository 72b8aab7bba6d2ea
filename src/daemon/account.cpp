#include "daemon/account.h"

#include <cstdio>

#include "routing/link_events.h"

namespace mavbond {
namespace {

std::string seconds_text(Duration d) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%gs",
                  std::chrono::duration_cast<std::chrono::duration<double>>(d).count());
    return buf;
}

}  // namespace

std::vector<std::string> derived_settings(const Config& config, const Router& router,
                                          const FilterChain& chain) {
    std::vector<std::string> lines;
    const IdentityConfig& id = config.identity;
    lines.push_back(
        "identity " + std::to_string(id.sysid) + "/" + std::to_string(id.compid) +
        (id.compid_given ? " (identity: compid): the other gateway of a bond needs another"
                         : std::string(": on the side that hears the vehicle's autopilot through "
                                       "a bond it becomes ") +
                               std::to_string(id.sysid) + "/192, so the two gateways never "
                               "share one (identity: compid fixes it)"));
    for (uint32_t b = 0; b < router.bonds().size(); b++) {
        const Bond& bond = router.bonds()[b];
        const std::string at = "bond " + bond.name() + ": ";
        const BondConfig* cfg = nullptr;
        for (const BondConfig& c : config.bonds)
            cfg = c.name == bond.name() ? &c : cfg;
        if (bond.renumbers())
            lines.push_back(at + "renumbers what it delivers, so a GCS counts as lost only what "
                                 "every link lost (" +
                            (cfg && cfg->renumber ? "renumber: true" : "dedup places every copy; "
                                                                       "renumber: false turns it off") +
                            ")");
        else
            lines.push_back(at + "does not renumber (" +
                            (cfg && cfg->renumber ? std::string("renumber: false")
                                                  : "no dedup filter on it places the copies") +
                            "): a GCS counts each frame a slower link rescues as ~255 lost");
        for (const std::string& line : chain.describe(b))
            lines.push_back(at + line);
        if (const Standby* standby = bond.standby()) {
            // A radio cut is found only after its silence (at most Standby::kMaxSilence) and
            // a report's way back: what went before it and is lost is resent only this far.
            if (cfg && cfg->resend > Duration::zero() && cfg->resend < Standby::kMaxSilence)
                lines.push_back(at + "resend " + seconds_text(cfg->resend) +
                                " is shorter than the " + seconds_text(Standby::kMaxSilence) +
                                " the far side may take to find a radio silent: frames of the "
                                "first part of an outage are not resent (resend: " +
                                seconds_text(Standby::kMaxSilence) + " covers it)");
            for (uint32_t m = 0; m < standby->member_count(); m++) {
                if (standby->metered(m))
                    lines.push_back(at + standby->member_name(m) +
                                    " is metered: in standby it carries " +
                                    standby->carried_in_standby(m) +
                                    ": paid for while the free members are healthy");
            }
        }
        if (config.link_events.enabled) {
            const LinkEventsConfig& ev = config.link_events;
            const LinkEvents rules(ev.silent_after, ev.min_interval);
            lines.push_back(
                at + "a link is lost when it brought nothing for " +
                std::to_string(LinkSilence::kGapFactor) + " of its usual gaps between frames (" +
                seconds_text(LinkSilence::kAssumedGap) + " until seen), at least silent_after " +
                seconds_text(rules.least_silence()) + ", at most " +
                seconds_text(rules.most_silence()) +
                (bond.standby()
                     ? ", while the far side evidently wrote on it (a report it sends on every "
                       "link came on another, not on this one, within this one's usual lag); "
                       "with nothing to go by (no report of the far side's on another link for " +
                           seconds_text(LinkSilence::kEvidenceTimeout) + "), the gaps alone"
                     : "; judged by the gaps alone (no metered member: no far side's reports to "
                       "go by), so a vehicle that pauses its stream that long reads as a lost link") +
                "; told to the GCS " +
                (ev.statustext ? (*ev.statustext ? "by this side (statustext: true)"
                                                 : "by neither side from here (statustext: false)")
                               : "by the side facing it (the one that does not hear the "
                                 "vehicle's autopilot on a link of its own)") +
                ", once per change of the link, both ways as one (one way only once it held " +
                seconds_text(LinkEvents::kSettle) + ")" +
                (bond.renumbers() ? ", as the vehicle's autopilot in its renumbered stream, which "
                                    "MAVProxy, QGroundControl and Mission Planner all show"
                                  : ", from identity: MAVProxy and Mission Planner show only the "
                                    "autopilot's texts (renumbering would let them)"));
        }
    }
    return lines;
}

}  // namespace mavbond
