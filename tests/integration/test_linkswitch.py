"""linkswitch as its users need it: real mavbond processes, real link emulators
(tests/tools/linkemu.py) and real UDP sockets on 127.0.0.1.

The vehicle's stream (tests/tools/synth.py, the ArduPilot rate of 124 frames/s) is sent to two
emulators, as the gateway on the vehicle fans it out, so the copies on both links are
byte-identical; the emulators forward to a ground gateway whose bond `vehicle` has linkswitch.
Ground truth is the emulators' drop logs (which datagram index each link lost; their loss
decisions depend only on (seed, index)); what linkswitch decided comes from its own counters
on the status socket and its log, never from wall-clock timing.

Runtime: about 70 s on 2 cores (one 40 s stream, two of 9 and 12 s, and config checks)."""
from __future__ import annotations

import re
import subprocess
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Dict, List

import pytest

from helpers import HOST, free_port, status_document, udp_server
from bonding_helpers import Receiver, paced_events, tlog
from synth import ardupilot_stream


def linkswitch_bond(path: Path) -> dict:
    """linkswitch's view of bond `vehicle`, with its links keyed by endpoint name (a UDP
    server's links are its peers, "link_a@127.0.0.1:PORT")."""
    doc = status_document(path)
    ls = next(f for f in doc["filters"] if f["name"] == "linkswitch")["status"]
    bond = next(b for b in ls["bonds"] if b["name"] == "vehicle")
    bond["by_endpoint"] = {l["name"].split("@")[0]: l for l in bond["links"]}
    return bond


class Rig:
    """A ground gateway (bond `vehicle`: UDP servers link_a, link_b, in that order of
    preference; a `gcs` UDP server), an emulator per link, the GCS receiving."""

    def __init__(self, lab, a_opts: dict, b_opts: dict, seeds=(1, 2), **linkswitch):
        self.ports = {k: free_port() for k in ("la", "lb", "ga", "gb", "gcs")}
        self.status_path = lab.workdir / f"status-{self.ports['gcs']}.sock"
        self.gateway = lab.gateway(
            [udp_server("link_a", self.ports["ga"], bond="vehicle"),
             udp_server("link_b", self.ports["gb"], bond="vehicle"),
             udp_server("gcs", self.ports["gcs"])],
            bonds=[{"name": "vehicle", "tx": "broadcast"}],
            filters=[{"plugin": "linkswitch", "bonds": ["vehicle"], **linkswitch}],
            name=f"ground-{self.ports['gcs']}", status_socket=str(self.status_path))
        # Both links in one emulator process: a busy machine delays both alike, so their
        # latency difference (what the tests below rely on) holds whatever the scheduler does.
        self.emus = lab.emu_group(
            [{"name": "a", "listen_port": self.ports["la"], "forward_ports": self.ports["ga"],
              "seed": seeds[0], **a_opts},
             {"name": "b", "listen_port": self.ports["lb"], "forward_ports": self.ports["gb"],
              "seed": seeds[1], **b_opts}], name=f"links-{self.ports['gcs']}")
        self.rx = Receiver(lab.sock(), hello_port=self.ports["gcs"])
        self.socks = [lab.sock(), lab.sock()]

    def stream(self, seconds: float, seed: int) -> List[bytes]:
        """The vehicle's stream, each frame to both emulators at once; returns the frames."""
        sched = [(t / 1e6, f) for t, f in ardupilot_stream(seconds, seed)]
        events = [(t, k, f) for t, f in sched for k in (0, 1)]
        paced_events(events, [(self.socks[0], (HOST, self.ports["la"])),
                              (self.socks[1], (HOST, self.ports["lb"]))])
        deadline = time.monotonic() + 30
        while any(c["up"]["in_flight"] for c in self.emus.counters_now().values()):
            assert time.monotonic() < deadline, "the emulators never emptied"
            time.sleep(0.1)
        self.rx.wait_quiet(0.5)
        return [f for _, f in sched]

    def delivered(self) -> List[bytes]:
        return [f for f in self.rx.stop() if tlog.sysid(f) == 1]

    def switch_lines(self) -> List[str]:
        return re.findall(r"active link \S+ -> \S+: .*", self.gateway.log())


# --- (a) two links of equal loss: it stays put ----------------------------------------------

def test_two_links_of_equal_loss_stay_put(lab):
    """Two links losing 5% each (seeded, Bernoulli), 40 s of the ArduPilot stream (4,960
    frames), linkswitch with its defaults: at most one switch, by its own counter and log
    (the previous linkswitch was reported switching 10 times in 50 s this way). While the
    stream runs, the status socket is read every half second to show that both links' loss
    was judged (a whole window with enough frames), so the rule that keeps them apart was
    armed."""
    rig = Rig(lab, dict(loss="5%", delay="10ms"), dict(loss="5%", delay="30ms"), seeds=(61, 62))
    judged: Dict[str, List[float]] = {"link_a": [], "link_b": []}
    done = threading.Event()

    def watch():
        while not done.wait(0.5):
            try:
                bond = linkswitch_bond(rig.status_path)
            except (OSError, ValueError, StopIteration):
                continue
            for name, link in bond["by_endpoint"].items():
                if link["loss_pct"] is not None:
                    judged[name].append(link["loss_pct"])

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    frames = rig.stream(40, seed=9)
    done.set()
    watcher.join(5)
    rig.delivered()
    pa, pb = rig.emus.loss_rate("a"), rig.emus.loss_rate("b")
    bond = linkswitch_bond(rig.status_path)
    lines = rig.switch_lines()
    print(f"\n[a] {len(frames)} frames; link_a lost {pa:.2%}, link_b {pb:.2%}; linkswitch "
          f"judged link_a {len(judged['link_a'])} times "
          f"({min(judged['link_a'], default=0):.1f}..{max(judged['link_a'], default=0):.1f}%), "
          f"link_b {len(judged['link_b'])} times "
          f"({min(judged['link_b'], default=0):.1f}..{max(judged['link_b'], default=0):.1f}%); "
          f"switches {bond['switches']} {bond['switches_by_reason']}; log: {lines}")
    assert 0.03 < pa < 0.07 and 0.03 < pb < 0.07, "the emulators did not lose about 5%"
    assert judged["link_a"] and judged["link_b"], "linkswitch never judged the links' loss"
    assert bond["switches"] <= 1, bond
    assert len(lines) == bond["switches"], lines


# --- (b) a switch delivers no duplicate and loses nothing the new link carried -------------

@pytest.mark.parametrize("cause", ["loss", "outage"])
def test_a_switch_delivers_no_duplicate_and_loses_nothing_the_new_link_carried(lab, cause):
    """link_a (preferred) 10 ms, link_b 2% loss. `loss`: link_a loses 30% from the start and
    link_b is 150 ms behind it (18 frames), so at the loss switch (once link_a has been heard
    for the 5 s window) link_b's first frames are copies of frames link_a already delivered,
    and some of the frames link_a lost: 12 s of stream. `outage`: link_a is cut 4 s after its
    emulator started, link_b 20 ms; switch_after 1.5s puts link_b's first frames after the
    switch about 190 frames ahead of the last one delivered, which modulo 256 reads as just
    behind it: 9 s of stream.

    Ground truth from the emulators' drop logs: which frames each link carried to the
    gateway, in order. linkswitch's counters say how many of each link's frames it saw while
    that link was active (passed, or dropped as already delivered): link_a's first ones and
    link_b's last ones. The GCS must have got exactly the union of those frames, each once:
    nothing link_a carried before the switch and nothing link_b carried after it is lost, and
    no frame is delivered twice. The switch is the one the daemon's counters name; the copies
    of delivered frames it dropped are counted (loss), or there were none (outage)."""
    if cause == "loss":
        rig = Rig(lab, dict(loss="30%", delay="10ms"), dict(loss="2%", delay="150ms"),
                  seeds=(71, 72))
        frames = rig.stream(12, seed=10)
    else:
        rig = Rig(lab, dict(delay="10ms", outage="4s+30s"), dict(loss="2%", delay="20ms"),
                  seeds=(81, 82), switch_after="1500ms")
        frames = rig.stream(9, seed=11)
    n = len(frames)
    got = rig.delivered()
    counters = rig.emus.stop()
    ca, cb = counters["a"], counters["b"]
    assert ca["up"]["received"] == n and cb["up"]["received"] == n, (ca["up"], cb["up"])
    da, db = rig.emus.dropped("a"), rig.emus.dropped("b")
    carried_a = [i for i in range(n) if i not in da]
    carried_b = [i for i in range(n) if i not in db]
    bond = linkswitch_bond(rig.status_path)
    a, b = bond["by_endpoint"]["link_a"], bond["by_endpoint"]["link_b"]
    active_a = a["passed"] + a["already_delivered"]
    active_b = b["passed"] + b["already_delivered"]
    before = carried_a[:active_a]              # link_a's frames while it was active
    after = carried_b[len(carried_b) - active_b:]  # link_b's frames once it was
    want = Counter(frames[i] for i in set(before) | set(after))
    have = Counter(got)
    missing, extra = want - have, have - want
    lost_b = [i for i in after if frames[i] in missing]
    print(f"\n[b {cause}] {n} frames; link_a lost {len(da)}, link_b {len(db)}; linkswitch: "
          f"link_a {a['passed']} passed, {a['dropped']} dropped; link_b {b['passed']} passed, "
          f"{b['already_delivered']} dropped as already delivered, {b['dropped']} dropped; "
          f"switches {bond['switches']} {bond['switches_by_reason']}; GCS got {len(got)}, "
          f"missing {sum(missing.values())} (of them link_b's after the switch: {len(lost_b)}), "
          f"extra {sum(extra.values())}; log: {rig.switch_lines()}")
    # linkswitch saw every frame the emulators forwarded: its counters place the switch.
    assert a["passed"] + a["already_delivered"] + a["dropped"] == len(carried_a), a
    assert b["passed"] + b["already_delivered"] + b["dropped"] == len(carried_b), b
    assert bond["switches"] == 1, bond
    assert bond["switches_by_reason"]["loss" if cause == "loss" else "silence"] == 1, bond
    assert len(rig.switch_lines()) == 1
    assert active_a > 0 and active_b > 0
    assert len(got) == a["passed"] + b["passed"]
    assert not extra, f"{sum(extra.values())} frames delivered twice (or from nowhere)"
    assert not missing, (f"{sum(missing.values())} frames lost, {len(lost_b)} of them "
                         f"carried by link_b after the switch: {lost_b[:10]}")
    # The copies it dropped at the switch are exactly link_b's frames that link_a delivered.
    assert b["already_delivered"] == len(set(after) & set(before)), (b, len(set(after) & set(before)))
    if cause == "loss":
        # link_b is 18 frames behind (both links in one emulator process: the lag holds), so
        # its first frames after the switch were copies.
        assert b["already_delivered"] > 0, b
        assert after[0] < before[-1], (after[0], before[-1])
    else:
        assert b["already_delivered"] == 0, b
        assert after[0] > before[-1], (after[0], before[-1])


# --- (c) a typo in `priority` ----------------------------------------------------------------

EPS = ("endpoints:\n"
       "  - {name: radio, type: udp, mode: server, address: 127.0.0.1:%d, bond: vehicle}\n"
       "  - {name: lte, type: udp, mode: server, address: 127.0.0.1:%d, bond: vehicle}\n"
       "bonds:\n"
       "  - {name: vehicle, tx: broadcast}\n"
       "filters:\n")
PRIORITY = {
    "flow": "  - {plugin: linkswitch, bonds: [vehicle], priority: [radio, radoi]}\n",
    "block": ("  - plugin: linkswitch\n"
              "    bonds: [vehicle]\n"
              "    priority:\n"
              "      - lte\n"
              "      - radoi\n"),
}


@pytest.mark.parametrize("style", ["flow", "block"])
@pytest.mark.parametrize("check", [True, False], ids=["check-config", "run"])
def test_unknown_priority_name_exits_78_at_the_item(mavbond_bin, tmp_path, plugin_dir, style,
                                                    check):
    """`priority` naming no endpoint of the bonds in scope stops the daemon (exit 78) with
    file:line:column of that item, with --check-config and on a normal start alike."""
    text = EPS % (free_port(), free_port()) + PRIORITY[style]
    path = tmp_path / "typo.yaml"
    path.write_text(text)
    args = [mavbond_bin, "-c", str(path), "--plugin-dir", plugin_dir]
    r = subprocess.run(args + (["--check-config"] if check else []), capture_output=True,
                       text=True, timeout=10)
    print(f"\n[c {style}] exit {r.returncode}: {r.stderr.strip()}")
    lines = text.splitlines()
    line = next(i for i, l in enumerate(lines) if "radoi" in l)
    where = f"{path}:{line + 1}:{lines[line].index('radoi') + 1}: "
    assert r.returncode == 78, r.stderr
    first = r.stderr.splitlines()[0]
    assert first.startswith(where), (where, r.stderr)
    assert ("filter 'linkswitch': option 'priority': 'radoi' is not an endpoint of bond "
            "vehicle (radio, lte)") in first, first
    assert "running with" not in r.stderr
