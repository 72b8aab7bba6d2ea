#include "endpoints/endpoint.h"

#include <algorithm>
#include <cerrno>

#include "core/event_loop.h"
#include "core/log.h"
#include "mavlink/frame_writer.h"
#include "routing/egress_numbering.h"
#include "routing/standby.h"

namespace mavbond {

bool MessageFilter::passes(uint32_t msgid) const { return config_.passes(msgid); }

namespace {

// What a datagram carries beyond its frame on the way out: IPv4 and UDP headers.
constexpr uint32_t kDatagramOverhead = 20 + 8;
// How soon a bond member's first count marker follows its first frame.
constexpr Duration kFirstCountMarker = milliseconds(100);

}  // namespace

Endpoint::Endpoint(const EndpointConfig& config, std::string name, EventLoop& loop,
                   TxQueue::Mode mode, const Endpoint* parent, Role role)
    : Link(std::move(name), config.name, config.bond, role == Role::Recorder), loop_(loop),
      config_(config), tx_(mode, config.tx_queue_bytes),
      filter_in_(config_.filter_in), filter_out_(config_.filter_out) {
    if (parent) {
        verifier_ = parent->verifier_;
        bond_signing_ = parent->bond_signing_;
        bond_member_ = parent->bond_member_;
    } else if (config.signing.enabled && !config.signing.by_bond) {
        verifier_ = std::make_shared<SignatureVerifier>(config.signing.key);
    }
    budget_ = make_budget();
    if (parent)
        marker_source_ = parent->marker_source_;
    marker_session_ = static_cast<uint32_t>(
        std::chrono::duration_cast<milliseconds>(loop.now().time_since_epoch()).count());
    if (!config.bond.empty() && role == Role::Link) {
        // The first marker as soon as the link has written something (its far side's figure
        // starts there), then one a kCountMarkerEvery.
        marker_timer_ = loop.schedule(kFirstCountMarker, [this] {
            send_count_marker();
            return marked_ == 0 ? kFirstCountMarker : kCountMarkerEvery;
        });
    }
}

void Endpoint::send_count_marker() {
    // Only when frames went out since the last one: an idle link says nothing (a server
    // itself writes nothing; its peers do).
    if (!ready() || tx_.frames_written() <= marked_ ||
        !tx_.put_marker([](void* self, std::span<uint8_t> out, uint64_t before) {
            return static_cast<Endpoint*>(self)->write_marker(out, before);
        }, this))
        return;
    marker_source_.seq++;
    // Its bytes go on the line as a frame's do: a budget pays for them.
    if (budget_)
        budget_->spend(marker_length(), loop_.now());
    flush();
}

size_t Endpoint::write_marker(std::span<uint8_t> out, uint64_t frames_before) {
    marked_ = frames_before + 1;
    const CountMarker marker{static_cast<uint32_t>(frames_before), marker_session_, standby()};
    if (!bond_signing_)
        return write_count_marker(out, marker_source_, config_.name, marker);
    // On a link its bond signs the far side takes only signed frames: the marker too.
    std::array<uint8_t, kMaxFrameLen> plain;
    size_t len = write_count_marker(plain, marker_source_, config_.name, marker);
    return bond_signing_->sign(std::span<const uint8_t>(plain.data(), len), out);
}

size_t Endpoint::marker_length() const {
    return count_marker_length(config_.name) + (bond_signing_ ? kSignatureLen : 0);
}

std::unique_ptr<TxBudget> Endpoint::make_budget() {
    const TxBudgetConfig& b = config_.tx_budget;
    if (!b.enabled()) {
        follow_radio(0);
        return nullptr;
    }
    // A UART's own rate: 8N1 puts 10 bits on the line for each byte. A rate in baud is a
    // serial line's (a radio behind the datagrams): no headers go over it.
    uint64_t rate = b.uart_baud ? config_.options.number("baud") / 10 : b.bytes_per_s;
    rate = follow_radio(rate);
    bool headers = tx_.mode() == TxQueue::Mode::Datagram && !b.serial;
    return std::make_unique<TxBudget>(rate, headers ? kDatagramOverhead : 0, b.classes,
                                      config_.tx_queue_bytes, stats_.tx_class);
}

uint64_t Endpoint::follow_radio(uint64_t ceiling) {
    if (config_.tx_budget.radio_status == RadioStatusSource::None || ceiling == 0) {
        radio_.reset();
        radio_timer_.cancel();
        return ceiling;
    }
    if (radio_)
        radio_->set_ceiling(ceiling);  // a reload: what the reports learned stays
    else
        radio_ = std::make_unique<RadioFlow>(ceiling, loop_.now());
    if (!radio_timer_.active()) {
        radio_timer_ = loop_.schedule(seconds(1), [this] {
            if (radio_ && budget_ && radio_->check(loop_.now()) != budget_->bytes_per_s())
                apply_radio_rate(radio_->rate());
            return Duration(seconds(1));
        });
    }
    return radio_->rate();
}

void Endpoint::retune(const TxBudgetConfig& budget) {
    if (budget_)
        budget_->drain(loop_.now(), [this](std::span<uint8_t> b, uint64_t t) { lend_held(b, t); });
    budget_timer_.cancel();
    budget_due_ = TimePoint::max();
    config_.tx_budget = budget;
    budget_ = make_budget();
}

Endpoint::~Endpoint() = default;

void Endpoint::defer(EventLoop& loop, std::function<void()> fn) {
    loop.defer([alive = std::weak_ptr<void>(alive_), fn = std::move(fn)] {
        if (!alive.expired())
            fn();
    });
}

uint8_t Endpoint::take_budget_room(TimePoint now) {
    if (!budget_)
        return 100;
    const TxBudget::Load load = budget_->load();
    const TxBudget::Load d = load - room_seen_;
    const double span_s = room_at_ == TimePoint{} ? 0.0
                                                  : std::chrono::duration<double>(now - room_at_).count();
    room_seen_ = load;
    room_at_ = now;
    return budget_room(d.offered_frames, d.offered_bytes, d.lost, budget_->bytes_per_s(), span_s);
}

void Endpoint::take_radio_report(const Frame& frame, TimePoint arrival) {
    uint64_t before = radio_->rate();
    // Only a rate that held the stream back may grow: the buffer of a radio given less than
    // the rate lets is empty whatever the radio could carry. Held back: samples thinned since
    // the last report, or a queue waiting (a file transfer); a sample that waits a few ms for
    // the bucket is pacing, not a rate too low.
    uint64_t lost = 0;  // the link's counters: they outlive a budget a reload replaces
    for (const TxClassCounters& c : stats_.tx_class)
        lost += c.thinned + c.dropped;
    const bool rate_was_limit = lost != lost_at_report_ || (budget_ && budget_->queued());
    lost_at_report_ = lost;
    uint64_t rate = radio_->report(RadioReport::decode(frame.payload), arrival, rate_was_limit);
    if (rate != before)
        apply_radio_rate(rate);
}

void Endpoint::apply_radio_rate(uint64_t rate) {
    if (!budget_)
        return;
    budget_->set_rate(rate, loop_.now());
    // Held frames wait on a timer set for the old rate: after this round (the receive batch
    // in progress lends frames to the queue until its end), they go by the new one.
    defer(loop_, [this] {
        if (budget_ && budget_->holding())
            release_budgeted();
    });
}

bool Endpoint::sign_with(std::shared_ptr<BondSigning> signing) {
    std::optional<unsigned> member = signing ? signing->member(config_.name) : std::nullopt;
    if (!member)
        return false;
    bond_signing_ = std::move(signing);
    bond_member_ = *member;
    return true;
}

Endpoint::Received Endpoint::receive(ReceivedBatch& batch, const Frame& received,
                                     TimePoint arrival, SignedId* id) {
    // The radio's own report is taken here and goes no further: mavbond reports for the bond
    // (src/daemon/radio_report.h). Before the signature check: a radio cannot sign. Nor does it
    // make the link look alive: the radio says it whether or not the far side hears.
    if (radio_ && is_radio_report(received, config_.tx_budget.radio_status)) {
        take_radio_report(received, arrival);
        return Received::Taken;  // nor does it say who sends on the link
    }
    Frame frame = received;
    SignedId own;
    SignedId& signed_id = id ? *id : own;
    Received how = judge(frame, signed_id);
    if (how == Received::Refused) {
        // The far side wrote it (or a stranger did): it arrived, whatever it is, and tells
        // nothing (a marker that does not verify included).
        if (!is_radio_own_report(received))
            account().frame_in();
        return how;
    }
    return let_in(batch, frame, arrival, signed_id) ? how : Received::Taken;
}

bool Endpoint::let_in(ReceivedBatch& batch, const Frame& frame, TimePoint arrival,
                      const SignedId& id) {
    // Heard: what signing let in (a stranger's forged frames keep no dead link alive). A
    // radio's own report (when the radio is not this link's budget) neither counts nor says
    // the far side is there.
    const bool radio_own = is_radio_own_report(frame);
    if (!radio_own)
        stats_.last_rx = arrival;
    CountMarker marker;
    if (read_count_marker(frame, marker)) {
        if (marker.names(config_.name))
            account().take_marker(marker, arrival);  // the link's own: never routed
        else
            stats_.markers_foreign++;
        return false;
    }
    if (!radio_own)
        account().frame_in();
    bool accepted = filter_in_.empty() || filter_in_.passes(frame.msgid);
    if (!accepted)
        stats_.rx_filtered++;
    batch.add(frame, *this, arrival, accepted, id);
    return true;
}

Endpoint::Received Endpoint::judge(Frame& frame, SignedId& id) {
    if (!config_.signing.enabled)
        return frame.crc_checked ? Received::Valid : Received::Unchecked;
    SignatureVerifier::Verdict verdict = SignatureVerifier::Verdict::BadSignature;
    if (bond_signing_)
        verdict = bond_signing_->verify(frame, bond_member_, &id);
    else if (verifier_)
        verdict = verifier_->check(frame);
    // else a link its bond signs that was never given the bond's signing: nothing passes.
    switch (verdict) {
    case SignatureVerifier::Verdict::Accept:
        return Received::Verified;
    case SignatureVerifier::Verdict::Unsigned:
        stats_.sig_unsigned++;
        if (config_.signing.require)
            return Received::Refused;
        break;
    case SignatureVerifier::Verdict::BadSignature:
        stats_.sig_bad++;
        return Received::Refused;
    case SignatureVerifier::Verdict::Replay:
        stats_.sig_replay++;
        return Received::Refused;
    }
    return frame.crc_checked ? Received::Valid : Received::Unchecked;
}

bool Endpoint::send(const Frame& frame, BondCopy* copy) {
    if (!filter_out_.empty() && !filter_out_.passes(frame.msgid)) {
        stats_.tx_filtered++;
        return false;
    }
    if (!ready()) {
        stats_.tx_dropped++;
        return false;
    }
    // A frame its bond numbers comes as routed: signed, where the bond signs this link, only
    // as it goes; its budget is charged the signature now.
    const bool signs = copy && bond_signing_ && !frame.is_signed() && frame.version == 2;
    const uint8_t extra = signs ? static_cast<uint8_t>(kSignatureLen) : 0;
    if (budget_ && Standby::is_report(frame)) {
        // The bond's standby reports go on every member at once, paid for as its count markers
        // are: a budget that held or thinned them (one sample slot for all of mavbond's
        // NAMED_VALUE_INTs) would make the far side take the link for silent (LinkSilence).
        budget_->spend(frame.bytes.size() + extra, loop_.now());
    } else if (budget_ && !budget_->offer(frame, loop_.now(), copy ? copy->ticket : 0, extra)) {
        if (copy && numbering_ != copy->numbering)
            numbering_ = copy->numbering;
        release_budgeted();  // it waits (or a cap or its class's turn holds it)
        return false;
    }
    const Frame* out = copy ? copy->now(bond_signing_ != nullptr) : &frame;
    if (!out)
        return false;  // MAVLink 1 on a link its bond signs (counted by the bond)
    count_signed(out->bytes);
    bool was_clean = !tx_.has_lent();
    if (!tx_.lend(out->bytes)) {
        flush();
        tx_.lend(out->bytes);
        was_clean = true;
    }
    return was_clean;
}

void Endpoint::lend_held(std::span<uint8_t> frame, uint64_t ticket) {
    if (ticket == 0 || !numbering_) {
        lend_now(frame);
        return;
    }
    if (numbering_->superseded(ticket))
        return;  // another link carried it long ago (routing/egress_numbering.h)
    rewrite_seq(frame, numbering_->number(ticket, frame[frame[0] == kMagicV2 ? 5 : 3],
                                          frame[frame[0] == kMagicV2 ? 6 : 4]));
    if (!bond_signing_) {
        lend_now(frame);
        return;
    }
    std::array<uint8_t, kMaxFrameLen> signed_frame;
    const size_t n = bond_signing_->sign(frame, signed_frame);
    if (n != 0)
        lend_now(std::span<const uint8_t>(signed_frame.data(), n));
}

void Endpoint::lend_now(std::span<const uint8_t> frame) {
    if (!ready()) {
        stats_.tx_dropped++;
        return;
    }
    count_signed(frame);
    if (!tx_.lend(frame)) {
        flush();
        tx_.lend(frame);
    }
    flush();
}

void Endpoint::release_budgeted() {
    const TimePoint now = loop_.now();
    // A held frame's bytes are the budget's until its next call: each goes out at once.
    TimePoint due = budget_->release(now, [this](std::span<uint8_t> b, uint64_t t) { lend_held(b, t); });
    if (due == TimePoint::max() || (budget_timer_.active() && budget_due_ <= due))
        return;
    budget_due_ = due;
    budget_timer_ = loop_.schedule(std::max(due - now, Duration(1)), [this] {
        budget_timer_.cancel();
        budget_due_ = TimePoint::max();
        release_budgeted();
        return Duration::zero();
    });
}

int Endpoint::write_datagrams(const iovec*, size_t) { return -ENOTSUP; }
ssize_t Endpoint::write_stream(const iovec*, size_t) { return -ENOTSUP; }

void Endpoint::flush() {
    if (tx_.empty())
        return;
    TxQueue::WriteResult r;
    if (tx_.mode() == TxQueue::Mode::Datagram) {
        r = tx_.write_datagrams(
            [](void* self, const iovec* frames, size_t count) {
                return static_cast<Endpoint*>(self)->write_datagrams(frames, count);
            },
            this);
    } else {
        r = tx_.write_stream(
            [](void* self, const iovec* iov, size_t count) {
                return static_cast<Endpoint*>(self)->write_stream(iov, count);
            },
            this);
    }
    stats_.tx_frames += r.frames_sent;
    stats_.tx_bytes += r.bytes_sent;
    stats_.tx_dropped += r.frames_dropped;
    if (r.error != 0) {
        stats_.tx_errors++;
        if (tx_.mode() == TxQueue::Mode::Stream)
            on_write_error(r.error);
    }
    on_backlog(tx_.has_backlog());
}

void Endpoint::finish(TimePoint deadline) {
    if (budget_)  // what the budget held goes now, or is counted below with the rest
        budget_->drain(loop_.now(), [this](std::span<uint8_t> b, uint64_t t) { lend_held(b, t); });
    flush();
    while (tx_.mid_frame() && wait_writable(deadline))
        flush();
    // A peer that took only part of a frame gets the rest of the stream as it is: every whole
    // frame the kernel holds for it still arrives, then the cut frame (counted as dropped),
    // which a MAVLink parser discards. A reset instead would lose all of those frames.
    if (tx_.mid_frame())
        log_warning("[%s] the peer took only part of a frame before the stop: its stream ends "
                    "with a cut frame", name().c_str());
    clear_tx();
}

void Endpoint::clear_tx() {
    stats_.tx_dropped += tx_.clear() + (budget_ ? budget_->clear() : 0);
    on_backlog(false);
}

}  // namespace mavbond
