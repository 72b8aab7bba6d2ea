#include "routing/link.h"

#include <algorithm>

namespace mavbond {

LinkCounters& LinkCounters::operator+=(const LinkCounters& o) {
    rx += o.rx;
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
    tx_signed += o.tx_signed;
    resolve_failures += o.resolve_failures;
    address_changes += o.address_changes;
    peer_rebinds += o.peer_rebinds;
    stranger_datagrams += o.stranger_datagrams;
    peers_evicted += o.peers_evicted;
    clients_refused += o.clients_refused;
    clients_idle_closed += o.clients_idle_closed;
    routes_evicted += o.routes_evicted;
    markers_foreign += o.markers_foreign;
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
