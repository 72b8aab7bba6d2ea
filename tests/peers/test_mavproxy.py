"""MAVProxy (PyPI) as the ground station at the ground-side mavbond, the MAVSDK vehicle behind
the bond (tests/peers/peerlab.py: pty UART, air mavbond, two seeded 5 % links 300 ms apart,
dedup on both gateways; the ground bond renumbers: `renumber: true`, dedup `key: content`).

MAVProxy runs as it does for its users, reading its commands on stdin (no terminal), and is
connected before the vehicle starts, so it sees the vehicle's stream from its first frame.
It fetches the parameters (`param fetch`, after the fetch it makes by itself on connecting);
once, in the middle of the stream, both links are cut together for 10 of the vehicle's
ATTITUDE messages, so some frames are surely lost on every link. Then the vehicle stops and
MAVProxy's `link` command is read.

Its figures must be the bond's: the frames it counts lost (sequence gaps, as MAVProxy and
QGroundControl count them) are exactly the frames lost on every link (the emulator's drop
records, each dropped datagram known as a frame or a count marker by its record of what it
received; those after the last frame delivered show as a gap to nobody), which is the
number of gaps the ground gateway's renumbering stepped over (its status socket), and its
loss percentage is that count over what was delivered plus it. MAVProxy is connected over
TCP: a UDP socket of its default size overflows under the vehicle's parameter burst (300
frames at once), and that loss would be MAVProxy's, not the bond's."""
from __future__ import annotations

import json
import os
import time

from mavproxy import MAVProxy, mavproxy_path
from peerlab import HOST, PeerLab, Rig, gather, status_document

ATTITUDE = 30


def test_mavproxy_link_loss_is_the_bonds_and_param_fetch_completes(mavsdk_available, mavbond_bin,
                                                                   plugin_dir, tmp_path):
    mavproxy_path()
    lab = PeerLab(mavbond_bin, plugin_dir, tmp_path / "mavproxy")
    cuts = [{"on": {"link": "fast", "dir": "up", "msgid": ATTITUDE, "count": 100},
             "do": [["cut", "fast"], ["cut", "slow"]]},
            {"on": {"link": "fast", "dir": "up", "msgid": ATTITUDE, "count": 10},
             "do": [["restore", "fast"], ["restore", "slow"]]}]
    mp = None
    try:
        rig = Rig(lab, "dedup", cuts, renumber=True, name="mavproxy").start_links()
        mp = MAVProxy(rig.dir, f"tcp:{HOST}:{rig.ports['gcs']}",
                      ["--no-state", "--default-modules=param", "--streamrate=-1",
                       "--source-system=255"])
        rig.ground.wait_log(r"\[tcp:gcs\].*(accepted|new client|connected)", timeout=20)
        rig.start_vehicle()
        mp.wait_for(r"Received 300 parameters")          # its own fetch on connecting
        mp.send("set param_ftp 0")                        # the PARAM protocol, not FTP
        mp.send("param fetch")
        mp.wait_for(r"Requested parameter list")
        mp.wait_for(r"Received 300 parameters", count=2)
        # The cut happens by the stream's own count (the 100th ATTITUDE, 5 s of it) and
        # ends 10 ATTITUDEs later; wait for both steps, then for 64 frames after them at
        # least (renumbering shows a gap once 64 newer frames came), then stop the vehicle.
        deadline = time.monotonic() + 60
        while len(rig.cut_log.read_text().splitlines() if rig.cut_log.exists() else []) < 2:
            assert time.monotonic() < deadline, "the cut never happened"
            time.sleep(0.1)
        # By frames, not datagrams: the links carry the gateway's count markers between
        # the vehicle's frames.
        restored = json.loads(rig.cut_log.read_text().splitlines()[-1])["frame"]
        while rig.frames_so_far("fast") < restored + 100:
            assert time.monotonic() < deadline, "the vehicle's stream stopped"
            time.sleep(0.1)
        rig.stop_vehicle()
        status = status_document(rig.status["ground"])
        mp.send("link")
        _, line = mp.wait_for(r"link \S+ (OK|DOWN) \((\d+) packets, \d+ bytes, [-\d.]+s delay, "
                              r"(\d+) lost, ([\d.]+)% loss")[-1]
        mp.stop()
        rig.finish()
        ev = gather(rig, renumbered=True, directions=("up",))
    finally:
        if mp is not None:
            mp.stop()
        lab.kill()

    packets, lost, pct = int(line[2]), int(line[3]), line[4]
    up = ev["up"]
    delivered = [i for i, f in enumerate(up.sent) if f.delivered_at is not None]
    # Lost on every link, between the first and the last frame delivered (a loss shows as a
    # gap only once a later frame comes).
    everywhere = [i for i in range(delivered[0], delivered[-1])
                  if up.sent[i].dropped_on == frozenset(rig.links)]
    truth_pct = f"{100.0 * len(everywhere) / (len(delivered) + len(everywhere)):.1f}"
    bond = next(b for b in status["bonds"] if b["name"] == "vehicle")
    stats = next(f for f in status["filters"] if f["name"] == "stats")["status"]
    shown = next(b for b in stats["bonds"] if b["name"] == "vehicle")
    report = (f"MAVProxy through mavbond: `link`: {packets} packets, {lost} lost, {pct}% loss. "
          f"The bond: {len(delivered)} of the vehicle's {len(up.sent)} frames delivered "
          f"(+{up.duplicates} duplicates), {len(everywhere)} lost on every link "
          f"({truth_pct}%). The ground gateway's own figures: renumbering stepped over "
          f"{bond['renumber']['gaps']} numbers (late_filled {bond['renumber']['late_filled']}), "
          f"stats: delivered_lost {shown['delivered_lost']} "
          f"({shown['delivered_loss_pct']:.1f}%)")
    print("\n" + report)
    if os.environ.get("MAVBOND_PEERS_SUMMARY"):
        with open(os.environ["MAVBOND_PEERS_SUMMARY"], "a") as f:
            f.write(report + "\n")
    assert len(everywhere) >= 10, "the cut did not cost frames on every link"
    wrong = []
    if rig.dropped_inside():
        wrong.append(f"frames dropped inside a gateway: {rig.dropped_inside()}")
    if up.duplicates or up.lost_by_bond:
        wrong.append(f"the bond delivered {up.duplicates} duplicates and lost "
                     f"{len(up.lost_by_bond)} frames a link brought")
    if packets != len(delivered) + up.duplicates:
        wrong.append(f"MAVProxy counted {packets} packets, the bond delivered "
                     f"{len(delivered) + up.duplicates}")
    if (lost, pct) != (len(everywhere), truth_pct):
        wrong.append(f"MAVProxy: {lost} lost ({pct}%), the bond lost {len(everywhere)} "
                     f"({truth_pct}%)")
    if bond["renumber"]["gaps"] != len(everywhere):
        wrong.append(f"renumbering stepped over {bond['renumber']['gaps']} numbers for "
                     f"{len(everywhere)} frames lost on every link")
    if shown["delivered_lost"] != len(everywhere):
        wrong.append(f"the stats plugin shows {shown['delivered_lost']} delivered frames lost "
                     f"({shown['delivered_loss_pct']:.1f}%) for {len(everywhere)}")
    assert not wrong, "; ".join(wrong)
