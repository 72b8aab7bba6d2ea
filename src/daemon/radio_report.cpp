#include "daemon/radio_report.h"

#include "routing/local_source.h"

namespace mavbond {

RadioStatusReporter::RadioStatusReporter(EventLoop& loop, Router& router,
                                         const std::vector<Endpoint::Ptr>& endpoints)
    : loop_(loop), router_(router), endpoints_(endpoints) {
    timer_ = loop_.schedule(kInterval, [this] {
        report();
        return kInterval;
    });
}

const RadioStatusReporter::BondReports* RadioStatusReporter::find(const std::string& bond) const {
    for (const BondReports& b : bonds_) {
        if (b.bond == bond)
            return &b;
    }
    return nullptr;
}

RadioStatusReporter::BondReports& RadioStatusReporter::entry(const std::string& bond) {
    for (BondReports& b : bonds_) {
        if (b.bond == bond)
            return b;
    }
    return bonds_.emplace_back(BondReports{bond});
}

void RadioStatusReporter::report() {
    const TimePoint now = loop_.now();
    for (const Bond& bond : router_.bonds()) {
        if (!bond.reports_radio_status)
            continue;
        votes_.clear();
        const Standby* standby = bond.standby();
        for (const Endpoint::Ptr& e : endpoints_) {
            if (e->config().bond != bond.name())
                continue;
            RadioVote& v = votes_.emplace_back();
            v.room = e->take_budget_room(now);
            if (const RadioFlow* radio = e->radio()) {
                v.reports = true;
                v.fresh = radio->fresh(now);
                v.last = radio->last();
            } else {
                TimePoint heard = e->total_counters().last_rx;
                v.alive = heard != TimePoint{} && now - heard < kAlive;
                const uint32_t member = bond.member_index(e->config().name);
                v.standby = standby && member != Bond::kNoMember && standby->metered(member) &&
                            !standby->active();
            }
        }
        std::optional<RadioReport> r = bond_report(votes_);
        if (!r)
            continue;  // nothing known: ArduPilot takes silence as a free buffer after 5 s
        auto payload = r->encode();
        if (!inject_local_frame(router_, FrameSource{kSikSysid, kSikCompid, seq_}, kMsgRadioStatus,
                                payload, Router::Reach::OutsideBonds))
            continue;
        seq_++;
        BondReports& b = entry(bond.name());
        b.sent++;
        b.last = r;
    }
}

}  // namespace mavbond
