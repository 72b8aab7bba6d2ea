#include "routing/standby.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>

#include "routing/local_source.h"
#include "routing/router.h"

namespace mavbond {

Standby::Standby(const BondConfig& bond, const std::vector<const EndpointConfig*>& members,
                 const TxClassesConfig& classes, TimePoint now)
    : classes_(classes), failover_loss_(bond.failover_loss), failback_loss_(bond.failback_loss),
      failback_after_(bond.failback_after), resend_(bond.resend), started_(now) {
    for (const EndpointConfig* ep : members) {
        Member& m = members_.emplace_back();
        m.name = ep->name;
        m.metered = ep->metered;
        m.carries = ep->standby_classes;
    }
    if (resend_ > Duration::zero())
        held_.resize(kHeldCapacity);
}

bool Standby::continue_from(const Standby& old) {
    auto same = [](const Member& a, const Member& b) {
        return a.name == b.name && a.metered == b.metered;
    };
    if (!std::equal(members_.begin(), members_.end(), old.members_.begin(), old.members_.end(), same))
        return false;
    for (size_t i = 0; i < members_.size(); i++) {
        const uint8_t carries = members_[i].carries;
        members_[i] = old.members_[i];
        members_[i].carries = carries;
    }
    peer_ = old.peer_;
    started_ = old.started_;  // the loss buckets count from it
    last_report_ = old.last_report_;
    active_ = old.active_;
    counters_ = old.counters_;
    if (failback_after_ == old.failback_after_) {
        healthy_since_ = old.healthy_since_;
        healthy_ = old.healthy_;
    }
    if (!held_.empty() && !old.held_.empty()) {
        held_ = old.held_;
        held_head_ = old.held_head_;
        held_count_ = old.held_count_;
    }
    return true;
}

void Standby::hold(uint32_t member, const Frame& frame, uint64_t route, TimePoint now) {
    counters_.withheld++;
    if (held_.empty())
        return;
    if (held_count_ != 0) {
        const Held& last = held_[(held_head_ + held_count_ - 1) % held_.size()];
        if (last.route == route && last.member == member)
            return;  // another link of the same member: one copy is enough
    }
    // Older than the resend window, or the ring is full: the oldest goes.
    while (held_count_ != 0 && (held_count_ == held_.size() || now - held_[held_head_].at > resend_)) {
        held_head_ = (held_head_ + 1) % held_.size();
        held_count_--;
    }
    Held& h = held_[(held_head_ + held_count_) % held_.size()];
    held_count_++;
    h.at = now;
    h.route = route;
    h.member = member;
    h.len = static_cast<uint16_t>(frame.bytes.size());
    std::memcpy(h.bytes.data(), frame.bytes.data(), frame.bytes.size());
}

int64_t Standby::bucket_of(TimePoint t) const {
    return (t - started_) / (kLossWindow / kBuckets);
}

void Standby::roll(Member& m, int64_t epoch) {
    if (epoch <= m.epoch)
        return;
    for (int64_t e = m.epoch + 1; e <= epoch && e <= m.epoch + kBuckets; e++) {
        m.received[static_cast<size_t>(e % kBuckets)] = 0;
        m.lost[static_cast<size_t>(e % kBuckets)] = 0;
    }
    m.epoch = epoch;
}

void Standby::received(uint32_t member, const StreamStep& step, TimePoint arrival) {
    if (member >= members_.size() || arrival < started_)
        return;
    Member& m = members_[member];
    int64_t epoch = bucket_of(arrival);
    roll(m, epoch);
    // A frame a little older than the newest bucket counts in the newest: a window is a window.
    size_t b = static_cast<size_t>(m.epoch % kBuckets);
    m.received[b]++;
    m.lost[b] += step.lost;
    if (arrival > m.last_arrival) {
        if (m.last_arrival != TimePoint{}) {
            double gap = static_cast<double>((arrival - m.last_arrival).count());
            m.gap_ns = m.gap_ns == 0 ? gap : 0.9 * m.gap_ns + 0.1 * gap;
        }
        m.last_arrival = arrival;
    }
}

int32_t Standby::measured_permille(uint32_t member, TimePoint now, TimePoint last_heard) {
    Member& m = members_[member];
    // Silent after four usual gaps: a 124 frames/s radio in a quarter second, a side that
    // hears a HEARTBEAT and a report a second in three.
    // Until two frames came, the usual gap is unknown: the longest wait.
    const Duration silence =
        m.gap_ns == 0 ? Duration(kMaxSilence)
                      : std::clamp(Duration(static_cast<int64_t>(4 * m.gap_ns)),
                                   Duration(kMinSilence), Duration(kMaxSilence));
    // A link never heard is silent once the bond has waited as long as for any (the peer
    // may be starting, and its first frame may come over the other link first).
    if (last_heard == TimePoint{})
        return now - started_ > kMaxSilence ? 1000 : 0;
    if (now - last_heard > silence)
        return 1000;
    if (now >= started_)
        roll(m, bucket_of(now));
    int64_t received = 0, lost = 0;
    for (size_t i = 0; i < kBuckets; i++) {
        received += m.received[i];
        lost += m.lost[i];
    }
    lost = std::max<int64_t>(lost, 0);  // a late frame may fill a gap counted before the window
    // Too few frames to judge a loss figure (a side that hears a HEARTBEAT and a report a
    // second: one lost frame would be 25%): only silence counts then.
    if (received + lost < kMinExpected)
        return 0;
    return static_cast<int32_t>(lost * 1000 / (received + lost));
}

std::vector<Standby::Report> Standby::reports(TimePoint now,
                                              const std::vector<TimePoint>& last_heard) {
    std::vector<Report> out;
    bool changed = now - last_report_ >= kReportEvery;
    for (uint32_t i = 0; i < members_.size(); i++) {
        if (members_[i].metered)
            continue;
        Report& r = out.emplace_back();
        std::string name = std::string(kNamePrefix) + members_[i].name;
        std::memcpy(r.name.data(), name.data(), std::min(name.size(), kNameLen));
        r.permille = measured_permille(i, now, i < last_heard.size() ? last_heard[i] : TimePoint{});
        const int32_t before = members_[i].reported;
        changed = changed || before < 0 || std::abs(r.permille - before) >= kReportStep ||
                  (r.permille == 1000) != (before == 1000);
    }
    if (!changed)
        return {};
    for (uint32_t i = 0, k = 0; i < members_.size(); i++) {
        if (!members_[i].metered)
            members_[i].reported = out[k++].permille;
    }
    last_report_ = now;
    counters_.reports_sent += out.size();
    return out;
}

bool Standby::take_report(const Frame& frame, TimePoint arrival) {
    // time_boot_ms (4), value (4), name (10); a v2 payload may end early (its zeros trimmed).
    if (frame.msgid != kMsgNamedValueInt || frame.payload.size() < 8 + std::strlen(kNamePrefix))
        return false;
    const uint8_t* p = frame.payload.data();
    if (std::memcmp(p + 8, kNamePrefix, std::strlen(kNamePrefix)) != 0)
        return false;
    size_t len = std::min(frame.payload.size() - 8, kNameLen);
    std::string name(reinterpret_cast<const char*>(p + 8), len);
    name = name.substr(std::strlen(kNamePrefix), name.find('\0') - std::strlen(kNamePrefix));
    // An endpoint name's characters only: anything else is not a report of ours.
    for (char c : name) {
        if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '-'))
            return false;
    }
    if (name.empty())
        return false;
    int32_t value;
    std::memcpy(&value, p + 4, 4);  // little-endian on the wire, as on every host mavbond runs on
    value = std::clamp(value, 0, 1000);
    counters_.reports_received++;
    auto it = std::find_if(peer_.begin(), peer_.end(), [&](const PeerLink& l) { return l.name == name; });
    if (it == peer_.end()) {
        if (peer_.size() >= 16)
            return true;  // a peer with more free links than any bond has: the rest unjudged
        it = peer_.insert(peer_.end(), PeerLink{name, value, arrival});
    }
    // The copies of one report come over every link: the latest arrival wins, with its value.
    if (arrival >= it->heard) {
        it->permille = value;
        it->heard = arrival;
    }
    return true;
}

bool Standby::judge(TimePoint now) {
    // The best free link the peer reports now; none heard lately counts as all failing.
    int32_t best = 1000;
    bool heard = false;
    for (const PeerLink& l : peer_) {
        if (now - l.heard <= kReportTimeout) {
            best = std::min(best, l.permille);
            heard = true;
        }
    }
    // A peer not yet started is no outage: silence counts once the bond has had time to hear one.
    if (!heard && now - started_ < 2 * kReportTimeout)
        return false;
    const double loss = best / 1000.0;
    if (!active_) {
        if (loss > failover_loss_) {
            active_ = true;
            healthy_since_ = TimePoint::max();
            counters_.to_active++;
            return true;
        }
        return false;
    }
    // Failing no more: back to standby once it has not failed for failback_after and the best
    // free link's loss, averaged over the last failback_after (every judgement: ten a second
    // and one per report), is below failback_loss. An average, not every window: a link
    // losing 1 % has 2 s windows above 2 % by chance.
    if (loss > failover_loss_) {
        healthy_since_ = TimePoint::max();
        return false;
    }
    if (healthy_since_ == TimePoint::max()) {
        healthy_since_ = now;
        healthy_ = {};
    }
    const Duration width = std::max(failback_after_ / kHealthyBuckets, Duration(1));
    const int64_t epoch = (now - started_) / width;
    HealthyBucket& b = healthy_[static_cast<size_t>(epoch % kHealthyBuckets)];
    if (b.epoch != epoch)
        b = HealthyBucket{epoch, 0, 0};
    b.sum += loss;
    b.count++;
    if (now - healthy_since_ < failback_after_)
        return false;
    double sum = 0;
    uint64_t count = 0;
    for (const HealthyBucket& h : healthy_) {
        if (h.count != 0 && h.epoch > epoch - kHealthyBuckets) {
            sum += h.sum;
            count += h.count;
        }
    }
    if (count != 0 && sum / static_cast<double>(count) < failback_loss_) {
        active_ = false;
        counters_.to_standby++;
    }
    return false;
}

StandbyMonitor::StandbyMonitor(Router& router, EventLoop& loop, LocalSource& source)
    : router_(router), source_(source) {
    timer_ = loop.schedule(Standby::kTick, [this, &loop] {
        tick(router_.arrival_clock(loop.now()));
        return Standby::kTick;
    });
}

void StandbyMonitor::tick(TimePoint now) {
    for (uint32_t b = 0; b < router_.bonds().size(); b++) {
        Bond& bond = router_.bond(b);
        Standby* standby = bond.standby();
        if (!standby)
            continue;
        std::vector<TimePoint> heard(bond.members().size());
        for (uint32_t m = 0; m < heard.size(); m++)
            heard[m] = bond.last_heard(m);
        for (const Standby::Report& r : standby->reports(now, heard))
            source_.send_named_value_int(r.name, r.permille, b);
        router_.judge_standby(b, now);
    }
}

}  // namespace mavbond
