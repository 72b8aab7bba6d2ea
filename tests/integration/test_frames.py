"""Frame shapes at the edges: signed v2 frames, unknown incompat flags, the largest frames,
and a TCP client that does not read (bounded queue: others do not wait)."""
from __future__ import annotations

import socket
import time

from helpers import (HOST, FrameMaker, free_port, recv_datagrams, send_paced, split_stream,
                     tcp_server, tlog, uart, udp_client, udp_server, udp_socket)


def signed_maker(sysid=1, compid=1) -> FrameMaker:
    m = FrameMaker(sysid, compid)
    m.mav.signing.secret_key = bytes(range(32))
    m.mav.signing.link_id = 3
    m.mav.signing.timestamp = 1_000_000
    m.mav.signing.sign_outgoing = True
    return m


def big_frames(m: FrameMaker, n: int):
    """FILE_TRANSFER_PROTOCOL with a full payload (266 bytes on the wire, 279 when signed)."""
    out = []
    for i in range(n):
        payload = bytes((i + k) % 251 or 1 for k in range(251))
        out.append(m.pack(m.mod.MAVLink_file_transfer_protocol_message(0, 0, 0, payload)))  # broadcast
    return out


def test_signed_and_largest_frames_udp_and_pty(start_daemon, pty_pair):
    sm = signed_maker()
    frames = [sm.heartbeat(), sm.attitude(5)] + big_frames(sm, 3) + big_frames(FrameMaker(1, 1), 3)
    assert all(f[2] & 0x01 for f in frames[:5]) and len(frames[2]) == 279
    assert len(frames[5]) == 266  # 254-byte payload: the largest
    assert all(tlog.crc_ok(f) for f in frames)
    pty = pty_pair()
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), uart("u", pty.path, baud=1500000),
                      udp_client("out", out_port)])
    d.wait_log(r"\[uart:u\] .* open at")
    tx = udp_socket()
    try:
        for f in frames:
            tx.sendto(f, (HOST, in_port))
        got = [f for dg in recv_datagrams(rx, len(frames), timeout=3) for f in split_stream(dg)]
        at_pty = split_stream(pty.read_for(timeout=3, until=lambda b: len(split_stream(b)) >= len(frames)))
        # and from the pty side
        pty.write_all(b"".join(frames))
        got_from_pty = [f for dg in recv_datagrams(rx, len(frames), timeout=3) for f in split_stream(dg)]
        st = d.stats()
    finally:
        tx.close()
        rx.close()
    print(f"\nsigned/large frames: UDP->UDP {len(got)}/{len(frames)}, UDP->pty {len(at_pty)}, "
          f"pty->UDP {len(got_from_pty)}; in bad_flags={st['in']['bad_flags']}")
    assert got == frames, "signed frames are forwarded with their signature, unchanged"
    assert at_pty == frames
    assert got_from_pty == frames
    assert st["in"]["bad_flags"] == 0 and st["u"]["crc_errors"] == 0
    assert d.stop() == 0


def test_unknown_incompat_flags_dropped(start_daemon):
    """A v2 frame with an incompat flag the daemon does not understand must be discarded
    (MAVLink 2 spec) and counted in bad_flags; the frames around it pass."""
    vm = FrameMaker(1, 1)
    good1, odd, good2 = vm.heartbeat(), bytearray(vm.attitude(1)), vm.heartbeat()
    odd[2] |= 0x02  # unknown incompat flag; CRC recomputed so only the flag is wrong
    extra = tlog.crc_extras()[tlog.msgid(bytes(odd))]
    crc = tlog.compute_crc(bytes(odd), extra)
    odd[-2:] = bytes([crc & 0xFF, crc >> 8])
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)])
    tx = udp_socket()
    try:
        for f in (good1, bytes(odd), good2):
            tx.sendto(f, (HOST, in_port))
        got = [f for dg in recv_datagrams(rx, 2, timeout=2) for f in split_stream(dg)]
        got += [f for dg in recv_datagrams(rx, None, timeout=0.3) for f in split_stream(dg)]
        st = d.stats()["in"]
    finally:
        tx.close()
        rx.close()
    print(f"\nincompat flag 0x02: forwarded {len(got)} of 3; bad_flags={st['bad_flags']}")
    assert got == [good1, good2]
    assert st["bad_flags"] == 1
    assert d.stop() == 0


def test_stalled_tcp_client_does_not_block_others(start_daemon):
    """A TCP client that never reads: its queue fills, frames for it are dropped and counted,
    and the UDP GCS still receives everything."""
    tcp_port, in_port, gcs_port = free_port(socket.SOCK_STREAM), free_port(), free_port()
    d = start_daemon([tcp_server("t", tcp_port), udp_server("in", in_port),
                      udp_server("gcs", gcs_port)])
    stalled = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: small window
    stalled.connect((HOST, tcp_port))
    d.wait_log(r"\[tcp:t\] client .* connected")
    gcs = udp_socket()
    gm, vm = FrameMaker(255, 190), FrameMaker(1, 1)
    tx = udp_socket()
    try:
        gcs.sendto(gm.heartbeat(6), (HOST, gcs_port))
        time.sleep(0.2)
        # 8 MB: more than the kernel's socket buffers (tcp_wmem max is typically 4 MB, and
        # it grows to it for a peer that does not read) plus the 16 KiB tx_queue
        frames = big_frames(vm, 100) * 300
        t0 = time.monotonic()
        got = []
        for i in range(0, len(frames), 100):
            send_paced(tx, (HOST, in_port), frames[i:i + 100], burst=100)
            got += [f for dg in recv_datagrams(gcs, min(i + 100, len(frames)) - len(got), timeout=2)
                    for f in split_stream(dg)]
        elapsed = time.monotonic() - t0
        st = d.settle_stats(lambda s: s["t"]["tx_dropped"])
    finally:
        stalled.close()
        gcs.close()
        tx.close()
    print(f"\nstalled TCP client: GCS got {len(got)}/{len(frames)} in {elapsed:.1f}s; t "
          f"tx_frames={st['t']['tx_frames']} tx_dropped={st['t']['tx_dropped']}")
    assert got == frames
    assert st["t"]["tx_dropped"] > 0
    # everything routed to it was written, dropped, or still waits in its 16 KiB queue
    accounted = st["t"]["tx_frames"] + st["t"]["tx_dropped"]
    assert len(frames) + 1 - (16384 // 266 + 1) <= accounted <= len(frames) + 1
    assert d.alive()
    assert d.stop() == 0
