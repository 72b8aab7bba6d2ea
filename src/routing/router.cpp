#include "routing/router.h"

#include <algorithm>
#include <cstring>

#include "core/log.h"
#include "core/plural.h"
#include "mavlink/frame_parser.h"
#include "mavlink/frame_writer.h"
#include "mavlink/radio_status.h"

namespace mavbond {

namespace {
constexpr uint32_t kMsgHeartbeat = 0;
}  // namespace

Router::Router(EventLoop& loop, Duration route_timeout) : loop_(loop), route_timeout_(route_timeout) {}

// --- what endpoints call -------------------------------------------------------------------

void Router::attach(Link& link) {
    auto free_slot = std::find_if(slots_.begin(), slots_.end(), [](const Slot& s) { return !s.link; });
    if (free_slot == slots_.end())
        free_slot = slots_.emplace(slots_.end());
    link.id_ = static_cast<LinkId>(free_slot - slots_.begin());
    free_slot->link = &link;
    free_slot->routes.clear();
    free_slot->positions.clear();
    place_links();
    if (link.records_everything())
        recorders_.push_back(&link);
    if (filter_)
        filter_->on_link(link, true);
}

void Router::detach(Link& link) {
    LinkId id = link.id();
    if (id >= slots_.size() || slots_[id].link != &link)
        return;
    if (filter_)
        filter_->on_link(link, false);
    Slot& s = slots_[id];
    if (s.bond != kNoBond) {
        Bond& bond = bonds_[s.bond];
        bond.forget_link(id);
        // Its frames still waiting go with it (a link gone within a round of a stall).
        // Lent frames of a socket that goes are no longer valid, copied ones no longer wanted.
        auto& waiting = bond.waiting;
        size_t before = waiting.size();
        waiting.erase(std::remove_if(waiting.begin(), waiting.end(),
                                     [&](const Bond::WaitingFrame& w) { return w.received.from == &link; }),
                      waiting.end());
        if (waiting.size() != before)
            log_warning("[%s] removed with %zu received frames not yet handled: dropped",
                        link.name().c_str(), before - waiting.size());
    }
    s = Slot{};
    dirty_.erase(std::remove(dirty_.begin(), dirty_.end(), &link), dirty_.end());
    recorders_.erase(std::remove(recorders_.begin(), recorders_.end(), &link), recorders_.end());
    link.id_ = kNoLink;
}

void Router::attach(Input& input) {
    inputs_.push_back(&input);
    place_links();
}

void Router::detach(Input& input) {
    inputs_.erase(std::remove(inputs_.begin(), inputs_.end(), &input), inputs_.end());
    place_links();
}

void Router::ingress(ReceivedBatch& batch) {
    Input* input = batch.input();
    if (input) {
        // A socket epoll reported readable held its first datagram when epoll looked.
        polled_no_earlier_than(input->first_reported());
        if (input->bond_index_ != kNoBond) {
            // A datagram socket's buffer lasts the round: its bond's frames wait there, lent,
            // for the merge of everything the round read (its links are the bond's).
            Bond& bond = bonds_[input->bond_index_];
            for (size_t i = 0; i < batch.size(); i++) {
                const ReceivedFrame& r = batch[i];
                heard(bond, slot(*r.from).member, r);
                bond.wait(r, wait_order_++, false);
            }
            return;
        }
    }
    ready_.clear();
    for (size_t i = 0; i < batch.size(); i++) {
        ReceivedFrame& r = batch[i];
        const Slot& from = slot(*r.from);
        if (from.bond == kNoBond) {
            ready_.push_back(&r);
            continue;
        }
        Bond& bond = bonds_[from.bond];
        heard(bond, from.member, r);
        if (bond.must_wait(r.arrival, polled(), loop_.all_reported())) {
            // A byte stream reuses its buffer at its next read: the frame is copied aside.
            bond.wait(r, wait_order_++, true);
            frames_held_back_++;
        } else {
            ready_.push_back(&r);
        }
    }
    handle(ready_.data(), ready_.size());
}

void Router::end_batch() {
    // flush() may call back into detach() (a connection closing on a write error), which
    // edits dirty_: take from the back until it is empty.
    while (!dirty_.empty()) {
        Link* link = dirty_.back();
        dirty_.pop_back();
        link->flush();
    }
    // Nothing is lent from the arena any more (written, or copied into a queue or a budget).
    sign_chunk_ = sign_used_ = 0;
    routing_++;
}

std::shared_ptr<BondSigning> Router::bond_signing(const std::string& bond) {
    uint32_t b = bond_index(bond);
    return b == kNoBond ? nullptr : bonds_[b].signing();
}

// --- bonds and links -----------------------------------------------------------------------

void Router::replace_bonds(const Config& config) {
    // Frames waiting in a bond that is replaced are handled first, in the order they came.
    merge_round(true);
    std::vector<Bond> old = std::move(bonds_);
    bonds_.clear();
    for (const auto& b : config.bonds) {
        Bond& bond = bonds_.emplace_back(b, config.endpoints, config.tx_classes, loop_.now());
        auto was = std::find_if(old.begin(), old.end(),
                                [&](const Bond& o) { return o.name() == bond.name(); });
        if (was != old.end() && bond.continue_from(*was))
            log_info("bond %s: standby continues %s", bond.name().c_str(),
                     bond.standby()->active() ? "active" : "in standby");
    }
    egress_.assign(bonds_.size(), Egress{});
    for (size_t b = 0; b < bonds_.size(); b++) {
        egress_[b].router = this;
        egress_[b].bond = static_cast<uint32_t>(b);
        egress_[b].numbering = bonds_[b].numbering();
    }
    place_links();
}

void Router::place_links() {
    for (Slot& s : slots_) {
        if (!s.link)
            continue;
        s.bond = bond_index(s.link->bond());
        s.member = s.bond == kNoBond ? Bond::kNoMember
                                     : bonds_[s.bond].member_index(s.link->endpoint_name());
        s.signs = s.bond != kNoBond && bonds_[s.bond].signs(s.link->endpoint_name());
    }
    for (Bond& b : bonds_)
        b.inputs.clear();
    for (Input* in : inputs_) {
        in->bond_index_ = bond_index(in->bond());
        if (in->bond_index_ != kNoBond)
            bonds_[in->bond_index_].inputs.push_back(in);
    }
    mark_standby(kNoBond);
}

void Router::mark_standby(uint32_t bond) {
    for (Slot& s : slots_) {
        if (!s.link || (bond != kNoBond && s.bond != bond))
            continue;
        const Standby* standby = s.bond == kNoBond ? nullptr : bonds_[s.bond].standby();
        s.link->set_standby(standby && s.member != Bond::kNoMember && standby->metered(s.member) &&
                            !standby->active());
    }
}

bool Router::member_account(uint32_t bond, uint32_t member, Standby::Account& out) const {
    out = Standby::Account{};
    bool exact = false;
    for (const Slot& s : slots_) {
        if (!s.link || s.bond != bond || s.member != member || !s.link->account().exact())
            continue;
        const LinkAccount& a = s.link->account();
        exact = true;
        out.expected += a.expected();
        out.received += a.received();
        out.at = std::max(out.at, a.last_marker());
    }
    return exact;
}

uint32_t Router::bond_index(const std::string& name) const {
    for (size_t i = 0; i < bonds_.size(); i++) {
        if (bonds_[i].name() == name)
            return static_cast<uint32_t>(i);
    }
    return kNoBond;
}

void Router::set_filter(FrameFilter* filter) {
    filter_ = filter;
    if (!filter_)
        return;
    for (const Slot& s : slots_) {
        if (s.link)
            filter_->on_link(*s.link, true);
    }
}

bool Router::set_active_link(uint32_t bond, LinkId link) {
    if (bond >= bonds_.size() || link >= slots_.size() || !slots_[link].link ||
        slots_[link].bond != bond)
        return false;
    bonds_[bond].set_active_link(link);
    return true;
}

// --- routes --------------------------------------------------------------------------------

void Router::learn(Slot& from, uint8_t sysid, uint8_t compid, TimePoint now) {
    for (auto& r : from.routes) {
        if (r.sysid == sysid && r.compid == compid) {
            r.last_heard = now;
            return;
        }
    }
    if (from.routes.size() < kMaxRoutesPerLink) {
        from.routes.push_back(Route{sysid, compid, now});
        return;
    }
    // Full: the route heard least recently makes room (counted on the link). A sender cycling
    // through ids churns its own link's table only; a frame to a forgotten target goes to
    // every link, as one to a target never heard.
    auto oldest = std::min_element(from.routes.begin(), from.routes.end(),
                                   [](const Route& a, const Route& b) { return a.last_heard < b.last_heard; });
    *oldest = Route{sysid, compid, now};
    from.link->route_evicted();
}

bool Router::knows(const Link& link, uint8_t sysid, uint8_t compid) const {
    if (link.id() >= slots_.size())
        return false;
    for (const auto& r : slot(link).routes) {
        if (r.sysid == sysid && (compid == 0 || r.compid == compid))
            return true;
    }
    return false;
}

bool Router::target_knows(const Slot& to, uint8_t sysid, uint8_t compid) const {
    if (to.bond == kNoBond)
        return knows(*to.link, sysid, compid);
    for (const Slot& s : slots_) {
        if (s.link && s.bond == to.bond && knows(*s.link, sysid, compid))
            return true;
    }
    return false;
}

void Router::expire_routes(TimePoint now) {
    for (Slot& s : slots_) {
        s.routes.erase(std::remove_if(s.routes.begin(), s.routes.end(),
                                      [&](const Route& r) { return now - r.last_heard > route_timeout_; }),
                       s.routes.end());
    }
}

// --- the data path -------------------------------------------------------------------------

TimePoint Router::polled() const {
    return polled_round_ == loop_.round() ? polled_ : loop_.polled_after();
}

void Router::polled_no_earlier_than(TimePoint t) {
    if (t == TimePoint{})
        return;
    polled_ = std::max(polled(), t);
    polled_round_ = loop_.round();
}

void Router::merge_round(bool all) {
    // Each bond's frames of the round in arrival order, as far as every socket of the bond is
    // read: filtered and routed as one batch.
    std::vector<size_t>& released = released_;
    released.assign(bonds_.size(), 0);
    bool any = false;
    for (size_t b = 0; b < bonds_.size(); b++) {
        Bond& bond = bonds_[b];
        if (bond.waiting.empty())
            continue;
        any = true;
        released[b] = bond.release(polled(), loop_.all_reported(), all);
        ready_.clear();
        for (size_t i = 0; i < released[b]; i++)
            ready_.push_back(&bond.released(i));
        handle(ready_.data(), ready_.size());
    }
    if (!any)
        return;
    // The frames just routed are lent to the links' queues: sent before their bytes move.
    end_batch();
    bool held = false;
    for (size_t b = 0; b < bonds_.size(); b++) {
        Bond& bond = bonds_[b];
        if (bond.waiting.empty())
            continue;
        // What waits past this round needed a copy: it is held back for arrival order.
        frames_held_back_ += bond.keep_unreleased(released[b]);
        held = held || !bond.waiting.empty();
    }
    if (held)
        loop_.request_prompt_round();
}

TimePoint Router::arrival_clock(TimePoint now) const {
    TimePoint t = now;
    for (const Bond& b : bonds_) {
        if (!b.waiting.empty())
            t = std::min(t, b.held_until);
    }
    return t;
}

void Router::handle(ReceivedFrame* const* frames, size_t count) {
    if (count == 0)
        return;
    verdicts_.assign(count, FrameFilter::Ingress{});
    // Each frame's place in its source's stream on its link, once, for the filters and standby.
    for (size_t i = 0; i < count; i++) {
        ReceivedFrame& r = *frames[i];
        if (r.routed)
            r.step = slots_[r.from->id()].positions.track(r.frame.sysid, r.frame.compid, r.frame.seq);
    }
    if (filter_)
        filter_->on_ingress(frames, count, verdicts_.data());
    for (size_t i = 0; i < count; i++) {
        ReceivedFrame& r = *frames[i];
        Slot& from = slots_[r.from->id()];
        // Only a frame whose CRC was checked may teach a route: noise never creates one.
        if (r.frame.crc_checked) {
            learn(from, r.frame.sysid, r.frame.compid, r.arrival);
            if (r.frame.msgid == kMsgHeartbeat)
                note_heartbeat(from, r.frame);
            if (r.frame.sysid == own_sysid_ && r.frame.compid == own_compid_) {
                if (own_heard_.count++ == 0) {
                    own_heard_.first = r.arrival;
                    own_heard_.link = r.from->name();
                }
                own_heard_.last = r.arrival;
            }
        }
        if (!r.routed)
            continue;
        if (standby_sees(from, r))
            continue;
        const FrameFilter::Ingress& v = verdicts_[i];
        bool pass = v.pass;
        if (pass && from.bond != kNoBond && is_radio_status(r.frame.msgid) &&
            bonds_[from.bond].reports_radio_status) {
            bonds_[from.bond].foreign_radio_status++;
            pass = false;
        }
        // A signed frame is delivered once, whatever dedup remembers (bond_signing.h).
        if (pass && r.signed_id.known && from.bond != kNoBond && bonds_[from.bond].signing() &&
            !bonds_[from.bond].signing()->first_delivery(r.signed_id))
            pass = false;
        if (from.bond != kNoBond && bonds_[from.bond].renumbers())
            bonds_[from.bond].renumber(r.frame, pass, v.bond_pos, r.arrival);
        if (pass)
            route(r);
    }
}

void Router::note_heartbeat(const Slot& from, const Frame& frame) {
    // custom_mode (4), type, autopilot, ...; a v2 payload may end early (its zeros trimmed).
    auto byte = [&](size_t i) { return i < frame.payload.size() ? frame.payload[i] : uint8_t{0}; };
    constexpr uint8_t kTypeGcs = 6, kAutopilotInvalid = 8;
    if (byte(4) == kTypeGcs || byte(5) == kAutopilotInvalid)
        return;
    if (from.bond == kNoBond)
        local_autopilot_ = true;
    else
        bonds_[from.bond].heard_autopilot(frame.sysid, frame.compid);
}

bool Router::standby_sees(const Slot& from, const ReceivedFrame& r) {
    Standby* standby = from.bond == kNoBond ? nullptr : bonds_[from.bond].standby();
    if (standby)
        standby->received(from.member, r.step, r.arrival);
    if (!Standby::is_report(r.frame))
        return false;
    // A report is a gateway's to the other gateway of its bond: one from outside (a GCS port)
    // would steer the bond it is routed into.
    if (!standby) {
        standby_reports_dropped_++;
        return true;
    }
    standby->take_report(from.member, r.frame, r.arrival);
    // A report may say the free links are failing: act on it at once, not at the next tick.
    judge_standby(from.bond, r.arrival);
    return true;
}

void Router::judge_standby(uint32_t bond, TimePoint now) {
    Standby& standby = *bonds_[bond].standby();
    const uint64_t to_standby = standby.counters().to_standby;
    if (standby.judge(now)) {
        uint64_t resent = resend_held(bond, now);
        log_notice("bond %s: metered links active (the free links are failing); %s standby "
                   "held back resent",
                   bonds_[bond].name().c_str(), plural(resent, "frame").c_str());
    } else if (standby.counters().to_standby != to_standby) {
        log_notice("bond %s: metered links back in standby (the free links are healthy)",
                   bonds_[bond].name().c_str());
    }
    mark_standby(bond);
}

uint8_t* Router::sign_room() {
    if (sign_used_ + kMaxFrameLen > kSignChunkBytes) {
        sign_chunk_++;
        sign_used_ = 0;
    }
    if (sign_chunk_ == sign_chunks_.size())  // more in one batch than ever: a new high
        sign_chunks_.push_back(std::make_unique<std::array<uint8_t, kSignChunkBytes>>());
    return sign_chunks_[sign_chunk_]->data() + sign_used_;
}

const Frame* Router::signed_for(const Frame& frame, uint32_t bond_index) {
    Bond& bond = bonds_[bond_index];
    Bond::SignedCopy& copy = bond.signed_copy;
    if (copy.routing != routing_) {
        copy.routing = routing_;
        uint8_t* out = sign_room();
        const size_t n = bond.signing()->sign(frame.bytes, std::span<uint8_t>(out, kMaxFrameLen));
        copy.refused = n == 0;
        if (n != 0) {
            sign_used_ += n;
            copy.frame = frame;
            copy.frame.bytes = std::span<const uint8_t>(out, n);
            copy.frame.payload = std::span<const uint8_t>(out + kHeaderLenV2, frame.payload.size());
            copy.frame.incompat_flags |= kIncompatSigned;
        }
    }
    return copy.refused ? nullptr : &copy.frame;
}

BondCopy* Router::egress_copy(const Frame& frame, const Slot& to, uint64_t ticket) {
    if (to.bond == kNoBond)
        return nullptr;
    Egress& e = egress_[to.bond];
    if (e.routing != routing_) {
        e.routing = routing_;
        e.routed = frame;
        e.made = false;
        e.ticket = ticket != 0 ? ticket : bonds_[to.bond].numbering()->issue(frame);
    }
    return e.ticket != 0 ? &e : nullptr;
}

const Frame* Router::Egress::now(bool signed_link) {
    if (!made) {
        made = true;
        const uint8_t n = numbering->number(ticket, routed.sysid, routed.compid);
        uint8_t* out = router->sign_room();
        std::memcpy(out, routed.bytes.data(), routed.bytes.size());
        router->sign_used_ += routed.bytes.size();
        numbered = routed;
        numbered.bytes = std::span<const uint8_t>(out, routed.bytes.size());
        numbered.payload = std::span<const uint8_t>(out + (routed.payload.data() - routed.bytes.data()),
                                                    routed.payload.size());
        rewrite_seq_in_place(numbered, n);
    }
    return signed_link ? router->signed_for(numbered, bond) : &numbered;
}

void Router::deliver(const Frame& frame, Slot& to, uint64_t ticket) {
    if (BondCopy* copy = egress_copy(frame, to, ticket)) {
        // The link numbers (and signs) what it sends of it: Egress::now, or its held copy.
        if (filter_ && !filter_->on_egress(frame, *to.link))
            return;
        if (to.link->send(frame, copy))
            dirty_.push_back(to.link);
        return;
    }
    const Frame* out = &frame;
    if (to.signs && !frame.is_signed()) {
        out = signed_for(frame, to.bond);
        if (!out)
            return;  // MAVLink 1: not on a signed link (counted once for the bond)
    }
    if (filter_ && !filter_->on_egress(*out, *to.link))
        return;
    if (to.link->send(*out))
        dirty_.push_back(to.link);
}

void Router::deliver_to_recorders(const Slot& from, const Frame& frame) {
    for (Link* to : recorders_) {
        Slot& s = slots_[to->id()];
        if (may_send(from, s, frame))
            deliver(frame, s);
    }
}

void Router::route(const ReceivedFrame& received) {
    const Frame& frame = received.frame;
    const Slot& from = slots_[received.from->id()];
    frames_routed_++;
    begin_routing();

    if (!frame.is_broadcast()) {
        auto ts = static_cast<uint8_t>(frame.target_system);
        auto tc = static_cast<uint8_t>(frame.target_component > 0 ? frame.target_component : 0);
        // Prefer where the exact component was heard, then where the system was heard;
        // a target heard nowhere is sent everywhere, as a broadcast is.
        for (uint8_t want_comp : {tc, uint8_t{0}}) {
            bool found = false;
            for (Slot& to : slots_) {
                if (!to.link || same_target(from, to))
                    continue;
                if (!target_knows(to, ts, want_comp))
                    continue;
                found = true;
                if (bond_lets_send(to, frame))
                    deliver(frame, to);
            }
            if (found) {
                deliver_to_recorders(from, frame);
                return;
            }
            if (want_comp == 0)
                break;
        }
    }
    bool any = false;
    for (Slot& to : slots_) {
        if (to.link && may_send(from, to, frame)) {
            deliver(frame, to);
            any = true;
        }
    }
    if (!any)
        frames_without_destination_++;
}

void Router::inject(const Frame& frame, Reach reach) {
    begin_routing();
    for (Slot& to : slots_) {
        if (!to.link)
            continue;
        bool sends = false;
        switch (reach.kind) {
        case Reach::Everywhere:
            sends = bond_lets_send(to, frame);
            break;
        case Reach::OutsideBonds:
            sends = to.bond == kNoBond;
            break;
        case Reach::OneBond:
            sends = to.bond == reach.bond;
            break;
        case Reach::BondRouted:
            sends = to.bond == reach.bond && bond_lets_send(to, frame);
            break;
        case Reach::LikeBond:
            sends = to.bond != reach.bond && bond_lets_send(to, frame);
            break;
        }
        if (sends)
            deliver(frame, to);
    }
    end_batch();
}

void Router::mark_radio_status_bonds(const Config& config) {
    for (Bond& b : bonds_) {
        b.reports_radio_status = std::any_of(
            config.endpoints.begin(), config.endpoints.end(), [&](const EndpointConfig& ep) {
                return ep.bond == b.name() &&
                       ep.tx_budget.radio_status != RadioStatusSource::None;
            });
    }
}

uint64_t Router::resend_held(uint32_t bond, TimePoint now) {
    Standby* standby = bond < bonds_.size() ? bonds_[bond].standby() : nullptr;
    if (!standby)
        return 0;
    uint64_t sent = 0;
    standby->take_held(now, [&](uint32_t member, std::span<const uint8_t> bytes, uint64_t ticket) {
        // Parsed back as it came (it was a routed frame): the links take a Frame.
        ParserCounters counters;
        DatagramParser parser(bytes, UnknownIdPolicy::Forward, counters);
        Frame frame;
        if (!parser.next(frame))
            return;
        begin_routing();  // signed afresh: a new timestamp for the new copy
        for (Slot& to : slots_) {
            if (to.link && to.bond == bond && to.member == member) {
                deliver(frame, to, ticket);  // the number its first copy took, if one went
                sent++;
            }
        }
        // Each frame's bytes live in the ring only until the next: sent before it is reused.
        end_batch();
    });
    standby->counters().resent += sent;
    return sent;
}

}  // namespace mavbond
