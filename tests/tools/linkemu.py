#!/usr/bin/env python3
"""linkemu: a UDP relay that emulates one telemetry link (radio or LTE) between two local ports.

    side A  --udp-->  [--listen HOST:PORT]  linkemu  [--source]  --udp-->  [--forward HOST:PORT]  side B
            <--------------------------------------------------------------------------------------

Side A is whoever sends to the listen port (learned from its datagrams, like a UDP server; the
last sender wins). Everything from A goes to B ("up" direction); whatever B sends back to the
emulator's source socket goes to A's last address ("down" direction). Datagrams from any other
address than --forward on the source socket are ignored (counted as `foreign`).

Each direction has its own, independent impairments. A plain option (`--loss 1%`) applies to both
directions; `--up-loss` / `--down-loss` override it for one direction. The pipeline for one
datagram, in this order:

  1. index      every datagram received in a direction gets the next index (0, 1, 2, ...). The
                per-datagram random numbers (loss, Gilbert-Elliott, corruption) are drawn from a
                generator seeded by (--seed, direction), always the same count per datagram, so
                every such decision depends only on the seed and the index, never on timing.
  2. outage     `--outage START+LEN` (repeatable): dropped if it arrives while
                START <= t < START+LEN, t in seconds since the emulator started (not since the
                first datagram), so two emulators started together have comparable schedules.
  3. loss       Bernoulli `--loss P` and/or Gilbert-Elliott `--ge p_gb,p_bg,loss_good,loss_bad`
                (two-state Markov chain stepped once per datagram; starts in the good state; the
                loss decision uses the current state, then the state transitions). Mean burst
                length in the bad state is 1/p_bg.
  4. corrupt    `--corrupt P`: with probability P one uniformly chosen bit of the datagram is
                flipped (the datagram is still forwarded).
  5. rate       `--rate BITS/S` with `--overhead BYTES` per datagram: serialisation like a radio
                at that bit rate; frames queue behind each other (FIFO). The queue holds at most
                `--queue-bytes` bytes of payload waiting or being sent; a datagram that does not
                fit is dropped (tail drop). An empty queue always accepts one datagram.
  6. delay      `--delay D` plus jitter `--jitter J` (`--jitter-dist uniform`: uniform in
                [-J, +J]; `normal`: gaussian with sigma J, clipped at +-3J); never below zero.
                By default a direction never reorders: a datagram is not sent before the one
                received before it (its time is raised to the previous one's), so jitter larger
                than the spacing compresses the tail of the distribution instead of reordering.
                `--reorder` lets each datagram keep its own sampled time (jitter may reorder,
                but only as much as the jitter implies).

Scheduled sends live in one heap driven by a select() loop with timeouts (select() has
microsecond resolution); no thread per datagram. Time is CLOCK_MONOTONIC (time.monotonic()).

Counters: on exit (--duration elapsed, SIGTERM, SIGINT) and on SIGUSR1, one JSON line per
direction is printed to stdout:
  {"direction": "up", "t": 12.3, "received": .., "forwarded": .., "dropped_loss": ..,
   "dropped_outage": .., "dropped_queue": .., "dropped_no_peer": .., "corrupted": .., ...}
`--log-drops FILE` writes one JSON line per dropped datagram: {"direction", "index", "reason",
"t"} with reason loss | outage | queue | no_peer, and one line with reason "corrupted" (plus
"bit") for each corrupted datagram; those are NOT drops (the datagram was still forwarded
unless a later line drops the same index for "queue").

Importable:  from linkemu import LinkEmulator
    emu = LinkEmulator(listen="127.0.0.1:0", forward="127.0.0.1:14550", seed=1, loss="1%",
                       down_delay="40ms", outage=["10s+15s"], record_drops=True)
    emu.start(); ...; emu.stop(); emu.counters(); emu.drops()
Options take the CLI's strings ("1%", "40ms") or plain numbers (probability, seconds, bit/s).

Stdlib only (Python 3.11).
"""
from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import random
import re
import select
import signal
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Dict, IO, List, Optional, Sequence, Tuple

DIRECTIONS = ("up", "down")
MAX_DATAGRAM = 65535
SOCK_BUF = 4 * 1024 * 1024
RECV_BATCH = 256          # datagrams drained per socket per loop turn
IDLE_WAKE = 0.5           # s; the loop wakes at least this often even with nothing to do


# --- value parsing -----------------------------------------------------------------------------

_DUR_RE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(us|µs|ms|s|min)?\s*$")
_DUR_UNITS = {"us": 1e-6, "µs": 1e-6, "ms": 1e-3, "s": 1.0, "min": 60.0}


def parse_duration(v, bare_unit: Optional[str] = "s") -> float:
    """'40ms' | '1.5s' | '500us' | '2min' -> seconds. A bare number is in `bare_unit`
    (None: a bare number other than 0 is an error, so '--delay 40' is not silently 40 s)."""
    if isinstance(v, (int, float)):
        if v < 0 or math.isnan(v):
            raise ValueError(f"negative duration {v}")
        return float(v)
    m = _DUR_RE.match(str(v))
    if not m:
        raise ValueError(f"bad duration {v!r} (use e.g. 40ms, 1.5s, 500us)")
    num, unit = float(m.group(1)), m.group(2)
    if unit is None:
        if num == 0:
            return 0.0
        if bare_unit is None:
            raise ValueError(f"duration {v!r} needs a unit (e.g. {m.group(1)}ms)")
        unit = bare_unit
    return num * _DUR_UNITS[unit]


def parse_prob(v) -> float:
    """'1%' | '0.01' -> 0.01, must lie in [0, 1]."""
    if isinstance(v, (int, float)):
        p = float(v)
    else:
        s = str(v).strip()
        try:
            p = float(s[:-1]) / 100.0 if s.endswith("%") else float(s)
        except ValueError:
            raise ValueError(f"bad probability {v!r} (use e.g. 1% or 0.01)") from None
    if not 0.0 <= p <= 1.0:
        raise ValueError(f"probability {v!r} outside [0, 1]")
    return p


def parse_rate(v) -> Optional[float]:
    """'57600' | '57.6k' | '2M' (bit/s) -> float; 0 or None = unlimited."""
    if v is None:
        return None
    if isinstance(v, (int, float)):
        r = float(v)
    else:
        m = re.match(r"^\s*([0-9]*\.?[0-9]+)\s*([kKmM]?)(?:bps|bit/s|b/s)?\s*$", str(v))
        if not m:
            raise ValueError(f"bad rate {v!r} (bits per second, e.g. 57600 or 57.6k)")
        r = float(m.group(1)) * {"": 1, "k": 1e3, "K": 1e3, "m": 1e6, "M": 1e6}[m.group(2)]
    if r < 0:
        raise ValueError(f"negative rate {v!r}")
    return r or None


def parse_ge(v) -> Optional[Tuple[float, float, float, float]]:
    """'p_gb,p_bg,loss_good,loss_bad' -> 4 probabilities (each may be a percentage)."""
    if v is None:
        return None
    parts = v.split(",") if isinstance(v, str) else list(v)
    if len(parts) != 4:
        raise ValueError(f"--ge wants p_gb,p_bg,loss_good,loss_bad, got {v!r}")
    t = tuple(parse_prob(x) for x in parts)
    return t  # type: ignore[return-value]


def parse_outage(v) -> Tuple[float, float]:
    """'10s+15s' -> (10.0, 15.0): down from t=10 s (since start) for 15 s. Bare numbers = s."""
    if isinstance(v, (tuple, list)) and len(v) == 2:
        return parse_duration(v[0]), parse_duration(v[1])
    s = str(v)
    if "+" not in s:
        raise ValueError(f"bad outage {v!r} (use START+LENGTH, e.g. 10s+15s)")
    a, b = s.split("+", 1)
    return parse_duration(a), parse_duration(b)


def parse_int(v) -> int:
    n = int(v)
    if n < 0:
        raise ValueError(f"negative value {v!r}")
    return n


def parse_addr(v, what: str = "address") -> Tuple[str, int]:
    if isinstance(v, (tuple, list)):
        return str(v[0]), int(v[1])
    s = str(v)
    host, sep, port = s.rpartition(":")
    if not sep or not port.isdigit():
        raise ValueError(f"bad {what} {v!r} (use HOST:PORT, e.g. 127.0.0.1:14550)")
    host = host.strip("[]") or "0.0.0.0"
    return host, int(port)


# --- per-direction configuration ---------------------------------------------------------------

@dataclass
class DirConfig:
    loss: float = 0.0
    ge: Optional[Tuple[float, float, float, float]] = None
    delay: float = 0.0
    jitter: float = 0.0
    jitter_dist: str = "uniform"
    outage: List[Tuple[float, float]] = field(default_factory=list)
    corrupt: float = 0.0
    rate: Optional[float] = None
    overhead: int = 0
    queue_bytes: int = 4096
    reorder: bool = False


def _parse_jdist(v) -> str:
    if v not in ("uniform", "normal"):
        raise ValueError(f"jitter distribution {v!r}: uniform or normal")
    return v


def _parse_outages(v) -> List[Tuple[float, float]]:
    if v is None:
        return []
    if isinstance(v, str) or (isinstance(v, tuple) and len(v) == 2
                              and not isinstance(v[0], (tuple, list, str))):
        v = [v]
    return sorted(parse_outage(x) for x in v)


# name -> (parser, CLI metavar, help). Every name also exists as up_<name> / down_<name>.
PARAMS: Dict[str, Tuple[Callable, str, str]] = {
    "loss": (parse_prob, "P", "Bernoulli loss probability, e.g. 1%% or 0.01"),
    "ge": (parse_ge, "p_gb,p_bg,lg,lb",
           "Gilbert-Elliott burst loss: P(good->bad), P(bad->good), loss in good, loss in bad; "
           "e.g. 0.01,0.3,0,1"),
    "delay": (lambda v: parse_duration(v, None), "D", "one-way latency, e.g. 40ms"),
    "jitter": (lambda v: parse_duration(v, None), "J", "jitter amplitude, e.g. 5ms"),
    "jitter_dist": (_parse_jdist, "uniform|normal",
                    "uniform in [-J,+J] (default) or normal with sigma J, clipped at 3J"),
    "outage": (_parse_outages, "START+LEN",
               "link down from START for LEN (s since emulator start), repeatable, e.g. 10s+15s"),
    "corrupt": (parse_prob, "P", "probability that a datagram gets one random bit flipped"),
    "rate": (parse_rate, "BITS/S", "bandwidth cap in bit/s incl. --overhead, e.g. 57600"),
    "overhead": (parse_int, "BYTES", "bytes added to each datagram for --rate (default 0)"),
    "queue_bytes": (parse_int, "BYTES", "queue bound for --rate; tail drop when full "
                                        "(default 4096)"),
    "reorder": (bool, "", "let jitter reorder datagrams (default: keep FIFO order)"),
}


def resolve_configs(opts: Dict[str, object]) -> Dict[str, DirConfig]:
    """Keyword options (name, up_name, down_name) -> one DirConfig per direction."""
    unknown = [k for k in opts if k not in PARAMS and not (
        k.startswith(("up_", "down_")) and k.split("_", 1)[1] in PARAMS)]
    if unknown:
        raise TypeError(f"unknown link option(s): {', '.join(sorted(unknown))}")
    out = {}
    for d in DIRECTIONS:
        cfg = DirConfig()
        for name, (parser, _, _) in PARAMS.items():
            v = opts.get(f"{d}_{name}")
            if v is None:
                v = opts.get(name)
            if v is None:
                continue
            setattr(cfg, name, parser(v))
        if cfg.ge is not None and cfg.ge == (0.0, 0.0, 0.0, 0.0):
            cfg.ge = None
        out[d] = cfg
    return out


# --- one direction -----------------------------------------------------------------------------

class _Direction:
    def __init__(self, name: str, cfg: DirConfig, seed: int, record: Optional[list]):
        self.name = name
        self.cfg = cfg
        # String seeds are hashed with SHA-512 by random.Random: stable across runs/processes.
        self.rng = random.Random(f"linkemu:{seed}:{name}:decide")
        self.jrng = random.Random(f"linkemu:{seed}:{name}:jitter")
        self.record = record
        self.index = 0
        self.ge_bad = False
        self.busy_until = 0.0
        self.queue: deque = deque()    # (finish_time, size) of datagrams waiting or serialising
        self.queued_bytes = 0
        self.last_due = 0.0
        self.c = dict(received=0, forwarded=0, dropped_loss=0, dropped_outage=0,
                      dropped_queue=0, dropped_no_peer=0, corrupted=0, send_errors=0,
                      bytes_received=0, bytes_forwarded=0)
        self.scheduled = 0
        self.late_max = 0.0

    def _drop(self, idx: int, reason: str, rel: float, **extra) -> None:
        self.c["dropped_" + reason] += 1
        if self.record is not None:
            self.record.append(dict(direction=self.name, index=idx, reason=reason,
                                    t=round(rel, 6), **extra))

    def admit(self, data: bytes, now: float, rel: float, have_peer: bool = True):
        """One received datagram -> (due_time, data) to schedule, or None if dropped."""
        cfg = self.cfg
        idx = self.index
        self.index += 1
        c = self.c
        c["received"] += 1
        c["bytes_received"] += len(data)
        r = self.rng.random
        # Always five draws per datagram: decisions depend on (seed, index) only.
        u_loss, u_gt, u_gl, u_cor, u_bit = r(), r(), r(), r(), r()
        j1, j2 = self.jrng.random(), self.jrng.random()
        lost = u_loss < cfg.loss
        if cfg.ge is not None:
            p_gb, p_bg, l_good, l_bad = cfg.ge
            if self.ge_bad:
                lost = lost or u_gl < l_bad
                if u_gt < p_bg:
                    self.ge_bad = False
            else:
                lost = lost or u_gl < l_good
                if u_gt < p_gb:
                    self.ge_bad = True
        for start, length in cfg.outage:
            if start <= rel < start + length:
                self._drop(idx, "outage", rel)
                return None
        if lost:
            self._drop(idx, "loss", rel)
            return None
        if not have_peer:
            self._drop(idx, "no_peer", rel)
            return None
        if cfg.corrupt and u_cor < cfg.corrupt and data:
            nbits = len(data) * 8
            bit = min(int(u_bit * nbits), nbits - 1)
            b = bytearray(data)
            b[bit >> 3] ^= 1 << (bit & 7)
            data = bytes(b)
            c["corrupted"] += 1
            if self.record is not None:
                self.record.append(dict(direction=self.name, index=idx, reason="corrupted",
                                        t=round(rel, 6), bit=bit))
        t = now
        if cfg.rate:
            q = self.queue
            while q and q[0][0] <= now:
                self.queued_bytes -= q.popleft()[1]
            size = len(data)
            if q and self.queued_bytes + size > cfg.queue_bytes:
                self._drop(idx, "queue", rel)
                return None
            start = self.busy_until if self.busy_until > now else now
            t = start + (size + cfg.overhead) * 8.0 / cfg.rate
            self.busy_until = t
            q.append((t, size))
            self.queued_bytes += size
        t += cfg.delay
        if cfg.jitter:
            if cfg.jitter_dist == "normal":
                z = math.sqrt(-2.0 * math.log(1.0 - j1)) * math.cos(2.0 * math.pi * j2)
                t += max(-3.0, min(3.0, z)) * cfg.jitter
            else:
                t += (2.0 * j1 - 1.0) * cfg.jitter
            if t < now:
                t = now
        if not cfg.reorder:
            if t < self.last_due:
                t = self.last_due
            self.last_due = t
        self.scheduled += 1
        return t, data

    def counters(self, rel: float) -> dict:
        d = dict(direction=self.name, t=round(rel, 3))
        d.update(self.c)
        d["in_flight"] = self.scheduled - self.c["forwarded"] - self.c["send_errors"]
        d["late_max_ms"] = round(self.late_max * 1e3, 3)
        return d


# --- the emulator ------------------------------------------------------------------------------

def _resolve(host: str, port: int) -> Tuple[int, tuple]:
    infos = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    fam, _, _, _, addr = infos[0]
    return fam, addr


def _udp_socket(fam: int, bind: tuple) -> socket.socket:
    s = socket.socket(fam, socket.SOCK_DGRAM)
    for opt in (socket.SO_RCVBUF, socket.SO_SNDBUF):
        try:
            s.setsockopt(socket.SOL_SOCKET, opt, SOCK_BUF)
        except OSError:
            pass
    s.bind(bind)
    s.setblocking(False)
    return s


class LinkEmulator:
    """One emulated link. Sockets are bound in the constructor (listen port 0 -> see
    `listen_addr`); `start()` runs the loop in a daemon thread, `run()` in the caller's."""

    def __init__(self, listen="127.0.0.1:0", forward="127.0.0.1:14550", *,
                 seed: Optional[int] = None, duration=None, source=None,
                 log_drops: Optional[str] = None, record_drops: bool = False,
                 out: Optional[IO[str]] = None, **link_opts):
        self.configs = resolve_configs(link_opts)
        self.seed = random.SystemRandom().randrange(2 ** 32) if seed is None else int(seed)
        self.duration = None if duration in (None, 0, "0") else parse_duration(duration)
        lhost, lport = parse_addr(listen, "--listen address")
        fhost, fport = parse_addr(forward, "--forward address")
        lfam, laddr = _resolve(lhost, lport)
        ffam, self.forward_addr = _resolve(fhost, fport)
        if source is not None:
            shost, sport = parse_addr(source, "--source address")
            _, saddr = _resolve(shost, sport)
        else:
            saddr = ("::", 0) if ffam == socket.AF_INET6 else ("0.0.0.0", 0)
        self.sock_a = _udp_socket(lfam, laddr)
        try:
            self.sock_b = _udp_socket(ffam, saddr)
        except OSError:
            self.sock_a.close()
            raise
        self.listen_addr = self.sock_a.getsockname()[:2]
        self.source_addr = self.sock_b.getsockname()[:2]
        self.out = out if out is not None else sys.stdout
        self._record: Optional[list] = [] if (record_drops or log_drops) else None
        self._log_path = log_drops
        self._log_written = 0
        self.dirs = {d: _Direction(d, self.configs[d], self.seed, self._record)
                     for d in DIRECTIONS}
        self.peer_a: Optional[tuple] = None
        self.foreign = 0
        self.t0: Optional[float] = None
        self._stop = False
        self._dump = False
        self._rpipe, self._wpipe = os.pipe()
        os.set_blocking(self._rpipe, False)
        os.set_blocking(self._wpipe, False)
        self._thread: Optional[threading.Thread] = None
        self._closed = False
        self.started = threading.Event()

    # control (thread- and signal-safe: set a flag, wake the loop)
    def _wake(self) -> None:
        try:
            os.write(self._wpipe, b"x")
        except (BlockingIOError, OSError):
            pass

    def request_stop(self) -> None:
        self._stop = True
        self._wake()

    def request_dump(self) -> None:
        self._dump = True
        self._wake()

    def start(self) -> "LinkEmulator":
        self._thread = threading.Thread(target=self.run, name="linkemu", daemon=True)
        self._thread.start()
        self.started.wait(5)
        return self

    def stop(self, timeout: float = 5.0) -> dict:
        self.request_stop()
        if self._thread is not None:
            self._thread.join(timeout)
        self.close()
        return self.counters()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def close(self) -> None:
        if self._closed or (self._thread is not None and self._thread.is_alive()):
            return
        self._closed = True
        for s in (self.sock_a, self.sock_b):
            s.close()
        for fd in (self._rpipe, self._wpipe):
            os.close(fd)

    def elapsed(self) -> float:
        return 0.0 if self.t0 is None else time.monotonic() - self.t0

    def counters(self) -> Dict[str, dict]:
        rel = self.elapsed()
        out = {d: self.dirs[d].counters(rel) for d in DIRECTIONS}
        out["up"]["foreign"] = 0
        out["down"]["foreign"] = self.foreign
        return out

    def drops(self) -> List[dict]:
        """Drop (and corruption) records so far; needs record_drops=True or log_drops."""
        return list(self._record or [])

    def dump(self) -> None:
        """Print the counters (one JSON line per direction) and flush the drop log."""
        for d in self.counters().values():
            self.out.write(json.dumps(d) + "\n")
        self.out.flush()
        self._flush_log()

    def _flush_log(self) -> None:
        if self._log_path is None or self._record is None:
            return
        new = self._record[self._log_written:]
        with open(self._log_path, "a" if self._log_written else "w") as f:
            for r in new:
                f.write(json.dumps(r) + "\n")
        self._log_written += len(new)

    # the loop
    def run(self) -> None:
        mono = time.monotonic
        heappush, heappop = heapq.heappush, heapq.heappop
        up, down = self.dirs["up"], self.dirs["down"]
        sa, sb, rp = self.sock_a, self.sock_b, self._rpipe
        fwd = self.forward_addr
        heap: List[tuple] = []     # (due, seq, direction, data)
        seq = 0
        t0 = self.t0 = mono()
        deadline = t0 + self.duration if self.duration else math.inf
        rlist = [sa, sb, rp]
        self.started.set()
        try:
            while not self._stop:
                now = mono()
                if now >= deadline:
                    break
                # 1. everything due
                while heap and heap[0][0] <= now:
                    due, _, d, data = heappop(heap)
                    late = now - due
                    if late > d.late_max:
                        d.late_max = late
                    try:
                        if d is up:
                            sb.sendto(data, fwd)
                        else:
                            sa.sendto(data, self.peer_a)
                        d.c["forwarded"] += 1
                        d.c["bytes_forwarded"] += len(data)
                    except OSError:
                        d.c["send_errors"] += 1
                    now = mono()
                if self._dump:
                    self._dump = False
                    self.dump()
                # 2. wait for input or the next due time
                timeout = min(deadline - now, IDLE_WAKE)
                if heap:
                    timeout = min(timeout, heap[0][0] - now)
                if timeout < 0:
                    timeout = 0
                readable, _, _ = select.select(rlist, [], [], timeout)
                for s in readable:
                    if s is rp:
                        try:
                            os.read(rp, 4096)
                        except BlockingIOError:
                            pass
                        continue
                    for _ in range(RECV_BATCH):
                        try:
                            data, addr = s.recvfrom(MAX_DATAGRAM)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:   # e.g. ICMP errors reported on the socket
                            continue
                        now = mono()
                        if s is sa:
                            self.peer_a = addr
                            d = up
                            r = d.admit(data, now, now - t0)
                        else:
                            if addr[:2] != fwd[:2]:
                                self.foreign += 1
                                continue
                            d = down
                            r = d.admit(data, now, now - t0, self.peer_a is not None)
                        if r is not None:
                            seq += 1
                            heappush(heap, (r[0], seq, d, r[1]))
        finally:
            self._stop = True


# --- CLI ---------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="linkemu",
        description="Relay UDP between --listen (side A) and --forward (side B), emulating one "
                    "lossy, delayed, rate-limited telemetry link in each direction.",
        epilog="Every link option X also exists as --up-X (A->B only) and --down-X (B->A "
               "only), which override --X for that direction. Durations take units (us, ms, s; "
               "bare numbers are seconds for --outage and --duration), probabilities take % or "
               "a fraction. Counters: one JSON line per direction on stdout at exit and on "
               "SIGUSR1. See the module docstring for the exact semantics.",
    )
    p.add_argument("--listen", required=True, metavar="HOST:PORT",
                   help="where side A sends to (port 0: pick one, printed on stderr)")
    p.add_argument("--forward", required=True, metavar="HOST:PORT", help="side B's address")
    p.add_argument("--source", metavar="HOST:PORT",
                   help="bind the socket that talks to B here (default: ephemeral port)")
    p.add_argument("--seed", type=int, help="random seed (default: random, printed on stderr)")
    p.add_argument("--duration", metavar="T", help="exit by itself after T (e.g. 30s)")
    p.add_argument("--log-drops", metavar="FILE",
                   help="write one JSON line per dropped (or corrupted) datagram")
    for name, (_, metavar, help_) in PARAMS.items():
        flag = name.replace("_", "-")
        for prefix, h in (("", help_), ("up-", argparse.SUPPRESS), ("down-", argparse.SUPPRESS)):
            dest = (prefix.replace("-", "_")) + name
            if name == "reorder":
                p.add_argument(f"--{prefix}{flag}", dest=dest, action="store_const", const=True,
                               default=None, help=h)
            elif name == "outage":
                p.add_argument(f"--{prefix}{flag}", dest=dest, action="append", metavar=metavar,
                               help=h)
            else:
                p.add_argument(f"--{prefix}{flag}", dest=dest, metavar=metavar, help=h)
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    link_opts = {}
    for name in PARAMS:
        for prefix in ("", "up_", "down_"):
            v = getattr(a, prefix + name)
            if v is not None:
                link_opts[prefix + name] = v
    try:
        emu = LinkEmulator(a.listen, a.forward, seed=a.seed, duration=a.duration,
                           source=a.source, log_drops=a.log_drops, **link_opts)
    except (ValueError, TypeError) as e:
        parser.error(str(e))
    except OSError as e:
        print(f"linkemu: {e}", file=sys.stderr)
        return 1
    signal.signal(signal.SIGTERM, lambda *_: emu.request_stop())
    signal.signal(signal.SIGINT, lambda *_: emu.request_stop())
    signal.signal(signal.SIGUSR1, lambda *_: emu.request_dump())
    la, fa, sa = emu.listen_addr, emu.forward_addr, emu.source_addr
    print(f"linkemu: listening on {la[0]}:{la[1]}, forwarding to {fa[0]}:{fa[1]} from "
          f"{sa[0]}:{sa[1]}, seed {emu.seed}", file=sys.stderr, flush=True)
    emu.run()
    emu.dump()
    emu.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
