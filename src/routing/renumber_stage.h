// The filter chain plus sequence renumbering for the bonds that ask for it (`renumber: true`):
// it reads the position dedup noted on each frame the bond delivers (the same for every link's
// copy) and rewrites its seq before it is routed. Bonds without
// renumbering, and signed frames (the signature covers seq, they are counted), pass untouched.
#pragma once

#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "routing/renumber.h"
#include "routing/router.h"
#include "routing/filter_chain.h"

namespace mavbond {

class RenumberStage : public FrameFilter {
public:
    RenumberStage(FilterChain& chain, const Router& router, const std::vector<BondConfig>& bonds);

    /// Whether any bond renumbers (otherwise the router can use the chain directly).
    bool active() const { return active_; }

    Verdict on_ingress(const Frame& frame, Endpoint& from, TimePoint now) override;
    Verdict on_egress(const Frame& frame, Endpoint& to, TimePoint now) override;
    void on_endpoint(Endpoint& endpoint, bool added) override;

    /// What bond `bond` (router index) did, as (name, count) pairs in a fixed order; empty
    /// when it does not renumber. For the exit log, the status socket and /metrics alike.
    std::vector<std::pair<const char*, uint64_t>> counters(size_t bond) const;

    /// One log line per renumbering bond: what it did.
    void log_summary() const;

private:
    struct BondState {
        std::unique_ptr<SeqRenumberer> renumberer;  // nullptr: this bond does not renumber
        uint64_t signed_left_alone = 0;
    };

    FilterChain& chain_;
    const Router& router_;
    std::vector<BondState> bonds_;  // index = bond index
    bool active_ = false;
};

}  // namespace mavbond
