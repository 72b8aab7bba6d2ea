"""Runs one scenario: the same stream through one link alone, linkswitch and dedup, at once.

For each mode (all on 127.0.0.1, every box a real process):

    vehicle --udp--> [mavbond air] ==link emulator per link (linkemu.py)==> [mavbond ground] --udp--> GCS
                     bond, tx: broadcast                                     bond + the mode's filter

The three modes run side by side on the same paced stream (one sender, each frame sent to the
three air gateways back to back), each with its own gateways and emulators; an emulator of link
X gets the same seed in every mode, so it loses the same frames. What is recorded, per mode:
when each frame left the vehicle, which datagrams each emulator dropped (its --log-drops file:
index and reason), when the GCS got what, and when the ground gateway logged a link switch
(its log is read every few ms while the stream runs). Frames are matched to what was sent by
their bytes: a recording repeats byte-identical frames, but never within 2 s, and no copy is
that late here, so a delivery is the latest frame with those bytes sent before it arrived."""
from __future__ import annotations

import bisect
import os
import re
import select
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
sys.path.insert(0, str(REPO / "tests" / "tools"))

from bonding_helpers import Emu, Gateway, gcs_hello, udp_sock  # noqa: E402
from helpers import HOST, free_port, split_stream, udp_client, udp_server  # noqa: E402
import tlog  # noqa: E402
from synth import ardupilot_stream  # noqa: E402

import scenarios as S  # noqa: E402

DEFAULT_TLOG = "ardupilot-sub-real-2023-qgc-small.tlog"
TLOG_OFFSET = 5.0     # s; the recording opens with a parameter download burst
LEAD = 1.5            # s from the emulators' start to the first frame
QUIET = 1.5           # s to wait after the last frame (covers 300 ms skew and a full radio queue)
SWITCH_RE = re.compile(r"active link (\S+) -> (\S+): (.*)")


# --- the stream ---------------------------------------------------------------------------

def tlog_dir() -> Path:
    return Path(os.environ.get("MAVBOND_TLOG_DIR", REPO.parent / "shared" / "data" / "tlogs"))


def load_stream(source: str, seconds: float, offset: float = TLOG_OFFSET
                ) -> Tuple[str, List[Tuple[float, bytes]]]:
    """(description, [(t seconds from the start, frame)]) for `seconds` of vehicle frames.
    `source`: "auto" (the ArduSub recording if ../shared has it, else synthetic), "synth", or
    a recording's path."""
    path: Optional[Path] = None
    if source == "auto":
        candidate = tlog_dir() / DEFAULT_TLOG
        path = candidate if candidate.exists() else None
    elif source != "synth":
        path = Path(source)
    if path is None:
        return ("synthetic ArduPilot-like stream, 124 frames/s",
                [(t / 1e6, f) for t, f in ardupilot_stream(seconds, seed=1)])
    frames = [(t, f) for t, f in tlog.iter_frames(str(path))
              if tlog.sysid(f) < 250 and tlog.crc_ok(f) is not False]
    if not frames:
        raise SystemExit(f"no vehicle frames in {path}")
    # The autopilot's own stream (its busiest source). Other components of a recording may
    # share their sequence counter with channels that were not recorded (the ArduSub dive's
    # compid 194 skips 4 numbers in 5): anything that measures loss from sequence gaps, as
    # linkswitch does, would read that as 4 % loss on every link.
    main = Counter((tlog.sysid(f), tlog.compid(f)) for _, f in frames).most_common(1)[0][0]
    frames = [(t, f) for t, f in frames if (tlog.sysid(f), tlog.compid(f)) == main]
    if frames[0][0] is None:  # a raw stream without timestamps: pace at 124 frames/s
        frames = [(int(i * 1e6 / 124), f) for i, (_, f) in enumerate(frames)]
        offset = 0.0
    t0 = frames[0][0] + offset * 1e6
    out = [((t - t0) / 1e6, f) for t, f in frames if t >= t0]
    out = [(t, f) for t, f in out if t < seconds]
    if out and out[-1][0] < seconds * 0.9:
        print(f"note: {path.name} holds only {out[-1][0]:.0f} s after the offset", file=sys.stderr)
    rate = len(out) / max(seconds, 1e-9)
    return (f"{path.name} (autopilot {main[0]}/{main[1]}) from {offset:g} s, "
            f"{rate:.0f} frames/s", out)


# --- processes ----------------------------------------------------------------------------

class ParallelEmu(Emu):
    """An Emu run through emu_gate.py: launched without waiting, and its clock started by
    release(), so all of a run's emulators count their outages from the same moment."""

    def launch(self) -> None:
        self.args[1] = str(HERE / "emu_gate.py")
        self._out = open(self.out_path, "wb")
        self._err = open(self.err_path, "wb")
        self.proc = subprocess.Popen(self.args, stdin=subprocess.PIPE, stdout=self._out,
                                     stderr=self._err)

    def wait_started(self, deadline: float) -> None:
        while b"listening on" not in self.err_path.read_bytes():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"linkemu {self.name} did not start: "
                                   f"{self.err_path.read_text(errors='replace')}")
            time.sleep(0.005)

    def release(self) -> None:
        self.proc.stdin.write(b"go\n")
        self.proc.stdin.close()
        self.t_start = time.monotonic()

    def stop(self):
        if self.proc is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        return super().stop()


class ModeRig:
    """Gateways and emulators of one mode."""

    def __init__(self, mode: str, sc: S.Scenario, workdir: Path, mavbond: str,
                 plugin_dir: str):
        self.mode = mode
        self.links = S.links_for(mode, sc)
        self.dir = workdir / mode
        self.dir.mkdir(parents=True, exist_ok=True)
        self.p_auto, self.p_gcs = free_port(), free_port()
        self.listen = {l.name: free_port() for l in self.links}
        self.ground_port = {l.name: free_port() for l in self.links}
        eps = [udp_server(l.name, self.ground_port[l.name], bond="vehicle") for l in self.links]
        eps.append(udp_server("gcs", self.p_gcs))
        self.ground = Gateway(mavbond, self.dir, eps, bonds=[{"name": "vehicle", "tx": "broadcast"}],
                              filters=S.filters_for(mode, sc), name="ground",
                              plugin_dir=plugin_dir, log_level="info")
        air_eps = [udp_server("autopilot", self.p_auto)]
        air_eps += [udp_client(l.name, self.listen[l.name], bond="ground") for l in self.links]
        air_filters = [{"plugin": "dedup", "bonds": ["ground"]}] if len(self.links) > 1 else []
        self.air = Gateway(mavbond, self.dir, air_eps, bonds=[{"name": "ground", "tx": "broadcast"}],
                           filters=air_filters, name="air", plugin_dir=plugin_dir,
                           log_level="info")
        self.emus: Dict[str, ParallelEmu] = {}
        self.gcs = udp_sock()
        self.gcs.setblocking(False)
        self.vehicle = udp_sock()
        self.received: List[Tuple[float, bytes]] = []
        self.switches: List[Tuple[float, str, str, str]] = []
        self._log_pos = 0

    def make_emus(self, sc: S.Scenario, lead: float) -> None:
        for l in self.links:
            opts = dict(l.opts)
            if l.name in sc.outages:
                start, length = sc.outages[l.name]
                opts["outage"] = f"{start + lead:.3f}s+{length:.3f}s"
            self.emus[l.name] = ParallelEmu(self.dir, l.name, self.listen[l.name],
                                            self.ground_port[l.name], seed=l.seed, **opts)

    def poll_log(self, now: float) -> None:
        """Link switches the ground gateway logged since the last call, stamped now."""
        try:
            with open(self.ground.log_path, "rb") as f:
                f.seek(self._log_pos)
                data = f.read()
        except FileNotFoundError:
            return
        cut = data.rfind(b"\n") + 1
        self._log_pos += cut
        for line in data[:cut].decode(errors="replace").splitlines():
            m = SWITCH_RE.search(line)
            if m:
                self.switches.append((now, m.group(1), m.group(2), m.group(3)))

    def stop(self) -> None:
        for e in self.emus.values():
            try:
                e.stop()
            except Exception:  # noqa: BLE001 - a half-started rig is torn down anyway
                e.kill()
        for g in (self.air, self.ground):
            try:
                g.stop()
            except AssertionError:  # did not exit in time: it was killed
                pass
        for s in (self.gcs, self.vehicle):
            s.close()


class Collector(threading.Thread):
    """Receives at every mode's GCS socket, says hello once a second (a UDP server forgets a
    silent peer), and reads the ground gateways' logs for link switches."""

    def __init__(self, rigs: Sequence[ModeRig]):
        super().__init__(daemon=True)
        self.rigs = list(rigs)
        self.stop_flag = False

    def run(self) -> None:
        socks = {r.gcs: r for r in self.rigs}
        next_hello = 0.0
        next_log = 0.0
        while not self.stop_flag:
            now = time.monotonic()
            if now >= next_hello:
                for r in self.rigs:
                    gcs_hello(r.gcs, r.p_gcs)
                next_hello = now + 1.0
            if now >= next_log:
                for r in self.rigs:
                    if r.mode == "linkswitch":
                        r.poll_log(now)
                next_log = now + 0.005
            ready, _, _ = select.select(list(socks), [], [], 0.005)
            for s in ready:
                rig = socks[s]
                while True:
                    try:
                        dg = s.recv(65536)
                    except (BlockingIOError, InterruptedError):
                        break
                    t = time.monotonic()
                    for f in split_stream(dg):
                        if tlog.sysid(f) < 250:
                            rig.received.append((t, f))


def paced_send(frames: Sequence[Tuple[float, bytes]], rigs: Sequence[ModeRig],
               start: float) -> List[float]:
    """Sends frame i at start + frames[i][0] to every rig's air gateway; returns when each
    frame left (taken before the first sendto, so every latency is >= 0)."""
    sent: List[float] = []
    targets = [(r.vehicle, (HOST, r.p_auto)) for r in rigs]
    burst = 0.001
    i, n = 0, len(frames)
    while i < n:
        now = time.monotonic()
        due = start + frames[i][0]
        if due > now + burst:
            time.sleep(min(due - now - burst / 2, 0.02))
            continue
        while i < n and start + frames[i][0] <= now + burst:
            t = time.monotonic()
            f = frames[i][1]
            for s, addr in targets:
                s.sendto(f, addr)
            sent.append(t)
            i += 1
    return sent


def match(frames: Sequence[bytes], sent: Sequence[float],
          received: Sequence[Tuple[float, bytes]]) -> Tuple[List[Tuple[int, float]], int]:
    """[(frame index, receive time)] in arrival order, and the count of frames that match
    nothing sent. A delivery is the latest frame with its bytes sent before it arrived."""
    where: Dict[bytes, Tuple[List[float], List[int]]] = {}
    for i, f in enumerate(frames):
        ts, ix = where.setdefault(f, ([], []))
        ts.append(sent[i])
        ix.append(i)
    out, foreign = [], 0
    for t, f in received:
        w = where.get(f)
        k = bisect.bisect_right(w[0], t) - 1 if w else -1
        if k < 0:
            foreign += 1
            continue
        out.append((w[1][k], t))
    return out, foreign


def run(sc: S.Scenario, mavbond: str, plugin_dir: str, stream_source: str, workdir: Path,
        modes: Sequence[str] = S.MODES, log=print) -> dict:
    """Runs `sc` in every mode at once and returns the raw record (JSON-able)."""
    desc, stream = load_stream(stream_source, sc.seconds)
    frames = [f for _, f in stream]
    workdir.mkdir(parents=True, exist_ok=True)
    rigs = [ModeRig(m, sc, workdir, mavbond, plugin_dir) for m in modes]
    collector = None
    try:
        for r in rigs:
            r.ground.start()
        for r in rigs:
            r.make_emus(sc, LEAD)
        emus = [e for r in rigs for e in r.emus.values()]
        for e in emus:
            e.launch()
        deadline = time.monotonic() + 10
        for e in emus:
            e.wait_started(deadline)
        for r in rigs:
            r.air.start()
        collector = Collector(rigs)
        collector.start()
        for e in emus:
            e.release()
        starts = [e.t_start for e in emus]
        # The stream starts LEAD after the emulators did (their outages count from there).
        t_stream = min(starts) + LEAD
        time.sleep(max(0.0, t_stream - time.monotonic()))
        log(f"[{sc.name}] streaming {len(frames)} frames ({desc}) for {sc.seconds:g} s "
            f"in {len(rigs)} modes")
        sent = paced_send(stream, rigs, t_stream)
        time.sleep(QUIET)
        for r in rigs:
            if r.mode == "linkswitch":
                r.poll_log(time.monotonic())
        collector.stop_flag = True
        collector.join(2)
        out = {"scenario": sc.name, "stream": desc, "n": len(frames), "t_stream": t_stream,
               "sent": [t - t_stream for t in sent], "frame_len": [len(f) for f in frames],
               "has_time": [ts_field(f) for f in frames],
               "source": [tlog.sysid(f) * 256 + tlog.compid(f) for f in frames],
               "emu_start_spread_ms": (max(starts) - min(starts)) * 1e3, "modes": {}}
        for r in rigs:
            counters = {name: e.stop() for name, e in r.emus.items()}
            deliveries, foreign = match(frames, sent, r.received)
            drops = {name: [(d["index"], d["reason"]) for d in e.drops("up")
                            if d["reason"] != "corrupted"] for name, e in r.emus.items()}
            out["modes"][r.mode] = {
                "links": [l.name for l in r.links],
                "deliveries": [(i, t - t_stream) for i, t in deliveries],
                "foreign": foreign,
                "drops": drops,
                "received_by_link": {n: c["up"]["received"] for n, c in counters.items()},
                "late_max_ms": {n: c["up"]["late_max_ms"] for n, c in counters.items()},
                "switches": [(t - t_stream, a, b, why) for t, a, b, why in r.switches],
            }
        return out
    finally:
        if collector is not None:
            collector.stop_flag = True
        for r in rigs:
            r.stop()


_decoder = None


def ts_field(frame: bytes) -> bool:
    """Whether a frame carries time_boot_ms / time_usec (what dedup's drop_stale looks at)."""
    global _decoder
    if _decoder is None:
        from pymavlink.dialects.v20 import all as mav2  # noqa: PLC0415
        _decoder = mav2.MAVLink(None)
        _decoder.robust_parsing = True
    try:
        msg = _decoder.decode(bytearray(frame))
    except Exception:  # noqa: BLE001 - an id pymavlink does not know has no known timestamp
        return False
    names = msg.get_fieldnames() if msg is not None else []
    return "time_boot_ms" in names or "time_usec" in names
