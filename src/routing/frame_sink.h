// What an endpoint is handed to put its frames into routing: a FrameSink (the router). It is
// the whole interface between the two layers: endpoints attach their links and their inputs,
// hand over what each read returned, and end the batch before reusing their buffers; routing
// never calls an endpoint but through Link.
#pragma once

#include <array>
#include <cstddef>
#include <memory>
#include <string>

#include "core/clock.h"
#include "core/event_loop.h"
#include "mavlink/bond_signing.h"
#include "mavlink/frame.h"
#include "routing/link.h"
#include "routing/stream_positions.h"

namespace mavbond {

/// A datagram socket that feeds links of a bond (a UDP server for its peers, a UDP client):
/// what the arrival-order merge must know of it. The endpoint owns it and attaches it to the
/// sink for the socket's life, before its first read.
class Input {
public:
    /// `watch`: the socket's (its address must stay put while the input lives).
    Input(std::string bond, const EventLoop::Watch& watch) : bond_(std::move(bond)), watch_(watch) {}
    Input(const Input&) = delete;
    Input& operator=(const Input&) = delete;

    const std::string& bond() const { return bond_; }
    /// After each read: `until`, the time up to which everything that arrived for it has been
    /// read (the last datagram of a full batch; else the round's start, or the last datagram
    /// if later). `first`: when the first datagram the read returned arrived (zero if none).
    void read(TimePoint until, TimePoint first) {
        last_ = until;
        first_ = first;
    }
    /// The time up to which every datagram that arrived for it has been read, as far as this
    /// round shows: a socket epoll did not report had nothing new when epoll looked (`polled`,
    /// a time no later than that); one it did is read to where its read got.
    TimePoint read_to(TimePoint polled, bool all_reported) const {
        return watch_.ready_this_round() || !all_reported ? last_ : std::max(last_, polled);
    }
    /// When the first datagram of the last read arrived, if epoll reported the socket in this
    /// round (it held that datagram when epoll looked); zero otherwise.
    TimePoint first_reported() const {
        return watch_.ready_this_round() ? first_ : TimePoint{};
    }

private:
    friend class Router;  // places it in its bond
    std::string bond_;
    const EventLoop::Watch& watch_;
    TimePoint last_{};
    TimePoint first_{};
    uint32_t bond_index_ = UINT32_MAX;  // the router's index of bond_ (UINT32_MAX: none)
};

/// One frame as an endpoint hands it over.
struct ReceivedFrame {
    Frame frame;
    Link* from = nullptr;
    TimePoint arrival;  // the kernel's receive time (UDP), the read's time (byte streams)
    /// false: the endpoint's allow_in/block_in refused it; routing only learns its source.
    bool routed = true;
    /// Its place in its source's stream on this link: the router tracks it once, before the
    /// filters, for every frame it routes (stats, linkswitch, dedup and standby read it).
    StreamStep step{};
    /// A frame its link's bond verified (signed by the peer or its source): its signature's
    /// identity, by which the router delivers it once (BondSigning::first_delivery).
    SignedId signed_id{};
};

class FrameSink;

/// The frames of one read in arrival order, from one input (or none: a byte stream), on
/// their way to a sink. Their bytes are lent: an input's until the loop's round ends (a
/// datagram socket is read once a round, into a buffer of its own), a byte stream's until
/// the endpoint calls the sink's end_batch().
class ReceivedBatch {
public:
    static constexpr size_t kCapacity = 64;
    ReceivedBatch(FrameSink& sink, Input* input = nullptr) : sink_(sink), input_(input) {}

    /// Adds a frame; a full batch goes to the sink first.
    inline void add(const Frame& frame, Link& from, TimePoint arrival, bool routed,
                    const SignedId& signed_id = {});
    /// Hands the frames to the sink. Called after every read that returned something, even
    /// when no frame came of it: the sink learns how far the input is read.
    inline void submit();

    size_t size() const { return size_; }
    Input* input() const { return input_; }
    ReceivedFrame& operator[](size_t i) { return frames_[i]; }

private:
    FrameSink& sink_;
    Input* input_;
    std::array<ReceivedFrame, kCapacity> frames_;
    size_t size_ = 0;
};

class FrameSink {
public:
    virtual ~FrameSink() = default;
    /// A link comes (a UART or client opened, a UDP peer learned, a TCP client accepted); it
    /// must detach before it goes away.
    virtual void attach(Link& link) = 0;
    virtual void detach(Link& link) = 0;
    /// An input of a bond's links comes (before its first read) and goes.
    virtual void attach(Input& input) = 0;
    virtual void detach(Input& input) = 0;
    /// Takes the frames of a read (ReceivedBatch::submit). Frames of a bond's links may be
    /// kept aside until the frames that arrived before them are in.
    virtual void ingress(ReceivedBatch& batch) = 0;
    /// Sends what the batches since the last call gave the links, and afterwards no frame a
    /// byte-stream endpoint handed over is lent any more: it calls this before it reuses the
    /// buffer its frames point into. (The loop calls it at every round's end too.)
    virtual void end_batch() = 0;
    /// The signing of bond `bond` (mavlink/bond_signing.h), which the links it signs verify
    /// what they receive with; null when it signs nothing (or there is no such bond).
    virtual std::shared_ptr<BondSigning> bond_signing(const std::string& bond) {
        (void)bond;
        return nullptr;
    }
};

void ReceivedBatch::add(const Frame& frame, Link& from, TimePoint arrival, bool routed,
                        const SignedId& signed_id) {
    if (size_ == kCapacity)
        submit();
    frames_[size_++] = ReceivedFrame{frame, &from, arrival, routed, {}, signed_id};
}

void ReceivedBatch::submit() {
    sink_.ingress(*this);
    size_ = 0;
}

}  // namespace mavbond
