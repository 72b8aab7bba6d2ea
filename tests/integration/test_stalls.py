"""Exact under stress: the bonded scenarios with the ground gateway frozen (SIGSTOP/SIGCONT)
150 ms every 2 to 2.5 s and once for a whole second, as a busy companion computer freezes it.

Each scenario runs the emulated links of one process (tests/tools/linkemu.py --group) with
every link teed to two ground gateways: one frozen over and over, one left alone. Both get the
same datagrams in the same order, so the claim is checked as it is made: for the same
arrivals, the frozen gateway delivers the same frames in the same order as the other, only
later. Each gateway also delivers every frame some link brought exactly once (ground truth:
the emulators' drop logs), no duplicate, none lost, except timestamped samples that came more
than stale_after behind a newer one (dedup's `stale` counter, and each such frame is checked
to be that late). The evidence that the freezes happened and mattered is the daemon's own: its
exit line counts the frames it held back for arrival order, and nothing overflowed a socket
(rx_overflows)."""
from __future__ import annotations

import os
import re
import signal
import socket
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import pytest

from helpers import HOST, FrameMaker, free_port, udp_server
from bonding_helpers import Receiver, timestamp_of, tlog
from synth import ardupilot_stream
from test_metrics import status_document

STALE_AFTER = 0.25       # dedup's default stale_after
STALLS = dict(every=(2.0, 2.5), length=0.150, long_stalls=[(6.0, 1.0)])

# The 57600-baud SiK radio: 8N1 leaves 46,080 bit/s of payload; it buffers a few KB.
RADIO_57600 = {"rate": 46080, "queue_bytes": 4096}


@dataclass
class Scenario:
    name: str
    links: Dict[str, dict]               # link name -> linkemu options
    seconds: float = 20.0
    stream: str = "ardupilot"            # or "repeats": 1,000 frames/s of a 256-frame cycle
    dedup: Dict[str, object] = field(default_factory=dict)


SCENARIOS = [
    Scenario("paper", {"link1": {"loss": "1%", "delay": "10ms"},
                       "link2": {"loss": "1%", "delay": "40ms"}}),
    Scenario("skew", {"fast": {"loss": "1%", "delay": "5ms"},
                      "slow": {"loss": "1%", "delay": "300ms"}}),
    Scenario("late_link", {"a": {"loss": "10%", "delay": "10ms"},
                           "b": {"delay": "2000ms"}}, dedup={"window": "5s"}),
    Scenario("outage", {"link1": {"loss": "1%", "delay": "20ms", "outage": ["4s+8s"]},
                        "link2": {"loss": "1%", "delay": "20ms"}}),
    Scenario("three", {"radio": {"loss": "1%", "delay": "15ms", "jitter": "2ms"},
                       "lte": {"loss": "2%", "delay": "60ms", "jitter": "15ms"},
                       "sat": {"ge": "0.005,0.1,0.005,1", "delay": "250ms", "jitter": "20ms"}}),
    Scenario("repeats_1khz", {"a": {"loss": "5%"}, "b": {"loss": "5%", "delay": "300ms"}},
             seconds=12, stream="repeats"),
    Scenario("radio_beside_lte", {
        "radio": {"loss": "1%", "delay": "30ms", "jitter": "10ms", **RADIO_57600},
        "lte": {"loss": "1%", "delay": "60ms", "jitter": "30ms", "jitter_dist": "normal",
                "reorder": True}}),
    # The radio's queue stands still for longer than the window (its model given no CPU on a
    # saturated machine, in the operator stage): it then brings copies LTE delivered 4.5 s
    # before, and a lagging link's copies are copies however late (the constant samples
    # among them, which drop_stale cannot judge, reached the GCS again).
    Scenario("radio_stood_still", {
        "radio": {"loss": "1%", "delay": "30ms", "jitter": "10ms", "stall": ["5s+4.5s"],
                  **RADIO_57600},
        "lte": {"loss": "1%", "delay": "60ms", "jitter": "15ms"}},
             seconds=14, dedup={"window": "2s"}),
]


def repeats_stream(seconds: float) -> List[tuple]:
    """1,000 frames/s of one 256-frame cycle without timestamps (HEARTBEAT, SYS_STATUS,
    VFR_HUD with fixed values), every 4th frame a unique VFR_HUD: the same bytes recur every
    0.256 s, well inside the window, beside frames that never recur."""
    m = FrameMaker(1, 1)
    cycle = []
    for k in range(256):
        m.mav.seq = k
        cycle.append(m.heartbeat() if k % 3 == 0 else m.sys_status() if k % 3 == 1 else
                     m.pack(m.mod.MAVLink_vfr_hud_message(0.5, 0.4, 90, 48, 20.0, 0.1)))
    out = []
    for i in range(int(seconds * 1000)):
        f = cycle[i % 256]
        if i % 4 == 3:
            m.mav.seq = i % 256
            f = m.pack(m.mod.MAVLink_vfr_hud_message(0.5, 0.4, 90, 48, float(i), 0.1))
        out.append((i / 1000.0, f))
    return out


def paced(schedule, send) -> None:
    """Calls send(frame) for each (t, frame) at t seconds from now (bursts within 2 ms)."""
    start = time.monotonic()
    i, n = 0, len(schedule)
    while i < n:
        now = time.monotonic() - start
        if schedule[i][0] > now + 0.002:
            time.sleep(min(schedule[i][0] - now - 0.001, 0.05))
            continue
        while i < n and schedule[i][0] <= now + 0.002:
            send(schedule[i][1])
            i += 1


def drained(group, timeout: float = 30.0) -> None:
    """Waits until the emulators have sent every datagram they hold (the slowest link's
    last frames come seconds after the stream ends)."""
    deadline = time.monotonic() + timeout
    while any(c["up"]["in_flight"] for c in group.counters_now().values()):
        assert time.monotonic() < deadline, "the emulators never emptied"
        time.sleep(0.1)


def ground(lab, name, ports, gcs_port, status, dedup):
    eps = [udp_server(link, port, bond="vehicle") for link, port in ports.items()]
    eps.append(udp_server("gcs", gcs_port))
    # Delivered frames are known by their bytes here: no renumbering (test_renumber's part).
    return lab.gateway(eps, bonds=[{"name": "vehicle", "tx": "broadcast", "renumber": False}],
                       filters=[{"plugin": "dedup", "bonds": ["vehicle"], **dedup},
                                {"plugin": "stats", "log": False}],
                       name=name, status_socket=str(status), log_level="info")


def dedup_links(doc) -> Dict[str, dict]:
    f = next(x for x in doc["filters"] if x["plugin"] == "dedup")
    return {l["name"]: l for l in f["status"]["links"]}


def held_back(log: str) -> int:
    m = re.search(r"exit: routed \d+ frames, \d+ without a destination, (\d+) held back", log)
    assert m, log[-2000:]
    return int(m.group(1))


def stale_justified(frame, delivered_before) -> bool:
    """Whether a missing timestamped frame is more than STALE_AFTER behind a sample of its
    stream that was delivered (the reason dedup gives for dropping it)."""
    ts = timestamp_of(frame)
    if ts is None:
        return False
    unit = 1e-6 if ts[0] == "time_usec" else 1e-3
    key = (tlog.sysid(frame), tlog.compid(frame), tlog.msgid(frame))
    newest = delivered_before.get(key)
    return newest is not None and (newest - ts[1]) * unit > STALE_AFTER


@pytest.mark.parametrize("sc", SCENARIOS, ids=[s.name for s in SCENARIOS])
def test_a_frozen_gateway_delivers_what_an_unfrozen_one_does(lab, tmp_path, sc):
    sched = (repeats_stream(sc.seconds) if sc.stream == "repeats" else
             [(t / 1e6, f) for t, f in ardupilot_stream(sc.seconds, seed=12)])
    frames = [f for _, f in sched]
    n = len(frames)
    names = list(sc.links)
    listen = {l: free_port() for l in names}
    gw_ports = {g: {l: free_port() for l in names} for g in ("frozen", "steady")}
    gcs_ports = {g: free_port() for g in gw_ports}
    status = {g: tmp_path / f"{g}.sock" for g in gw_ports}
    gws = {g: ground(lab, g, gw_ports[g], gcs_ports[g], status[g],
                     {"window": "3s", **sc.dedup}) for g in gw_ports}
    group = lab.emu_group([{"name": l, "listen_port": listen[l], "seed": 100 + i,
                            "forward_ports": [gw_ports["steady"][l], gw_ports["frozen"][l]],
                            **opts} for i, (l, opts) in enumerate(sc.links.items())])
    # One CPU for the emulators: a datagram sent after another is then queued to its socket
    # after it too. A sender moving between CPUs could have two datagrams in two CPUs' queues
    # at once, each stamped in send order but delivered in either (both gateways alike would
    # then see an order the stamps contradict, the steady one handling it at once).
    os.sched_setaffinity(group.proc.pid, {min(os.sched_getaffinity(0))})
    rx = {g: Receiver(lab.sock(), hello_port=gcs_ports[g]) for g in gw_ports}
    vehicle = lab.sock()
    stall = lab.stall(gws["frozen"], duration=sc.seconds, **STALLS)
    paced(sched, lambda f: [vehicle.sendto(f, (HOST, listen[l])) for l in names])
    drained(group)
    stall.stop()
    for r in rx.values():
        r.wait_quiet(0.6, timeout=20)
    got = {g: [f for f in r.stop() if tlog.sysid(f) == 1] for g, r in rx.items()}
    docs = {g: status_document(status[g]) for g in gw_ports}
    counters = group.stop()
    for g in gws.values():
        assert g.stop() == 0
    logs = {g: gws[g].log() for g in gws}

    # Ground truth: which frames some link forwarded (every link saw every frame).
    for l in names:
        assert counters[l]["up"]["received"] == n, (l, counters[l]["up"])
    dropped = {l: group.dropped(l) for l in names}
    reached = [i for i in range(n) if not all(i in dropped[l] for l in names)]
    want = Counter(frames[i] for i in reached)
    report = [f"\n[{sc.name}] {n} frames, {sc.seconds:.0f} s; lost per link: "
              + ", ".join(f"{l} {len(dropped[l])}" for l in names)
              + f"; on every link {n - len(reached)}; {stall.count} freezes, "
              f"{sum(e - s for s, e in stall.stalls):.2f} s frozen in all"]
    checks = []
    for g in gw_ports:
        have = Counter(got[g])
        missing, extra = want - have, have - want
        links = dedup_links(docs[g])
        stale = sum(l["stale"] for l in links.values())
        overflows = sum(e["rx_overflows"] for e in docs[g]["endpoints"])
        # Every frame missing must be a sample dedup dropped as stale, and there are as many
        # of them as it says; a stale one is that far behind one delivered before it.
        newest = {}
        for f in got[g]:
            ts = timestamp_of(f)
            if ts is not None:
                key = (tlog.sysid(f), tlog.compid(f), tlog.msgid(f))
                newest[key] = max(newest.get(key, ts[1]), ts[1])
        unjustified = [f for f in missing.elements() if not stale_justified(f, newest)]
        justified = sum(missing.values()) - len(unjustified)
        report.append(f"[{sc.name} {g}] delivered {len(got[g])} of {len(reached)} that "
                      f"reached it; duplicates {sum(extra.values())}; good frames dropped "
                      f"{len(unjustified)}; stale samples dropped {stale} ({justified} seen "
                      f"missing); held back for arrival order {held_back(logs[g])}; receive "
                      f"overflows {overflows}")
        checks.append((not extra, f"{g}: {sum(extra.values())} duplicates delivered"))
        checks.append((not unjustified, f"{g}: {len(unjustified)} good frames dropped"))
        checks.append((justified == stale, f"{g}: {justified} missing, {stale} stale"))
        checks.append((overflows == 0, f"{g}: {overflows} receive overflows"))
        report.append(f"[{sc.name} {g}] dedup: {links}; event loop: {docs[g]['event_loop']}")
    print("\n".join(report))
    for ok, what in checks:
        assert ok, what
    assert stall.count >= int(sc.seconds / 2.5), stall.summary()
    assert held_back(logs["frozen"]) > 0, "the freezes left no backlog to merge"
    # The frozen gateway's own clock saw its longest freeze: stopped while it waited, it woke
    # at least the freeze less its longest wait (the link-event tick, 100 ms) after its timer;
    # stopped in a round, that round took the whole freeze.
    loop, longest = docs["frozen"]["event_loop"], max(e - s for s, e in stall.stalls)
    seen_ms = max(loop["latest_wakeup_ms"], loop["longest_round_ms"])
    assert loop["late_wakeups"] + loop["long_rounds"] >= 1 and seen_ms >= 1000 * longest - 100, \
        (loop, stall.summary())
    # The claim itself: the same frames, in the same order, only later.
    assert got["frozen"] == got["steady"], first_difference(got["frozen"], got["steady"])


def first_difference(a: List[bytes], b: List[bytes]) -> str:
    def show(fs):
        return " ".join(f"{tlog.msgid(f)}#{tlog.seq(f)}" for f in fs)
    for k, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return (f"first difference at delivery {k} of {len(a)} / {len(b)} (msgid#seq): "
                    f"frozen {show(a[max(0, k - 3):k + 5])}; steady {show(b[max(0, k - 3):k + 5])}")
    return f"lengths differ: {len(a)} / {len(b)}"


def test_a_one_second_backlog_at_10000_frames_per_second_overflows_nothing(lab, tmp_path):
    """The gateway frozen while each of two links brings 10,000 frames (a second of a
    10,000 frames/s stream): the kernel queues them all (rx_buffer's default), and once thawed
    the gateway delivers each frame exactly once, in order."""
    ports = {"a": free_port(), "b": free_port()}
    gcs_port = free_port()
    status = tmp_path / "status.sock"
    g = ground(lab, "ground", ports, gcs_port, status, {"window": "3s"})
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.setsockopt(socket.SOL_SOCKET, 33, 64 << 20)  # SO_RCVBUFFORCE: room for all of it
    gcs.bind((HOST, 0))
    lab.socks.append(gcs)
    rx = Receiver(gcs, hello_port=gcs_port)
    m = FrameMaker(1, 1)
    frames = []
    for i in range(10000):
        m.mav.seq = i % 256
        frames.append(m.attitude(i))  # time_boot_ms = i: every frame unique
    sender = lab.sock()
    g.proc.send_signal(signal.SIGSTOP)
    try:
        for f in frames:
            sender.sendto(f, (HOST, ports["a"]))
            sender.sendto(f, (HOST, ports["b"]))
    finally:
        g.proc.send_signal(signal.SIGCONT)
    rx.wait_quiet(0.6, timeout=30)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    doc = status_document(status)
    assert g.stop() == 0
    overflows = {e["name"]: e["rx_overflows"] for e in doc["endpoints"]}
    links = dedup_links(doc)
    print(f"\n[backlog] 2 x 10,000 frames queued while frozen; delivered {len(got)}, "
          f"duplicates dropped {sum(l['duplicates'] for l in links.values())}; receive "
          f"overflows {overflows}; held back for arrival order {held_back(g.log())}")
    assert overflows == {"a": 0, "b": 0, "gcs": 0}
    assert got == frames


def test_what_a_full_receive_buffer_drops_is_counted(lab, tmp_path):
    """A receive buffer too small for the backlog (rx_buffer at its minimum, 64 KiB: about 80
    small datagrams) while the gateway is frozen: what the kernel drops is counted on the
    endpoint (rx_overflows, from the socket's own drop counter), so the frames sent are exactly
    those delivered plus those counted."""
    port, gcs_port = free_port(), free_port()
    status = tmp_path / "status.sock"
    g = lab.gateway([udp_server("a", port, rx_buffer="64KiB"), udp_server("gcs", gcs_port)],
                    name="small", status_socket=str(status), log_level="info")
    rx = Receiver(lab.sock(), hello_port=gcs_port)
    m = FrameMaker(1, 1)
    frames = []
    for i in range(2000):
        m.mav.seq = i % 256
        frames.append(m.attitude(i))
    sender = lab.sock()
    g.proc.send_signal(signal.SIGSTOP)
    try:
        for f in frames:
            sender.sendto(f, (HOST, port))
    finally:
        g.proc.send_signal(signal.SIGCONT)
    rx.wait_quiet(0.6, timeout=20)
    got = [f for f in rx.stop() if tlog.sysid(f) == 1]
    doc = status_document(status)
    overflows = next(e["rx_overflows"] for e in doc["endpoints"] if e["name"] == "a")
    assert g.stop() == 0
    exit_line = next(l for l in g.log().splitlines() if "stats endpoint=a " in l)
    print(f"\n[small buffer] 2,000 frames sent while frozen; delivered {len(got)}, counted as "
          f"dropped by the kernel {overflows}; exit line: {exit_line.split('stats ')[-1]}")
    assert overflows > 0
    assert len(got) + overflows == len(frames)
    assert got == [f for f in frames if f in set(got)], "what was delivered came in order"
    assert f"rx_overflows={overflows}" in exit_line
