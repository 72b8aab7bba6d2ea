#!/usr/bin/env python3
"""linkemu: a UDP relay that emulates one telemetry link (radio or LTE) between two local ports,
or (--group) several links in one loop.

    side A  --udp-->  [--listen HOST:PORT]  linkemu  [--source]  --udp-->  [--forward HOST:PORT]  side B
            <--------------------------------------------------------------------------------------

Side A is whoever sends to the listen port (learned from its datagrams, like a UDP server; the
last sender wins). Everything from A goes to B ("up" direction); whatever B sends back to the
emulator's source socket goes to A's last address ("down" direction). Datagrams from any other
address than --forward on the source socket are ignored (counted as `foreign`).

Down tee: `--down-tee HOST:PORT` (repeatable; "down_tee" in a group spec) also sends each down
datagram there as it goes to A: a sniffer of what A received. Counters are unchanged.

Tee: `--forward` may be given several times. Each up datagram, when due, is sent to every
forward address, one right after the other, before any other datagram is sent. The down
direction is taken from the FIRST forward address only; replies from the others are counted as
`foreign` and not relayed. Counters count datagrams, not copies: `forwarded` when every copy
was sent, `send_errors` when any copy failed.

Each direction has its own, independent impairments. A plain option (`--loss 1%`) applies to both
directions; `--up-loss` / `--down-loss` override it for one direction. The pipeline for one
datagram, in this order:

  1. index      every datagram received in a direction gets the next index (0, 1, 2, ...). The
                per-datagram random numbers (loss, Gilbert-Elliott, corruption) are drawn from a
                generator seeded by (--seed, direction), always the same count per datagram, so
                every such decision depends only on the seed and the index, never on timing.
  2. outage     `--outage START+LEN` (repeatable): dropped if it arrives while
                START <= t < START+LEN, t in seconds since the emulator (the group) started (not
                since the first datagram), so two emulators started together have comparable
                schedules, and the links of a group share one.
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
  7. stall      `--stall START+LEN` (repeatable): nothing leaves from START for LEN, as when a
                radio's queue stands still (its process given no CPU, a modem's buffer held): a
                datagram due in that time leaves at its end instead, in order, nothing lost.

Scheduled sends live in one heap driven by a select() loop with timeouts (select() has
microsecond resolution); no thread per datagram. Time is CLOCK_MONOTONIC (time.monotonic()).
Datagrams due at the same time leave in the order they arrived.

Group: `--group SPEC.json` runs several links in ONE process and ONE loop, with one heap of due
sends across all links, so whatever is due first leaves first whatever its link, and every
receiver of a tee sees the same interleaving of the links. SPEC.json is a list of links:
    [{"name": "radio", "listen": "127.0.0.1:14601", "forward": ["127.0.0.1:14551",
      "127.0.0.1:14561"], "seed": 1, "loss": "1%", "up-delay": "20ms", "outage": ["5s+2s"],
      "log_drops": "radio-drops.jsonl"},
     {"name": "lte", "listen": "127.0.0.1:14602", "forward": "127.0.0.1:14552", "seed": 2}]
Each link takes the CLI's link options (with - or _, e.g. "up-loss" or "up_loss"; "reorder":
true; values as strings like "1%", "40ms" or plain numbers: probability, seconds, bit/s) and
"source", "log_drops", "log_sends", "log_received" (its own files). Each link keeps its own
seed and decisions, which depend only on (seed, direction, index): link "radio" with seed 1
drops exactly what a single linkemu with --seed 1 and the same options drops. Outages count
from the group's start. --group takes --duration; every other option goes in the spec.
Banner: one line per link,
`linkemu: link NAME: listening on H:P, forwarding to H:P[, H:P] from H:P, seed N`, then,
once the group's clock has started (its outages count from before this line),
`linkemu: group of N links listening`.

Counters: on exit (--duration elapsed, SIGTERM, SIGINT) and on SIGUSR1, one JSON line per
direction is printed to stdout (in a group: per link and direction, with a "link" field first):
  {"direction": "up", "t": 12.3, "received": .., "forwarded": .., "dropped_loss": ..,
   "dropped_outage": .., "dropped_queue": .., "dropped_no_peer": .., "corrupted": .., ...}
`--log-drops FILE` writes one JSON line per dropped datagram: {"direction", "index", "reason",
"t"} with reason loss | outage | queue | no_peer, and one line with reason "corrupted" (plus
"bit") for each corrupted datagram; those are NOT drops (the datagram was still forwarded
unless a later line drops the same index for "queue").
`--log-sends FILE` writes one JSON line per datagram sent: {"direction", "index", "arrived",
"due", "sent", "n"}: when it arrived, when it was due and when it was sent (s since the start,
unrounded), n its place among all the sends of the process (of every link of a group). This is
the emulator's own account of what it decided and did, independent of anybody's scheduling:
sent - due is how late the loop was.
`--log-received FILE` writes one JSON line per datagram received: {"direction", "index",
"data"}, data its bytes as they arrived (hex), whatever became of it: with the drop log, the
account of every index (a receiver that writes datagrams of its own between the ones it
relays, such as mavbond's count markers, is known datagram by datagram).

Importable:  from linkemu import LinkEmulator, LinkGroup
    emu = LinkEmulator(listen="127.0.0.1:0", forward="127.0.0.1:14550", seed=1, loss="1%",
                       down_delay="40ms", outage=["10s+15s"], record_drops=True)
    emu.start(); ...; emu.stop(); emu.counters(); emu.drops()
    tee = LinkEmulator("127.0.0.1:0", ["127.0.0.1:14550", "127.0.0.1:14560"], seed=1)
    group = LinkGroup([dict(name="radio", listen="127.0.0.1:0", forward=[...], seed=1,
                            loss="1%"), dict(name="lte", ...)], record_drops=True)
    group.start(); group.link("radio").listen_addr; group.counters()["radio"]["up"];
    group.drops("radio"); group.sends("radio")   # sends: record_sends=True
    group.received("radio")                      # record_received=True
    group.request_rebind("lte")   # a NAT rebinding: B hears the link from a new source port
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
    stall: List[Tuple[float, float]] = field(default_factory=list)
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
    "stall": (_parse_outages, "START+LEN",
              "nothing leaves from START for LEN; what is due meanwhile leaves at its end, "
              "repeatable, e.g. 4s+3.5s"),
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
    def __init__(self, name: str, cfg: DirConfig, seed: int, record: Optional[list],
                 sends: Optional[list] = None, received: Optional[list] = None):
        self.name = name
        self.up = name == "up"
        self.cfg = cfg
        # String seeds are hashed with SHA-512 by random.Random: stable across runs/processes.
        self.rng = random.Random(f"linkemu:{seed}:{name}:decide")
        self.jrng = random.Random(f"linkemu:{seed}:{name}:jitter")
        self.record = record
        self.sends = sends             # one dict per datagram sent, when asked for
        self.received = received       # one dict per datagram received, when asked for
        self.link: Optional["Link"] = None
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
        """One received datagram -> (due_time, data, index) to schedule, or None if dropped."""
        cfg = self.cfg
        idx = self.index
        self.index += 1
        c = self.c
        c["received"] += 1
        c["bytes_received"] += len(data)
        if self.received is not None:
            self.received.append(dict(direction=self.name, index=idx, data=data.hex()))
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
        for start, length in cfg.stall:
            due_rel = rel + (t - now)
            if start <= due_rel < start + length:
                t += start + length - due_rel
        if not cfg.reorder:
            if t < self.last_due:
                t = self.last_due
            self.last_due = t
        self.scheduled += 1
        return t, data, idx

    def counters(self, rel: float) -> dict:
        d = dict(direction=self.name, t=round(rel, 3))
        d.update(self.c)
        d["in_flight"] = self.scheduled - self.c["forwarded"] - self.c["send_errors"]
        d["late_max_ms"] = round(self.late_max * 1e3, 3)
        return d


# --- one link ----------------------------------------------------------------------------------

def _resolve(host: str, port: int) -> Tuple[int, tuple]:
    infos = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    fam, _, _, _, addr = infos[0]
    return fam, addr


def _udp_socket(fam: int, bind: tuple) -> socket.socket:
    s = socket.socket(fam, socket.SOCK_DGRAM)
    # Forced past net.core.rmem_max when privileged (the tests run as root): a stock kernel
    # caps an unprivileged buffer at about 212 KB, a third of a second at 1 kHz.
    for force, opt in ((33, socket.SO_RCVBUF), (32, socket.SO_SNDBUF)):  # SO_*BUFFORCE
        for o in (force, opt):
            try:
                s.setsockopt(socket.SOL_SOCKET, o, SOCK_BUF)
                break
            except OSError:
                continue
    s.bind(bind)
    s.setblocking(False)
    return s


def _forward_list(v) -> list:
    """'H:P' | (host, port) | a list of either -> a non-empty list of addresses."""
    if isinstance(v, str) or (isinstance(v, (tuple, list)) and len(v) == 2
                              and isinstance(v[1], int)):
        return [v]
    out = list(v or [])
    if not out:
        raise ValueError("no --forward address")
    return out


class _JsonLog:
    """Appends the records of a list to a file, each record once (flushed on every dump)."""

    def __init__(self, path: Optional[str], records: Optional[list]):
        self.path, self.records, self.written = path, records, 0

    def flush(self) -> None:
        if self.path is None or self.records is None:
            return
        new = self.records[self.written:]
        with open(self.path, "a" if self.written else "w") as f:
            for r in new:
                f.write(json.dumps(r) + "\n")
        self.written += len(new)


class Link:
    """One emulated link: the listen socket (side A), the source socket that talks to side B,
    the forward addresses (several = a tee: the up direction goes to each of them, the down
    direction is taken from the first only) and the two directions. Sockets are bound here.
    It runs inside a LinkGroup's loop."""

    def __init__(self, name: str = "", listen="127.0.0.1:0", forward="127.0.0.1:14550", *,
                 seed: Optional[int] = None, source=None, log_drops: Optional[str] = None,
                 record_drops: bool = False, log_sends: Optional[str] = None,
                 record_sends: bool = False, log_received: Optional[str] = None,
                 record_received: bool = False, down_tee=None, **link_opts):
        self.name = name
        self.configs = resolve_configs(link_opts)
        self.seed = random.SystemRandom().randrange(2 ** 32) if seed is None else int(seed)
        lhost, lport = parse_addr(listen, "--listen address")
        lfam, laddr = _resolve(lhost, lport)
        self.forward_addrs: List[tuple] = []
        ffam = None
        for f in _forward_list(forward):
            fam, addr = _resolve(*parse_addr(f, "--forward address"))
            if ffam is not None and fam != ffam:
                raise ValueError("--forward addresses of one link must be of one family")
            ffam = fam
            self.forward_addrs.append(addr)
        self.forward_addr = self.forward_addrs[0]    # the only one replies are taken from
        # Where each down datagram also goes, when it is sent to A (a sniffer of that side).
        self.down_tee: List[tuple] = [
            _resolve(*parse_addr(t, "down tee address"))[1]
            for t in (_forward_list(down_tee) if down_tee else [])]
        if source is not None:
            shost, sport = parse_addr(source, "--source address")
            _, saddr = _resolve(shost, sport)
        else:
            saddr = ("::", 0) if ffam == socket.AF_INET6 else ("0.0.0.0", 0)
        self._source = (ffam, saddr)
        self.sock_a = _udp_socket(lfam, laddr)
        try:
            self.sock_b = _udp_socket(ffam, saddr)
        except OSError:
            self.sock_a.close()
            raise
        self.listen_addr = self.sock_a.getsockname()[:2]
        self.source_addr = self.sock_b.getsockname()[:2]
        self._record: Optional[list] = [] if (record_drops or log_drops) else None
        self._sends: Optional[list] = [] if (record_sends or log_sends) else None
        self._received: Optional[list] = [] if (record_received or log_received) else None
        self._logs = [_JsonLog(log_drops, self._record), _JsonLog(log_sends, self._sends),
                      _JsonLog(log_received, self._received)]
        self.dirs = {d: _Direction(d, self.configs[d], self.seed, self._record, self._sends,
                                   self._received)
                     for d in DIRECTIONS}
        for d in self.dirs.values():
            d.link = self
        self.peer_a: Optional[tuple] = None
        self.foreign = 0
        self.rebinds = 0
        self.closed = False

    def counters(self, rel: float, with_name: bool = False) -> Dict[str, dict]:
        out = {}
        for d in DIRECTIONS:
            row = {"link": self.name} if with_name else {}
            row.update(self.dirs[d].counters(rel))
            row["foreign"] = self.foreign if d == "down" else 0
            out[d] = row
        return out

    def drops(self) -> List[dict]:
        """Drop (and corruption) records so far; needs record_drops=True or log_drops."""
        return list(self._record or [])

    def rebind(self) -> socket.socket:
        """A NAT rebinding: side B is talked to from a new source socket (a new port on the
        same address) from now on. Returns the old socket, for the loop to forget and close:
        what B sends to the old port after this goes nowhere, as a NAT drops what comes to a
        mapping it gave up."""
        fam, (host, *_rest) = self._source
        old = self.sock_b
        self.sock_b = _udp_socket(fam, (host, 0) if fam == socket.AF_INET else (host, 0, 0, 0))
        self.source_addr = self.sock_b.getsockname()[:2]
        self.rebinds += 1
        return old

    def sends(self) -> List[dict]:
        """One record per datagram sent: {"direction", "index", "arrived", "due", "sent", "n"},
        times in s since the start, n its place in the group's sends; needs record_sends=True
        or log_sends."""
        return list(self._sends or [])

    def received(self) -> List[dict]:
        """One record per datagram received: {"direction", "index", "data"}, data its bytes
        as they arrived (hex); needs record_received=True or log_received."""
        return list(self._received or [])

    def flush_logs(self) -> None:
        for log in self._logs:
            log.flush()

    def banner(self) -> str:
        la, sa = self.listen_addr, self.source_addr
        fwd = ", ".join(f"{h}:{p}" for h, p in (a[:2] for a in self.forward_addrs))
        return (f"listening on {la[0]}:{la[1]}, forwarding to {fwd} from {sa[0]}:{sa[1]}, "
                f"seed {self.seed}")

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.sock_a.close()
            self.sock_b.close()


# --- the loop ----------------------------------------------------------------------------------

class LinkGroup:
    """Several links driven by ONE loop: one heap of due sends across all links, so a datagram
    due before another leaves first whatever link either is on, and a tee's receivers all see
    the same interleaving of the links. Each link keeps its own options, seed, decisions,
    counters and logs; outages count from the group's start. `start()` runs the loop in a
    daemon thread, `run()` in the caller's.

        group = LinkGroup([dict(name="radio", listen="127.0.0.1:0", forward=[g1, g2], seed=1,
                                loss="1%"), dict(name="lte", ...)], duration="60s")
    """

    def __init__(self, links: Sequence = (), *, duration=None, out: Optional[IO[str]] = None,
                 record_drops: bool = False, record_sends: bool = False,
                 record_received: bool = False):
        self.links: List[Link] = []
        try:
            for spec in links:
                if not isinstance(spec, Link):
                    spec = dict(spec)
                    spec.setdefault("record_drops", record_drops)
                    spec.setdefault("record_sends", record_sends)
                    spec.setdefault("record_received", record_received)
                    spec = Link(**spec)
                self.links.append(spec)
        except BaseException:
            for link in self.links:
                link.close()
            raise
        names = [link.name for link in self.links]
        if len(set(names)) != len(names):
            self.close_links()
            raise ValueError(f"link names must differ: {names}")
        self.duration = None if duration in (None, 0, "0") else parse_duration(duration)
        self.out = out if out is not None else sys.stdout
        self.t0: Optional[float] = None
        self._stop = False
        self._dump = False
        self._rebind: List[str] = []
        self._rpipe, self._wpipe = os.pipe()
        os.set_blocking(self._rpipe, False)
        os.set_blocking(self._wpipe, False)
        self._thread: Optional[threading.Thread] = None
        self._closed = False
        self.started = threading.Event()
        self.on_start: Optional[Callable[[], None]] = None   # called once t0 is set

    def link(self, name: str) -> Link:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)

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

    def request_rebind(self, name: str) -> None:
        """A NAT rebinding of link `name` (Link.rebind), taken by the loop between two
        datagrams: whatever is due after it leaves from the new source port."""
        self.link(name)   # KeyError now, not in the loop
        self._rebind.append(name)
        self._wake()

    def start(self):
        self._thread = threading.Thread(target=self.run, name="linkemu", daemon=True)
        self._thread.start()
        self.started.wait(5)
        return self

    def stop(self, timeout: float = 5.0):
        self.request_stop()
        if self._thread is not None:
            self._thread.join(timeout)
        self.close()
        return self.counters()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def close_links(self) -> None:
        for link in self.links:
            link.close()

    def close(self) -> None:
        if self._closed or (self._thread is not None and self._thread.is_alive()):
            return
        self._closed = True
        self.close_links()
        for fd in (self._rpipe, self._wpipe):
            os.close(fd)

    def elapsed(self) -> float:
        return 0.0 if self.t0 is None else time.monotonic() - self.t0

    def counters(self) -> Dict[str, Dict[str, dict]]:
        """{link name: {"up": {...}, "down": {...}}}, each row with a "link" field."""
        rel = self.elapsed()
        return {link.name: link.counters(rel, with_name=True) for link in self.links}

    def drops(self, name: str) -> List[dict]:
        return self.link(name).drops()

    def sends(self, name: str) -> List[dict]:
        return self.link(name).sends()

    def received(self, name: str) -> List[dict]:
        return self.link(name).received()

    def _counter_rows(self) -> List[dict]:
        return [row for per_link in self.counters().values() for row in per_link.values()]

    def dump(self) -> None:
        """Print the counters (one JSON line per link and direction) and flush the logs."""
        for row in self._counter_rows():
            self.out.write(json.dumps(row) + "\n")
        self.out.flush()
        for link in self.links:
            link.flush_logs()

    def run(self) -> None:
        mono = time.monotonic
        heappush, heappop = heapq.heappush, heapq.heappop
        heap: List[tuple] = []     # (due, seq, direction, data, index, arrived)
        seq = 0                    # admission order: breaks ties between equal due times
        n_sent = 0
        # socket -> (its link, True for the listen socket (side A))
        role = {}
        for link in self.links:
            role[link.sock_a] = (link, True)
            role[link.sock_b] = (link, False)
        rp = self._rpipe
        rlist = [rp, *role]
        t0 = self.t0 = mono()
        deadline = t0 + self.duration if self.duration else math.inf
        self.started.set()
        if self.on_start is not None:
            self.on_start()
        try:
            while not self._stop:
                now = mono()
                if now >= deadline:
                    break
                # 1. everything due, in due order across all links. Each datagram goes to
                # every forward address of its link before the next datagram is looked at.
                while heap and heap[0][0] <= now:
                    due, _, d, data, idx, arrived = heappop(heap)
                    late = now - due
                    if late > d.late_max:
                        d.late_max = late
                    link = d.link
                    ok = True
                    if d.up:
                        for addr in link.forward_addrs:
                            try:
                                link.sock_b.sendto(data, addr)
                            except OSError:
                                ok = False
                    else:
                        try:
                            link.sock_a.sendto(data, link.peer_a)
                            for addr in link.down_tee:
                                link.sock_a.sendto(data, addr)
                        except OSError:
                            ok = False
                    if ok:
                        d.c["forwarded"] += 1
                        d.c["bytes_forwarded"] += len(data)
                    else:
                        d.c["send_errors"] += 1
                    if d.sends is not None:
                        d.sends.append(dict(direction=d.name, index=idx, arrived=arrived - t0,
                                            due=due - t0, sent=now - t0, n=n_sent))
                    n_sent += 1
                    now = mono()
                if self._dump:
                    self._dump = False
                    self.dump()
                while self._rebind:
                    link = self.link(self._rebind.pop(0))
                    old = link.rebind()
                    del role[old]
                    role[link.sock_b] = (link, False)
                    rlist = [rp, *role]
                    old.close()
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
                    link, side_a = role[s]
                    primary = link.forward_addr[:2]
                    for _ in range(RECV_BATCH):
                        try:
                            data, addr = s.recvfrom(MAX_DATAGRAM)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:   # e.g. ICMP errors reported on the socket
                            continue
                        now = mono()
                        if side_a:
                            link.peer_a = addr
                            d = link.dirs["up"]
                            r = d.admit(data, now, now - t0)
                        else:
                            # replies only from the first forward address (a tee's others
                            # are receivers only)
                            if addr[:2] != primary:
                                link.foreign += 1
                                continue
                            d = link.dirs["down"]
                            r = d.admit(data, now, now - t0, link.peer_a is not None)
                        if r is not None:
                            seq += 1
                            heappush(heap, (r[0], seq, d, r[1], r[2], now))
        finally:
            self._stop = True


class LinkEmulator(LinkGroup):
    """One emulated link: a group of one, with the single link's attributes (listen_addr,
    source_addr, forward_addr(s), seed, dirs, ...) and its counters and drops without a link
    name. Sockets are bound in the constructor (listen port 0 -> see `listen_addr`)."""

    def __init__(self, listen="127.0.0.1:0", forward="127.0.0.1:14550", *,
                 seed: Optional[int] = None, duration=None, source=None,
                 log_drops: Optional[str] = None, record_drops: bool = False,
                 log_sends: Optional[str] = None, record_sends: bool = False,
                 out: Optional[IO[str]] = None, **link_opts):
        link = Link("", listen, forward, seed=seed, source=source, log_drops=log_drops,
                    record_drops=record_drops, log_sends=log_sends,
                    record_sends=record_sends, **link_opts)
        super().__init__([link], duration=duration, out=out)
        for attr in ("configs", "seed", "forward_addr", "forward_addrs", "listen_addr",
                     "source_addr", "dirs", "sock_a", "sock_b"):
            setattr(self, attr, getattr(link, attr))

    @property
    def peer_a(self) -> Optional[tuple]:
        return self.links[0].peer_a

    @property
    def foreign(self) -> int:
        return self.links[0].foreign

    def counters(self) -> Dict[str, dict]:
        return self.links[0].counters(self.elapsed())

    def drops(self) -> List[dict]:
        """Drop (and corruption) records so far; needs record_drops=True or log_drops."""
        return self.links[0].drops()

    def sends(self) -> List[dict]:
        return self.links[0].sends()

    def received(self) -> List[dict]:
        return self.links[0].received()

    def _counter_rows(self) -> List[dict]:
        return list(self.counters().values())


# --- CLI ---------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="linkemu",
        description="Relay UDP between --listen (side A) and --forward (side B), emulating one "
                    "lossy, delayed, rate-limited telemetry link in each direction; or, with "
                    "--group, several links in one loop.",
        epilog="Every link option X also exists as --up-X (A->B only) and --down-X (B->A "
               "only), which override --X for that direction. Durations take units (us, ms, s; "
               "bare numbers are seconds for --outage and --duration), probabilities take % or "
               "a fraction. Counters: one JSON line per direction on stdout at exit and on "
               "SIGUSR1. See the module docstring for the exact semantics.",
    )
    p.add_argument("--listen", metavar="HOST:PORT",
                   help="where side A sends to (port 0: pick one, printed on stderr)")
    p.add_argument("--forward", action="append", metavar="HOST:PORT",
                   help="side B's address; repeat it to tee the up direction to several "
                        "receivers (replies are taken from the first only)")
    p.add_argument("--group", metavar="SPEC.json",
                   help="run the links of this JSON list in one loop (see the module "
                        "docstring); instead of --listen/--forward and link options")
    p.add_argument("--source", metavar="HOST:PORT",
                   help="bind the socket that talks to B here (default: ephemeral port)")
    p.add_argument("--down-tee", action="append", metavar="HOST:PORT",
                   help="also send every down datagram here as it goes to A (repeatable): a "
                        "sniffer of what A received")
    p.add_argument("--seed", type=int, help="random seed (default: random, printed on stderr)")
    p.add_argument("--duration", metavar="T", help="exit by itself after T (e.g. 30s)")
    p.add_argument("--log-drops", metavar="FILE",
                   help="write one JSON line per dropped (or corrupted) datagram")
    p.add_argument("--log-sends", metavar="FILE",
                   help="write one JSON line per datagram sent: index, arrival, due and send "
                        "times")
    p.add_argument("--log-received", metavar="FILE",
                   help="write one JSON line per datagram received: index and bytes (hex)")
    for name, (_, metavar, help_) in PARAMS.items():
        flag = name.replace("_", "-")
        for prefix, h in (("", help_), ("up-", argparse.SUPPRESS), ("down-", argparse.SUPPRESS)):
            dest = (prefix.replace("-", "_")) + name
            if name == "reorder":
                p.add_argument(f"--{prefix}{flag}", dest=dest, action="store_const", const=True,
                               default=None, help=h)
            elif name in ("outage", "stall"):
                p.add_argument(f"--{prefix}{flag}", dest=dest, action="append", metavar=metavar,
                               help=h)
            else:
                p.add_argument(f"--{prefix}{flag}", dest=dest, metavar=metavar, help=h)
    return p


_LINK_KEYS = ("name", "listen", "forward", "seed", "source", "log_drops", "log_sends",
              "log_received", "down_tee")


def load_group_spec(path: str) -> List[dict]:
    """The --group file: a JSON list of links, each {"name", "listen", "forward" (one address
    or a list), "seed", optional "source", "log_drops", "log_sends", "log_received", and link
    options named as on the command line ("loss", "up-delay" or "up_delay", "outage": [...],
    "reorder": true)}."""
    with open(path) as f:
        spec = json.load(f)
    if not isinstance(spec, list) or not spec:
        raise ValueError(f"{path}: want a non-empty JSON list of links")
    links = []
    for i, item in enumerate(spec):
        if not isinstance(item, dict):
            raise ValueError(f"{path}: link {i} is not an object")
        link = {k.replace("-", "_"): v for k, v in item.items()}
        for key in ("name", "listen", "forward"):
            if key not in link:
                raise ValueError(f"{path}: link {i} has no {key!r}")
        links.append(link)
    return links


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = build_parser()
    a = parser.parse_args(argv)
    link_opts = {}
    for name in PARAMS:
        for prefix in ("", "up_", "down_"):
            v = getattr(a, prefix + name)
            if v is not None:
                link_opts[prefix + name] = v
    if a.group:
        single = [f for f, v in (("--listen", a.listen), ("--forward", a.forward),
                                 ("--source", a.source), ("--seed", a.seed),
                                 ("--down-tee", a.down_tee),
                                 ("--log-drops", a.log_drops), ("--log-sends", a.log_sends),
                                 ("--log-received", a.log_received))
                  if v is not None]
        if single or link_opts:
            parser.error(f"with --group, {', '.join(single) or 'link options'} go in the "
                         f"group's spec, per link")
    elif a.listen is None or a.forward is None:
        parser.error("the following arguments are required: --listen, --forward (or --group)")
    try:
        if a.group:
            emu = LinkGroup(load_group_spec(a.group), duration=a.duration)
        else:
            emu = LinkEmulator(a.listen, a.forward, seed=a.seed, duration=a.duration,
                               source=a.source, log_drops=a.log_drops, log_sends=a.log_sends,
                               log_received=a.log_received,
                               down_tee=a.down_tee, **link_opts)
    except (ValueError, TypeError) as e:
        parser.error(str(e))
    except OSError as e:
        print(f"linkemu: {e}", file=sys.stderr)
        return 1
    signal.signal(signal.SIGTERM, lambda *_: emu.request_stop())
    signal.signal(signal.SIGINT, lambda *_: emu.request_stop())
    signal.signal(signal.SIGUSR1, lambda *_: emu.request_dump())
    if a.group:
        for link in emu.links:
            print(f"linkemu: link {link.name}: {link.banner()}", file=sys.stderr)
        # Printed once the clock runs: whoever reads it knows the group's t0 is behind it.
        emu.on_start = lambda: print(f"linkemu: group of {len(emu.links)} links listening",
                                     file=sys.stderr, flush=True)
    else:
        print(f"linkemu: {emu.links[0].banner()}", file=sys.stderr, flush=True)
    emu.run()
    emu.dump()
    emu.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
