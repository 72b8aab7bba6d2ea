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
    last_rx = std::max(last_rx, o.last_rx);
    for (size_t c = 0; c < kTxClassCount; c++) {
        tx_class[c].frames += o.tx_class[c].frames;
        tx_class[c].bytes += o.tx_class[c].bytes;
        tx_class[c].waited += o.tx_class[c].waited;
        tx_class[c].thinned += o.tx_class[c].thinned;
        tx_class[c].dropped += o.tx_class[c].dropped;
    }
    return *this;
}

}  // namespace mavbond
