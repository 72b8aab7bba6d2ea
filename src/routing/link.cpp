#include "routing/link.h"

#include <algorithm>

namespace mavbond {

LinkCounters& LinkCounters::operator+=(const LinkCounters& o) {
    rx.frames += o.rx.frames;
    rx.bytes += o.rx.bytes;
    rx.crc_errors += o.rx.crc_errors;
    rx.garbage_bytes += o.rx.garbage_bytes;
    rx.unknown_ids += o.rx.unknown_ids;
    rx.bad_flags += o.rx.bad_flags;
    rx_filtered += o.rx_filtered;
    rx_overflows += o.rx_overflows;
    tx_frames += o.tx_frames;
    tx_bytes += o.tx_bytes;
    tx_filtered += o.tx_filtered;
    tx_dropped += o.tx_dropped;
    tx_errors += o.tx_errors;
    sig_unsigned += o.sig_unsigned;
    sig_bad += o.sig_bad;
    sig_replay += o.sig_replay;
    resolve_failures += o.resolve_failures;
    address_changes += o.address_changes;
    peer_rebinds += o.peer_rebinds;
    last_rx = std::max(last_rx, o.last_rx);
    for (size_t c = 0; c < kTxClassCount; c++)
        tx_class[c] += o.tx_class[c];
    return *this;
}

TxClassCounters& TxClassCounters::operator+=(const TxClassCounters& o) {
    frames += o.frames;
    bytes += o.bytes;
    waited += o.waited;
    thinned += o.thinned;
    dropped += o.dropped;
    return *this;
}

}  // namespace mavbond
