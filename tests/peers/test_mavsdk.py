"""An independent MAVLink stack at both ends of the bond: MAVSDK (PyPI `mavsdk`: its C++
library) as the vehicle, on a UART (a pseudo-terminal) behind an air-side mavbond, and as the
ground station, on TCP at a ground-side mavbond. Between the gateways two emulated links
(tests/tools/linkemu.py, seeded), each losing 5 %, the slow one 300 ms behind the fast one.

The ground station downloads 300 parameters, uploads a 100-item mission and reads it back,
arms and takes off (each acked), receives the vehicle's telemetry, and downloads a 256 KiB
file by MAVLink FTP (burst mode), byte-exact. Five runs at once, each with its own
processes: over one clean link without a bond (the reference), through the bond with dedup,
the same with each link cut in the middle of each transfer (tests/peers/peerlab.cut_plan),
and both again with linkswitch instead of dedup.

"Harder than a clean link", precisely (tests/peers/evidence.py counts it from the two
gateways' flight logs and the emulator's records of what each link received and dropped,
never from the clock):
  - no duplicate is delivered, either way;
  - no frame is lost that the links brought: with dedup, none that some link brought; with
    linkswitch, none that every link brought (it takes one link's frames by design);
  - every retry (a parameter read, a mission item asked for again, a command repeated, an
    FTP request repeated or a piece of a file read again) is explained by the attempt before
    it: that attempt or all its answers were lost on every link, or one of them was lost on
    the fast link and so came by the slow one, 300 ms later. Over the clean link there is
    neither, and the reference run must have no retry at all. An unexplained retry, one the
    bond caused (a duplicate, a frame held up), fails the run;
  - FTP NAKs: none but those answering MAVSDK's own read at the end of the file, which the
    clean link has too."""
from __future__ import annotations

import os
import re
import threading
import time
import traceback

import pytest

from peerlab import PeerLab, Rig, cut_plan, gather

SCENARIOS = {
    "clean": ("clean", False),
    "dedup": ("dedup", False),
    "dedup+cut": ("dedup", True),
    "linkswitch": ("linkswitch", False),
    "linkswitch+cut": ("linkswitch", True),
}
PROTOCOLS = ("params", "mission_upload", "mission_download", "command", "ftp")
TELEMETRY = ("ATTITUDE", "GLOBAL_POSITION_INT", "BATTERY_STATUS")


class Outcome:
    def __init__(self, name: str):
        self.name = name
        self.error = None
        self.gcs = None
        self.rig = None
        self.ev = None
        self.seconds = None


def run_one(name: str, mode: str, cut: bool, lab: PeerLab, out: Outcome) -> None:
    t0 = time.monotonic()
    try:
        rig = Rig(lab, mode, cut_plan() if cut else [], name=name.replace("+", "-")).start()
        out.rig = rig
        out.gcs = rig.run_mavsdk_gcs()
        rig.finish()
        out.ev = gather(rig, steps=out.gcs["steps"])
    except Exception:  # noqa: BLE001 - reported by the test of this scenario
        out.error = traceback.format_exc()
    finally:
        lab.kill()
        out.seconds = time.monotonic() - t0


@pytest.fixture(scope="module")
def runs(mavsdk_available, mavbond_bin, plugin_dir, tmp_path_factory):
    """All five runs at once (they spend their time waiting on the links and on MAVSDK's
    timeouts, not on the CPU); every process each started is ended before this returns."""
    base = tmp_path_factory.mktemp("mavsdk")
    outcomes = {name: Outcome(name) for name in SCENARIOS}
    threads = []
    for name, (mode, cut) in SCENARIOS.items():
        lab = PeerLab(mavbond_bin, plugin_dir, base / name.replace("+", "-"))
        t = threading.Thread(target=run_one, args=(name, mode, cut, lab, outcomes[name]),
                             name=name, daemon=True)
        t.start()
        threads.append((t, lab))
    deadline = time.monotonic() + 420
    for t, lab in threads:
        t.join(max(0.0, deadline - time.monotonic()))
    for (t, lab), name in zip(threads, SCENARIOS):
        if t.is_alive():
            lab.kill()
            outcomes[name].error = outcomes[name].error or "still running after 420 s"
    summary = summarize(outcomes)
    print(summary)
    path = os.environ.get("MAVBOND_PEERS_SUMMARY")
    if path:
        with open(path, "a") as f:
            f.write(summary + "\n")
    return outcomes


def telemetry_rates(up) -> dict:
    """Per telemetry stream: (published, delivered, Hz published, Hz delivered), the rates
    over the span the vehicle published it (its gateway's log)."""
    out = {}
    for t in TELEMETRY:
        frames = [f for f in up.sent if f.msg.get_type() == t]
        if len(frames) < 2:
            out[t] = (len(frames), sum(f.delivered_at is not None for f in frames), 0.0, 0.0)
            continue
        span = frames[-1].t - frames[0].t
        delivered = sum(f.delivered_at is not None for f in frames)
        out[t] = (len(frames), delivered, (len(frames) - 1) / span, (delivered - 1) / span)
    return out


def summarize(outcomes) -> str:
    lines = ["MAVSDK vehicle and ground station through mavbond: retries per protocol "
             "(lost/late/unexplained), duration"]
    for name, o in outcomes.items():
        if o.ev is None:
            why = (o.error or "").strip().splitlines()[-1:] or o.gcs and o.gcs["tail"][-300:]
            lines.append(f"  {name:15} did not complete: {why}")
            continue
        r, rep = o.ev["retries"], o.ev["repeats"]
        cells = [f"{p} {r[p].retries} ({r[p].lost}/{r[p].late}/{len(r[p].unexplained)})"
                 for p in PROTOCOLS]
        steps = o.gcs["steps"]
        lines.append(f"  {name:15} " + ", ".join(cells) + f"; {o.seconds:.0f} s")
        lines.append(f"  {'':15} repeated PARAM_VALUEs {rep['repeated_param_values']}, "
                     f"duplicate MISSION_REQUESTs {rep['duplicate_mission_requests_upload']} "
                     f"(upload) {rep['duplicate_mission_requests_download']} (download), "
                     f"FTP re-reads {rep['ftp_rereads']} and resent {rep['ftp_resent']} of "
                     f"{rep['ftp_requests']} requests, FTP NAKs {rep['ftp_naks']} "
                     f"(+{rep['ftp_eof_naks']} at the end of the file); duplicates delivered "
                     f"{o.ev['up'].duplicates}+{o.ev['down'].duplicates}; lost on every link "
                     f"{o.ev['up'].lost_everywhere}+{o.ev['down'].lost_everywhere} of "
                     f"{len(o.ev['up'].sent)}+{len(o.ev['down'].sent)} frames; transfers "
                     f"started again: {sum(len(a) - 1 for a in o.ev['attempts'].values())}; steps "
                     + " ".join(f"{k} {v.get('seconds', 0):.1f}s" for k, v in steps.items()
                                if "seconds" in v and k != "telemetry"))
        lines.append(f"  {'':15} telemetry published/delivered Hz: " + ", ".join(
            f"{t} {hs:.2f}/{hd:.2f}" for t, (_, _, hs, hd) in telemetry_rates(o.ev["up"]).items()))
    return "\n".join(lines)


def check_completed(o: Outcome) -> None:
    assert o.error is None, f"{o.name}: {o.error}"
    steps = o.gcs["steps"]
    assert o.gcs["rc"] == 0 and "done" in steps, \
        f"{o.name}: the ground station did not finish: {o.gcs['tail']}"
    assert steps["params"]["count"] == 300
    assert steps["mission_download"]["items"] == 100
    assert steps["ftp"]["identical"] and steps["ftp"]["bytes"] == 256 * 1024
    vehicle = o.rig.vehicle.lines()
    assert any(d.get("event") == "mission" and d["items"] == 100 for d in vehicle), vehicle
    assert any(d.get("event") == "arm" and d["arm"] for d in vehicle), vehicle
    assert any(d.get("event") == "takeoff" for d in vehicle), vehicle
    received = steps["telemetry"]["received"]
    assert all(received[k] > 0 for k in ("position", "attitude", "battery")), received
    # What the tlogs say was delivered was: no gateway dropped a frame on the way.
    assert not o.rig.dropped_inside(), o.rig.dropped_inside()


def test_one_clean_link_is_the_reference(runs):
    """Over one clean link nothing is lost, so nothing may be retried: if it were, the
    counting (or MAVSDK over a plain link) would be wrong and nothing below would mean much."""
    o = runs["clean"]
    check_completed(o)
    ev = o.ev
    for d in (ev["up"], ev["down"]):
        assert d.missing == 0 and d.duplicates == 0, d.name
    for p in PROTOCOLS:
        assert ev["retries"][p].retries == 0, (p, ev["retries"][p].unexplained)
    assert ev["repeats"]["ftp_naks"] == 0 and ev["repeats"]["ftp_eof_naks"] <= 1


@pytest.mark.parametrize("name", [n for n in SCENARIOS if n != "clean"])
def test_through_the_bond_no_protocol_works_harder(runs, name):
    o = runs[name]
    check_completed(o)
    mode = SCENARIOS[name][0]
    ev = o.ev
    up, down = ev["up"], ev["down"]

    # Delivery: no duplicate either way; nothing lost that the links brought.
    assert up.duplicates == 0 and down.duplicates == 0, \
        f"duplicates delivered: {up.duplicates} to the GCS, {down.duplicates} to the vehicle"
    if mode == "dedup":
        assert not up.lost_by_bond and not down.lost_by_bond, \
            f"lost although a link brought them: {up.lost_by_bond[:10]} (up), " \
            f"{down.lost_by_bond[:10]} (down)"
    else:
        assert not up.lost_unhurt and not down.lost_unhurt, \
            f"lost although every link brought them: {up.lost_unhurt[:10]} (up), " \
            f"{down.lost_unhurt[:10]} (down)"

    # Telemetry at the vehicle's rates: of each stream the vehicle published, the GCS got
    # every sample but those the links lost (with linkswitch: those its active link lost),
    # so its rate differs from the vehicle's by that loss only.
    for t, (sent, delivered, hz_sent, hz_delivered) in telemetry_rates(up).items():
        frames = [f for f in up.sent if f.msg.get_type() == t]
        if mode == "dedup":
            excused = sum(1 for f in frames if f.dropped_on == frozenset(o.rig.links))
        else:
            excused = sum(1 for f in frames if f.dropped_on and f.delivered_at is None)
        assert sent > 0 and delivered == sent - excused, \
            f"{t}: {sent} published ({hz_sent:.2f} Hz), {delivered} delivered " \
            f"({hz_delivered:.2f} Hz), {excused} lost by the links"

    # Retries: each explained by a loss on every link or on the fast link.
    problems = {p: ev["retries"][p].unexplained for p in PROTOCOLS if ev["retries"][p].unexplained}
    assert not problems, f"retries the links' losses do not explain: {problems}"
    # FTP NAKs: only the answers to MAVSDK's read at the end of the file (one per download
    # over the clean link; a read of it sent again after its NAK was lost is a retry above).
    assert ev["repeats"]["ftp_naks"] == 0, "FTP NAKs beside those at the end of the file"

    if SCENARIOS[name][1]:
        # The cuts happened (every step fired: each falls inside its transfer, by the
        # transfer's own messages) and mattered: frames a cut link did not carry were
        # delivered by the other one (dedup), or each gateway moved to the slow link and
        # back (linkswitch).
        assert len(o.rig.cuts_done) == len(cut_plan()), o.rig.cuts_done
        # The vehicle's frames a cut link did not carry (a cut's count markers are no frame).
        cut = {up.frame_at(l, r["index"]) for l in o.rig.links
               for r in o.rig.emu.drops(l, "up") if r["reason"] == "outage"} - {None}
        rescued = sum(1 for i in cut if up.sent[i].delivered_at is not None)
        print(f"{name}: {len(cut)} of the vehicle's frames cut on a link, {rescued} delivered")
        if mode == "dedup":
            assert rescued > 0
        else:
            for g in (o.rig.air, o.rig.ground):
                moves = re.findall(r"active link (\S+) -> (\S+):", g.log())
                to = [b.split("@")[0] for _, b in moves]
                assert "slow" in to and "fast" in to[to.index("slow"):], \
                    f"{g.config_path.name}: linkswitch did not move to the slow link and " \
                    f"back: {moves}"
