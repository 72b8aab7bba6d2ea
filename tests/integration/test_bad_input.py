"""Garbage, truncated frames and wrong CRCs between good frames, on UDP and on a pty: every
good frame is delivered, in order and unchanged, and the counters account for the rest."""
from __future__ import annotations

import random
from typing import List, Tuple

from helpers import (HOST, FrameMaker, corrupt_crc, free_port, recv_datagrams, send_paced,
                     split_stream, uart, udp_client, udp_server, udp_socket)

Piece = Tuple[str, bytes]  # ("good" | "garbage" | "trunc" | "badcrc", bytes)


def garbage(rng: random.Random, n: int, with_start_bytes: bool = False) -> bytes:
    b = bytearray(rng.randrange(256) for _ in range(n))
    if with_start_bytes:
        # start bytes with lengths that run into what follows
        b[0] = 0xFD
        b[n // 2] = 0xFE
    return bytes(b)


def build_datagrams(rounds: int = 20, seed: int = 7) -> List[List[Piece]]:
    """Datagrams, each a list of pieces, mixing good and bad in every arrangement."""
    rng = random.Random(seed)
    v2, v1 = FrameMaker(1, 1), FrameMaker(1, 1, v1=True)
    out: List[List[Piece]] = []
    for r in range(rounds):
        good = lambda: ("good", v2.attitude(r))  # noqa: E731
        out += [
            [good()],
            [("garbage", garbage(rng, 20))],
            [good(), ("garbage", garbage(rng, 7))],
            [("garbage", garbage(rng, 9)), good()],
            [("trunc", v2.sys_status()[:12])],
            [("badcrc", corrupt_crc(v2.heartbeat()))],
            [good(), good()],
            [("trunc", v2.attitude(r)[:20]), good()],
            [good(), ("badcrc", corrupt_crc(v2.sys_status())), good()],
            [("garbage", garbage(rng, 12, with_start_bytes=True)), good()],
            [("good", v1.heartbeat())],
            [("badcrc", corrupt_crc(v1.attitude(r)))],
            [("good", v1.attitude(r)), ("trunc", v1.heartbeat()[:5])],
        ]
    return out


def tally(pieces: List[Piece]):
    good = [b for k, b in pieces if k == "good"]
    n_bad = sum(1 for k, _ in pieces if k == "badcrc")
    junk = sum(len(b) for k, b in pieces if k in ("garbage", "trunc", "badcrc"))
    return good, n_bad, junk


def test_bad_input_udp(start_daemon):
    datagrams = build_datagrams()
    pieces = [p for dg in datagrams for p in dg]
    good, n_bad, junk = tally(pieces)
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)])
    tx = udp_socket()
    try:
        # paced: 260 small datagrams at once would overflow a default 208 KiB receive buffer
        send_paced(tx, (HOST, in_port), [b"".join(b for _, b in dg) for dg in datagrams],
                   burst=50, pause=0.01)
        got = [f for dg in recv_datagrams(rx, len(good), timeout=5) for f in split_stream(dg)]
        st = d.settle_stats(lambda s: s["in"]["rx_frames"])["in"]
    finally:
        tx.close()
        rx.close()
    print(f"\nUDP: {len(datagrams)} datagrams, {len(good)} good frames, {n_bad} bad CRCs, "
          f"{junk} bytes of garbage/truncated/bad frames; delivered {len(got)}")
    print(f"  mavbond in: rx_frames={st['rx_frames']} crc_errors={st['crc_errors']} "
          f"garbage_bytes={st['garbage_bytes']}")
    assert got == good, "every good frame, in order, unchanged"
    assert st["rx_frames"] == len(good)
    assert st["crc_errors"] >= n_bad
    assert st["garbage_bytes"] > 0
    # Every byte that was not a good frame is accounted for as garbage (a rejected frame's
    # bytes become garbage).
    assert st["garbage_bytes"] == junk
    assert d.stop() == 0


def test_bad_input_pty_stream(start_daemon, pty_pair):
    datagrams = build_datagrams(rounds=30, seed=11)
    # end on a good frame: bytes after the last frame wait in the parser for more input
    datagrams.append([("good", FrameMaker(1, 1).heartbeat())])
    pieces = [p for dg in datagrams for p in dg]
    good, n_bad, junk = tally(pieces)
    stream = b"".join(b for _, b in pieces)
    pty = pty_pair()
    out_port = free_port()
    rx = udp_socket(out_port)
    d = start_daemon([uart("u", pty.path, baud=921600), udp_client("out", out_port)])
    d.wait_log(r"\[uart:u\] .* open at 921600 baud")
    try:
        # In odd-sized slices, so frames and garbage straddle reads.
        for pos in range(0, len(stream), 997):
            pty.write_all(stream[pos:pos + 997])
        got = [f for dg in recv_datagrams(rx, len(good), timeout=5) for f in split_stream(dg)]
        st = d.settle_stats(lambda s: s["u"]["rx_frames"])["u"]
    finally:
        rx.close()
    print(f"\npty: {len(stream)} bytes, {len(good)} good frames, {n_bad} bad CRCs, {junk} bytes "
          f"of garbage/truncated/bad frames; delivered {len(got)}")
    print(f"  mavbond u: rx_frames={st['rx_frames']} crc_errors={st['crc_errors']} "
          f"garbage_bytes={st['garbage_bytes']}")
    assert got == good, "every good frame, in order, unchanged"
    assert st["rx_frames"] == len(good)
    assert st["crc_errors"] >= n_bad
    assert st["garbage_bytes"] == junk
    assert d.stop() == 0


def test_empty_and_noise_datagrams(start_daemon):
    """An empty datagram and datagrams of noise change nothing for the frames after them;
    the noise is counted. (Datagrams larger than 2 KiB: see the next test.)"""
    import os as _os
    vm = FrameMaker(1, 1)
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)])
    tx = udp_socket()
    noise = bytes(b for b in _os.urandom(3000) if b not in (0xFD, 0xFE))[:1800]
    frames = [vm.heartbeat(), vm.attitude(1), vm.sys_status()]
    try:
        tx.sendto(frames[0], (HOST, in_port))
        tx.sendto(b"", (HOST, in_port))
        tx.sendto(noise, (HOST, in_port))
        tx.sendto(noise[:1000] + frames[1], (HOST, in_port))
        tx.sendto(frames[2], (HOST, in_port))
        got = [f for dg in recv_datagrams(rx, 3, timeout=3) for f in split_stream(dg)]
        st = d.settle_stats(lambda s: s["in"]["garbage_bytes"])["in"]
    finally:
        tx.close()
        rx.close()
    print(f"\nempty + 1800-byte noise datagrams: delivered {len(got)}/3, "
          f"garbage_bytes={st['garbage_bytes']}")
    assert got == frames
    assert st["garbage_bytes"] == len(noise) + 1000
    assert d.alive()
    assert d.stop() == 0


def test_datagram_larger_than_2k_with_many_frames(start_daemon):
    """A datagram may carry many frames (e.g. socat or a serial-to-UDP bridge forwards
    whatever a read returned, up to 8 KiB or more). All of them must be delivered, and if
    the daemon cannot take a datagram whole, what it cut must at least be counted.
    Also a 65,000-byte datagram of noise is counted in full."""
    import os as _os
    vm = FrameMaker(1, 1)
    frames = vm.telemetry(200)  # 7,800 bytes
    big = b"".join(frames)
    noise = bytes(b for b in _os.urandom(70000) if b not in (0xFD, 0xFE))[:65000]
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)])
    tx = udp_socket()
    try:
        tx.sendto(big, (HOST, in_port))
        got = [f for dg in recv_datagrams(rx, len(frames), timeout=2) for f in split_stream(dg)]
        st1 = d.settle_stats(lambda s: s["in"]["rx_bytes"])["in"]
        tx.sendto(noise, (HOST, in_port))
        st2 = d.settle_stats(lambda s: s["in"]["garbage_bytes"])["in"]
    finally:
        tx.close()
        rx.close()
    print(f"\none {len(big)}-byte datagram of {len(frames)} frames: delivered {len(got)}; "
          f"in rx_frames={st1['rx_frames']} rx_bytes={st1['rx_bytes']} "
          f"garbage_bytes={st1['garbage_bytes']}; after a {len(noise)}-byte noise datagram "
          f"garbage_bytes={st2['garbage_bytes']}")
    accounted = st1["rx_bytes"] + st1["garbage_bytes"]
    assert accounted == len(big), (f"{len(big) - accounted} bytes of the datagram vanished "
                                   f"without being counted")
    assert got == frames, f"{len(frames) - len(got)} good frames lost from one large datagram"
    assert st2["garbage_bytes"] - st1["garbage_bytes"] == len(noise)
