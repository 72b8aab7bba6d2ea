"""Tests of the link emulator tests/tools/linkemu.py (tee, link groups) and of the Stall
injector: real UDP sockets on 127.0.0.1, the emulator in a background thread or as its own
process. Only the last test runs mavbond (the lab's factories on real gateways).

No test here judges the machine's scheduler. Timing is checked against the emulator's own
account: its counters, its drop log and its record of every send (when each datagram arrived,
when it was due and when it left). What that record says the emulator decided is checked
exactly; what the test sees on its sockets is checked against the record (nothing arrives
before it was due, nothing arrives that the emulator did not send, in the order it sent).
Measured delays and lateness are printed (run with -s) but not judged: a loaded machine makes
them worse without anything being wrong. Waits are on counters, never on sleeps, and every
loop has a deadline far beyond what an idle machine needs."""
from __future__ import annotations

import json
import os
import random
import re
import select
import signal
import socket
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TOOLS = REPO / "tests" / "tools"
sys.path.insert(0, str(TOOLS))

from linkemu import LinkEmulator  # noqa: E402
from helpers import FrameMaker, free_port, udp_server  # noqa: E402
from bonding_helpers import EmuGroup, Stall, process_state  # noqa: E402

HOST = "127.0.0.1"
LINKEMU = str(TOOLS / "linkemu.py")
HDR = struct.Struct("!Id")     # index, send time (time.monotonic(), system-wide clock)
TAG = struct.Struct("!BI")     # link number, index (the group tests)
WAIT = 30.0                    # s: the longest any wait may take before the test fails
EPS = 1e-9                     # s: float slack when comparing the emulator's own times

# The counter keys of a single-forward emulator, in the order it prints them: the format that
# other tools parse (a tee or a group must not change it).
COUNTER_KEYS = ["direction", "t", "received", "forwarded", "dropped_loss", "dropped_outage",
                "dropped_queue", "dropped_no_peer", "corrupted", "send_errors",
                "bytes_received", "bytes_forwarded", "in_flight", "late_max_ms", "foreign"]


# --- helpers -----------------------------------------------------------------------------------

def udp(timeout: float = WAIT) -> socket.socket:
    """A socket on 127.0.0.1 with buffers large enough that a test that drains it late (the
    machine was busy) loses nothing: SO_RCVBUFFORCE when allowed (root), else the capped one."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUFFORCE, 32 << 20)
    except (OSError, AttributeError):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 32 << 20)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    s.bind((HOST, 0))
    s.settimeout(timeout)
    return s


def port(s: socket.socket) -> int:
    return s.getsockname()[1]


def drain(sock: socket.socket, into: list) -> list:
    """Appends whatever is waiting on sock (non-blocking) to `into`."""
    sock.setblocking(False)
    try:
        while True:
            into.append(sock.recv(65535))
    except BlockingIOError:
        pass
    finally:
        sock.settimeout(WAIT)
    return into


def pct(xs, q):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(q / 100.0 * len(xs)))]


def until(pred, what: str, timeout: float = WAIT, step: float = 0.002):
    """Polls pred() until it returns something true; fails with `what` after `timeout`."""
    deadline = time.monotonic() + timeout
    while not (r := pred()):
        assert time.monotonic() < deadline, f"never happened: {what}"
        time.sleep(step)
    return r


@pytest.fixture
def emu_factory():
    """emu_factory(**opts) -> (LinkEmulator started, side A socket, side B socket)."""
    made = []

    def make(**opts):
        a, b = udp(), udp()
        emu = LinkEmulator(f"{HOST}:0", f"{HOST}:{port(b)}", **opts)
        made.append((emu, a, b))
        emu.start()
        return emu, a, b

    yield make
    for emu, a, b in made:
        emu.stop()
        a.close()
        b.close()


class Proc:
    """linkemu as its own process; listen/source ports parsed from its stderr banner."""

    def __init__(self, args):
        self._pending = {}
        self.p = subprocess.Popen([sys.executable, LINKEMU, *args], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        self.banner = self._readline(self.p.stderr, WAIT)
        assert "listening on" in self.banner, self.banner
        words = self.banner.split()
        self.listen = (HOST, int(words[words.index("on") + 1].rstrip(",").rsplit(":", 1)[1]))
        self.source = (HOST, int(words[words.index("from") + 1].rstrip(",").rsplit(":", 1)[1]))

    def _readline(self, f, timeout):
        # Lines are assembled here from the raw descriptor: select() on a pipe whose data
        # Python's text buffer already holds would wait for nothing (two lines in one read).
        fd = f.fileno()
        buf = self._pending.get(fd, b"")
        deadline = time.monotonic() + timeout
        while b"\n" not in buf:
            r, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            assert r, "linkemu printed nothing in time"
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            buf += chunk
        line, _, self._pending[fd] = buf.partition(b"\n")
        return line.decode()

    def stdout_lines(self, n, timeout=WAIT):
        return [json.loads(self._readline(self.p.stdout, timeout)) for _ in range(n)]

    def counters(self) -> dict:
        """SIGUSR1 -> {"up": .., "down": ..} as of now (also flushes its logs)."""
        self.p.send_signal(signal.SIGUSR1)
        return {d["direction"]: d for d in self.stdout_lines(2)}

    def finish(self) -> dict:
        """SIGTERM -> the final counters; it must exit with status 0."""
        self.p.send_signal(signal.SIGTERM)
        out, err = self.p.communicate(timeout=WAIT)
        assert self.p.returncode == 0, err
        rows = [json.loads(x) for x in out.splitlines()]
        return {d["direction"]: d for d in rows[-2:]}

    def cpu_seconds(self) -> float:
        """User + system CPU time it used so far (/proc/PID/stat)."""
        with open(f"/proc/{self.p.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def kill(self):
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(5)
        self.p.stdout.close()
        self.p.stderr.close()


@pytest.fixture
def emu_proc():
    made = []

    def start(*args):
        p = Proc([str(a) for a in args])
        made.append(p)
        return p

    yield start
    for p in made:
        p.kill()


@pytest.fixture
def group_factory(tmp_path):
    """group_factory(links, **kw) -> EmuGroup started (a linkemu --group process), killed at
    the end."""
    made = []

    def make(links, name="group", **kw):
        g = EmuGroup(tmp_path, name, links, **kw)
        made.append(g)
        return g.start()

    yield make
    for g in made:
        g.kill()


def wait_counters(emu, ready, timeout=WAIT):
    """Waits until ready(emu.counters()) holds; fails with the counters after `timeout`."""
    deadline = time.monotonic() + timeout
    while not ready(c := emu.counters()):
        assert time.monotonic() < deadline, f"counters never got there: {c}"
        time.sleep(0.002)
    return c


def settled(c: dict, received: int, got: int) -> bool:
    """The emulator took `received` datagrams, has none in flight, and the receiver holds
    every one it forwarded."""
    return c["received"] == received and c["in_flight"] == 0 and got == c["forwarded"]


def pump(emu, a, b, n, payload=lambda i: HDR.pack(i, 0.0), batch=250, timeout=WAIT):
    """Send n datagrams A->B through emu in batches (so no socket buffer overflows), wait for
    each batch to be fully handled, return what B received, in order."""
    got = []
    sent = 0
    deadline = time.monotonic() + timeout
    while sent < n:
        k = min(batch, n - sent)
        for i in range(sent, sent + k):
            a.sendto(payload(i), emu.listen_addr)
        sent += k
        while not settled(emu.counters()["up"], sent, len(drain(b, got))):
            assert time.monotonic() < deadline, "pump did not finish in time"
            time.sleep(0.0005)
    return got


def drop_indices(emu, reason=None, direction="up"):
    return [d["index"] for d in emu.drops() if d["direction"] == direction
            and d["reason"] != "corrupted" and (reason is None or d["reason"] == reason)]


def sends_of(emu, direction="up"):
    return [r for r in emu.sends() if r["direction"] == direction]


def paced(streams, complete=None, tail=0.0):
    """Send datagrams at fixed intervals and timestamp arrivals, from one select loop.
    streams: dicts with src (socket), dst (addr), rx (socket), n, interval, size.
    Receives until complete() (default: every stream got all n) holds, or fails after WAIT.
    Returns per stream: list of (index, send_time, recv_time) of what arrived, and the first
    and last send times."""
    t0 = time.monotonic() + 0.05
    for s in streams:
        s.update(next=0, rcv=[], first=None, last=None)
        s["rx"].setblocking(False)
    rxs = {s["rx"]: s for s in streams}
    complete = complete or (lambda: all(len(s["rcv"]) == s["n"] for s in streams))
    end = t0 + max(s["n"] * s["interval"] for s in streams) + tail
    hard_end = end + WAIT
    while True:
        now = time.monotonic()
        if now > end and complete():
            break
        assert now < hard_end, "not everything arrived: " + ", ".join(
            f"{len(s['rcv'])} of {s['n']}" for s in streams)
        nxt = end if now < end else now + 0.01
        for s in streams:
            while s["next"] < s["n"]:
                due = t0 + s["next"] * s["interval"]
                if due > now:
                    nxt = min(nxt, due)
                    break
                ts = time.monotonic()
                pad = b"\0" * max(0, s["size"] - HDR.size)
                s["src"].sendto(HDR.pack(s["next"], ts) + pad, s["dst"])
                s["first"] = s["first"] or ts
                s["last"] = ts
                s["next"] += 1
        r, _, _ = select.select(list(rxs), [], [], max(0.0, nxt - time.monotonic()))
        for sock in r:
            while True:
                try:
                    data = sock.recv(65535)
                except BlockingIOError:
                    break
                tr = time.monotonic()
                i, ts = HDR.unpack_from(data)
                rxs[sock]["rcv"].append((i, ts, tr))
    for s in streams:
        s["rx"].settimeout(WAIT)
    return streams


def check_against_record(rcv, record, t0, first_index=0):
    """What a receiver saw (index, send time, receive time) against the emulator's record of
    the same datagrams (emulator index = test index + first_index): it arrived in the order
    the emulator sent it, never before the emulator sent it, and the test sent it before the
    emulator took it. So the delay the test measured is at least the emulated delay plus the
    emulator's own lateness, whatever the scheduler did. Returns (emulated delay, lateness)
    lists in ms."""
    by_index = {r["index"]: r for r in record}
    assert [i + first_index for i, _, _ in rcv] == [r["index"] for r in
                                                    sorted(record, key=lambda r: r["n"])]
    emulated, late = [], []
    for i, ts, tr in rcv:
        r = by_index[i + first_index]
        assert ts <= t0 + r["arrived"] + EPS, (i, r)
        assert r["sent"] >= r["due"] - EPS, (i, r)
        assert tr >= t0 + r["sent"] - EPS, (i, r)
        emulated.append((r["due"] - r["arrived"]) * 1e3)
        late.append((r["sent"] - r["due"]) * 1e3)
    return emulated, late


# --- loss --------------------------------------------------------------------------------------

def test_bernoulli_loss_rate_within_bounds(emu_factory):
    n = 20000
    emu, a, b = emu_factory(seed=7, loss="1%", record_drops=True)
    got = pump(emu, a, b, n)
    c = emu.counters()["up"]
    rate = c["dropped_loss"] / n
    print(f"\nBernoulli 1%: {c['dropped_loss']} of {n} dropped = {rate:.3%}")
    assert c["received"] == n
    assert c["forwarded"] == len(got) == n - c["dropped_loss"]
    assert 0.007 <= rate <= 0.013
    # what arrived is exactly what was not dropped, in order
    dropped = set(drop_indices(emu, "loss"))
    assert [HDR.unpack_from(d)[0] for d in got] == [i for i in range(n) if i not in dropped]


def test_same_seed_same_drops_different_seed_different(emu_factory, emu_proc, tmp_path):
    n = 5000
    e1, a1, b1 = emu_factory(seed=42, loss="2%", corrupt="1%", record_drops=True)
    pump(e1, a1, b1, n)
    e2, a2, b2 = emu_factory(seed=43, loss="2%", corrupt="1%", record_drops=True)
    pump(e2, a2, b2, n)
    # the same seed in a separate process, with other timing (smaller batches), via
    # --log-drops; after each batch its counters (SIGUSR1) say when it has taken them all
    log = tmp_path / "drops.jsonl"
    b3, a3 = udp(), udp()
    p = emu_proc("--listen", f"{HOST}:0", "--forward", f"{HOST}:{port(b3)}",
                 "--seed", 42, "--loss", "2%", "--corrupt", "1%", "--log-drops", log)
    got3 = []
    deadline = time.monotonic() + WAIT
    for start in range(0, n, 100):
        for i in range(start, min(n, start + 100)):
            a3.sendto(HDR.pack(i, 0.0), p.listen)
        while p.counters()["up"]["received"] < min(n, start + 100):
            assert time.monotonic() < deadline, "the emulator process did not take its input"
        drain(b3, got3)
    counters = p.finish()
    assert counters["up"]["received"] == n
    recs = [json.loads(line) for line in log.read_text().splitlines()]
    d3 = [r["index"] for r in recs if r["reason"] == "loss"]
    c3 = [(r["index"], r["bit"]) for r in recs if r["reason"] == "corrupted"]
    d1, d2 = drop_indices(e1, "loss"), drop_indices(e2, "loss")
    c1 = [(r["index"], r["bit"]) for r in e1.drops() if r["reason"] == "corrupted"]
    print(f"\nseed 42: {len(d1)} drops, {len(c1)} corrupted; seed 43: {len(d2)} drops; "
          f"{len(set(d1) & set(d2))} indices in common")
    assert d1 == d3 and c1 == c3 and len(d1) > 50
    assert d1 != d2
    a3.close()
    b3.close()


def test_gilbert_elliott_produces_bursts(emu_factory):
    n = 20000
    p_gb, p_bg = 0.01, 0.3
    emu, a, b = emu_factory(seed=3, ge=f"{p_gb},{p_bg},0,1", record_drops=True)
    pump(emu, a, b, n)
    idx = drop_indices(emu, "loss")
    bursts, run = [], 1
    for prev, cur in zip(idx, idx[1:]):
        if cur == prev + 1:
            run += 1
        else:
            bursts.append(run)
            run = 1
    bursts.append(run)
    mean = statistics.mean(bursts)
    loss = len(idx) / n
    print(f"\nGilbert-Elliott {p_gb},{p_bg},0,1: loss {loss:.2%} (expected "
          f"{p_gb / (p_gb + p_bg):.2%}), {len(bursts)} bursts, mean length {mean:.2f} "
          f"(expected {1 / p_bg:.2f}), longest {max(bursts)}")
    assert abs(mean - 1 / p_bg) < 0.2 / p_bg
    assert abs(loss - p_gb / (p_gb + p_bg)) < 0.012
    # Bernoulli at the same rate gives bursts of ~1
    emu2, a2, b2 = emu_factory(seed=3, loss=loss, record_drops=True)
    pump(emu2, a2, b2, 5000)
    idx2 = drop_indices(emu2, "loss")
    adjacent = sum(1 for x, y in zip(idx2, idx2[1:]) if y == x + 1)
    assert adjacent < 0.15 * len(idx2)


# --- timing ------------------------------------------------------------------------------------

def test_delay_and_jitter_as_recorded(emu_factory):
    """40 ms both ways, 5 ms uniform jitter on the up direction (--reorder there, so each
    datagram keeps its own jitter sample and the record shows the distribution itself)."""
    emu, a, b = emu_factory(seed=1, delay="40ms", up_jitter="5ms", up_reorder=True,
                            record_sends=True)
    a.sendto(HDR.pack(0, 0.0), emu.listen_addr)  # teach the emulator side A's address
    assert HDR.unpack_from(b.recv(100))[0] == 0
    up, down = paced([dict(src=a, dst=emu.listen_addr, rx=b, n=200, interval=0.01, size=40),
                      dict(src=b, dst=(HOST, emu.source_addr[1]), rx=a, n=200, interval=0.01,
                           size=40)])
    c = wait_counters(emu, lambda c: c["up"]["forwarded"] == 201 and c["down"]["forwarded"] == 200)
    assert c["up"]["received"] == 201 and c["down"]["received"] == 200
    # the emulator's decisions, exactly: down is 40 ms flat; up is 40 ms plus a sample in
    # [-5, +5] ms whose spread is that of the uniform distribution (stdev 2.887 ms)
    rec_up, rec_down = sends_of(emu, "up")[1:], sends_of(emu, "down")
    assert all(abs(r["due"] - r["arrived"] - 0.040) < EPS for r in rec_down)
    jitter = [(r["due"] - r["arrived"] - 0.040) * 1e3 for r in rec_up]
    assert all(-5 - 1e-6 <= j <= 5 + 1e-6 for j in jitter)
    sd = statistics.pstdev(jitter)
    assert 2.887 * 0.8 < sd < 2.887 * 1.2, sd
    assert abs(statistics.mean(jitter)) < 0.6
    # what the sockets saw agrees with the record
    emu_up, late_up = check_against_record(up["rcv"], rec_up, emu.t0, first_index=1)
    emu_down, late_down = check_against_record(down["rcv"], rec_down, emu.t0)
    d_up = [(tr - ts) * 1e3 for _, ts, tr in up["rcv"]]
    d_down = [(tr - ts) * 1e3 for _, ts, tr in down["rcv"]]
    assert min(d_down) >= 40 - 1e-3 and min(d_up) >= 35 - 1e-3
    print(f"\nrecorded jitter (up): min {min(jitter):.3f} max {max(jitter):.3f} stdev {sd:.3f} "
          f"ms (uniform +-5: stdev 2.887)")
    print(f"measured delay down: p50 {pct(d_down, 50):.3f} p99 {pct(d_down, 99):.3f} max "
          f"{max(d_down):.3f} ms; up: p50 {pct(d_up, 50):.3f} max {max(d_up):.3f} ms")
    print(f"emulator lateness: p50 {pct(late_up + late_down, 50):.3f} p99 "
          f"{pct(late_up + late_down, 99):.3f} max {max(late_up + late_down):.3f} ms")


def test_jitter_keeps_order_unless_reorder_is_asked(emu_factory):
    for reorder in (False, True):
        emu, a, b = emu_factory(seed=5, delay="10ms", jitter="20ms", reorder=reorder or None,
                                record_sends=True)
        got = pump(emu, a, b, 300, batch=300)
        order = [HDR.unpack_from(d)[0] for d in got]
        rec = sends_of(emu)
        by_n = sorted(rec, key=lambda r: r["n"])
        inversions = sum(1 for x, y in zip(order, order[1:]) if y < x)
        print(f"\njitter 20ms, 300 back-to-back datagrams, reorder={reorder}: "
              f"{inversions} inversions")
        assert len(order) == 300
        # B saw them in the order the emulator sent them, which is the order they were due
        assert order == [r["index"] for r in by_n]
        assert all(x["due"] <= y["due"] for x, y in zip(by_n, by_n[1:]))
        if reorder:
            # each kept its own time: 10 ms +- 20 ms from its arrival, never before it
            assert all(max(0.0, 0.010 - 0.020) - EPS <= r["due"] - r["arrived"] <= 0.030 + EPS
                       for r in rec)
            # 300 datagrams sent back to back sit in the socket together: their jitter
            # samples (40 ms wide) reorder them
            assert inversions > 0
        else:
            assert order == list(range(300))


def every_2ms_until(emu, a, b, until: float):
    """One numbered datagram from `a` every 2 ms until the emulator's clock reads `until`;
    returns (what `b` got, how many were sent, the up direction's counters once settled)."""
    got, n = [], 0
    while emu.elapsed() < until:
        a.sendto(HDR.pack(n, 0.0), emu.listen_addr)
        n += 1
        time.sleep(0.002)
        drain(b, got)
    c = wait_counters(emu, lambda c: settled(c["up"], n, len(drain(b, got))))["up"]
    return got, n, c


def test_outage_drops_its_span_and_nothing_else(emu_factory):
    spans = [(0.3, 0.4), (1.0, 0.3)]
    emu, a, b = emu_factory(seed=1, outage=[f"{s}s+{l}s" for s, l in spans], record_drops=True,
                            record_sends=True)
    inside = lambda t, tol=0.0: any(s - tol <= t < s + l + tol for s, l in spans)  # noqa: E731
    # until well after the last span (by the emulator's clock)
    got, n, c = every_2ms_until(emu, a, b, 1.6)
    dropped = drop_indices(emu, "outage")
    rec = sends_of(emu)
    arrived = [r["arrived"] for r in rec]
    print(f"\noutages {spans}: {n} sent, {len(dropped)} dropped (outage), "
          f"{c['forwarded']} forwarded")
    # the emulator's account: every outage drop arrived inside a span (its t is rounded to
    # 1 us), every forwarded datagram outside
    assert all(inside(r["t"], 1e-6) for r in emu.drops())
    assert not any(inside(t) for t in arrived)
    assert c["dropped_outage"] == len(dropped) == len(emu.drops()) == n - c["forwarded"]
    # ... and B got exactly the others, in order
    assert [HDR.unpack_from(d)[0] for d in got] == sorted(set(range(n)) - set(dropped))
    # each span dropped something, and the link worked before, between and after them
    for s, l in spans:
        assert any(s <= r["t"] < s + l for r in emu.drops()), (s, l)
    for lo, hi in ((0.0, 0.3), (0.7, 1.0), (1.3, 1.6)):
        assert any(lo <= t < hi for t in arrived), (lo, hi)


def test_stall_holds_its_span_and_lets_it_go_in_order(emu_factory):
    start, length = 0.3, 0.4
    emu, a, b = emu_factory(seed=1, delay="10ms", stall=[f"{start}s+{length}s"],
                            record_sends=True)
    got, n, c = every_2ms_until(emu, a, b, 1.2)
    rec = sends_of(emu)
    held = [r for r in rec if start <= r["arrived"] + 0.010 < start + length]
    print(f"\nstall {start}s+{length}s: {n} sent, {len(held)} held, {c['forwarded']} forwarded")
    # nothing lost, nothing reordered
    assert c["forwarded"] == n
    assert [HDR.unpack_from(d)[0] for d in got] == list(range(n))
    # what was due in the span left at its end, nothing else was moved
    assert len(held) > 50
    assert all(abs(r["due"] - (start + length)) < 1e-6 for r in held), held[:3]
    assert not any(start <= r["due"] < start + length - 1e-6 for r in rec)
    assert all(abs(r["due"] - r["arrived"] - 0.010) < 1e-6 for r in rec if r not in held)


def test_corruption_flips_exactly_one_bit(emu_factory):
    n = 4000
    rnd = random.Random(9)
    payloads = [bytes(rnd.getrandbits(8) for _ in range(40)) for _ in range(n)]
    emu, a, b = emu_factory(seed=11, corrupt="5%", record_drops=True)
    got = pump(emu, a, b, n, payload=lambda i: payloads[i])
    assert len(got) == n
    changed = {}
    for i, (s, r) in enumerate(zip(payloads, got)):
        if s != r:
            x = int.from_bytes(s, "big") ^ int.from_bytes(r, "big")
            assert len(r) == len(s) and bin(x).count("1") == 1, f"datagram {i}"
            changed[i] = (len(s) * 8 - 1 - (x.bit_length() - 1))   # bit number, MSB-first
    c = emu.counters()["up"]
    recs = {r["index"]: r["bit"] for r in emu.drops() if r["reason"] == "corrupted"}
    print(f"\ncorrupt 5%: {len(changed)} of {n} datagrams had one bit flipped")
    assert c["corrupted"] == len(changed) == len(recs)
    assert set(recs) == set(changed)
    assert 0.035 * n <= len(changed) <= 0.065 * n
    # the log's bit number is byte*8 + bit-in-byte (LSB = 0)
    for i, bit in recs.items():
        byte, b_in = divmod(bit, 8)
        assert payloads[i][byte] ^ got[i][byte] == 1 << b_in


# --- rate cap ----------------------------------------------------------------------------------

def check_rate_model(sends, drops, size, overhead, rate, queue_bytes):
    """Replays the rate stage from the emulator's record: each forwarded datagram finishes one
    serialisation time after it arrived or after the one before it finished, whichever is
    later; a datagram was tail-dropped only when the payload still queued at its arrival plus
    its own exceeded queue_bytes, and accepted only when it fitted (or the queue was empty).
    Returns how many forwarded datagrams found the link busy."""
    ser = (size + overhead) * 8.0 / rate
    events = sorted([(r["index"], "sent", r) for r in sends] +
                    [(r["index"], "drop", r) for r in drops if r["reason"] == "queue"],
                    key=lambda e: e[0])
    finishes = []           # finish times of the datagrams accepted so far
    busy = 0
    for idx, kind, r in events:
        if kind == "sent":
            queued = sum(size for f in finishes if f > r["arrived"])
            assert queued == 0 or queued + size <= queue_bytes, (idx, queued)
            start = max(r["arrived"], finishes[-1] if finishes else -1.0)
            busy += start > r["arrived"]
            assert abs(r["due"] - (start + ser)) < 1e-7, (idx, r, start + ser)
            finishes.append(r["due"])
        else:   # the drop record's t is rounded to 1 us: count what may have been queued
            queued = sum(size for f in finishes if f > r["t"] - 1e-6)
            assert queued > 0 and queued + size > queue_bytes, (idx, queued)
    return busy


def test_rate_cap_as_recorded(emu_factory):
    size, overhead, rate, qbytes = 40, 8, 57600, 1000
    cap = rate / ((size + overhead) * 8)       # 150 frames/s
    emu, a, b = emu_factory(seed=1, rate=rate, overhead=overhead, queue_bytes=qbytes,
                            record_drops=True, record_sends=True)
    a.sendto(HDR.pack(0, 0.0) + b"\0" * (size - HDR.size), emu.listen_addr)  # side A known
    b.recv(100)
    # overload: twice the capacity for 2 s
    s = dict(src=a, dst=emu.listen_addr, rx=b, n=600, interval=1 / (2 * cap), size=size)
    paced([s], complete=lambda: settled(emu.counters()["up"], 601, 1 + len(s["rcv"])))
    c = emu.counters()["up"]
    rec = sends_of(emu)
    busy = check_rate_model(rec, emu.drops(), size, overhead, rate, qbytes)
    check_against_record(s["rcv"], rec[1:], emu.t0, first_index=1)
    assert c["received"] == 601 and c["forwarded"] + c["dropped_queue"] == 601
    assert c["dropped_queue"] == len(drop_indices(emu, "queue")) > 0
    over = rec[1:]
    dues = [r["due"] for r in over]
    tput = (len(dues) - 1) / (dues[-1] - dues[0])
    rcv = s["rcv"]
    seen = (len(rcv) - 1) / (rcv[-1][2] - rcv[0][2])
    print(f"\nrate {rate} bit/s, {size}+{overhead} B frames at {2 * cap:.0f}/s: {c['forwarded']} "
          f"forwarded ({busy} behind another), {c['dropped_queue']} queue drops; due at "
          f"{tput:.2f} frames/s (cap {cap:.2f}), received at {seen:.2f} frames/s")
    # under the cap: each frame that found the link idle takes exactly one serialisation time
    s2 = dict(src=a, dst=emu.listen_addr, rx=b, n=100, interval=1 / (0.5 * cap), size=size)
    paced([s2], complete=lambda: settled(emu.counters()["up"], 701,
                                         1 + len(s["rcv"]) + len(s2["rcv"])))
    c2 = emu.counters()["up"]
    rec2 = sends_of(emu)
    busy2 = check_rate_model(rec2, emu.drops(), size, overhead, rate, qbytes)
    check_against_record(s2["rcv"], rec2[len(rec):], emu.t0, first_index=601)
    idle = [(r["due"] - r["arrived"]) * 1e3 for r in rec2[len(rec):]]
    print(f"at {0.5 * cap:.0f}/s: {len(s2['rcv'])} of 100 forwarded, "
          f"{c2['dropped_queue'] - c['dropped_queue']} queue drops, "
          f"{busy2 - busy} behind another; time in the link p50 {pct(idle, 50):.3f} ms "
          f"(serialisation {1e3 / cap:.3f} ms)")
    assert c2["received"] == 701


# --- both directions, process life -------------------------------------------------------------

def test_replies_flow_back_and_directions_are_independent(emu_factory):
    emu, a, b = emu_factory(seed=2, down_delay="30ms", up_loss="100%", record_drops=True,
                            record_sends=True)
    # B talks before A is known: nowhere to go
    src = (HOST, emu.source_addr[1])
    b.sendto(b"early", src)
    stranger = udp()
    stranger.sendto(b"noise", src)
    # Each step waits until the emulator has handled the last (it may run late under load).
    wait_counters(emu, lambda c: c["down"]["dropped_no_peer"] == 1 and c["down"]["foreign"] == 1)
    # A's datagrams are all lost on the way up (up_loss 100%), but A is now known
    for i in range(20):
        a.sendto(b"up%d" % i, emu.listen_addr)
    wait_counters(emu, lambda c: c["up"]["received"] == 20)
    t = time.monotonic()          # before the send: the emulator cannot take it earlier
    b.sendto(b"reply", src)
    data, addr = a.recvfrom(100)
    rtt = (time.monotonic() - t) * 1e3
    assert data == b"reply" and addr == tuple(emu.listen_addr)
    c = wait_counters(emu, lambda c: c["down"]["forwarded"] == 1)
    (r,) = sends_of(emu, "down")
    print(f"\nreply B->A after {rtt:.1f} ms (down delay 30 ms, emulator "
          f"{(r['sent'] - r['arrived']) * 1e3:.1f} ms); counters {c}")
    assert abs(r["due"] - r["arrived"] - 0.030) < EPS and r["index"] == 1
    assert rtt >= 30 - 1e-3
    assert c["up"]["received"] == 20 and c["up"]["dropped_loss"] == 20
    assert c["up"]["forwarded"] == 0 and not sends_of(emu, "up")
    assert c["down"]["dropped_no_peer"] == 1 and c["down"]["forwarded"] == 1
    assert c["down"]["foreign"] == 1
    stranger.close()


def test_a_nat_rebinding_moves_the_source_port_once(emu_factory):
    """request_rebind: B hears A's datagrams from a new source port from then on, every one of
    them (the rebinding is taken between two datagrams); B's replies to the new port reach A,
    those to the old one nothing (the NAT gave that mapping up)."""
    emu, a, b = emu_factory(seed=3)
    for i in range(10):
        a.sendto(b"before%d" % i, emu.listen_addr)
    got = [b.recvfrom(100) for _ in range(10)]
    old = got[0][1]
    assert {addr for _, addr in got} == {old} and old[1] == emu.source_addr[1]
    emu.request_rebind("")
    until(lambda: emu.links[0].rebinds == 1, "the loop took the rebinding")
    for i in range(10):
        a.sendto(b"after%d" % i, emu.listen_addr)
    after = [b.recvfrom(100) for _ in range(10)]
    new = after[0][1]
    assert [d for d, _ in got + after] == [b"before%d" % i for i in range(10)] + \
        [b"after%d" % i for i in range(10)]
    link = emu.links[0]    # emu.source_addr is the address it started with
    assert {addr for _, addr in after} == {new} and new != old and new[1] == link.source_addr[1]
    b.sendto(b"to-old", old)
    b.sendto(b"to-new", new)
    data, _ = a.recvfrom(100)
    assert data == b"to-new"
    c = wait_counters(emu, lambda c: c["down"]["forwarded"] == 1)
    assert c["down"]["received"] == 1 and c["up"]["forwarded"] == 20
    print(f"\nsource port {old[1]} -> {new[1]}; the reply to the old port went nowhere")


def test_sigterm_and_sigusr1_print_counters(emu_proc):
    a, b = udp(), udp()
    p = emu_proc("--listen", f"{HOST}:0", "--forward", f"{HOST}:{port(b)}", "--seed", 1)
    # the single-forward banner, as other tools parse it
    assert re.fullmatch(r"linkemu: listening on 127\.0\.0\.1:\d+, forwarding to "
                        rf"127\.0\.0\.1:{port(b)} from 0\.0\.0\.0:\d+, seed 1", p.banner), p.banner
    for i in range(10):
        a.sendto(b"%d" % i, p.listen)
        b.recv(100)
    p.p.send_signal(signal.SIGUSR1)
    lines = p.stdout_lines(2)
    assert [d["direction"] for d in lines] == ["up", "down"]
    assert lines[0]["received"] == lines[0]["forwarded"] == 10
    b.sendto(b"back", p.source)
    assert a.recv(100) == b"back"
    p.p.send_signal(signal.SIGTERM)
    out, err = p.p.communicate(timeout=WAIT)
    assert p.p.returncode == 0, err
    final = [json.loads(x) for x in out.splitlines()]
    print(f"\nSIGTERM counters: {final}")
    assert [d["direction"] for d in final] == ["up", "down"]
    assert all(list(d) == COUNTER_KEYS for d in final), [list(d) for d in final]
    assert final[0]["forwarded"] == 10 and final[1]["forwarded"] == 1
    a.close()
    b.close()


def test_duration_exits_by_itself_and_bad_options_are_refused(emu_proc, tmp_path):
    p = emu_proc("--listen", f"{HOST}:0", "--forward", f"{HOST}:9", "--duration", "0.3")
    out, _ = p.p.communicate(timeout=WAIT)     # no signal: it ends by itself
    rows = [json.loads(x) for x in out.splitlines()]
    assert p.p.returncode == 0 and len(rows) == 2
    # its clock says it ran out its duration (t: seconds since it started, to 1 ms)
    assert all(r["t"] >= 0.3 - 0.0005 for r in rows), rows
    spec = tmp_path / "g.json"
    spec.write_text(json.dumps([{"name": "x", "listen": f"{HOST}:0", "forward": f"{HOST}:9"}]))
    dup = tmp_path / "dup.json"
    dup.write_text(json.dumps([{"name": "x", "listen": f"{HOST}:0", "forward": f"{HOST}:9"}] * 2))
    unknown = tmp_path / "unknown.json"
    unknown.write_text(json.dumps([{"name": "x", "listen": f"{HOST}:0", "forward": f"{HOST}:9",
                                    "lossy": "1%"}]))
    for bad in (["--delay", "40"], ["--loss", "120%"], ["--ge", "0.1,0.2"],
                ["--outage", "10s"], ["--rate", "fast"], ["--group", spec, "--loss", "1%"],
                ["--group", spec, "--seed", "1"], ["--group", dup], ["--group", unknown]):
        head = [] if "--group" in bad else ["--listen", f"{HOST}:0", "--forward", f"{HOST}:9"]
        r = subprocess.run([sys.executable, LINKEMU, *head, *map(str, bad)], capture_output=True,
                           text=True, timeout=WAIT)
        assert r.returncode == 2 and "linkemu: error" in r.stderr, (bad, r.stderr)
    r = subprocess.run([sys.executable, LINKEMU, "--forward", f"{HOST}:9"], capture_output=True,
                       text=True, timeout=WAIT)
    assert r.returncode == 2 and "--listen" in r.stderr, r.stderr


def test_keeps_up_with_1000_datagrams_per_second_each_way(emu_proc, tmp_path):
    """5,000 datagrams each way at 1 kHz through a separate emulator process, 20 ms both ways:
    nothing lost, each one due exactly 20 ms after it arrived, delivered in the order sent,
    and the process needs well under one CPU for it (its CPU time, not the wall clock, so a
    busy machine does not change the verdict)."""
    a, b = udp(), udp()
    log = tmp_path / "sends.jsonl"
    p = emu_proc("--listen", f"{HOST}:0", "--forward", f"{HOST}:{port(b)}",
                 "--delay", "20ms", "--seed", 1, "--log-sends", log)
    a.sendto(HDR.pack(0, 0.0), p.listen)
    assert HDR.unpack_from(b.recv(100))[0] == 0
    n = 5000
    cpu0 = p.cpu_seconds()
    up, down = paced([dict(src=a, dst=p.listen, rx=b, n=n, interval=1 / 1000, size=40),
                      dict(src=b, dst=p.source, rx=a, n=n, interval=1 / 1000, size=40)])
    cpu = p.cpu_seconds() - cpu0
    wall = max(s["last"] for s in (up, down)) - min(s["first"] for s in (up, down))
    c = p.finish()
    assert c["up"]["forwarded"] == n + 1 and c["down"]["forwarded"] == n
    assert c["up"]["in_flight"] == c["down"]["in_flight"] == 0
    rec = [json.loads(x) for x in log.read_text().splitlines()]
    rec_up = [r for r in rec if r["direction"] == "up"]
    rec_down = [r for r in rec if r["direction"] == "down"]
    for r in rec:   # its own record (its t0 is not known here)
        assert abs(r["due"] - r["arrived"] - 0.020) < EPS and r["sent"] >= r["due"] - EPS
    assert [i + 1 for i, _, _ in up["rcv"]] == [r["index"] for r in rec_up[1:]]
    assert [i for i, _, _ in down["rcv"]] == [r["index"] for r in rec_down]
    assert [r["n"] for r in rec] == sorted(r["n"] for r in rec) == list(range(2 * n + 1))
    late = [(r["sent"] - r["due"]) * 1e3 for r in rec]
    for name, s in (("A->B", up), ("B->A", down)):
        err = [(tr - ts) * 1e3 - 20 for _, ts, tr in s["rcv"]]
        print(f"\n{name}: {len(s['rcv'])} received; measured delay error p50 "
              f"{pct(err, 50):.3f} p99 {pct(err, 99):.3f} max {max(err):.3f} ms")
        assert min(err) >= -1e-3
    print(f"emulator: {cpu:.2f} s CPU in {wall:.2f} s ({cpu / wall:.0%} of one CPU); lateness "
          f"p50 {pct(late, 50):.3f} p99 {pct(late, 99):.3f} max {max(late):.3f} ms; "
          f"late_max up {c['up']['late_max_ms']} ms, down {c['down']['late_max_ms']} ms")
    assert cpu < 0.6 * wall, (cpu, wall)
    a.close()
    b.close()


# --- tee ---------------------------------------------------------------------------------------

def test_tee_sends_every_datagram_to_every_receiver_and_replies_come_from_the_first():
    a, b1, b2 = udp(), udp(), udp()
    emu = LinkEmulator(f"{HOST}:0", [f"{HOST}:{port(b1)}", f"{HOST}:{port(b2)}"], seed=4,
                       up_loss="3%", up_corrupt="1%", delay="2ms", jitter="1ms",
                       record_drops=True)
    emu.start()
    try:
        n, batch = 3000, 250
        got1, got2 = [], []
        deadline = time.monotonic() + WAIT
        for start in range(0, n, batch):
            for i in range(start, start + batch):
                a.sendto(HDR.pack(i, 0.0) + bytes(20), emu.listen_addr)
            while not (settled(emu.counters()["up"], start + batch, len(drain(b1, got1)))
                       and len(drain(b2, got2)) == len(got1)):
                assert time.monotonic() < deadline, "the tee did not deliver in time"
                time.sleep(0.0005)
        c = emu.counters()
        dropped = drop_indices(emu, "loss")
        corrupted = {r["index"]: r["bit"] for r in emu.drops() if r["reason"] == "corrupted"}
        print(f"\ntee to 2 receivers: {n} sent, {len(dropped)} lost, {len(corrupted)} "
              f"corrupted, {len(got1)} and {len(got2)} received")
        # both receivers got the same bytes (corruption included) in the same order: what
        # was sent, less the drops, with the logged bit flipped in each corrupted one
        assert got1 == got2
        assert len(got1) == c["up"]["forwarded"] == n - len(dropped) and corrupted
        want = []
        for i in sorted(set(range(n)) - set(dropped)):
            d = bytearray(HDR.pack(i, 0.0) + bytes(20))
            if i in corrupted:
                d[corrupted[i] >> 3] ^= 1 << (corrupted[i] & 7)
            want.append(bytes(d))
        assert got1 == want
        assert c["up"]["send_errors"] == 0
        # down: only the first receiver's replies are relayed; the second's are counted
        src = (HOST, emu.source_addr[1])
        for i in range(5):
            b2.sendto(b"second%d" % i, src)
        for i in range(7):
            b1.sendto(b"first%d" % i, src)
        c = wait_counters(emu, lambda c: c["down"]["forwarded"] + c["down"]["foreign"] == 12)
        replies = drain(a, [])
        print(f"replies: {c['down']['forwarded']} relayed, {c['down']['foreign']} ignored")
        assert c["down"]["received"] == c["down"]["forwarded"] == 7 and c["down"]["foreign"] == 5
        assert replies == [b"first%d" % i for i in range(7)]
    finally:
        emu.stop()
        for s in (a, b1, b2):
            s.close()


def test_tee_from_the_command_line(emu_proc):
    a, b1, b2 = udp(), udp(), udp()
    p = emu_proc("--listen", f"{HOST}:0", "--forward", f"{HOST}:{port(b1)}",
                 "--forward", f"{HOST}:{port(b2)}", "--seed", 1)
    assert f"forwarding to 127.0.0.1:{port(b1)}, 127.0.0.1:{port(b2)} from" in p.banner
    for i in range(50):
        a.sendto(b"%d" % i, p.listen)
    got1 = [b1.recv(100) for _ in range(50)]
    got2 = [b2.recv(100) for _ in range(50)]
    assert got1 == got2 == [b"%d" % i for i in range(50)]
    b2.sendto(b"ignored", p.source)
    b1.sendto(b"back", p.source)
    assert a.recv(100) == b"back"
    c = p.finish()
    assert list(c["up"]) == list(c["down"]) == COUNTER_KEYS
    assert c["up"]["forwarded"] == 50 and c["down"]["forwarded"] == 1
    assert c["down"]["foreign"] == 1
    for s in (a, b1, b2):
        s.close()


# --- link groups -------------------------------------------------------------------------------

def send_paced_tags(targets, n, rate, start_at, drain_into):
    """Sends TAG(link, i) for i < n to every target (link number, socket, address) at `rate`
    per second and link, from `start_at` (monotonic) on, draining the (socket, list) pairs of
    drain_into as it goes. Returns when all are sent."""
    interval = 1.0 / rate
    nxt = 0
    while nxt < n:
        now = time.monotonic()
        due = start_at + nxt * interval
        if due <= now:
            for link, sock, addr in targets:
                sock.sendto(TAG.pack(link, nxt) + bytes(30), addr)
            nxt += 1
            continue
        for sock, into in drain_into:
            drain(sock, into)
        time.sleep(min(0.001, due - now))


def test_group_receivers_see_one_cross_link_order(group_factory):
    """Two links in one group process, each teed to the same two receivers, 3,000 datagrams
    per link at 1 kHz per link: both receivers get the same bytes in the same cross-link
    order, which is the order of the emulator's own sends; each link lost and corrupted
    exactly what a single emulator with its seed and options does."""
    r1, r2 = udp(), udp()
    n = 3000
    opts = {"radio": dict(seed=11, loss="2%", delay="5ms", jitter="3ms"),
            "lte": dict(seed=22, ge="0.01,0.3,0,1", corrupt="0.5%", delay="15ms",
                        jitter="10ms")}
    listen = {name: free_port() for name in opts}
    g = group_factory([dict(name=name, listen_port=listen[name],
                            forward_ports=[port(r1), port(r2)], **o) for name, o in opts.items()],
                      log_sends=True)
    tx = {name: udp() for name in opts}
    got1, got2 = [], []
    links = list(opts)
    send_paced_tags([(k, tx[name], (HOST, listen[name])) for k, name in enumerate(links)], n,
                    1000, time.monotonic(), [(r1, got1), (r2, got2)])
    until(lambda: (c := g.counters_now()) and all(
        c[name]["up"]["received"] == n and c[name]["up"]["in_flight"] == 0 for name in links)
        and len(drain(r1, got1)) == len(drain(r2, got2)) == sum(
            c[name]["up"]["forwarded"] for name in links), "all sent and received", step=0.05)
    g.stop()
    sends = sorted((r["n"], links.index(name), r["index"]) for name in links
                   for r in g.sends(name))
    seq = [(k, i) for _, k, i in sends]       # the emulator's order of sends
    switches = sum(1 for x, y in zip(seq, seq[1:]) if x[0] != y[0])
    flips = {k: {r["index"]: r["bit"] for r in g.drops(name) if r["reason"] == "corrupted"}
             for k, name in enumerate(links)}

    def as_sent(k, i):     # the datagram the test sent, with the bit the emulator flipped
        d = bytearray(TAG.pack(k, i) + bytes(30))
        if i in flips[k]:
            d[flips[k][i] >> 3] ^= 1 << (flips[k][i] & 7)
        return bytes(d)
    print(f"\ngroup of 2 links, each teed to 2 receivers: {len(got1)} datagrams received by "
          f"each, {switches} switches between the links; lost: radio {len(g.dropped('radio'))},"
          f" lte {len(g.dropped('lte'))}; corrupted: lte {len(g.corrupted('lte'))}")
    assert got1 == got2
    assert got1 == [as_sent(k, i) for k, i in seq]
    assert switches > 100, "the links' datagrams hardly interleaved: the check proved little"
    for k, name in enumerate(links):
        assert g.counters(name)["up"]["received"] == n
        assert sorted(i for link, i in seq if link == k) == \
            sorted(set(range(n)) - g.dropped(name))
        # the same decisions as one emulator alone with that seed and those options
        emu, a, b = None, udp(), udp()
        try:
            emu = LinkEmulator(f"{HOST}:0", f"{HOST}:{port(b)}", record_drops=True,
                               **opts[name]).start()
            pump(emu, a, b, n, payload=lambda i: TAG.pack(k, i) + bytes(30))  # same sizes
            alone = [(r["index"], r["reason"], r.get("bit")) for r in emu.drops()]
        finally:
            if emu:
                emu.stop()
            a.close()
            b.close()
        grouped = [(r["index"], r["reason"], r.get("bit")) for r in g.drops(name)]
        assert grouped == alone and grouped, name
    for s in (r1, r2, *tx.values()):
        s.close()


def test_group_outage_counts_from_the_group_start(group_factory):
    """Link x has an outage at 0.6 s + 0.4 s and starts sending only at 0.4 s; link y sends
    from the start and has none. x loses what arrived in [0.6, 1.0) of the group's clock (not
    of its first datagram: what it got in [1.0, 1.4) went through), y loses nothing."""
    r = udp()
    lx, ly = free_port(), free_port()
    g = group_factory([dict(name="x", listen_port=lx, forward_ports=port(r), seed=1,
                            outage="0.6s+0.4s"),
                       dict(name="y", listen_port=ly, forward_ports=port(r), seed=2)],
                      log_sends=True)
    # g.t_start is after the group's clock started (it prints its last line then)
    sx, sy = udp(), udp()
    got = []
    send_paced_tags([(1, sy, (HOST, ly))], 200, 500, g.t_start, [(r, got)])      # 0 .. 0.4 s
    send_paced_tags([(0, sx, (HOST, lx)), (1, sy, (HOST, ly))], 600, 500, g.t_start + 0.4,
                    [(r, got)])                                                   # 0.4 .. 1.6 s
    nx, ny = 600, 800
    until(lambda: (c := g.counters_now()) and c["x"]["up"]["received"] == nx
          and c["y"]["up"]["received"] == ny and len(drain(r, got)) == sum(
              c[k]["up"]["forwarded"] for k in "xy"), "all sent and received", step=0.05)
    g.stop()
    x_sent = [s["arrived"] for s in g.sends("x")]
    y_sent = [s["arrived"] for s in g.sends("y")]
    x_drops = g.drops("x")
    print(f"\noutage 0.6s+0.4s on x: {len(x_drops)} dropped, {len(x_sent)} forwarded (first "
          f"arrival at {min(x_sent + [r['t'] for r in x_drops]):.3f} s); y: "
          f"{len(y_sent)} forwarded")
    assert x_drops and all(d["reason"] == "outage" and 0.6 - 1e-6 <= d["t"] < 1.0 + 1e-6
                           for d in x_drops)
    assert not any(0.6 <= t < 1.0 for t in x_sent)
    assert min(x_sent) >= 0.4, "x's first datagram is at 0.4 s on the group's clock"
    assert any(1.0 <= t < 1.4 for t in x_sent), "the outage did not count from the group start"
    assert not g.drops("y") and len(y_sent) == ny and any(0.6 <= t < 1.0 for t in y_sent)
    tags = [TAG.unpack_from(d) for d in got]
    assert sorted(i for k, i in tags if k == 0) == sorted(set(range(nx)) - g.dropped("x"))
    for s in (r, sx, sy):
        s.close()


# --- Stall -------------------------------------------------------------------------------------

# A child that notes the time every millisecond (a stopped process notes nothing) and prints
# its notes when it ends: its own account of when it ran.
TIMELINE_CHILD = ("import json, sys, time\n"
                  "end = time.monotonic() + float(sys.argv[1]); ts = []\n"
                  "while time.monotonic() < end:\n"
                  "    ts.append(time.monotonic()); time.sleep(0.001)\n"
                  "print(json.dumps(ts))\n")


@pytest.fixture
def child():
    made = []

    def start(seconds):
        p = subprocess.Popen([sys.executable, "-c", TIMELINE_CHILD, str(seconds)],
                             stdout=subprocess.PIPE, text=True)
        made.append(p)
        return p

    yield start
    for p in made:
        if p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
            p.kill()
        p.communicate(timeout=WAIT)


def test_stall_freezes_and_thaws_on_its_schedule(child):
    p = child(4.0)
    until(lambda: process_state(p.pid) in ("S", "R"), "the child runs")
    st = Stall(p.pid, duration=2.5, every=(0.3, 0.4), length=0.1, long_stalls=[(1.0, 0.4)],
               seed=5)
    # the plan is the seed's: reproducible, and another seed gives another
    assert st.plan == Stall(1, duration=2.5, every=(0.3, 0.4), length=0.1,
                            long_stalls=[(1.0, 0.4)], seed=5).plan
    assert st.plan != Stall(1, duration=2.5, every=(0.3, 0.4), length=0.1,
                            long_stalls=[(1.0, 0.4)], seed=6).plan
    assert (1.0, 0.4) in st.plan and not any(1.0 <= o < 1.4 for o, l in st.plan if l == 0.1)
    assert all(o + l <= 2.5 for o, l in st.plan) and len(st.plan) >= 4
    st.start()
    samples = []          # (before, state, after): what /proc said between those times
    while st.running():
        t1 = time.monotonic()
        s = process_state(p.pid)
        samples.append((t1, s, time.monotonic()))
        time.sleep(0.001)
    st.stop()
    print(f"\n{st.summary()}; plan {[(round(o, 3), l) for o, l in st.plan]}; "
          f"{len(samples)} /proc samples")
    assert st.error is None and st.count == len(st.plan) == len(st.windows)
    assert process_state(p.pid) != "T" and p.poll() is None
    for (start, end), (offset, length), (w0, w1) in zip(st.stalls, st.plan, st.windows):
        assert w0 <= start < end <= w1
        assert end - start >= length - 0.002
        assert st.t_start + offset <= w0 and w1 <= st.t_start + st.duration + 0.5
    # /proc: stopped whenever inside a stall, never stopped outside every window
    inside = [s for t1, s, t2 in samples if any(a <= t1 and t2 <= b for a, b in st.stalls)]
    outside = [s for t1, s, t2 in samples if all(t2 < a or t1 > b for a, b in st.windows)]
    assert inside and set(inside) == {"T"}, set(inside)
    assert outside and "T" not in outside
    # the child's own account: it ran before and after every stall and never during one
    out, _ = p.communicate(timeout=WAIT)
    assert p.returncode == 0
    ts = json.loads(out)
    for a, b in st.stalls:
        assert not any(a < t < b for t in ts), (a, b)
        assert any(t < a for t in ts) and any(t > b for t in ts)


def test_stall_stop_during_a_stall_leaves_the_process_running(child):
    p = child(6.0)
    until(lambda: process_state(p.pid) in ("S", "R"), "the child runs")
    st = Stall(p.pid, duration=10, every=(20, 20), long_stalls=[(0.1, 5.0)]).start()
    until(lambda: process_state(p.pid) == "T", "the child is stopped")
    time.sleep(0.3)       # into the stall (only so the figures below mean something)
    t = time.monotonic()
    st.stop()
    stopped_in = time.monotonic() - t
    state = process_state(p.pid)
    print(f"\nstop() during a 5 s stall returned after {stopped_in * 1e3:.1f} ms; state {state}; "
          f"{st.summary()}")
    assert not st.running() and state in ("S", "R") and p.poll() is None
    (start, end), = st.stalls
    assert end - start < 4.0 and st.count == 1 and st.error is None
    os.kill(p.pid, signal.SIGTERM)


# --- the lab's factories on real gateways ------------------------------------------------------

def test_lab_group_tees_into_two_gateways_while_one_is_stalled(lab):
    """lab.emu_group tees two links into two gateways (one UDP server per link each);
    lab.stall freezes the second gateway now and then. Both gateways read exactly what each
    link forwarded: a stalled gateway's socket holds the datagrams until it runs again."""
    ports = {g: {"radio": free_port(), "lte": free_port()} for g in ("g1", "g2")}
    gws = {g: lab.gateway([udp_server("radio", ports[g]["radio"]),
                           udp_server("lte", ports[g]["lte"]),
                           udp_server("gcs", free_port())], name=g) for g in ports}
    listen = {"radio": free_port(), "lte": free_port()}
    grp = lab.emu_group([dict(name=k, listen_port=listen[k], seed=i + 1, loss="1%",
                              forward_ports=[ports["g1"][k], ports["g2"][k]])
                         for i, k in enumerate(listen)], name="tee")
    st = lab.stall(gws["g2"], duration=2.4, every=(0.4, 0.5), length=0.15, seed=3)
    fm = FrameMaker(1, 1)
    tx = lab.sock()
    frames = 0
    t0 = time.monotonic()
    while st.running() or frames < 400:       # 200 frames/s per link, for the stall's run
        time.sleep(max(0.0, t0 + frames * 0.005 - time.monotonic()))
        f = fm.attitude(frames)
        for k in listen:
            tx.sendto(f, (HOST, listen[k]))
        frames += 1
        assert frames < 2000, "the stall schedule never ended"
    c = until(lambda: (c := grp.counters_now()) and all(
        c[k]["up"]["received"] == frames and c[k]["up"]["in_flight"] == 0 for k in listen)
        and c, "the group forwarded everything", step=0.05)
    want = {k: c[k]["up"]["forwarded"] for k in listen}
    seen = until(lambda: (s := {g: gw.stats() for g, gw in gws.items()}) and all(
        s[g][k]["rx_frames"] == want[k] for g in gws for k in listen) and s,
        "both gateways read every forwarded frame", step=0.1)
    print(f"\n{frames} frames per link; forwarded {want}; {st.summary()}; "
          f"g2 read {[seen['g2'][k]['rx_frames'] for k in listen]}")
    assert st.error is None and st.count == len(st.plan) >= 3
    assert gws["g2"].alive() and process_state(gws["g2"].proc.pid) != "T"
