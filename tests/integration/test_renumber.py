"""Sequence renumbering (`renumber: true` on a dedup key: content bond), end to end.

An autopilot's stream (tests/tools/synth.py: 124 frames/s from 1/1) reaches a ground mavbond
over two links that number it each their own way: link B's copy of every frame carries link
A's seq + 77 (CRC recomputed) and comes 15 ms later. Each link loses 5% (seeded), and some
frames are lost on both. Two gateways get the very same datagrams: one renumbers, one does
not. A pymavlink "GCS" decodes every frame (CRC checked) and counts loss from sequence gaps as
MAVProxy does (QGroundControl counts the same way: a step back is ~255 lost frames).

Ground truth is the test's own loss decisions, never the daemon's counters."""
from __future__ import annotations

import random
import re
import subprocess
from collections import Counter, defaultdict
from pathlib import Path

import pytest

from helpers import HOST, free_port, mav2, udp_server
from bonding_helpers import (Gateway, Receiver, content_key, multiset_diff, paced_events,
                             tlog, udp_sock, with_seq)
from synth import ardupilot_stream
from test_metrics import scrape, status_document, tcp_port, value


def gcs_loss(frames):
    """Per source, the frames a GCS counts lost: sum of (seq - last - 1) mod 256."""
    last, lost = {}, Counter()
    for f in frames:
        src = (tlog.sysid(f), tlog.compid(f))
        if src in last:
            lost[src] += (tlog.seq(f) - last[src] - 1) % 256
        last[src] = tlog.seq(f)
    return lost


def signed_pair(i: int, key: bytes):
    """The i-th signed ATTITUDE of source 2/1 as link A's sender and link B's (own seq, own
    signature) would send it."""
    out = []
    for seq0 in (0, 100):
        mav = mav2.MAVLink(None, srcSystem=2, srcComponent=1)
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = 1000 + i
        mav.seq = (seq0 + i) % 256
        out.append(bytes(mav2.MAVLink_attitude_message(i * 100, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav)))
    return out


def through_gateways(mavbond_bin, tmp_path, plugin_dir, events, variants, while_running=None):
    """Ground gateways, one per variant (name: (bond keys, dedup keys, top-level keys)), each
    with two bonded UDP servers (link_a, link_b) and a GCS; every event (t, link, frame) goes
    to each gateway's link at its time. Returns what each GCS got and each gateway's log;
    `while_running(gateways)` is called once the GCSs are quiet, before the gateways stop."""
    gws, rxs, targets, socks = [], [], [], []
    for name, (bond, dedup, top) in variants.items():
        ga, gb, gcs = free_port(), free_port(), free_port()
        g = Gateway(mavbond_bin, tmp_path,
                    [udp_server("link_a", ga, bond="vehicle"), udp_server("link_b", gb, bond="vehicle"),
                     udp_server("gcs", gcs)],
                    bonds=[{"name": "vehicle", **bond}],
                    filters=[{"plugin": "dedup", "bonds": ["vehicle"], **dedup}],
                    name=name, plugin_dir=plugin_dir, log_level="info", **top).start()
        gws.append(g)
        s = udp_sock()
        socks.append(s)
        rxs.append(Receiver(s, hello_port=gcs))
        sa, sb = udp_sock(), udp_sock()
        socks += [sa, sb]
        targets += [(sa, (HOST, ga)), (sb, (HOST, gb))]
    try:
        # Every event goes to every gateway, link A's to its link_a, link B's to its link_b.
        flat = [(t, 2 * g + k, f) for t, k, f in events for g in range(len(gws))]
        paced_events(flat, targets)
        for rx in rxs:
            rx.wait_quiet(0.5)
        got = {name: rx.stop() for name, rx in zip(variants, rxs)}
        if while_running:
            while_running(gws)
        for g in gws:
            assert g.stop() == 0
        return got, {name: g.log() for name, g in zip(variants, gws)}
    finally:
        for g in gws:
            g.kill()
        for s in socks:
            s.close()


def test_gcs_sees_exactly_the_frames_lost_on_both_links(mavbond_bin, tmp_path, plugin_dir):
    seconds = 6
    sched = [(t / 1e6, f) for t, f in ardupilot_stream(seconds, seed=8)]
    n = len(sched)
    rng = random.Random(8)
    lost_a, lost_b = set(), set()
    for i in range(n):
        if rng.random() < 0.05:
            lost_a.add(i)
        if rng.random() < 0.05:
            lost_b.add(i)
    # Some bursts lost on both; none at the start (link A is heard first) nor in the last
    # 1.5 s (a gap is shown once its hole has waited: it needs frames after it).
    for start in (150, 400, 520):
        lost_a.update(range(start, start + 3))
        lost_b.update(range(start, start + 3))
    head = {i for i in range(n) if sched[i][0] < 0.1}
    tail = {i for i in range(n) if sched[i][0] > seconds - 1.5}
    lost_a -= head
    lost_b -= head | tail
    lost_a -= tail & lost_b
    both = lost_a & lost_b
    key = bytes(range(32))
    events = []
    for i, (t, f) in enumerate(sched):
        if i not in lost_a:
            events.append((t, 0, f))
        if i not in lost_b:
            events.append((t + 0.015, 1, with_seq(f, tlog.seq(f) + 77)))
    signed_sent = set()
    for k in range(20):  # a signed source: never renumbered
        fa, fb = signed_pair(k, key)
        signed_sent |= {fa, fb}
        events += [(0.2 + k * 0.25, 0, fa), (0.2 + k * 0.25 + 0.015, 1, fb)]
    events.sort(key=lambda e: e[0])

    # The renumbering gateway also answers on its status socket and /metrics.
    status_path, m_port = tmp_path / "status.sock", tcp_port()
    shown = dict(status_socket=str(status_path), metrics=f"{{listen: {HOST}:{m_port}}}")
    seen = {}

    def read_status(gws):
        seen["status"] = {b["name"]: b for b in status_document(status_path)["bonds"]}
        seen["metrics"] = scrape(m_port)
        seen["ctl"] = subprocess.run([str(Path(mavbond_bin).with_name("mavbondctl")), "status",
                                      "--socket", str(status_path)], capture_output=True,
                                     text=True, timeout=10)

    got, logs = through_gateways(mavbond_bin, tmp_path, plugin_dir, events, {
        "renumber": ({"renumber": True}, {"key": "content"}, shown),
        "plain": ({"renumber": False}, {"key": "content"}, {})}, read_status)
    status, metrics, ctl = seen["status"], seen["metrics"], seen["ctl"]
    got = {name: [f for f in frames if tlog.sysid(f) in (1, 2)] for name, frames in got.items()}

    ren = got["renumber"]
    for f in ren:
        mav2.MAVLink(None).decode(bytearray(f))  # raises on a bad CRC
    auto = [f for f in ren if tlog.sysid(f) == 1]
    reached = [i for i in range(n) if i not in both]
    missing, extra = multiset_diff((content_key(sched[i][1]) for i in reached),
                                   (content_key(f) for f in auto))
    assert not missing and not extra, "dedup delivers each message that arrived exactly once"
    steps = [(tlog.seq(b) - tlog.seq(a)) % 256 for a, b in zip(auto, auto[1:])]
    assert all(1 <= s < 128 for s in steps), "no repeat, no step back"
    gaps = sum(s - 1 for s in steps)
    loss = {name: gcs_loss([f for f in frames if tlog.sysid(f) == 1])[(1, 1)]
            for name, frames in got.items()}
    late = sum(1 for i in lost_a - lost_b)
    print(f"\n[renumber] {n} frames; link A lost {len(lost_a)}, link B {len(lost_b)}, both "
          f"{len(both)}; delivered {len(auto)}; loss a GCS counts: {loss['renumber']} with "
          f"renumbering, {loss['plain']} without ({late} rescued by link B)")
    assert gaps == len(both) == loss["renumber"]
    assert loss["plain"] > 10 * len(both), "without renumbering the GCS is misled"

    # Signed frames pass untouched: each delivered one is a frame one of the links sent.
    signed = [f for f in ren if tlog.sysid(f) == 2]
    assert len(signed) == 20
    assert all(f in signed_sent for f in signed)
    summary = re.search(r"renumber bond=vehicle renumbered=(\d+) .*signed_left_alone=(\d+)",
                        logs["renumber"])
    assert summary, logs["renumber"][-2000:]
    assert int(summary.group(1)) == len(auto)
    assert int(summary.group(2)) == 40, "both copies of each signed frame counted"

    # The same figures on the status socket, in /metrics and in mavbondctl, while running.
    shown = status["vehicle"]["renumber"]
    assert shown["renumbered"] == len(auto) and shown["gaps"] == len(both)
    assert shown["signed_left_alone"] == 40
    for name, count in shown.items():
        assert value(metrics, f"mavbond_renumber_{name}_total", bond="vehicle") == count, name
    assert ctl.returncode == 0, ctl.stderr
    assert (f"renumber vehicle: {len(auto)} frames renumbered, {len(both)} gaps (lost on every "
            f"link)") in ctl.stdout, ctl.stdout


def test_a_bond_with_dedup_renumbers_unless_told_not_to(mavbond_bin, tmp_path, plugin_dir):
    """The usual pair: one stream fanned out by the air gateway (the same bytes on both links,
    dedup's default key), link B 200 ms behind link A (within stale_after: no rescued sample is
    dropped as stale), each losing 5 % and some frames on both.
    What link B rescues comes after frames sent after it: without renumbering a GCS counts
    each such step back as ~255 lost. A bond with dedup renumbers without being told (and
    says so at start); `renumber: false` turns it off."""
    seconds = 6
    sched = [(t / 1e6, f) for t, f in ardupilot_stream(seconds, seed=11)]
    n = len(sched)
    rng = random.Random(11)
    lost_a = {i for i in range(n) if rng.random() < 0.05}
    lost_b = {i for i in range(n) if rng.random() < 0.05}
    for start in (200, 450):
        lost_a.update(range(start, start + 3))
        lost_b.update(range(start, start + 3))
    head = {i for i in range(n) if sched[i][0] < 0.1}
    tail = {i for i in range(n) if sched[i][0] > seconds - 1.5}
    lost_a -= head
    lost_b -= head | tail
    lost_a -= tail & lost_b
    both = lost_a & lost_b
    events = sorted([(t, 0, f) for i, (t, f) in enumerate(sched) if i not in lost_a] +
                    [(t + 0.2, 1, f) for i, (t, f) in enumerate(sched) if i not in lost_b],
                    key=lambda e: e[0])
    got, logs = through_gateways(mavbond_bin, tmp_path, plugin_dir, events, {
        "derived": ({}, {}, {}), "off": ({"renumber": False}, {}, {})})
    loss = {name: gcs_loss([f for f in frames if tlog.sysid(f) == 1])[(1, 1)]
            for name, frames in got.items()}
    print(f"\n[renumber by default] {n} frames, {len(lost_a - lost_b)} rescued late by link B, "
          f"{len(both)} lost on both: a GCS counts {loss['derived']} lost with the bond's "
          f"default, {loss['off']} with renumber: false")
    delivered = [f for f in got["derived"] if tlog.sysid(f) == 1]
    assert len(delivered) == n - len(both)
    assert loss["derived"] == len(both)
    assert loss["off"] > 10 * len(both), "rescued frames step back without renumbering"
    assert re.search(r"bond vehicle: renumbers what it delivers", logs["derived"]), logs["derived"]
    assert re.search(r"bond vehicle: does not renumber .*renumber: false", logs["off"]), logs["off"]
