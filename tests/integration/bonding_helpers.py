"""Helpers for the bonding tests: configs with bonds and filters, the plugin directory of a
build, link emulators (tests/tools/linkemu.py) run as real processes, a paced sender that
records when each frame left, and a receiver thread that timestamps every frame it gets.

Everything is real: mavbond processes, linkemu processes, UDP sockets on 127.0.0.1."""
from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

from helpers import (HOST, REPO, Daemon, FrameMaker, free_port, split_stream,  # noqa: F401
                     terminate, udp_client, udp_server, _yaml_scalar)

TOOLS = REPO / "tests" / "tools"
LINKEMU = TOOLS / "linkemu.py"
sys.path.insert(0, str(TOOLS))
import synth  # noqa: E402
import tlog  # noqa: E402


# --- plugins ------------------------------------------------------------------------------

def plugin_dir_for(binary: str) -> str:
    """The directory to pass as --plugin-dir for a mavbond binary of a build tree:
    <build>/plugins, where the build puts every NAME.so (the installed layout)."""
    root = Path(binary).resolve().parent.parent / "plugins"  # <build>/src/mavbond -> <build>
    if not (root / "dedup.so").is_file():
        raise FileNotFoundError(f"no plugins in {root} (build them: ninja -C <build>)")
    return str(root)


# --- config -------------------------------------------------------------------------------

def _flow(d: dict) -> str:
    return "{" + ", ".join(f"{k}: {_yaml_scalar(v)}" for k, v in d.items()) + "}"


def bond_config(endpoints: List[dict], bonds: Sequence[dict] = (),
                filters: Sequence[dict] = (), **top) -> str:
    """YAML: top-level scalars, endpoints, bonds and filters as flow mappings."""
    lines = [f"{k}: {_yaml_scalar(v)}" for k, v in top.items()]
    lines.append("endpoints:")
    lines += [f"  - {_flow(e)}" for e in endpoints]
    if bonds:
        lines.append("bonds:")
        lines += [f"  - {_flow(b)}" for b in bonds]
    if filters:
        lines.append("filters:")
        lines += [f"  - {_flow(f)}" for f in filters]
    return "\n".join(lines) + "\n"


class Gateway(Daemon):
    """A mavbond with bonds and filters; its stats() knows the endpoint names."""

    def __init__(self, binary: str, workdir: Path, endpoints: List[dict],
                 bonds: Sequence[dict] = (), filters: Sequence[dict] = (),
                 name: str = "mavbond", plugin_dir: Optional[str] = None,
                 log_level: str = "debug", **top):
        args = ["--log-level", log_level]
        if plugin_dir:
            args += ["--plugin-dir", plugin_dir]
        super().__init__(binary, workdir, bond_config(endpoints, bonds, filters, **top),
                         name=name, extra_args=args)
        self.endpoint_names = [e["name"] for e in endpoints]


# --- link emulators -----------------------------------------------------------------------

class _Linkemu:
    """A linkemu process: started until its banner says it listens, ended with SIGTERM (its
    counters are its last JSON lines on stdout), or killed."""

    def __init__(self, workdir: Path, name: str, banner: bytes):
        self.name = name
        self.out_path = workdir / f"linkemu-{name}.out"
        self.err_path = workdir / f"linkemu-{name}.err"
        self._banner = banner
        self.args: List[str] = []
        self.proc: Optional[subprocess.Popen] = None
        self.t_start: Optional[float] = None

    def start(self, timeout: float = 10.0):
        """Starts the process; returns once it listens (its clock starts then)."""
        self._out = open(self.out_path, "wb")
        self._err = open(self.err_path, "wb")
        self.proc = subprocess.Popen(self.args, stdin=subprocess.DEVNULL, stdout=self._out,
                                     stderr=self._err)
        deadline = time.monotonic() + timeout
        while self._banner not in self.err_path.read_bytes():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"linkemu {self.name} did not start: "
                                     f"{self.err_path.read_text(errors='replace')}")
            time.sleep(0.01)
        self.t_start = time.monotonic()
        return self

    def _terminate(self) -> List[dict]:
        """SIGTERM (once), and the JSON lines it printed."""
        terminate(self.proc)
        if self.proc is not None and not self._out.closed:
            self._out.close()
            self._err.close()
        return [json.loads(l) for l in self.out_path.read_text().splitlines() if l.startswith("{")]

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def _records(path: Optional[Path], direction: str) -> List[dict]:
    """The JSON lines of a drop or send log, of one direction."""
    if path is None or not path.exists():
        return []
    return [r for r in (json.loads(l) for l in path.read_text().splitlines() if l)
            if r["direction"] == direction]


class Emu(_Linkemu):
    """One linkemu process between `listen` (side A sends here) and `forward` (side B).
    Drops are logged to a file; counters come from its stdout on stop()."""

    def __init__(self, workdir: Path, name: str, listen_port: int, forward_port: int,
                 seed: int = 1, **opts):
        super().__init__(workdir, name, b"listening on")
        self.listen_port = listen_port
        self.forward_port = forward_port
        self.drops_path = workdir / f"linkemu-{name}-drops.jsonl"
        args = [sys.executable, str(LINKEMU), "--listen", f"{HOST}:{listen_port}",
                "--forward", f"{HOST}:{forward_port}", "--seed", str(seed),
                "--log-drops", str(self.drops_path)]
        for k, v in opts.items():
            flag = "--" + k.replace("_", "-")
            for x in (v if isinstance(v, (list, tuple)) else [v]):
                if x is True:
                    args.append(flag)
                else:
                    args += [flag, str(x)]
        self.args = args
        self._counters: Optional[Dict[str, dict]] = None

    def stop(self) -> Dict[str, dict]:
        rows = self._terminate()
        if self._counters is None:
            self._counters = {r["direction"]: r for r in rows[-2:]}
        return self._counters

    def counters(self) -> Dict[str, dict]:
        return self.stop() if self._counters is None else self._counters

    def drops(self, direction: str = "up") -> List[dict]:
        return _records(self.drops_path, direction)

    def dropped(self, direction: str = "up") -> set:
        """Indices of the datagrams this link did not forward (corrupted ones are forwarded)."""
        return {r["index"] for r in self.drops(direction) if r["reason"] != "corrupted"}

    def corrupted(self, direction: str = "up") -> set:
        return {r["index"] for r in self.drops(direction) if r["reason"] == "corrupted"}

    def loss_rate(self, direction: str = "up") -> float:
        c = self.counters()[direction]
        lost = c["received"] - c["forwarded"]
        return lost / c["received"] if c["received"] else 0.0


# --- sending and receiving ----------------------------------------------------------------

def udp_sock(port: int = 0, rcvbuf: int = 8 << 20) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    s.bind((HOST, port))
    return s


class Receiver:
    """A thread that receives every datagram on a socket and keeps (monotonic time, frame).
    With `hello_port`, it sends a GCS HEARTBEAT there every second, as a GCS does (a UDP
    server forgets a peer silent for peer_timeout)."""

    def __init__(self, sock: socket.socket, hello_port: Optional[int] = None):
        self.sock = sock
        self.frames: List[Tuple[float, bytes]] = []
        self._stop = False
        self._hello_port = hello_port
        self._next_hello = 0.0
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        if hello_port:
            time.sleep(0.2)  # the gateway has learned this peer before anything is sent

    def _run(self):
        self.sock.settimeout(0.1)
        while not self._stop:
            if self._hello_port and time.monotonic() >= self._next_hello:
                gcs_hello(self.sock, self._hello_port)
                self._next_hello = time.monotonic() + 1.0
            try:
                dg = self.sock.recv(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            now = time.monotonic()
            for f in split_stream(dg):
                self.frames.append((now, f))

    def wait_quiet(self, quiet: float = 0.5, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        n = -1
        while time.monotonic() < deadline:
            if len(self.frames) == n:
                return
            n = len(self.frames)
            time.sleep(quiet)

    def stop(self) -> List[bytes]:
        """Stops the thread, then takes what is still in the socket: every datagram that
        reached it before the call is kept (after the sender stopped, that is all it sent)."""
        self._stop = True
        self._t.join(2)
        self.sock.setblocking(False)
        while True:
            try:
                dg = self.sock.recv(65536)
            except OSError:  # nothing left (or closed)
                break
            now = time.monotonic()
            self.frames.extend((now, f) for f in split_stream(dg))
        return [f for _, f in self.frames]


def unique_stream(seconds, seed):
    """The ArduPilot-like stream with each frame whose bytes recur (a constant message with the
    same sequence byte 256 frames later) changed in its last payload byte (CRC recomputed):
    every frame is known by its bytes alone, and the sequence numbers stay unbroken."""
    seen, out = set(), []
    for t, f in synth.ardupilot_stream(seconds, seed=seed):
        b = bytearray(f)
        assert b[0] == 0xFD
        n = b[1]
        while bytes(b) in seen:
            b[9 + n] = (b[9 + n] % 255) + 1  # never 0: a v2 payload's last byte is not a zero
            crc = tlog.compute_crc(bytes(b), tlog.crc_extras()[tlog.msgid(bytes(b))])
            b[10 + n], b[11 + n] = crc & 0xFF, crc >> 8
        seen.add(bytes(b))
        out.append((t / 1e6, bytes(b)))
    return out


def paced_send(schedule: Sequence[Tuple[float, bytes]], targets: Sequence[Tuple[socket.socket, Tuple[str, int]]],
               burst_ms: float = 2.0) -> List[float]:
    """Sends frame i at schedule[i][0] seconds after the start on every target; returns the
    monotonic time each frame left. Frames due within burst_ms go together (Python's sleep
    cannot do 1 ms reliably)."""
    sent: List[float] = []
    start = time.monotonic()
    burst = burst_ms / 1000.0
    i = 0
    n = len(schedule)
    while i < n:
        now = time.monotonic() - start
        due = schedule[i][0]
        if due > now + burst:
            time.sleep(min(due - now - burst / 2, 0.05))
            continue
        while i < n and schedule[i][0] <= now + burst:
            f = schedule[i][1]
            for s, addr in targets:
                s.sendto(f, addr)
            sent.append(time.monotonic())
            i += 1
    return sent


def gcs_hello(sock: socket.socket, port: int, sysid: int = 255, compid: int = 190) -> bytes:
    """A GCS heartbeat so the gateway's `gcs` UDP server learns this peer."""
    hb = FrameMaker(sysid, compid).heartbeat(type_=6)
    sock.sendto(hb, (HOST, port))
    return hb


def wait_for(predicate, what: str, timeout: float = 60.0):
    """predicate()'s first true value, polled every 50 ms; fails after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def multiset_diff(want: Iterable[bytes], got: Iterable[bytes]) -> Tuple[Counter, Counter]:
    """(missing, extra): frames expected but not delivered, delivered beyond expected."""
    w, g = Counter(want), Counter(got)
    return w - g, g - w


def content_key(frame: bytes) -> tuple:
    """(sysid, compid, msgid, payload): a frame without its sequence byte."""
    return (tlog.sysid(frame), tlog.compid(frame), tlog.msgid(frame), tlog.payload(frame))


def with_seq(frame: bytes, seq: int) -> bytes:
    """The same MAVLink 2 frame with another sequence byte (CRC recomputed)."""
    b = bytearray(frame)
    assert b[0] == 0xFD
    b[4] = seq & 0xFF
    n = b[1]
    crc = tlog.compute_crc(bytes(b), tlog.crc_extras()[tlog.msgid(frame)])
    b[10 + n] = crc & 0xFF
    b[11 + n] = crc >> 8
    return bytes(b)


def paced_events(events: Sequence[Tuple[float, int, bytes]],
                 targets: Sequence[Tuple[socket.socket, Tuple[str, int]]],
                 burst_ms: float = 2.0) -> List[float]:
    """Sends each (t, target index, frame) at t seconds after the start (events sorted by t);
    returns the monotonic time each event was sent."""
    sent: List[float] = []
    start = time.monotonic()
    burst = burst_ms / 1000.0
    i, n = 0, len(events)
    while i < n:
        now = time.monotonic() - start
        due = events[i][0]
        if due > now + burst:
            time.sleep(min(due - now - burst / 2, 0.05))
            continue
        while i < n and events[i][0] <= now + burst:
            _, k, f = events[i]
            s, addr = targets[k]
            s.sendto(f, addr)
            sent.append(time.monotonic())
            i += 1
    return sent


def timestamp_of(frame: bytes) -> Optional[Tuple[str, int]]:
    """(field, value) of a frame's time_boot_ms / time_usec, or None when it has none."""
    from helpers import mav2
    dec = mav2.MAVLink(None)
    try:
        msg = dec.decode(bytearray(frame))
    except Exception:
        return None
    for field in ("time_boot_ms", "time_usec"):
        if field in msg.get_fieldnames():
            return field, getattr(msg, field)
    return None


class Ticker:
    """A thread that sends `frame_fn(k)` every `period` seconds from `sock` to `addr`."""

    def __init__(self, sock: socket.socket, addr, frame_fn, period: float = 1.0):
        self.sock, self.addr, self.frame_fn, self.period = sock, addr, frame_fn, period
        self.sent = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        while not self._stop.is_set():
            self.sock.sendto(self.frame_fn(self.sent), self.addr)
            self.sent += 1
            self._stop.wait(self.period)

    def stop(self):
        self._stop.set()
        self._t.join(2)


# --- what a link carried ---------------------------------------------------------------------

def msgid(frame: bytes) -> int:
    if frame[0] == 0xFD:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    return frame[5]


def frames_of(datagram: bytes):
    """The MAVLink frames of one datagram (v1 or v2, unsigned)."""
    i = 0
    while i < len(datagram):
        if datagram[i] == 0xFD:
            n = 12 + datagram[i + 1] + (13 if datagram[i + 2] & 1 else 0)
        elif datagram[i] == 0xFE:
            n = 8 + datagram[i + 1]
        else:
            return
        yield datagram[i:i + n]
        i += n


class Sniffer(threading.Thread):
    """Everything a link's emulator forwarded (its tee, or its down tee), in order; started."""

    def __init__(self, sock: socket.socket):
        super().__init__(daemon=True)
        self.sock, self.frames, self.stop_flag = sock, [], threading.Event()
        self.sock.settimeout(0.05)

    def run(self):
        while not self.stop_flag.is_set():
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            self.frames += list(frames_of(data))

    def stop(self):
        self.stop_flag.set()
        self.join()
        return self.frames



def sniffer(lab, port: int) -> "Sniffer":
    """A started Sniffer on `port` (a link emulator's tee address)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind((HOST, port))
    lab.socks.append(sock)
    s = Sniffer(sock)
    s.start()
    return s


def carried(stream: Sequence[bytes], sniffed: Sequence[bytes]) -> List[int]:
    """The indices of `stream` a FIFO link carried, from what its sniffer saw, in order: frames
    of anyone else in between (the gateways' own: count markers, standby reports) are passed
    over. A stream frame the sniffer does not have where it would be was dropped."""
    ours = set(stream)
    out, j = [], 0
    for k, f in enumerate(stream):
        while j < len(sniffed) and sniffed[j] != f and sniffed[j] not in ours:
            j += 1
        if j < len(sniffed) and sniffed[j] == f:
            out.append(k)
            j += 1
    return out


# --- a group of links in one emulator process -----------------------------------------------

class EmuGroup(_Linkemu):
    """Several links in ONE linkemu process (`linkemu.py --group`): one loop and one heap of
    due sends, so when two links' datagrams are due, every forward address gets the earlier
    one first. Each link: a dict with name, listen_port, forward_ports (a port or a list: a
    tee; replies come from the first only), seed and linkemu options as for Emu (loss="1%",
    outage=["5s+2s"], up_delay="20ms", reorder=True). Outages count from the group's start.
    Drops are logged per link; with log_sends, every send too (index, arrived, due, sent, n)."""

    def __init__(self, workdir: Path, name: str, links: Sequence[dict], duration=None,
                 log_sends: bool = False):
        super().__init__(workdir, name, b"links listening")
        self.spec_path = workdir / f"linkemu-{name}-group.json"
        self.drops_paths: Dict[str, Path] = {}
        self.sends_paths: Dict[str, Path] = {}
        spec = []
        for link in links:
            link = dict(link)
            lname = link.pop("name")
            fwd = link.pop("forward_ports")
            fwd = fwd if isinstance(fwd, (list, tuple)) else [fwd]
            item = {"name": lname, "listen": f"{HOST}:{link.pop('listen_port')}",
                    "forward": [f"{HOST}:{p}" for p in fwd], "seed": link.pop("seed", 1)}
            self.drops_paths[lname] = workdir / f"linkemu-{name}-{lname}-drops.jsonl"
            item["log_drops"] = str(self.drops_paths[lname])
            if log_sends:
                self.sends_paths[lname] = workdir / f"linkemu-{name}-{lname}-sends.jsonl"
                item["log_sends"] = str(self.sends_paths[lname])
            item.update(link)
            spec.append(item)
        self.link_names = [s["name"] for s in spec]
        self.spec_path.write_text(json.dumps(spec, indent=1))
        self.args = [sys.executable, str(LINKEMU), "--group", str(self.spec_path)]
        if duration is not None:
            self.args += ["--duration", str(duration)]
        self._counters: Optional[Dict[str, Dict[str, dict]]] = None

    def stop(self) -> Dict[str, Dict[str, dict]]:
        """SIGTERM; {link: {"up": counters, "down": counters}} from its last lines."""
        rows = self._terminate()
        if self._counters is None:
            self._counters = {}
            for r in rows[-2 * len(self.link_names):]:
                self._counters.setdefault(r["link"], {})[r["direction"]] = r
        return self._counters

    def counters_now(self, timeout: float = 10.0) -> Dict[str, Dict[str, dict]]:
        """{link: {"up", "down"}} as of now, while it runs (SIGUSR1: it prints them and
        flushes its logs). Waits for every line of this dump."""
        def rows():
            text = self.out_path.read_text()
            return [json.loads(l) for l in text[:text.rfind("\n") + 1].splitlines()
                    if l.startswith("{")]
        before = len(rows())
        want = before + 2 * len(self.link_names)
        self.proc.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        while len(got := rows()) < want:
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"linkemu group {self.name} printed no counters")
            time.sleep(0.005)
        out: Dict[str, Dict[str, dict]] = {}
        for r in got[before:want]:
            out.setdefault(r["link"], {})[r["direction"]] = r
        return out

    def counters(self, name: str) -> Dict[str, dict]:
        """{"up": .., "down": ..} of one link (stops the process the first time)."""
        return (self.stop() if self._counters is None else self._counters)[name]

    def drops(self, name: str, direction: str = "up") -> List[dict]:
        return _records(self.drops_paths[name], direction)

    def dropped(self, name: str, direction: str = "up") -> set:
        """Indices of the datagrams this link did not forward (corrupted ones are forwarded)."""
        return {r["index"] for r in self.drops(name, direction) if r["reason"] != "corrupted"}

    def corrupted(self, name: str, direction: str = "up") -> set:
        return {r["index"] for r in self.drops(name, direction) if r["reason"] == "corrupted"}

    def sends(self, name: str, direction: str = "up") -> List[dict]:
        """What the link sent (log_sends=True), in send order: written at stop or SIGUSR1."""
        return _records(self.sends_paths.get(name), direction)

    def loss_rate(self, name: str, direction: str = "up") -> float:
        c = self.counters(name)[direction]
        lost = c["received"] - c["forwarded"]
        return lost / c["received"] if c["received"] else 0.0


# --- freezing a process ------------------------------------------------------------------------

def _task_states(pid: int) -> List[str]:
    """The state letter of every thread of a process (R, S, D, T, t, Z, ...); [] when gone."""
    states = []
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except FileNotFoundError:
        return []
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as f:
                stat = f.read()
        except (FileNotFoundError, ProcessLookupError):
            continue
        states.append(stat.rsplit(")", 1)[1].split()[0])  # the name may hold spaces and ')'
    return states


def process_state(pid: int) -> Optional[str]:
    """The state letter of a process (its main thread) from /proc/PID/stat, None when gone."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return None


class Stall:
    """Freezes a process with SIGSTOP and thaws it with SIGCONT, from a thread, on a schedule
    fixed at construction (`plan`, reproducible from the seed): every `every` seconds (start to
    start, drawn uniformly from the range) for `length` seconds, plus `long_stalls`
    [(offset, length), ...] from the start. A regular stall that would begin inside a long one
    is left out, and so is any stall that would end after `duration`: the thread never runs
    past it. stop() ends it early; the process is always left running (SIGCONT in a finally).

    Records, in monotonic time: `stalls` [(start, end)], start when every thread of the process
    was seen stopped (/proc), end just before the SIGCONT: it was frozen throughout; `windows`
    [(stop sent, SIGCONT returned)]: outside these it was not frozen by us. `count`."""

    def __init__(self, pid: int, *, duration: float, every: Tuple[float, float] = (2.0, 2.5),
                 length: float = 0.150, long_stalls: Sequence[Tuple[float, float]] = (),
                 seed: int = 1):
        self.pid = pid
        self.duration = duration
        rnd = random.Random(f"stall:{seed}")
        longs = sorted((float(o), float(l)) for o, l in long_stalls)
        plan = list(longs)
        t = rnd.uniform(*every)
        while t + length <= duration:
            if not any(o <= t < o + l for o, l in longs):
                plan.append((t, length))
            t += rnd.uniform(*every)
        plan.sort()
        self.plan = [(o, l) for o, l in plan if o + l <= duration]
        self.stalls: List[Tuple[float, float]] = []
        self.windows: List[Tuple[float, float]] = []
        self.t_start: Optional[float] = None
        self.error: Optional[str] = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"stall-{pid}", daemon=True)

    @property
    def count(self) -> int:
        return len(self.stalls)

    def start(self) -> "Stall":
        self.t_start = time.monotonic()
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> "Stall":
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        return self

    def running(self) -> bool:
        return self._thread.is_alive()

    def _wait_frozen(self, limit: float = 2.0) -> bool:
        # SIGSTOP takes effect when the process next runs: wait until every thread shows it
        # (even when stop() came meanwhile: a stall once begun is recorded).
        deadline = time.monotonic() + limit
        while True:
            states = _task_states(self.pid)
            if not states or "Z" in states or "X" in states:
                return False
            if all(s in "Tt" for s in states):
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.0005)

    def _run(self) -> None:
        t0 = self.t_start
        end_of_run = t0 + self.duration
        for offset, length in self.plan:
            if self._stop.wait(max(0.0, t0 + offset - time.monotonic())):
                return
            now = time.monotonic()
            if now + length > end_of_run:     # late: a stall may not run past the duration
                return
            try:
                sent = time.monotonic()
                os.kill(self.pid, signal.SIGSTOP)
                try:
                    if not self._wait_frozen():
                        self.error = f"process {self.pid} did not stop: {_task_states(self.pid)}"
                        return
                    frozen = time.monotonic()
                    self._stop.wait(max(0.0, min(frozen + length, end_of_run) - frozen))
                    thaw = time.monotonic()
                finally:
                    os.kill(self.pid, signal.SIGCONT)
                self.windows.append((sent, time.monotonic()))
                self.stalls.append((frozen, thaw))
            except OSError as e:      # gone (ProcessLookupError) or not ours to signal
                self.error = f"process {self.pid}: {e}"
                return
            if self._stop.is_set():
                return

    def summary(self) -> str:
        lens = [round((e - s) * 1e3) for s, e in self.stalls]
        at = [round(s - self.t_start, 2) for s, _ in self.stalls] if self.t_start else []
        return f"{self.count} stalls of pid {self.pid} at {at} s, lasting {lens} ms"
