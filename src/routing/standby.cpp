#include "routing/standby.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>

#include "mavlink/message_table.h"
#include "routing/local_source.h"
#include "routing/router.h"

namespace mavbond {

Standby::Standby(const BondConfig& bond, const std::vector<const EndpointConfig*>& members,
                 const TxClassesConfig& classes, TimePoint now)
    : classes_(classes), failover_loss_(bond.failover_loss), failback_loss_(bond.failback_loss),
      failback_after_(bond.failback_after), resend_(bond.resend),
      silence_([&] {
          std::vector<std::string> names;
          for (const EndpointConfig* ep : members)
              names.push_back(ep->name);
          return names;
      }(), now),
      started_(now) {
    for (const EndpointConfig* ep : members) {
        Member& m = members_.emplace_back();
        m.name = ep->name;
        m.metered = ep->metered;
        m.carries = ep->standby_classes;
        m.out = ep->filter_out;
        free_filters_ = free_filters_ || (!m.metered && !(m.out == MessageFilterConfig{}));
    }
    if (resend_ > Duration::zero())
        held_.resize(kHeldCapacity);
}

bool Standby::a_free_member_carries(uint32_t msgid) const {
    return std::any_of(members_.begin(), members_.end(),
                       [msgid](const Member& m) { return !m.metered && m.out.passes(msgid); });
}

std::string Standby::carried_in_standby(uint32_t member) const {
    std::string text;
    for (size_t c = 0; c < kTxClassCount; c++) {
        if (members_[member].carries >> c & 1u)
            text += (text.empty() ? "" : ", ") + std::string(kTxClassNames[c]);
    }
    if (text.empty())
        text = "nothing of its own";
    // The messages the free members' lists name that none of them may carry (with allow lists
    // on every free member, also any message none of them allows).
    std::vector<uint32_t> named;
    bool all_allow = free_filters_;
    for (const Member& m : members_) {
        if (m.metered)
            continue;
        named.insert(named.end(), m.out.block.begin(), m.out.block.end());
        named.insert(named.end(), m.out.allow.begin(), m.out.allow.end());
        all_allow = all_allow && !m.out.allow.empty();
    }
    std::sort(named.begin(), named.end());
    named.erase(std::unique(named.begin(), named.end()), named.end());
    std::string only_here;
    for (uint32_t id : named) {
        if (!a_free_member_carries(id) &&
            !(members_[member].carries >> static_cast<unsigned>(classes_.class_of(id)) & 1u)) {
            const MessageInfo* info = find_message(id);
            only_here += (only_here.empty() ? "" : ", ") + (info ? std::string(info->name) : std::to_string(id));
        }
    }
    if (all_allow)
        only_here += std::string(only_here.empty() ? "" : ", ") + "any message no free member allows";
    if (!only_here.empty())
        text += "; and " + only_here + ", which no free member may carry (allow_out, block_out)";
    return text;
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
    silence_ = old.silence_;
    peer_resend_ = old.peer_resend_;
    peer_resend_announced_ = old.peer_resend_announced_;
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

void Standby::hold(uint32_t member, const Frame& frame, uint64_t route, uint64_t ticket,
                   TimePoint now) {
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
    h.ticket = ticket;
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
    if (m.first_arrival == TimePoint{})
        m.first_arrival = arrival;
}

void Standby::accounted(uint32_t member, const Account& account) {
    if (member >= members_.size() || account.at == TimePoint{})
        return;
    Member& m = members_[member];
    const size_t n = m.accounts.size();
    if (m.accounts_count != 0) {
        const Account& newest = m.accounts[(m.accounts_head + n - 1) % n];
        if (account.at == newest.at)
            return;  // no marker since
        if (account.expected < newest.expected || account.received < newest.received)
            m.accounts_count = 0;  // a link of the member went away: its sums start again
    }
    m.accounts[m.accounts_head] = account;
    m.accounts_head = (m.accounts_head + 1) % n;
    m.accounts_count = std::min(m.accounts_count + 1, n);
}

int32_t Standby::account_permille(const Member& m, TimePoint now) {
    if (m.accounts_count == 0)
        return -1;
    const size_t n = m.accounts.size();
    const Account& newest = m.accounts[(m.accounts_head + n - 1) % n];
    if (now - newest.at > 2 * kLossWindow)
        return -1;  // the far side stopped counting: not a figure of now
    // From the latest marker at least a window before the newest (else the oldest remembered).
    const Account* from = &m.accounts[(m.accounts_head + n - m.accounts_count) % n];
    for (size_t i = 2; i <= m.accounts_count; i++) {
        const Account& a = m.accounts[(m.accounts_head + n - i) % n];
        if (newest.at - a.at >= kLossWindow) {
            from = &a;
            break;
        }
    }
    const auto expected = static_cast<int64_t>(newest.expected - from->expected);
    // Below 0 while a frame written after a marker overtook it (a reordering link).
    const int64_t lost =
        std::max<int64_t>(expected - static_cast<int64_t>(newest.received - from->received), 0);
    if (expected < kMinExpected)
        return 0;
    return static_cast<int32_t>(std::min<int64_t>(lost * 1000 / expected, 1000));
}

int32_t Standby::measured_permille(uint32_t member, TimePoint now, TimePoint last_heard) {
    Member& m = members_[member];
    // A link never heard is silent once the peer, heard on another link, has had kMaxSilence
    // to use it too (counted from our start, a peer that starts a little later had its radio
    // reported silent, and the metered link active for failback_after).
    if (silence_.judge(member, last_heard, now, kMinSilence, kMaxSilence).silent)
        return 1000;
    if (last_heard == TimePoint{})
        return 0;
    if (int32_t by_markers = account_permille(m, now); by_markers >= 0)
        return by_markers;
    // No markers yet: a far mavbond's first are on their way, and its sequence gaps would
    // count what it chose not to send (a budget's thinning) as loss.
    if (m.accounts_count == 0 && now - m.first_arrival < kAwaitMarkers)
        return 0;
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

void Standby::heard(const std::vector<TimePoint>& last_heard, TimePoint now) {
    for (uint32_t m = 0; m < members_.size() && m < last_heard.size(); m++)
        silence_.heard(m, last_heard[m], now);
}

std::vector<Standby::Report> Standby::reports(TimePoint now,
                                              const std::vector<TimePoint>& last_heard) {
    heard(last_heard, now);
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

std::optional<Standby::Report> Standby::resend_announcement(TimePoint now) {
    if (last_announced_ != TimePoint::min() && now - last_announced_ < kAnnounceEvery)
        return std::nullopt;
    last_announced_ = now;
    counters_.reports_sent++;
    Report r;
    std::memcpy(r.name.data(), kResendName, std::min(std::strlen(kResendName), kNameLen));
    r.permille = static_cast<int32_t>(std::chrono::duration_cast<milliseconds>(resend_).count());
    return r;
}

bool Standby::is_report(const Frame& frame) {
    const size_t prefix = std::strlen(kNamePrefix);
    // A judged link's loss ("mbl:...") or the far side's resend ("mbp:resend").
    // time_boot_ms (4), value (4), name (10); a v2 payload may end early (its zeros trimmed).
    return frame.msgid == kMsgNamedValueInt && frame.payload.size() >= 8 + prefix &&
           (std::memcmp(frame.payload.data() + 8, kNamePrefix, prefix) == 0 ||
            (frame.payload.size() >= 8 + std::strlen(kResendName) &&
             std::memcmp(frame.payload.data() + 8, kResendName, std::strlen(kResendName)) == 0));
}

void Standby::take_report(uint32_t member, const Frame& frame, TimePoint arrival) {
    const size_t prefix = std::strlen(kNamePrefix);
    const uint8_t* p = frame.payload.data();
    // The far side sends each report on every member: which ones brought this one says which
    // links carry what it writes.
    silence_.report(member, FrameSource{frame.sysid, frame.compid, frame.seq}, arrival);
    if (frame.payload.size() >= 8 + std::strlen(kResendName) &&
        std::memcmp(p + 8, kResendName, std::strlen(kResendName)) == 0) {
        int32_t ms;
        std::memcpy(&ms, p + 4, 4);
        peer_resend_ = milliseconds(std::clamp(ms, 0, 10'000));  // resend is at most 10 s
        peer_resend_announced_ = true;
        counters_.reports_received++;
        return;
    }
    const size_t len = std::min(frame.payload.size() - 8, kNameLen);
    std::string_view name(reinterpret_cast<const char*>(p + 8 + prefix), len - prefix);
    name = name.substr(0, name.find('\0'));
    counters_.reports_received++;
    // Which free member it names: the first six characters of its endpoint name.
    auto named = std::find_if(members_.begin(), members_.end(), [&](const Member& m) {
        return !m.metered && !name.empty() &&
               reported_name(m.name) == name;
    });
    if (named == members_.end()) {
        counters_.reports_ignored++;
        return;
    }
    int32_t value;
    std::memcpy(&value, p + 4, 4);  // little-endian on the wire, as on every host mavbond runs on
    value = std::clamp(value, 0, 1000);
    auto it = std::find_if(peer_.begin(), peer_.end(),
                           [&](const PeerLink& l) { return l.name == name; });
    if (it == peer_.end())
        it = peer_.insert(peer_.end(), PeerLink{std::string(name), value, arrival});
    // The copies of one report come over every link: the latest arrival wins, with its value.
    if (arrival >= it->heard) {
        it->permille = value;
        it->heard = arrival;
    }
}

bool Standby::judge(TimePoint now) {
    peer_.erase(std::remove_if(peer_.begin(), peer_.end(),
                               [&](const PeerLink& l) { return now - l.heard > kPeerExpiry; }),
                peer_.end());
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
        for (uint32_t m = 0; m < heard.size(); m++) {
            heard[m] = bond.last_heard(m);
            Standby::Account account;
            if (router_.member_account(b, m, account))
                standby->accounted(m, account);
        }
        std::vector<Standby::Report> reports = standby->reports(now, heard);
        for (const Standby::Report& r : reports)
            source_.send_named_value_int(r.name, r.permille, b);
        if (!reports.empty()) {
            if (auto r = standby->resend_announcement(now))
                source_.send_named_value_int(r->name, r->permille, b);
        }
        router_.judge_standby(b, now);
    }
}

}  // namespace mavbond
