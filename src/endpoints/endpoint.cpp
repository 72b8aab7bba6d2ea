#include "endpoints/endpoint.h"

#include <algorithm>
#include <cerrno>

#include "core/event_loop.h"
#include "core/log.h"

namespace mavbond {

bool MessageFilter::passes(uint32_t msgid) const {
    auto has = [msgid](const std::vector<uint32_t>& list) {
        return std::find(list.begin(), list.end(), msgid) != list.end();
    };
    if (!config_.allow.empty() && !has(config_.allow))
        return false;
    return !has(config_.block);
}

namespace {

// What a datagram carries beyond its frame on the way out: IPv4 and UDP headers.
constexpr uint32_t kDatagramOverhead = 20 + 8;

}  // namespace

Endpoint::Endpoint(const EndpointConfig& config, std::string name, EventLoop& loop,
                   TxQueue::Mode mode, const Endpoint* parent, Role role)
    : Link(std::move(name), config.name, config.bond, role == Role::Recorder), loop_(loop),
      config_(config), tx_(mode, config.tx_queue_bytes),
      filter_in_(config_.filter_in), filter_out_(config_.filter_out) {
    if (parent)
        verifier_ = parent->verifier_;
    else if (config.signing.enabled)
        verifier_ = std::make_shared<SignatureVerifier>(config.signing.key);
    budget_ = make_budget();
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
        radio_ = std::make_unique<RadioFlow>(ceiling);
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
        budget_->drain(loop_.now(), [this](std::span<const uint8_t> b) { lend_now(b); });
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

void Endpoint::take_radio_report(const Frame& frame, TimePoint arrival) {
    uint64_t before = radio_->rate();
    uint64_t rate = radio_->report(RadioReport::decode(frame.payload), arrival);
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

bool Endpoint::receive(ReceivedBatch& batch, const Frame& frame, TimePoint arrival) {
    // The radio's own report is taken here and goes no further: mavbond reports for the bond
    // (src/daemon/radio_report.h). Before the signature check: a radio cannot sign. Nor does it
    // make the link look alive: the radio says it whether or not the far side hears.
    if (radio_ && is_radio_report(frame, config_.tx_budget.radio_status)) {
        take_radio_report(frame, arrival);
        return false;  // nor does it say who sends on the link
    }
    stats_.last_rx = arrival;
    if (verifier_ && !authentic(frame))
        return false;
    bool accepted = filter_in_.empty() || filter_in_.passes(frame.msgid);
    if (!accepted)
        stats_.rx_filtered++;
    batch.add(frame, *this, arrival, accepted);
    return true;
}

Endpoint::FrameOrigin Endpoint::receive_datagram(ReceivedBatch& batch,
                                                 std::span<const uint8_t> datagram,
                                                 TimePoint arrival, UnknownIdPolicy policy) {
    DatagramParser parser(datagram, policy, stats_.rx);
    Frame frame;
    FrameOrigin last;
    while (parser.next(frame)) {
        // A frame signing refuses says nothing about who sent it (it may be forged).
        if (receive(batch, frame, arrival))
            last = FrameOrigin{true, frame.sysid, frame.compid, frame.seq};
    }
    return last;
}

bool Endpoint::authentic(const Frame& frame) {
    switch (verifier_->check(frame)) {
    case SignatureVerifier::Verdict::Accept:
        return true;
    case SignatureVerifier::Verdict::Unsigned:
        stats_.sig_unsigned++;
        return !config_.signing.require;
    case SignatureVerifier::Verdict::BadSignature:
        stats_.sig_bad++;
        return false;
    case SignatureVerifier::Verdict::Replay:
        stats_.sig_replay++;
        return false;
    }
    return false;
}

bool Endpoint::send(const Frame& frame) {
    if (!filter_out_.empty() && !filter_out_.passes(frame.msgid)) {
        stats_.tx_filtered++;
        return false;
    }
    if (!ready()) {
        stats_.tx_dropped++;
        return false;
    }
    if (budget_ && !budget_->offer(frame, loop_.now())) {
        release_budgeted();  // it waits (or a cap or its class's turn holds it)
        return false;
    }
    bool was_clean = !tx_.has_lent();
    if (!tx_.lend(frame.bytes)) {
        flush();
        tx_.lend(frame.bytes);
        was_clean = true;
    }
    return was_clean;
}

void Endpoint::lend_now(std::span<const uint8_t> frame) {
    if (!ready()) {
        stats_.tx_dropped++;
        return;
    }
    if (!tx_.lend(frame)) {
        flush();
        tx_.lend(frame);
    }
    flush();
}

void Endpoint::release_budgeted() {
    const TimePoint now = loop_.now();
    // A held frame's bytes are the budget's until its next call: each goes out at once.
    TimePoint due = budget_->release(now, [this](std::span<const uint8_t> b) { lend_now(b); });
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
        budget_->drain(loop_.now(), [this](std::span<const uint8_t> bytes) { lend_now(bytes); });
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
