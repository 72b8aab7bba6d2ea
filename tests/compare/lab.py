"""Runs one scenario: the same stream through several ground gateways at once, one per mode
(one link alone, linkswitch, dedup; or, for window_cost.py and stale_after.py, one per dedup
configuration), each frozen on a seeded schedule when asked.

    vehicle --> [mavbond air] ==> linkemu --group ==> [mavbond ground, per mode] --> GCS
                bond, tx: broadcast  one link per path,   bond + the mode's filters,
                                     each teed to every   status socket
                                     mode that uses it

One air gateway sends each frame once on every link, and one emulator process carries all the
links (tests/tools/linkemu.py --group), each link teed to the ground gateway of every mode that
uses it (one link alone gets the first link only). So every mode gets the same datagrams, in
the same order, lost and delayed alike: the emulator decides once, whatever the timing.

With `stall`, every ground gateway is frozen (SIGSTOP/SIGCONT, bonding_helpers.Stall) 150 ms
every 2 to 2.5 s and once for a whole second, on one seeded schedule per scenario, as a busy
companion computer freezes it.

What is recorded, per mode: when each frame left the vehicle, which datagrams each link dropped
(the emulator's drop log: index and reason), when the GCS got what, when the ground gateway
logged a link switch, when it was frozen (the Stall's record), and the gateway's own account at
the end: the status socket (dedup's per-link passed, duplicates and stale samples; each
endpoint's receive overflows), the exit line (frames held back for arrival order), and the
kernel's drop count of the GCS socket."""
from __future__ import annotations

import bisect
import os
import re
import select
import sys
import threading
import time
from collections import Counter, deque
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
sys.path.insert(0, str(REPO / "tests" / "tools"))

from bonding_helpers import EmuGroup, Gateway, Stall, gcs_hello, udp_sock  # noqa: E402
from helpers import HOST, FrameMaker, free_port, split_stream, udp_client, udp_server  # noqa: E402
from test_faults import udp_drops  # noqa: E402
from helpers import status_document  # noqa: E402
from test_stalls import STALLS, drained, held_back, repeats_stream  # noqa: E402
import tlog  # noqa: E402
from synth import ardupilot_stream  # noqa: E402

import scenarios as S  # noqa: E402

DEFAULT_TLOG = "ardupilot-sub-real-2023-qgc-small.tlog"
TLOG_OFFSET = 5.0     # s; the recording opens with a parameter download burst
LEAD = 1.5            # s from the emulators' start to the first frame
# Byte-identical frames sent less than this apart are "alike" (see match()): longer than any
# frame takes to reach the GCS here (300 ms of skew, a full radio queue, a 1 s freeze).
HORIZON = 3.0
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


def stamped_stream(seconds: float, rate: int = 1000) -> List[Tuple[float, bytes]]:
    """`rate` ATTITUDE frames/s, time_boot_ms counting the milliseconds: every frame a new
    sample of one stream, each 1 ms newer than the last at 1,000 frames/s."""
    m = FrameMaker(1, 1)
    out = []
    for i in range(int(seconds * rate)):
        m.mav.seq = i % 256
        out.append((i / rate, m.attitude(i * 1000 // rate)))
    return out


def stream_for(sc: S.Scenario, source: str) -> Tuple[str, List[Tuple[float, bytes]]]:
    """The scenario's stream: (description, [(t, frame)])."""
    if sc.stream == "repeats":
        return ("1,000 frames/s: a 256-frame cycle of identical bytes, every 4th frame a unique "
                "VFR_HUD", repeats_stream(sc.seconds))
    if sc.stream == "stamped_1khz":
        return "1,000 ATTITUDE frames/s, each 1 ms newer", stamped_stream(sc.seconds)
    return load_stream(source, sc.seconds)


_decoder = None
_sample_cache: Dict[bytes, Optional[Tuple[int, int]]] = {}


def sample_of(frame: bytes) -> Optional[Tuple[int, int]]:
    """(stream, time in ns) of a timestamped sample: what dedup's drop_stale compares. The
    stream is (sysid, compid, msgid) as one number, the time its time_boot_ms or time_usec;
    None for a frame without either."""
    global _decoder
    if frame in _sample_cache:
        return _sample_cache[frame]
    if _decoder is None:
        from pymavlink.dialects.v20 import all as mav2  # noqa: PLC0415
        _decoder = mav2.MAVLink(None)
        _decoder.robust_parsing = True
    out = None
    try:
        msg = _decoder.decode(bytearray(frame))
    except Exception:  # noqa: BLE001 - an id pymavlink does not know has no known timestamp
        msg = None
    names = msg.get_fieldnames() if msg is not None else []
    for field, unit_ns in (("time_boot_ms", 1_000_000), ("time_usec", 1_000)):
        if field in names:
            stream = tlog.sysid(frame) << 32 | tlog.compid(frame) << 24 | tlog.msgid(frame)
            out = (stream, getattr(msg, field) * unit_ns)
            break
    _sample_cache[frame] = out
    return out


def alike_runs(frames: Sequence[bytes], sent: Sequence[float]) -> List[int]:
    """For each frame, the index of the first frame of its run: byte-identical frames each
    sent less than HORIZON after the one before. A frame alone in its run is its own."""
    out, last = [], {}
    for i, f in enumerate(frames):
        prev = last.get(f)
        out.append(out[prev] if prev is not None and sent[i] - sent[prev] < HORIZON else i)
        last[f] = i
    return out


# --- processes ----------------------------------------------------------------------------

class Ground:
    """One mode's ground gateway (a UDP server per link in bond `vehicle`, its filters, a
    status socket) and the GCS socket it delivers to."""

    def __init__(self, mode: str, links: List[str], filters: List[dict], workdir: Path,
                 mavbond: str, plugin_dir: str):
        self.mode = mode
        self.links = links
        self.dir = workdir / mode
        self.dir.mkdir(parents=True, exist_ok=True)
        self.port = {l: free_port() for l in links}
        self.p_gcs = free_port()
        self.status_path = self.dir / "status.sock"
        eps = [udp_server(l, self.port[l], bond="vehicle") for l in links]
        eps.append(udp_server("gcs", self.p_gcs))
        # Deliveries are matched by their bytes: the bond does not renumber.
        self.gateway = Gateway(mavbond, self.dir, eps,
                               bonds=[{"name": "vehicle", "tx": "broadcast", "renumber": False}],
                               filters=filters,
                               name="ground", plugin_dir=plugin_dir, log_level="info",
                               status_socket=str(self.status_path))
        self.watch_switches = any(f["plugin"] == "linkswitch" for f in filters)
        self.gcs = udp_sock()
        self.gcs.setblocking(False)
        self.received: List[Tuple[float, bytes]] = []
        self.switches: List[Tuple[float, str, str, str]] = []
        self.stall: Optional[Stall] = None
        self._log_pos = 0

    def poll_log(self, now: float) -> None:
        """Link switches the gateway logged since the last call, stamped now."""
        try:
            with open(self.gateway.log_path, "rb") as f:
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

    def close(self) -> None:
        if self.stall is not None:
            self.stall.stop()      # before the gateway goes: never left frozen
        self.gateway.kill()
        self.gcs.close()


class Collector(threading.Thread):
    """Receives at every mode's GCS socket, says hello once a second (a UDP server forgets a
    silent peer), and reads the linkswitch gateways' logs for switches every 5 ms."""

    def __init__(self, grounds: Sequence[Ground]):
        super().__init__(daemon=True)
        self.grounds = list(grounds)
        self.stop_flag = False

    def run(self) -> None:
        socks = {g.gcs: g for g in self.grounds}
        next_hello = next_log = 0.0
        while not self.stop_flag:
            now = time.monotonic()
            if now >= next_hello:
                for g in self.grounds:
                    gcs_hello(g.gcs, g.p_gcs)
                next_hello = now + 1.0
            if now >= next_log:
                for g in self.grounds:
                    if g.watch_switches:
                        g.poll_log(now)
                next_log = now + 0.005
            ready, _, _ = select.select(list(socks), [], [], 0.005)
            for s in ready:
                g = socks[s]
                while True:
                    try:
                        dg = s.recv(65536)
                    except (BlockingIOError, InterruptedError):
                        break
                    t = time.monotonic()
                    for f in split_stream(dg):
                        if tlog.sysid(f) < 250:
                            g.received.append((t, f))


def paced_send(frames: Sequence[Tuple[float, bytes]], sock, addr, start: float) -> List[float]:
    """Sends frame i at start + frames[i][0]; returns when each frame left."""
    sent: List[float] = []
    burst = 0.001
    i, n = 0, len(frames)
    while i < n:
        now = time.monotonic()
        due = start + frames[i][0]
        if due > now + burst:
            time.sleep(min(due - now - burst / 2, 0.02))
            continue
        while i < n and start + frames[i][0] <= now + burst:
            sent.append(time.monotonic())
            sock.sendto(frames[i][1], addr)
            i += 1
    return sent


def wait_quiet(grounds: Sequence[Ground], quiet: float = 0.3, timeout: float = 10.0) -> None:
    """Returns once no GCS socket got anything for `quiet` seconds (or after `timeout`)."""
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        now = [len(g.received) for g in grounds]
        if now == last:
            return
        last = now
        time.sleep(quiet)


def match(frames: Sequence[bytes], sent: Sequence[float], alike: Sequence[int],
          carried: set, received: Sequence[Tuple[float, bytes]]
          ) -> Tuple[List[Tuple[int, float]], int]:
    """[(frame index, receive time)] in arrival order, and how many deliveries match nothing
    sent. A delivery belongs to the latest run of alike frames with its bytes that began
    before it arrived (alike_runs), and is taken to be the run's first instance, in sending
    order, that left the vehicle before it arrived and is not matched yet, carried ones (some
    link of the mode forwarded them) first; past them, a copy of the last one matched. A frame
    alone in its run (every frame of a recording, which repeats bytes seconds apart at the
    least) is matched exactly; inside a run of recurring bytes the counts are exact (how many
    delivered, how many more than the links carried), which instance a delivery was is not:
    its bytes cannot tell."""
    runs: Dict[bytes, Tuple[List[float], List[list]]] = {}
    for i, f in enumerate(frames):
        starts, members = runs.setdefault(f, ([], []))
        if alike[i] == i:
            starts.append(sent[i])
            members.append([deque(), deque(), None])   # carried, not carried, last matched
        members[-1][0 if i in carried else 1].append(i)
    out, foreign = [], 0
    for t, f in received:
        r = runs.get(f)
        k = bisect.bisect_right(r[0], t) - 1 if r else -1
        if k < 0:
            foreign += 1
            continue
        run = r[1][k]
        for queue in run[0], run[1]:
            if queue and sent[queue[0]] <= t:
                run[2] = queue.popleft()
                break
        if run[2] is None:
            foreign += 1
            continue
        out.append((run[2], t))
    return out, foreign


# --- one run ------------------------------------------------------------------------------

def run(sc: S.Scenario, mavbond: str, plugin_dir: str, stream, workdir: Path,
        modes: Optional[Dict[str, tuple]] = None, stall: bool = True, log=print) -> dict:
    """Runs `sc` with its `stream` ((description, [(t, frame)]), from stream_for) through the
    ground gateways of `modes` ({name: (link names, filters)}; the scenario's three modes by
    default) at once, and returns the raw record (JSON-able)."""
    desc, schedule = stream
    frames = [f for _, f in schedule]
    modes = modes or S.modes(sc)
    workdir.mkdir(parents=True, exist_ok=True)
    grounds = [Ground(name, links, filters, workdir, mavbond, plugin_dir)
               for name, (links, filters) in modes.items()]
    listen = {l.name: free_port() for l in sc.links}
    p_auto = free_port()
    air_eps = [udp_server("autopilot", p_auto)]
    air_eps += [udp_client(l.name, listen[l.name], bond="ground") for l in sc.links]
    air_filters = [{"plugin": "dedup", "bonds": ["ground"]}] if len(sc.links) > 1 else []
    air = Gateway(mavbond, workdir, air_eps,
                  bonds=[{"name": "ground", "tx": "broadcast", "renumber": False}],
                  filters=air_filters, name="air", plugin_dir=plugin_dir, log_level="info")
    spec = []
    for l in sc.links:
        opts = dict(l.opts)
        if l.name in sc.outages:    # stream-relative; linkemu counts from its start
            start, length = sc.outages[l.name]
            opts["outage"] = [f"{start + LEAD:.3f}s+{length:.3f}s"]
        spec.append({"name": l.name, "listen_port": listen[l.name], "seed": l.seed,
                     "forward_ports": [g.port[l.name] for g in grounds if l.name in g.port],
                     **opts})
    group = EmuGroup(workdir, "links", spec)
    vehicle = udp_sock()
    collector = None
    try:
        for g in grounds:
            g.gateway.start()
        group.start()
        air.start()
        collector = Collector(grounds)
        collector.start()
        t_stream = group.t_start + LEAD   # the outages count from the group's start
        time.sleep(max(0.0, t_stream - time.monotonic()))
        if stall:
            for g in grounds:
                g.stall = Stall(g.gateway.proc.pid, duration=sc.seconds, seed=sc.name,
                                **STALLS).start()
        log(f"[{sc.name}] streaming {len(frames)} frames ({desc}) for {sc.seconds:g} s to "
            f"{len(grounds)} ground gateways" + (", frozen on a schedule" if stall else ""))
        sent = paced_send(schedule, vehicle, (HOST, p_auto), t_stream)
        for g in grounds:
            if g.stall is not None:
                g.stall.stop()
        drained(group)
        wait_quiet(grounds)
        docs = {g.mode: status_document(g.status_path) for g in grounds}
        gcs_drops = {g.mode: udp_drops(g.gcs.getsockname()[1]) for g in grounds}
        collector.stop_flag = True
        collector.join(2)
        for g in grounds:
            if g.watch_switches:
                g.poll_log(time.monotonic())
        counters = group.stop()
        air.stop()
        exit_codes = {g.mode: g.gateway.stop() for g in grounds}

        sent_rel = [t - t_stream for t in sent]
        alike = alike_runs(frames, sent)
        samples = [sample_of(f) for f in frames]
        out = {"scenario": sc.name, "stream": desc, "n": len(frames), "t_stream": t_stream,
               "sent": sent_rel, "frame_len": [len(f) for f in frames], "alike": alike,
               "sample": samples, "source": [tlog.sysid(f) * 256 + tlog.compid(f) for f in frames],
               "stall": stall, "modes": {}}
        dropped = {l.name: group.dropped(l.name) for l in sc.links}
        for g in grounds:
            lost_all = set.intersection(*(dropped[l] for l in g.links))
            carried = set(range(len(frames))) - lost_all
            deliveries, foreign = match(frames, sent, alike, carried, g.received)
            dedup = next((f["status"] for f in docs[g.mode]["filters"]
                          if f["plugin"] == "dedup"), None)
            out["modes"][g.mode] = {
                "links": g.links,
                "deliveries": [(i, t - t_stream) for i, t in deliveries],
                "foreign": foreign,
                "drops": {l: [(d["index"], d["reason"]) for d in group.drops(l)
                              if d["reason"] != "corrupted"] for l in g.links},
                "received_by_link": {l: counters[l]["up"]["received"] for l in g.links},
                "late_max_ms": {l: counters[l]["up"]["late_max_ms"] for l in g.links},
                "switches": [(t - t_stream, a, b, why) for t, a, b, why in g.switches],
                "freezes": [(a - t_stream, b - t_stream) for a, b in g.stall.stalls]
                if g.stall else [],
                "stall_error": g.stall.error if g.stall else None,
                "dedup": dedup,
                "rx_overflows": {e["name"]: e["rx_overflows"] for e in docs[g.mode]["endpoints"]},
                "gcs_drops": gcs_drops[g.mode],
                "held_back": held_back(g.gateway.log()),
                "exit_code": exit_codes[g.mode],
            }
        return out
    finally:
        if collector is not None:
            collector.stop_flag = True
        for g in grounds:
            g.close()
        air.kill()
        group.kill()
        vehicle.close()
