"""The operator's session on a SITL rig, scripted as an operator would do it in MAVProxy, and
the healthy run beside it. Each step records what MAVProxy printed and when; nothing here
judges (tests/sitl/test_operator.py does, from these logs and the link models' records)."""
from __future__ import annotations

import random
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from rig import Rig

PARAMS = 1354                # ArduCopter's parameters (../shared/sitl/README.md)
FTP_BYTES = 20000            # the file downloaded by FTP, seeded
CUT = 10.0                   # s: each link cut
SETTLE = 15.0                # s after a cut ends before the links count as healthy again
HEALTHY = 600.0              # s: the healthy run, after its parameter download
MISSION = [                  # QGC WPL 110: home, takeoff, two waypoints, RTL
    (0, 1, 0, 16, -35.363261, 149.165230, 584.0),
    (1, 0, 3, 22, 0.0, 0.0, 10.0),
    (2, 0, 3, 16, -35.362500, 149.165000, 20.0),
    (3, 0, 3, 16, -35.362000, 149.166000, 20.0),
    (4, 0, 3, 20, 0.0, 0.0, 0.0),
]


def ftp_blob() -> bytes:
    return random.Random(23).randbytes(FTP_BYTES)


@dataclass
class Step:
    """One protocol as the operator ran it: ok, how long it took, what MAVProxy said."""
    name: str
    ok: bool = False
    seconds: Optional[float] = None
    detail: str = ""


@dataclass
class GcsSession:
    name: str
    started: float
    ended: Optional[float] = None
    link: Optional[re.Match] = None         # MAVProxy's `link` line at the end
    lines: List[Tuple[float, str]] = field(default_factory=list)
    tlog: Optional[Path] = None


@dataclass
class RunLog:
    rig: Rig
    steps: Dict[str, Step] = field(default_factory=dict)
    gcs: List[GcsSession] = field(default_factory=list)
    cuts: List[Tuple[str, float, float]] = field(default_factory=list)   # link, cut, restore
    healthy: List[Tuple[float, float]] = field(default_factory=list)      # both links up
    rebind: Optional[float] = None
    started: float = 0.0
    ended: float = 0.0


LINK_LINE = (r"link (\S+) (OK|DOWN) \((\d+) packets, \d+ bytes, [-\d.]+s delay, (\d+) lost, "
             r"([\d.]+)% loss")


def _outcome(mp, step: Step, ok: str, fail: Dict[str, str], since: float, timeout: float,
             t0: Optional[float] = None) -> Optional[re.Match]:
    name, t, m = mp.wait_any({"ok": ok, **fail}, timeout, since)
    step.ok = name == "ok"
    step.seconds = round(t - (since if t0 is None else t0), 2)
    step.detail = m.group(0) if m is not None else f"nothing within {timeout:.0f} s"
    return m if step.ok else None


def connect(rig: Rig, log: RunLog, name: str) -> object:
    """A MAVProxy as it starts: it asks for the streams (4 Hz) and fetches the parameters."""
    mp = rig.gcs(name)
    s = GcsSession(name, time.monotonic(), tlog=rig.dir / name / "mav.tlog")
    log.gcs.append(s)
    step = log.steps.setdefault(f"{name}: parameters", Step(f"{name}: parameters"))
    mp.wait_for(r"Detected vehicle 1:1", timeout=60, since=s.started)
    m = _outcome(mp, step, r"Received (\d+) parameters", {}, s.started, 180)
    if m is not None and int(m.group(1)) != PARAMS:
        step.ok = False
        step.detail += f" (of {PARAMS})"
    return mp


def disconnect(mp, log: RunLog) -> None:
    s = log.gcs[-1]
    t = mp.send("link")
    # MAVProxy reads a command after the telemetry queued before it: under the whole
    # scripts/test (2 CPUs saturated, 2026-12-03) its answer after ten healthy minutes came
    # later than 20 s. Its figure is judged against what its telemetry log shows, not by when.
    found = mp.wait_for(LINK_LINE, since=t, timeout=180)
    s.link = found[0][1]
    time.sleep(2.0)        # its telemetry log is flushed as it goes: let it take the last
    mp.stop()
    s.ended = time.monotonic()
    s.lines = list(mp.lines)


def mission(mp, rig: Rig, log: RunLog) -> None:
    path = rig.dir / "mission.txt"
    path.write_text("QGC WPL 110\n" + "".join(
        f"{i}\t{cur}\t{frame}\t{cmd}\t0\t0\t0\t0\t{lat:.6f}\t{lon:.6f}\t{alt:.6f}\t1\n"
        for i, cur, frame, cmd, lat, lon, alt in MISSION))
    up = log.steps.setdefault("mission upload", Step("mission upload"))
    t = mp.send(f"wp load {path}")
    _outcome(mp, up, r"Got MISSION_ACK: TYPE_MISSION: ACCEPTED",
             {"error": r"Got MISSION_ACK: TYPE_MISSION: (?!ACCEPTED)\w+|timed out|[Ff]ailed"},
             t, 60)
    time.sleep(2.0)
    acks = [m.group(0) for _, m in mp.find(r"Got MISSION_ACK: \w+: \w+", since=t)]
    up.detail += f" (every MISSION_ACK: {acks})"
    down = log.steps.setdefault("mission download", Step("mission download"))
    readback = Path(mp.workdir) / "way.txt"
    t = mp.send("wp list")
    if _outcome(mp, down, rf"Saved {len(MISSION)} waypoints to", {
            "error": r"Saved (?!5 )\d+ waypoints to|timed out|[Ff]ailed"}, t, 60):
        got = [l.split("\t") for l in readback.read_text().splitlines()[1:]]
        mine = [(int(r[3]), round(float(r[8]), 5), round(float(r[9]), 5), round(float(r[10]), 1))
                for r in got[1:]]
        want = [(cmd, round(lat, 5), round(lon, 5), round(alt, 1))
                for _, _, _, cmd, lat, lon, alt in MISSION[1:]]
        if mine != want:
            down.ok = False
            down.detail = f"read back {mine}, uploaded {want}"


def ftp(mp, rig: Rig, log: RunLog, blob: bytes) -> None:
    step = log.steps.setdefault("FTP download", Step("FTP download"))
    target = Path(mp.workdir) / "got.bin"
    t = mp.send(f"ftp get blob.bin {target}")
    if _outcome(mp, step, r"Wrote (\d+) bytes", {
            "error": r"FTP: request timed out|Read failed|ftp open failed|FTP: .*[Nn]ack"},
                t, 90):
        if target.read_bytes() != blob:
            step.ok = False
            step.detail += f"; the file differs from the {len(blob)} bytes served"


def arm_and_take_off(mp, rig: Rig, log: RunLog) -> None:
    """GUIDED, arm, take off to 10 m, once SITL has its position estimate (about 35 s after
    boot)."""
    estimate = log.steps.setdefault("position estimate", Step("position estimate"))
    _outcome(mp, estimate, r"EKF3 IMU\d is using GPS", {}, rig.sitl.started, 120)
    for name, cmd, ok in (("mode GUIDED", "mode guided", r"DO_SET_MODE: ACCEPTED"),
                          ("arm", "arm throttle", r"COMPONENT_ARM_DISARM: ACCEPTED"),
                          ("takeoff", "takeoff 10", r"NAV_TAKEOFF: ACCEPTED")):
        step = log.steps.setdefault(name, Step(name))
        t = mp.send(cmd)
        if not _outcome(mp, step, ok, {"error": r"COMMAND_ACK: \w+: (?!ACCEPTED)\w+|"
                                                r"PreArm: .*|Arm: .*"}, t, 30):
            return
    time.sleep(12.0)       # climbing to 10 m takes about 8 s


def cut(rig: Rig, log: RunLog, link: str, healthy_from: float) -> float:
    """The healthy stretch up to now, then `link` cut for CUT seconds (a snapshot in the
    middle) and SETTLE seconds after it: returns when the links count as healthy again."""
    log.healthy.append((healthy_from, time.monotonic()))
    t_cut = rig.cut(link)
    time.sleep(CUT / 2)
    rig.snapshot(f"{link} cut {CUT / 2:.0f} s")
    time.sleep(max(0.0, t_cut + CUT - time.monotonic()))
    log.cuts.append((link, t_cut, rig.restore(link)))
    time.sleep(SETTLE)
    return time.monotonic()


def operator_session(rig: Rig) -> RunLog:
    """The session of issue "As shipped": connect, parameters, mission, FTP, arm and take off,
    the radio cut for 10 s, the GCS reconnecting, a SIGHUP to each gateway, a NAT rebinding,
    the LTE cut for 10 s."""
    log = RunLog(rig)
    log.started = time.monotonic()
    rig.start()
    mp = connect(rig, log, "gcs1")
    healthy_from = time.monotonic()
    mission(mp, rig, log)
    ftp(mp, rig, log, rig.blob)
    arm_and_take_off(mp, rig, log)
    rig.snapshot("healthy, flying")
    healthy_from = cut(rig, log, "radio", healthy_from)
    rig.snapshot("radio back")
    disconnect(mp, log)
    time.sleep(5.0)
    mp = connect(rig, log, "gcs2")
    rig.snapshot("GCS reconnected")
    log.rebind = rig.rebind()["t"]
    time.sleep(5.0)
    for side in ("air", "ground"):
        rig.reload(side)
    time.sleep(10.0)
    rig.snapshot("reloaded")
    healthy_from = cut(rig, log, "lte", healthy_from)
    rig.snapshot("end")
    disconnect(mp, log)
    log.healthy.append((healthy_from, time.monotonic()))
    log.ended = time.monotonic()
    return log


def healthy_run(rig: Rig, seconds: float = HEALTHY) -> RunLog:
    """Both links healthy for `seconds` after MAVProxy has its parameters, nothing else."""
    log = RunLog(rig)
    log.started = time.monotonic()
    rig.start()
    mp = connect(rig, log, "gcs")
    t = time.monotonic()
    time.sleep(seconds)
    rig.snapshot("healthy")
    disconnect(mp, log)
    log.healthy.append((t, time.monotonic()))
    log.ended = time.monotonic()
    return log
