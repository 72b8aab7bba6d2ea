#include "routing/identity.h"

#include "core/log.h"

namespace mavbond {

OwnIdentity::OwnIdentity(const IdentityConfig& config, Router& router, EventLoop& loop,
                         LocalSource& source, std::function<void(uint8_t, uint8_t)> changed)
    : config_(config), router_(router), source_(source), changed_(std::move(changed)),
      derived_(source.compid() != config.compid) {  // a reload: the source kept what it took
    router_.watch_own_identity(source_.sysid(), source_.compid());
    timer_ = loop.schedule(kTick, [this] {
        review();
        return kTick;
    });
}

void OwnIdentity::review() {
    const Bond* beyond = nullptr;
    for (const Bond& b : router_.bonds())
        beyond = b.autopilot() ? &b : beyond;
    const bool ground_side = beyond && !router_.local_autopilot();
    if (!config_.compid_given && ground_side && !derived_) {
        derived_ = true;
        const uint8_t compid = kGroundCompid;  // compid not given: config_.compid is the default
        log_notice("identity: this side faces the ground station (the vehicle's autopilot %u/%u is "
                   "heard through bond %s): mavbond is %u/%u here, the vehicle's side keeps %u/%u, "
                   "so a GCS sees two components, each counted on its own (identity: compid "
                   "chooses)",
                   beyond->autopilot()->sysid, beyond->autopilot()->compid, beyond->name().c_str(),
                   source_.sysid(), compid, source_.sysid(), config_.compid);
        source_.set_compid(compid);
        router_.watch_own_identity(source_.sysid(), compid);
        if (changed_)
            changed_(source_.sysid(), compid);
    }
    // Until this side is known, it and its far side may still change identity (the far side
    // while it too waits for the autopilot's HEARTBEAT): what came in until then is forgotten,
    // and a clash counts once it lasts kClashAfter after.
    const bool settled = config_.compid_given || ground_side || router_.local_autopilot();
    if (!settled) {
        router_.watch_own_identity(source_.sysid(), source_.compid());
        return;
    }
    const Router::OwnIdentityHeard& heard = router_.own_identity_heard();
    if (!clash_logged_ && heard.count > 0 && heard.last - heard.first >= kClashAfter) {
        clash_logged_ = true;
        log_warning("identity %u/%u is mavbond's, yet %llu frames from it came in (first on %s): "
                    "another gateway or a routing loop uses it, and a GCS that hears both counts "
                    "their two sequence counters as loss. Give each gateway its own: identity: "
                    "{compid: 191} on the vehicle's side, {compid: 192} on the ground's",
                    source_.sysid(), source_.compid(), static_cast<unsigned long long>(heard.count),
                    heard.link.c_str());
    }
}

}  // namespace mavbond
