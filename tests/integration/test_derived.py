"""What the daemon derives from settings that depend on each other, end to end: mavbond's own
identity when two gateways face one GCS through a bond (src/routing/identity.h), and the
account it logs at start (src/daemon/account.h).

Two real gateways: the air side hears a test autopilot (1/1, an ArduPilot HEARTBEAT) on a UDP
endpoint and bonds two UDP links to the ground side, which serves a "GCS" (pymavlink frames,
every CRC checked). Both send mavbond's own HEARTBEAT (`identity: {heartbeat: ...}`), so a GCS
hears both gateways. Ground truth is what the GCS receives and counts as MAVProxy does (a step
of the seq other than one is loss), never the daemon's counters."""
from __future__ import annotations

import re
import time
from collections import Counter

from helpers import HOST, FrameMaker, free_port, udp_client, udp_server
from bonding_helpers import Receiver, Ticker, tlog, udp_sock

HEARTBEAT = 0
CLASH = r"identity 1/191 is mavbond's, yet \d+ frames from it came in"


def gateways(lab, identity):
    """The air and ground gateways, each with `identity` (and its HEARTBEAT every 200 ms);
    returns (air, ground, autopilot port, GCS port)."""
    p_ap, p_gcs, p_radio, p_lte = free_port(), free_port(), free_port(), free_port()
    top = {"identity": {"heartbeat": "200ms", **identity}, "log_level": "info"}
    ground = lab.gateway([udp_server("radio", p_radio, bond="vehicle"),
                          udp_server("lte", p_lte, bond="vehicle"),
                          udp_server("gcs", p_gcs)],
                         bonds=[{"name": "vehicle", "tx": "broadcast"}],
                         filters=[{"plugin": "dedup", "bonds": ["vehicle"]}],
                         name="ground", **top)
    air = lab.gateway([udp_server("autopilot", p_ap),
                       udp_client("radio", p_radio, bond="ground"),
                       udp_client("lte", p_lte, bond="ground")],
                      bonds=[{"name": "ground", "tx": "broadcast"}],
                      filters=[{"plugin": "dedup", "bonds": ["ground"]}], name="air", **top)
    return air, ground, p_ap, p_gcs


def autopilot(lab, port):
    """An ArduPilot HEARTBEAT from 1/1 every 200 ms to the air side's autopilot endpoint."""
    maker = FrameMaker(1, 1)

    def beat(k):
        maker.mav.seq = k % 256  # pack() alone does not count
        return maker.heartbeat()
    return Ticker(lab.sock(), (HOST, port), beat, 0.2)


def gcs_counts(frames):
    """Per source: HEARTBEATs received, and the frames a GCS counts lost (sum of
    (seq - last - 1) mod 256)."""
    beats, lost, last = Counter(), Counter(), {}
    for f in frames:
        src = (tlog.sysid(f), tlog.compid(f))
        beats[src] += tlog.msgid(f) == HEARTBEAT
        if src in last:
            lost[src] += (tlog.seq(f) - last[src] - 1) % 256
        last[src] = tlog.seq(f)
    return beats, lost


def test_two_gateways_never_share_one_identity(lab):
    """Both gateways left at the default identity (1/191, as the man page once advised). The
    ground side, which hears the vehicle's autopilot only through its bond, becomes 1/192: a
    GCS hears two components, each with a counter of its own, and counts nothing lost. The
    autopilot starts 6 s after the gateways (as a vehicle powered after its radio link): what
    came in from the far side before either side knew which it is is no clash."""
    air, ground, p_ap, p_gcs = gateways(lab, {})
    time.sleep(6)
    ap = autopilot(lab, p_ap)
    try:
        ground.wait_log(r"identity: this side faces the ground station .* mavbond is 1/192 here",
                        timeout=10)
        rx = Receiver(lab.sock(), hello_port=p_gcs)
        time.sleep(6)
        beats, lost = gcs_counts(rx.stop())
    finally:
        ap.stop()
    # Each gateway's HEARTBEAT, five a second, came to the GCS: the ground's as 1/192.
    assert beats[(1, 192)] >= 20 and beats[(1, 191)] >= 20, beats
    assert lost[(1, 191)] == 0 and lost[(1, 192)] == 0, (lost, beats)
    assert "identity: this side faces" not in air.log(), air.log()
    for g in (air, ground):
        assert not re.search(CLASH, g.log()), g.log()
    # The account at start says which rule gives each side its identity.
    assert re.search(r"identity 1/191: on the side that hears the vehicle's autopilot through a "
                     r"bond it becomes 1/192", ground.log()), ground.log()
    print(f"\nthe GCS heard HEARTBEATs {dict(beats)}, counted lost {dict(lost)}")


def test_one_identity_given_to_both_gateways_is_a_clash_said_once(lab):
    """`identity: {compid: 191}` in both files: the daemon keeps what it was told, and each side
    says once that another sender uses its identity, with the fix."""
    air, ground, p_ap, p_gcs = gateways(lab, {"compid": 191})
    ap = autopilot(lab, p_ap)
    try:
        for g in (air, ground):
            g.wait_log(CLASH + r" \(first on (radio|lte)[^)]*\).* identity: \{compid: 191\} on the "
                       r"vehicle's side, \{compid: 192\} on the ground's", timeout=15)
        time.sleep(2)
    finally:
        ap.stop()
    for g in (air, ground):
        assert len(re.findall(CLASH, g.log())) == 1, g.log()
        assert "identity: this side faces" not in g.log(), g.log()
        assert re.search(r"identity 1/191 \(identity: compid\): the other gateway of a bond needs "
                         r"another", g.log()), g.log()


def test_the_account_of_derived_settings_is_one_block_at_start(lab):
    """One gateway with what a ground side of a radio + LTE pair has: dedup on the bond, the
    radio blocking FILE_TRANSFER_PROTOCOL, LTE metered, link events on. At start the log has one
    block, each line what was derived and what may make it wrong."""
    g = lab.gateway([udp_server("radio", free_port(), bond="vehicle",
                                block_out=["FILE_TRANSFER_PROTOCOL"]),
                     udp_server("lte", free_port(), bond="vehicle", cost="metered"),
                     udp_server("gcs", free_port())],
                    bonds=[{"name": "vehicle"}],
                    filters=[{"plugin": "dedup", "bonds": ["vehicle"]}],
                    link_events={"silent_after": "1s"},
                    name="ground", log_level="info")
    g.wait_log(r"running with 3 endpoints")
    lines = g.log().splitlines()
    head = next(i for i, l in enumerate(lines) if "derived settings (" in l)
    block = []
    for line in lines[head + 1:]:
        if not re.search(r"notice:   \S", line):
            break
        block.append(line)
    text = "\n".join(block)
    want = [
        r"identity 1/191: on the side that hears the vehicle's autopilot",
        r"bond vehicle: renumbers what it delivers.*\(dedup places every copy; renumber: false",
        r"bond vehicle: dedup: frames remembered [\d.]+s, at least its window [\d.]+s, to cover "
        r"the far side's resend .* \(taken as this side's until it says\)",
        r"bond vehicle: lte is metered: in standby it carries control.*; and "
        r"FILE_TRANSFER_PROTOCOL, which no free member may carry .*: paid for while the free "
        r"members are healthy",
        r"bond vehicle: a link is lost when it brought nothing for 3 of its usual gaps .* at "
        r"least silent_after 1s, at most 10s, while the far side evidently wrote on it .*; told "
        r"to the GCS by the side facing it .*, once per change of the link, both ways as one",
    ]
    for rx in want:
        assert re.search(rx, text), f"{rx!r} not in the block:\n{text}\n\nlog:\n{g.log()}"
    assert len(block) == len(want), text
    assert g.stop() == 0
