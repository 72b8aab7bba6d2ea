#include "routing/link_silence.h"

namespace mavbond {

namespace {
long long ms(Duration d) { return std::chrono::duration_cast<milliseconds>(d).count(); }
}  // namespace

LinkSilence::LinkSilence(std::vector<std::string> members, TimePoint started) : started_(started) {
    for (std::string& name : members)
        members_.push_back(Member{std::move(name), {}, {}, {}, {}, false});
}

TimePoint LinkSilence::report_elsewhere(uint32_t member) const {
    TimePoint t{};
    for (uint32_t m = 0; m < members_.size(); m++) {
        if (m != member)
            t = std::max(t, members_[m].last_report);
    }
    return t;
}

void LinkSilence::heard(uint32_t member, TimePoint last_rx, TimePoint now) {
    if (member >= members_.size() || last_rx == TimePoint{})
        return;
    Member& m = members_[member];
    if (peer_since_ == TimePoint{} || last_rx < peer_since_)
        peer_since_ = last_rx;
    if (last_rx <= m.last) {
        // Silent since: nothing to go by once the far side's reports stopped elsewhere too.
        if (now - report_elsewhere(member) > kEvidenceTimeout)
            m.nothing_to_go_by = true;
        return;
    }
    if (m.last != TimePoint{}) {
        const Duration gap = last_rx - m.last;
        // The gap that ends an outage is no usual gap.
        if (m.gaps.count() < kMinSamples || gap <= kGapFactor * m.gaps.value())
            m.gaps.add(gap);
    }
    m.last = last_rx;
    m.nothing_to_go_by = false;
}

void LinkSilence::report(uint32_t member, const FrameSource& id, TimePoint arrival) {
    if (member >= members_.size() || member >= 64)
        return;
    Member& m = members_[member];
    m.last_report = std::max(m.last_report, arrival);
    const uint64_t bit = uint64_t{1} << member;
    for (Report& r : reports_) {
        if (r.first_member == kNone || r.id.sysid != id.sysid || r.id.compid != id.compid ||
            r.id.seq != id.seq || arrival - r.first > kSameReport || r.first - arrival > kSameReport)
            continue;
        if (!(r.on & bit)) {
            r.on |= bit;
            m.lags.add(std::max(arrival - r.first, Duration{}));
        }
        return;
    }
    reports_[next_] = Report{id, arrival, member, bit};
    next_ = (next_ + 1) % reports_.size();
    m.lags.add(Duration{});
}

Duration LinkSilence::usual_gap(uint32_t member) const {
    const Member& m = members_[member];
    return m.gaps.count() < kMinSamples ? Duration(kAssumedGap) : m.gaps.value();
}

Duration LinkSilence::allowed_lag(uint32_t member) const {
    const Member& m = members_[member];
    return m.lags.count() < kMinSamples ? Duration(kMaxLag)
                                        : std::min(m.lags.value() + kLagSlack, Duration(kMaxLag));
}

LinkSilence::Verdict LinkSilence::judge(uint32_t member, TimePoint last_rx, TimePoint now,
                                        Duration least, Duration most) const {
    Verdict v;
    most = std::max(least, most);
    if (last_rx == TimePoint{}) {
        // It starts after us, and its first frames may come over another link first.
        v.by = Verdict::By::NeverHeard;
        v.silent = now - (peer_since_ == TimePoint{} ? started_ : peer_since_) > most;
        return v;
    }
    const Member& m = members_[member];
    v.quiet = now - last_rx;
    v.usual_gap = usual_gap(member);
    if (v.quiet < std::clamp(Duration(kGapFactor * v.usual_gap), least, most))
        return v;
    // Heard since the last tick: what the ticks knew of its silence is of an older one.
    const bool known_silence = last_rx <= m.last && m.nothing_to_go_by;
    if (known_silence || now - report_elsewhere(member) > kEvidenceTimeout) {
        v.by = Verdict::By::NoEvidence;
        v.silent = true;
        return v;
    }
    v.by = Verdict::By::Evidence;
    v.allowed_lag = allowed_lag(member);
    const uint64_t bit = member < 64 ? uint64_t{1} << member : 0;
    for (const Report& r : reports_) {
        if (r.first_member == kNone || (r.on & bit) || r.first <= last_rx ||
            now - r.first < v.allowed_lag)
            continue;
        if (!v.silent || now - r.first > v.witness_age) {
            v.silent = true;
            v.witness = r.first_member;
            v.witness_age = now - r.first;
        }
    }
    return v;
}

std::string LinkSilence::explain(const Verdict& v) const {
    switch (v.by) {
    case Verdict::By::NeverHeard:
        return "never heard, though the far side had time to use it";
    case Verdict::By::Gaps:
        return "heard " + std::to_string(ms(v.quiet)) + " ms ago, within " +
               std::to_string(kGapFactor) + " of its usual " + std::to_string(ms(v.usual_gap)) +
               " ms gaps";
    case Verdict::By::NoEvidence:
        return "silent for " + std::to_string(ms(v.quiet)) + " ms, " + std::to_string(kGapFactor) +
               " of its usual " + std::to_string(ms(v.usual_gap)) +
               " ms gaps or at least the least silence, with no report of the far side's on "
               "another link to go by";
    case Verdict::By::Evidence:
        if (!v.silent)
            return "silent for " + std::to_string(ms(v.quiet)) +
                   " ms, no report of the far side's overdue here (allowed " +
                   std::to_string(ms(v.allowed_lag)) + " ms late)";
        return "silent for " + std::to_string(ms(v.quiet)) + " ms: the far side's report on " +
               (v.witness < members_.size() ? members_[v.witness].name : std::string("?")) + " " +
               std::to_string(ms(v.witness_age)) + " ms ago is not here (allowed " +
               std::to_string(ms(v.allowed_lag)) + " ms late)";
    }
    return "";
}

}  // namespace mavbond
