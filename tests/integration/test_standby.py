"""A metered link in standby (`cost: metered`): two gateways joined by a radio and an LTE link,
each a link emulator (tests/tools/linkemu.py) whose LTE side also tees every datagram it
forwards to the test (a sniffer), so what the LTE link carried is known frame by frame.

The air gateway gets an ArduPilot-like stream (124 frames/s) from the test; the ground gateway
(dedup on the bond) hands what it delivers to a GCS socket. Evidence is the emulators' records
(which frame each link dropped, what the LTE link carried), the sniffer and the daemons' own
counters (status socket), never the clock: the test waits for a counter to change, then sends
more and checks what those later frames did."""
from __future__ import annotations

import json
import signal
import socket
import threading
import time
from collections import defaultdict

import pytest

from helpers import HOST, free_port, status_document, udp_client, udp_server
from bonding_helpers import Receiver, Sniffer, frames_of, msgid, multiset_diff, tlog, unique_stream, wait_for

# The default control class (config.cpp default_tx_classes) as the stream has it.
CONTROL_IDS = {0, 253, 76, 75, 77}  # HEARTBEAT, STATUSTEXT, COMMAND_LONG/INT/ACK
NAMED_VALUE_INT = 252


class Stream(threading.Thread):
    """Sends the stream to the air gateway at its pace, for as long as it runs; `sent` counts
    the frames gone, so the test can mark where a counter changed."""

    def __init__(self, sock, addr, frames):
        super().__init__(daemon=True)
        self.sock, self.addr, self.frames = sock, addr, frames
        self.sent, self.stop_flag = 0, threading.Event()

    def run(self):
        start = time.monotonic()
        for t, f in self.frames:
            if self.stop_flag.is_set():
                return
            delay = start + t - time.monotonic()
            if delay > 0.002:
                time.sleep(delay)
            self.sock.sendto(f, self.addr)
            self.sent += 1

    def stop(self):
        self.stop_flag.set()
        self.join()


def standby_of(path):
    return status_document(path)["bonds"][0]["standby"]


def make_lab(lab, tmp_path, radio_opts, failback_after="2s", dedup=None):
    """The two gateways and the two links. Delivered frames are known by their bytes here:
    the bonds do not renumber (test_renumber's part). `dedup`: options of the ground's."""
    p = {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "e_radio", "e_lte", "sniff",
                                  "sniff_radio")}
    ground_sock = tmp_path / "ground.sock"
    air_sock = tmp_path / "air.sock"
    ground = lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                          udp_server("lte", p["g_lte"], bond="vehicle", cost="metered"),
                          udp_server("gcs", p["gcs"])],
                         bonds=[{"name": "vehicle", "tx": "broadcast", "renumber": False,
                                 "failback_after": failback_after}],
                         filters=[{"plugin": "dedup", "bonds": ["vehicle"], **(dedup or {})}],
                         name="ground",
                         status_socket=str(ground_sock))
    sniffers = {}
    for link in ("lte", "radio"):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        sock.bind((HOST, p["sniff" if link == "lte" else "sniff_radio"]))
        sniffers[link] = Sniffer(sock)
    emu = lab.emu_group([dict(name="radio", listen_port=p["e_radio"],
                              forward_ports=[p["g_radio"], p["sniff_radio"]],
                              seed=41, delay="20ms", **radio_opts),
                         dict(name="lte", listen_port=p["e_lte"],
                              forward_ports=[p["g_lte"], p["sniff"]], seed=42, delay="40ms")],
                        name="standby")
    air = lab.gateway([udp_server("ap", p["ap"]),
                       udp_client("radio", p["e_radio"], bond="vehicle"),
                       udp_client("lte", p["e_lte"], bond="vehicle", cost="metered")],
                      bonds=[{"name": "vehicle", "tx": "broadcast", "renumber": False,
                              "failback_after": failback_after}],
                      filters=[{"plugin": "dedup", "bonds": ["vehicle"]}], name="air",
                      status_socket=str(air_sock))
    return p, ground, air, emu, sniffers, ground_sock, air_sock


def start_traffic(lab, p, sniffers, seed):
    """Starts the sniffers, a GCS on the ground gateway and 60 s of stream into the air one."""
    for s in sniffers.values():
        s.start()
    gcs = Receiver(lab.sock(), hello_port=p["gcs"])
    frames = unique_stream(60, seed=seed)
    stream = Stream(lab.sock(), (HOST, p["ap"]), frames)
    stream.start()
    return gcs, frames, stream


def test_standby_carries_control_fails_over_on_a_cut_and_comes_back(lab, tmp_path):
    """Radio 1% loss, cut from 8 s to 14 s after its emulator started; failback_after 2 s; the
    air gateway reloads a changed bond once the cut is seen. Before the cut the LTE link carries only control frames (and the gateways' reports); during
    the cut it carries everything; once the air gateway's counters say it is back in standby,
    the frames sent after that go over LTE only if they are control. The GCS gets every frame
    that reached the ground on some link, exactly once."""
    p, ground, air, emu, sniffers, ground_sock, air_sock = make_lab(
        lab, tmp_path, dict(loss="1%", outage="8s+6s"))
    sniffer = sniffers["lte"]
    gcs, frames, stream = start_traffic(lab, p, sniffers, seed=9)
    # The cut is seen: the metered link went active (the ground reported the radio silent).
    wait_for(lambda: standby_of(air_sock)["to_active"] >= 1, "the air gateway to go active")
    # A reload that changes the bond (a threshold: the bond and the filters are rebuilt) goes
    # on from what the standby knew: still active, no second switch, nothing held lost (the
    # checks below find any frame of the cut the LTE link did not carry).
    air.config_path.write_text(air.config_path.read_text().replace(
        "failback_after: 2s", "failback_after: 2s, failover_loss: 12%"))
    air.proc.send_signal(signal.SIGHUP)
    air.wait_log(r"bond vehicle: standby continues active")
    air.wait_log(r"reloaded: .*filters restarted")
    reloaded = standby_of(air_sock)
    assert reloaded["state"] == "active" and reloaded["to_active"] == 1, reloaded
    # The radio is back and has been healthy for failback_after: standby again.
    wait_for(lambda: standby_of(air_sock)["to_standby"] >= 1, "the air gateway to go back")
    back_at = stream.sent
    # Two more seconds of stream, all of it sent after the switch back; the counters are read
    # while it still flows (once it stops, the radio is silent and the metered link rightly
    # goes active again).
    wait_for(lambda: stream.sent >= back_at + 248, "two more seconds of stream")
    # What LTE carried so far, then the counters: everything in it was sent by the air gateway
    # before the counters were read, so (with one switch each way) in standby after back_at.
    lte_by_then = set(sniffer.frames)
    air_status = status_document(air_sock)
    ground_status = status_document(ground_sock)
    stream.stop()
    n = stream.sent
    gcs.wait_quiet(0.5)
    got = [f for f in gcs.stop() if tlog.sysid(f) == 1 and tlog.compid(f) == 1]
    lte_frames = sniffer.stop()
    radio_set = set(sniffers["radio"].stop())
    # The bytes the daemon counts on the metered link are those the emulator received, once
    # neither changes between two readings of the emulator around one of the daemon.
    for _ in range(50):
        before = emu.counters_now()["lte"]["up"]["bytes_received"]
        metered = standby_of(air_sock)["metered_tx_bytes"]
        if emu.counters_now()["lte"]["up"]["bytes_received"] == before:
            break
    assert metered == before, (metered, before)
    emu.stop()
    sent = [f for _, f in frames[:n]]
    # The cut, in stream indices: the longest run of frames the radio did not carry (the
    # emulator's datagram indices count the gateways' own reports too).
    runs, start = [], None
    for i, f in enumerate(sent + [sent[0]]):
        if i < n and f not in radio_set:
            start = i if start is None else start
        elif start is not None:
            runs.append(range(start, i))
            start = None
    outage = list(max(runs, key=len, default=[]))
    assert len(outage) > 500, "the radio was never cut"
    radio_dropped = {i for i, f in enumerate(sent) if f not in radio_set}

    # What the LTE link carried of the autopilot's stream. A frame's bytes may recur (the same
    # values and sequence byte 256 frames later): it stands for every index it was sent at.
    at = defaultdict(list)
    for i, f in enumerate(sent):
        at[f].append(i)
    lte_set = set(lte_frames)
    carried = [i for i, f in enumerate(sent) if f in lte_set]
    non_control = [f for f in lte_frames if f in at and msgid(f) not in CONTROL_IDS]
    reports = [f for f in lte_frames if f not in at and msgid(f) == NAMED_VALUE_INT]
    sb = air_status["bonds"][0]["standby"]
    print(f"\n[standby] {n} frames; radio cut for {len(outage)} frames (from #{outage[0]}), "
          f"lost {len(radio_dropped) - len(outage)} more; LTE carried {len(carried)} of them "
          f"({len(non_control)} non-control) and {len(reports)} reports; back in standby at "
          f"frame #{back_at}; air standby {json.dumps(sb)}; ground standby "
          f"{json.dumps(ground_status['bonds'][0]['standby'])}")

    # Standby before the cut: only control went over LTE (a resend may go `resend` back from
    # it: 3 s by default, at 124 frames/s).
    resend_from = outage[0] - 3 * 124
    assert non_control, "the LTE link never carried telemetry"
    early = [f for f in non_control if max(at[f]) < resend_from]
    assert not early, f"{len(early)} non-control frames sent before the cut went over LTE"
    assert any(i < resend_from for i in carried), "no control frame went over LTE in standby"
    # Active during the cut: from the first frame of it the LTE link carried beyond control
    # (the resend of what standby held back while the cut was being detected), every one went
    # over LTE. A control frame of the cut went over LTE in standby, before the detection: it
    # marks no start (one did, under the whole run, 7 frames before the first the resend carried).
    in_cut = [i for i in outage if sent[i] in lte_set and msgid(sent[i]) not in CONTROL_IDS]
    gaps = [i for i in range(in_cut[0], outage[-1] + 1) if sent[i] not in lte_set] if in_cut else 0
    assert in_cut and not gaps, (outage[0], outage[-1], gaps)
    print(f"[standby] frames of the cut not carried (sent before the detection, beyond the "
          f"resend): {in_cut[0] - outage[0]}; resent {sb['resent']}")
    # Back in standby: what was sent after the daemon said so went over LTE only if control.
    # (Once the stream stops the radio is silent: the air gateway goes active again and
    # resends the last `resend`, which is why this looks at what LTE carried before that.)
    late = [f for f in non_control if min(at[f]) >= back_at and f in lte_by_then]
    assert not late, f"{len(late)} non-control frames sent after the switch back went over LTE"
    assert any(i >= back_at for i in carried), "no control frame went over LTE after it"
    # The switches, both ways, once each.
    assert sb["state"] == "standby" and sb["to_active"] == 1 and sb["to_standby"] == 1
    assert sb["withheld"] > 0 and sb["reports_received"] > 0
    # Exactly once: every frame that reached the ground on some link, no duplicate; dedup
    # counts as duplicates exactly the copies both links brought (the resent frames the radio
    # had delivered among them, and the reports, which go over every link). Once the stream
    # stops, the radio is silent and the air gateway resends its last `resend` over LTE: a frame
    # of it that only that resend carried comes after newer samples and dedup drops it as stale.
    reached = [f for f in sent if f in radio_set or f in lte_set]
    missing, extra = multiset_diff(reached, got)
    assert not extra, f"{sum(extra.values())} duplicates delivered"
    final_resend = {f for f in lte_set - lte_by_then - radio_set}
    # The failover's resend reaches `resend` back from the detection: a frame the radio lost
    # before the cut that only it carried comes after newer samples too (stale, on purpose).
    failover_resend = {f for f in lte_set - radio_set if f in at and min(at[f]) < in_cut[0]
                       and msgid(f) not in CONTROL_IDS}
    dedup = next(f["status"] for f in status_document(ground_sock)["filters"]
                 if f["plugin"] == "dedup")
    per_link = {l["name"].split("@")[0]: l for l in dedup["links"]}
    both = len((radio_set & lte_set) - {f for f in radio_set if tlog.sysid(f) == 255})
    print(f"[standby] ground dedup: {json.dumps(per_link)}; copies on both links {both}; lost "
          f"as stale after a resend {sum(missing.values())} of "
          f"{len(final_resend | failover_resend)} only a resend carried")
    assert set(missing) <= final_resend | failover_resend, "frames lost that a link carried"
    assert per_link["lte"]["stale"] + per_link["radio"]["stale"] >= sum(missing.values())
    assert per_link["lte"]["duplicates"] + per_link["radio"]["duplicates"] == both


def test_standby_goes_active_on_a_lossy_radio_and_stays(lab, tmp_path):
    """Radio 30% loss throughout (above failover_loss, 10%): the metered link goes active once
    and stays active; the GCS gets every frame exactly once, the radio's losses filled by LTE.
    (The loss is judged from the air side's count markers: two of them, a second apart, before
    the first report can say it. Of what standby held back until then, the resend delivers
    what is not older than a sample the radio already brought; dedup drops the rest as stale.)"""
    p, ground, air, emu, sniffers, ground_sock, air_sock = make_lab(lab, tmp_path,
                                                                    dict(loss="30%"))
    gcs, frames, stream = start_traffic(lab, p, sniffers, seed=10)
    wait_for(lambda: standby_of(air_sock)["to_active"] >= 1, "the air gateway to go active")
    active_at = stream.sent
    wait_for(lambda: stream.sent >= active_at + 496, "four more seconds of stream")
    sb = standby_of(air_sock)
    stream.stop()
    n = stream.sent
    gcs.wait_quiet(0.5)
    got = [f for f in gcs.stop() if tlog.sysid(f) == 1 and tlog.compid(f) == 1]
    lte_set = set(sniffers["lte"].stop())
    radio_set = set(sniffers["radio"].stop())
    emu.stop()
    sent = [f for _, f in frames[:n]]
    lte_ap = {i for i, f in enumerate(sent) if f in lte_set}
    print(f"\n[standby lossy] {n} frames, active from frame #{active_at}; LTE carried "
          f"{len(lte_ap)}; air standby {json.dumps(sb)}")
    assert sb["state"] == "active" and sb["to_active"] == 1 and sb["to_standby"] == 0
    # After the switch the LTE link carried every frame.
    assert set(range(active_at, n)) <= lte_ap
    reached = [f for f in sent if f in radio_set or f in lte_set]
    missing, extra = multiset_diff(reached, got)
    assert not extra, f"{sum(extra.values())} duplicates delivered"
    # What is missing is stale: held back before the switch, resent after newer samples.
    at = defaultdict(list)
    for i, f in enumerate(sent):
        at[f].append(i)
    dedup = next(f["status"] for f in status_document(ground_sock)["filters"]
                 if f["plugin"] == "dedup")
    stale = sum(link["stale"] for link in dedup["links"])
    print(f"[standby lossy] resent {sb['resent']}; dropped as stale {stale}; missing "
          f"{sum(missing.values())}")
    assert all(max(at[f]) < active_at for f in missing), "a frame lost after the switch"
    assert stale >= sum(missing.values())
