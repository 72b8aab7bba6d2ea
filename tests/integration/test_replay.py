"""Replays every recorded log of the shared data set through mavbond: UDP in -> UDP out, and a
byte stream through a pty. The output must be complete, byte-identical and in order, except
for frames whose CRC is wrong, which mavbond drops and counts. What is expected is computed
here independently, with pymavlink's CRC and crc_extra tables (tests/tools/tlog.py).

All frames of a log come in from one peer and there is one other endpoint, so routing sends
every frame there: broadcasts, and targeted frames whose target was heard only on the
source (it is not known anywhere else)."""
from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import List

import pytest

from conftest import tlog_files
from helpers import HOST, free_port, tlog, uart, udp_client, udp_server, udp_socket

BURST = 100  # datagrams in flight at most: well inside the default 208 KiB receive buffers


def load(path: Path):
    frames = [f for _, f in tlog.iter_frames(path)]
    verdicts = [tlog.crc_ok(f) for f in frames]
    expected = [f for f, ok in zip(frames, verdicts) if ok is not False]
    return frames, verdicts, expected


def recv_until(sock: socket.socket, out: List[bytes], have: List[int], want_bytes: int,
               timeout: float) -> None:
    """Appends datagrams to `out` until have[0] (bytes received) reaches want_bytes or the
    socket was quiet for `timeout`."""
    sock.settimeout(timeout)
    while have[0] < want_bytes:
        try:
            dg = sock.recv(65536)
        except socket.timeout:
            return
        out.append(dg)
        have[0] += len(dg)


def compare(got: bytes, expected: List[bytes]) -> str:
    """'' when `got` is exactly the expected frames; else where it first differs."""
    want = b"".join(expected)
    if got == want:
        return ""
    got_frames = [r.data for r in tlog.iter_records_bytes(got, raw=True) if r.kind == "frame"]
    for i, (g, w) in enumerate(zip(got_frames, expected)):
        if g != w:
            return (f"frame {i} differs: got {g.hex()} (msgid {tlog.msgid(g)}), expected "
                    f"{w.hex()} (msgid {tlog.msgid(w)}); {len(got_frames)} frames received, "
                    f"{len(expected)} expected")
    return f"{len(got_frames)} frames received, {len(expected)} expected (a prefix matches)"


@pytest.mark.parametrize("path", tlog_files() or [pytest.param(None, id="no-tlogs")],
                         ids=lambda p: p.name if isinstance(p, Path) else str(p))
def test_replay_udp(start_daemon, tlog_dir, path):
    frames, verdicts, expected = load(path)
    bad = verdicts.count(False)
    unknown = verdicts.count(None)
    in_port, out_port = free_port(), free_port()
    rx = udp_socket(out_port)
    d = start_daemon([udp_server("in", in_port), udp_client("out", out_port)],
                     log_level="info")
    d_addr = (HOST, in_port)
    tx = udp_socket()
    # cumulative expected bytes after frame i
    cum, total = [], 0
    for f, ok in zip(frames, verdicts):
        total += len(f) if ok is not False else 0
        cum.append(total)
    got: List[bytes] = []
    have = [0]
    t0 = time.monotonic()
    try:
        for start in range(0, len(frames), BURST):
            for f in frames[start:start + BURST]:
                tx.sendto(f, d_addr)
            recv_until(rx, got, have, cum[min(start + BURST, len(frames)) - 1], timeout=2.0)
        recv_until(rx, got, have, total + 1, timeout=0.3)  # anything extra?
        elapsed = time.monotonic() - t0
        st = d.settle_stats(lambda s: (s["in"]["rx_frames"], s["in"]["crc_errors"]))
    finally:
        tx.close()
        rx.close()
    s_in, s_out = st["in"], st["out"]
    print(f"\n{path.name}: sent {len(frames)} frames in {elapsed:.1f}s, received "
          f"{len(got)} datagrams ({have[0]} bytes); expected {len(expected)} "
          f"(bad CRC dropped {bad}, unknown ids forwarded {unknown})")
    print(f"  mavbond in: rx_frames={s_in['rx_frames']} crc_errors={s_in['crc_errors']} "
          f"unknown_ids={s_in['unknown_ids']} garbage_bytes={s_in['garbage_bytes']} "
          f"bad_flags={s_in['bad_flags']}; out: tx_frames={s_out['tx_frames']} "
          f"tx_dropped={s_out['tx_dropped']}")
    problem = compare(b"".join(got), expected)
    assert problem == "", f"{path.name}: output differs from the input minus bad-CRC frames: {problem}"
    assert len(got) == len(expected), "one frame per datagram"
    assert s_in["crc_errors"] == bad
    assert s_in["rx_frames"] == len(expected)
    assert s_in["unknown_ids"] == unknown
    assert s_out["tx_frames"] == len(expected) and s_out["tx_dropped"] == 0
    assert d.stop() == 0


def test_replay_stream_through_pty(start_daemon, pty_pair, tlog_dir):
    """One log's frames, concatenated, written to a pty in 32 KiB chunks (frames split
    across writes) -> uart endpoint -> UDP out."""
    candidates = [p for p in tlog_files() if "sub" in p.name] or tlog_files()
    path = candidates[0]
    frames, verdicts, expected = load(path)
    bad = verdicts.count(False)
    stream = b"".join(frames)
    # expected bytes delivered once the stream is written up to an offset
    ends, cum_exp, off, total = [], [], 0, 0
    for f, ok in zip(frames, verdicts):
        off += len(f)
        total += len(f) if ok is not False else 0
        ends.append(off)
        cum_exp.append(total)

    pty = pty_pair()
    out_port = free_port()
    rx = udp_socket(out_port)
    d = start_daemon([uart("fc", pty.path, baud=1500000), udp_client("out", out_port)],
                     log_level="info")
    d.wait_log(r"\[uart:fc\] .* open at 1500000 baud")
    got: List[bytes] = []
    have = [0]
    chunk = 32768
    t0 = time.monotonic()
    import bisect
    try:
        for pos in range(0, len(stream), chunk):
            pty.write_all(stream[pos:pos + chunk])
            end = min(pos + chunk, len(stream))
            # frames that end 300 bytes (more than one frame) before what was written must
            # be out: the parser may hold the tail back while resyncing
            i = bisect.bisect_right(ends, end - 300) - 1
            if i >= 0:
                recv_until(rx, got, have, cum_exp[i], timeout=2.0)
        recv_until(rx, got, have, total, timeout=2.0)
        recv_until(rx, got, have, total + 1, timeout=0.3)
        elapsed = time.monotonic() - t0
        st = d.settle_stats(lambda s: s["fc"]["rx_frames"])
    finally:
        rx.close()
    s = st["fc"]
    print(f"\n{path.name} via pty: wrote {len(frames)} frames ({len(stream)} bytes) in "
          f"{elapsed:.1f}s, received {len(got)} datagrams; expected {len(expected)} "
          f"(bad CRC {bad})")
    print(f"  mavbond fc: rx_frames={s['rx_frames']} crc_errors={s['crc_errors']} "
          f"garbage_bytes={s['garbage_bytes']} unknown_ids={s['unknown_ids']}; "
          f"out tx_frames={st['out']['tx_frames']}")
    problem = compare(b"".join(got), expected)
    assert problem == "", f"{path.name} via pty: {problem}"
    assert s["crc_errors"] == bad and s["rx_frames"] == len(expected)
    assert d.stop() == 0
