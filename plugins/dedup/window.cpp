#include "window.h"

#include <algorithm>

namespace mavbond::dedup {

Window::Need Window::need(uint32_t bond) const {
    const Bond& b = bonds_[bond];
    Need n;
    n.late_ns = std::max(b.current, b.previous);
    n.resend_ns = b.resend;
    if (floor_ == 0)
        return n;  // dedup is off
    uint64_t want = floor_;
    if (n.late_ns > 0)
        want = std::max(want, kHeadroom * n.late_ns + kMargin);
    if (n.resend_ns > 0)
        want = std::max(want, n.resend_ns + n.late_ns + kMargin);
    n.ns = std::min(want, std::max(floor_, kMaxWindow));
    return n;
}

void Window::peer_resend(uint32_t bond, uint64_t resend_ns) {
    bonds_[bond].resend = resend_ns;
    derive();
}

void Window::age(uint64_t now) {
    for (Bond& b : bonds_) {
        if (b.epoch_start != 0 && now - b.epoch_start >= kEpoch) {
            b.previous = b.current;
            b.current = 0;
            b.epoch_start = b.previous != 0 ? now : 0;
        }
    }
    derive();
}

void Window::derive() {
    window_ = floor_;
    for (uint32_t bond = 0; bond < kMaxBonds; bond++)
        window_ = std::max(window_, need(bond).ns);
}

}  // namespace mavbond::dedup
