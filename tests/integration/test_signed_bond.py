"""A signed bond (`bonds: - {signing: {key_file, links}}`): two gateways joined by a radio and an
LTE link, each a link emulator (tests/tools/linkemu.py); each side signs what it sends on the
bond's signed links and lets in only what verifies. What is checked, each from the daemons' own
counters and the emulators' records (every datagram each link took is logged, so the air side's
count markers, mavbond.yaml(5) LINK ACCOUNTING, are known apart from the stream), never the
clock:

- every frame some link carried reaches the GCS once, byte for byte as the vehicle sent it (the
  signature taken off), late copies on the slow link included, with the ground gateway frozen
  now and then and the LTE link reordering;
- replays (on the same link, on the other link, older than the window) reach nobody;
- a stranger at 127.0.0.2 with unsigned and badly signed frames (COMMAND_LONG arm, `mbl:`
  reports, a 5 Hz HEARTBEAT while the LTE link is dead) moves nothing;
- a flood of forged frames costs no legitimate frame;
- a bond that signs only its LTE link still delivers each frame once (dedup matches the signed
  and the unsigned copy);
- pymavlink, with the same key, verifies what mavbond signed (the wire is standard MAVLink);
- `mavbondctl keygen`, and the start-up warning for a listener anyone may reach unsigned."""
from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

from helpers import (HOST, FrameMaker, free_port, mav2, split_stream, status_document,
                     udp_client, udp_server)
from bonding_helpers import Receiver, multiset_diff, paced_send, tlog, unique_stream, wait_for

STRANGER = "127.0.0.2"
MBL_STRANGER_VALUE = 1000  # "the radio is silent": would pull a metered link out of standby
FORGED_MODE = 0xDEAD  # custom_mode of the stranger's HEARTBEATs: found wherever they land


def keygen(mavbondctl: str, path: Path) -> Path:
    r = subprocess.run([mavbondctl, "keygen", str(path)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return path


@pytest.fixture
def mavbondctl(mavbond_bin) -> str:
    return str(Path(mavbond_bin).parent / "mavbondctl")


@pytest.fixture
def key_file(tmp_path, mavbondctl) -> Path:
    return keygen(mavbondctl, tmp_path / "bond.key")


def key_of(path: Path) -> bytes:
    return bytes.fromhex(path.read_text().strip())


def signing(key_file: Path, links=None) -> str:
    """A bond's `signing:` value (YAML flow text)."""
    return f"{{key_file: {key_file}" + (f", links: [{', '.join(links)}]" if links else "") + "}"


class Sniffer(threading.Thread):
    """Every datagram an emulator forwarded to it (a tee of one link), in order."""

    def __init__(self, sock: socket.socket):
        super().__init__(daemon=True)
        self.sock, self.datagrams, self.stop_flag = sock, [], threading.Event()
        sock.settimeout(0.05)

    def run(self):
        while not self.stop_flag.is_set():
            try:
                self.datagrams.append(self.sock.recv(65536))
            except socket.timeout:
                continue
            except OSError:  # closed at teardown
                return

    def stop(self):
        self.stop_flag.set()
        self.join()
        return self.datagrams


def stranger_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((STRANGER, 0))
    return s


def badly_signed(sysid=1, compid=1) -> FrameMaker:
    """A FrameMaker that signs with a key of its own (not the bond's)."""
    m = FrameMaker(sysid, compid)
    m.mav.signing.secret_key = os.urandom(32)
    m.mav.signing.link_id = 0xBD  # even the bond's link id
    m.mav.signing.timestamp = int((time.time() - 1420070400) * 100000)
    m.mav.signing.sign_outgoing = True
    return m


def forged_heartbeat(m: FrameMaker) -> bytes:
    return m.pack(m.mod.MAVLink_heartbeat_message(2, 3, 0x81, FORGED_MODE, 4, 3))


def forged_report(m: FrameMaker, link=b"mbl:radio") -> bytes:
    return m.pack(m.mod.MAVLink_named_value_int_message(0, link, MBL_STRANGER_VALUE))


def arm(m: FrameMaker) -> bytes:
    # MAV_CMD_COMPONENT_ARM_DISARM (400), param1 = 1: arm
    return m.pack(m.mod.MAVLink_command_long_message(1, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0))


def msgid(frame: bytes) -> int:
    return tlog.msgid(frame)


def is_forged(frame: bytes) -> bool:
    """The stranger's frames, by what no legitimate frame here carries."""
    if msgid(frame) == 76:  # COMMAND_LONG: nobody legitimate sends one in these tests
        return True
    if msgid(frame) == 0 and tlog.payload(frame)[:4] == FORGED_MODE.to_bytes(4, "little"):
        return True
    return msgid(frame) == 252 and b"mbl:" in tlog.payload(frame)


def bond_status(sock_path) -> dict:
    return status_document(sock_path)["bonds"][0]


def endpoint_status(sock_path, name) -> dict:
    return next(e for e in status_document(sock_path)["endpoints"] if e["name"] == name)


LINKS = ("radio", "lte")


def unsigned(frame: bytes) -> bytes:
    """A MAVLink 2 frame without its signature (flag cleared, CRC recomputed): the frame as
    it was before the bond signed it."""
    if not frame[2] & 1:
        return frame
    n = frame[1]
    b = bytearray(frame[:12 + n])
    b[2] &= ~1
    crc = tlog.compute_crc(bytes(b), tlog.crc_extras()[tlog.msgid(frame)])
    b[10 + n], b[11 + n] = crc & 0xFF, crc >> 8
    return bytes(b)


def received_log(workdir: Path, link: str) -> Path:
    return workdir / f"linkemu-signed-{link}-received.jsonl"


def _json_lines(path: Path) -> list:
    """The whole lines of a JSON-lines file the emulator may be writing."""
    if not path.exists():
        return []
    text = path.read_text()
    return [json.loads(l) for l in text[:text.rfind("\n") + 1].splitlines() if l]


class Carried:
    """What one link took from the air side, datagram by datagram, from its emulator's record
    (every datagram it received, its drops): the stream's frames known by their index in the
    stream, the air side's count markers apart (mavbond.yaml(5), LINK ACCOUNTING)."""

    def __init__(self, datagrams: list, dropped: set, index_of: dict):
        self.datagrams, self.dropped = datagrams, dropped
        self.forwarded = [dg for i, dg in enumerate(datagrams) if i not in dropped]
        self.stream, self.markers, self.other = [], [], []  # emulator index, ...
        for i, dg in enumerate(datagrams):
            if (m := tlog.count_marker(dg)) is not None:
                self.markers.append((i, m[0]))
            elif (k := index_of.get(unsigned(dg))) is not None:
                self.stream.append((i, k))
            else:
                self.other.append(i)
        self.lost = {k for i, k in self.stream if i in dropped}   # stream indices
        self.marker_bytes = sum(len(datagrams[i]) for i, _ in self.markers)

    def complete(self, n: int) -> bool:
        """Every one of the `n` frames came, and the count marker after them: the link's
        last (one goes only when frames went since the one before)."""
        return len(self.stream) == n and bool(self.markers) and \
            self.markers[-1][0] == len(self.datagrams) - 1

    def check(self, n: int) -> None:
        """The air side wrote each frame once on the link, in order, and nothing else but
        its count markers, each carrying the frames written before it (its own index)."""
        assert [k for _, k in self.stream] == list(range(n)), "each frame once, in order"
        assert self.other == [], [self.datagrams[i][:12].hex() for i in self.other[:3]]
        assert all(i == count for i, count in self.markers), self.markers[:5]


def carried_now(emu, workdir: Path, counters: dict, index_of: dict) -> dict:
    """{link: Carried} as of `counters` (emu.counters_now()): waits until the emulator's logs,
    flushed after its counters, hold every datagram and every drop they count."""
    def logs():
        out = {}
        for link in LINKS:
            up = counters[link]["up"]
            got = [bytes.fromhex(r["data"]) for r in _json_lines(received_log(workdir, link))
                   if r["direction"] == "up"]
            drops = [r for r in _json_lines(emu.drops_paths[link])
                     if r["direction"] == "up" and r["reason"] != "corrupted"]
            lost = sum(v for k, v in up.items() if k.startswith("dropped_"))
            if len(got) < up["received"] or len(drops) < lost:
                return None
            out[link] = Carried(got[:up["received"]], {r["index"] for r in drops[:lost]},
                                index_of)
        return out
    return wait_for(logs, "the emulator's logs", timeout=10)


def verified_all(emu, workdir: Path, ground_sock, index_of: dict, n: int):
    """(counters, {link: Carried}) once both links took all `n` frames and the count marker
    after them, settled every datagram, and the ground verified every copy they forwarded,
    the count markers (signed too) included (None until then)."""
    c = emu.counters_now()
    for link in LINKS:
        u = c[link]["up"]
        if u["forwarded"] + sum(v for k, v in u.items() if k.startswith("dropped_")) != \
                u["received"]:
            return None  # some still on their way
    carried = carried_now(emu, workdir, c, index_of)
    if not all(carried[link].complete(n) for link in LINKS):
        return None
    verified = bond_status(ground_sock)["signing"]["verified"]
    return (c, carried) if verified == sum(c[k]["up"]["forwarded"] for k in LINKS) else None


def stream_index(frames) -> dict:
    """Each frame of a unique_stream by its bytes: its index."""
    return {f: i for i, (_, f) in enumerate(frames)}


def make_pair(lab, tmp_path, key_file, radio, lte, *, links=None, metered=False,
              ground_extra=None, tee=(), air_radio=None):
    """Ground and air gateways of bond "vehicle" (dedup on it, status sockets), the two links
    between them one emulator group; `tee`: links whose up direction is also sent to a
    sniffer. Returns (ports, ground, air, emu, sniffers)."""
    p = {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "e_radio", "e_lte")}
    sniffers = {}
    for link in tee:
        s = lab.sock()
        sniffers[link] = Sniffer(s)
        p[f"sniff_{link}"] = s.getsockname()[1]
    lte_cost = {"cost": "metered"} if metered else {}
    # renumber: false: the GCS is to get each frame byte for byte as the vehicle sent it, its
    # sender's numbers too (a bond with dedup renumbers in delivery order: test_renumber's).
    bond = {"name": "vehicle", "tx": "broadcast", "renumber": False,
            "signing": signing(key_file, links)}
    # Late copies are what this tests: none dropped as a stale sample.
    dedup = [{"plugin": "dedup", "bonds": ["vehicle"], "window": "2s", "drop_stale": False}]
    ground = lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                          udp_server("lte", p["g_lte"], bond="vehicle", **lte_cost),
                          udp_server("gcs", p["gcs"])],
                         bonds=[bond], filters=dedup, name="ground",
                         status_socket=str(tmp_path / "ground.sock"), **(ground_extra or {}))
    emu = lab.emu_group([dict(name="radio", listen_port=p["e_radio"],
                              forward_ports=[p["g_radio"]] + ([p["sniff_radio"]] if "radio" in tee else []),
                              seed=71, log_received=str(received_log(tmp_path, "radio")), **radio),
                         dict(name="lte", listen_port=p["e_lte"],
                              forward_ports=[p["g_lte"]] + ([p["sniff_lte"]] if "lte" in tee else []),
                              seed=72, log_received=str(received_log(tmp_path, "lte")), **lte)],
                         name="signed")
    air = lab.gateway([udp_server("ap", p["ap"]),
                       udp_client("radio", p["e_radio"], bond="vehicle", **(air_radio or {})),
                       udp_client("lte", p["e_lte"], bond="vehicle", **lte_cost)],
                      bonds=[bond], filters=dedup, name="air",
                      status_socket=str(tmp_path / "air.sock"))
    for s in sniffers.values():
        s.start()
    return p, ground, air, emu, sniffers


def stream_through(lab, p, frames):
    """A GCS on the ground gateway, the stream into the air one at its pace (every frame from
    the one socket a vehicle would send from). Returns (gcs receiver, vehicle socket)."""
    gcs = Receiver(lab.sock(), hello_port=p["gcs"])
    vehicle = lab.sock()
    paced_send(frames, [(vehicle, (HOST, p["ap"]))])
    return gcs, vehicle


def drain(sock: socket.socket, quiet=0.3) -> list:
    """Every frame waiting on `sock`, until it has been quiet for `quiet` seconds."""
    out = []
    sock.settimeout(quiet)
    while True:
        try:
            out.append(sock.recv(65536))
        except socket.timeout:
            return [f for dg in out for f in split_stream(dg)]


# --- every frame once, late copies included; replays dropped ----------------------------------

def test_every_frame_once_late_copies_included_replays_dropped(lab, tmp_path, key_file):
    """Both links signed. The radio is 300 ms behind LTE, both lose 2 % (seeded), LTE reorders
    (jitter 15 ms), the ground gateway is frozen 150 ms every 2 to 2.5 s. The GCS gets each
    frame some link carried exactly once, byte for byte as the vehicle sent it: the ones LTE
    lost come late over the radio, a copy the replay window lets in (a strictly increasing
    check would refuse it: the LTE link had carried newer frames). The radio's budget is
    charged the 13 signature bytes of each frame. Then captured datagrams come again from a
    stranger: on the link that carried them, on the other one, and older than the window. None
    reaches the GCS; each is counted."""
    frames = unique_stream(10, seed=31)
    p, ground, air, emu, sniffers = make_pair(
        lab, tmp_path, key_file, dict(delay="300ms", loss="2%"),
        dict(delay="20ms", jitter="15ms", loss="2%"), tee=("radio",),
        air_radio={"tx_rate": "100kB/s"})
    lab.stall(ground, duration=12.0, every=(2.0, 2.5), length=0.15)
    gcs, vehicle = stream_through(lab, p, frames)
    n = len(frames)
    counters, carried = wait_for(
        lambda: verified_all(emu, tmp_path, tmp_path / "ground.sock", stream_index(frames), n),
        "the ground to verify every copy the links carried")
    gcs.wait_quiet(0.5)
    # The emulators' datagram indices count the air side's count markers too: what each link
    # lost of the stream is known by the frames' own indices.
    for link in LINKS:
        carried[link].check(n)  # the air side sent each frame once on each link, and markers
    radio_lost, lte_lost = carried["radio"].lost, carried["lte"].lost
    markers = {link: len(carried[link].markers) for link in LINKS}
    got = [f for f in gcs.stop() if tlog.sysid(f) == 1]
    both_lost = radio_lost & lte_lost
    want = [f for i, (_, f) in enumerate(frames) if i not in both_lost]
    missing, extra = multiset_diff(want, got)
    rescued = lte_lost - radio_lost
    print(f"\n{n} frames; radio lost {len(radio_lost)}, LTE lost {len(lte_lost)}, both "
          f"{len(both_lost)}; {len(rescued)} came only over the 300 ms radio; GCS got "
          f"{len(got)}: missing {sum(missing.values())}, extra {sum(extra.values())}; count "
          f"markers: radio {markers['radio']}, LTE {markers['lte']}")
    assert rescued, "the seeds give LTE losses the radio covers"
    assert not missing and not extra, (list(missing)[:3], list(extra)[:3])
    g_bond, a_bond = bond_status(tmp_path / "ground.sock"), bond_status(tmp_path / "air.sock")
    carried_copies = counters["radio"]["up"]["forwarded"] + counters["lte"]["up"]["forwarded"]
    assert g_bond["signing"]["verified"] == carried_copies, \
        "every copy either link carried verified, count markers included"
    assert a_bond["signing"]["signed"] == n + markers["radio"] + markers["lte"], \
        "once per frame, whatever the links, and each link's own count markers"
    g_radio, g_lte = (endpoint_status(tmp_path / "ground.sock", k) for k in ("radio", "lte"))
    for e in (g_radio, g_lte):
        assert (e["sig_unsigned"], e["sig_bad"], e["sig_replay"]) == (0, 0, 0), e
    # The radio carried each frame 13 bytes longer, and its budget was charged them.
    a_radio = endpoint_status(tmp_path / "air.sock", "radio")
    sizes = sum(len(f) + 13 for _, f in frames)
    assert a_radio["tx_signed"] == n and a_radio["tx_frames"] == n + markers["radio"], a_radio
    assert a_radio["tx_bytes"] == sizes + carried["radio"].marker_bytes, a_radio
    charged = sum(c["bytes"] for k, c in a_radio["tx_budget"].items() if k != "rate")
    assert charged == sizes + 28 * n, "frame, signature and IP/UDP headers"
    print(f"radio: {a_radio['tx_bytes'] - carried['radio'].marker_bytes} bytes for {n} frames "
          f"({(a_radio['tx_bytes'] - carried['radio'].marker_bytes) / n:.1f} a frame, 13 of "
          f"them the signature), {carried['radio'].marker_bytes} for {markers['radio']} markers")

    # Replays, from a stranger's address, of the stream's datagrams the radio carried (the
    # sniffer's record: what the ground received): the last 300 on the radio (each carried
    # there: a replay), the same on LTE (a replay where LTE carried it; where LTE lost it, a
    # copy the window lets in once: dedup, its 2 s over, lets it through and the router does
    # not deliver it again), and the first 50 (older than the window: over 1024 newer frames
    # of their source) on both.
    captured = sniffers["radio"].stop()
    assert captured == carried["radio"].forwarded, "the tee: what the ground received"
    stream_carried = [(k, carried["radio"].datagrams[i]) for i, k in carried["radio"].stream
                      if i not in carried["radio"].dropped]
    assert len(stream_carried) == n - len(radio_lost)
    last = stream_carried[-300:]
    stranger = stranger_socket()
    for _, dg in last:
        stranger.sendto(dg, (HOST, p["g_radio"]))
    for _, dg in last:
        stranger.sendto(dg, (HOST, p["g_lte"]))
    for _, dg in stream_carried[:50]:
        stranger.sendto(dg, (HOST, p["g_radio"]))
        stranger.sendto(dg, (HOST, p["g_lte"]))
    lte_had = sum(1 for i, _ in last if i not in lte_lost)
    want_radio, want_lte = 350, lte_had + 50
    assert lte_had < 300, "some of them LTE lost (the seeds)"
    wait_for(lambda: (endpoint_status(tmp_path / "ground.sock", "radio")["sig_replay"],
                      endpoint_status(tmp_path / "ground.sock", "lte")["sig_replay"]) ==
             (want_radio, want_lte), "the replays to be counted", timeout=10)
    after = Receiver(gcs.sock)
    after.wait_quiet(0.5)
    late = [f for f in after.stop() if tlog.sysid(f) == 1]
    stranger.close()
    print(f"replays: radio {want_radio}, LTE {want_lte} refused; "
          f"{300 - lte_had} LTE had lost let in once, not delivered again; GCS got {len(late)} more")
    assert late == [], "no replay reached the GCS"
    after_replays = bond_status(tmp_path / "ground.sock")["signing"]
    assert after_replays["verified"] == carried_copies + 300 - lte_had
    assert after_replays["redelivered"] == 300 - lte_had
    assert ground.stop() == 0 and air.stop() == 0


# --- a stranger, while the LTE link is dead -----------------------------------------------------

def test_a_stranger_steers_nothing(lab, tmp_path, key_file):
    """LTE metered (standby), the radio healthy; the LTE link goes dead 6 s after the emulators
    started, for good. From then on a stranger at 127.0.0.2 sends the ground's LTE port, 5
    times a second, a HEARTBEAT as the vehicle's, a COMMAND_LONG arm and an `mbl:radio` report
    saying the radio is silent, each unsigned and signed with another key; and the same report
    to the GCS port. Nothing of it reaches the GCS or the vehicle, neither side's standby
    moves, the ground reports "lte downlink lost" all the same (its own reception of the
    vehicle's side: link events say which way) and its LTE link stays unheard; every forged
    frame is counted."""
    frames = unique_stream(20, seed=32)
    # The ground's own HEARTBEAT at 10 Hz: the air side hears the radio steadily (with a GCS's
    # 1 Hz alone, a gap of a second reads as a silent radio, and standby goes active).
    p, ground, air, emu, _ = make_pair(
        lab, tmp_path, key_file, dict(delay="20ms"), dict(delay="40ms", outage="6s+60s"),
        metered=True, ground_extra={"link_events": "{statustext: false, silent_after: 3s}",
                                    "identity": "{sysid: 255, compid: 191, heartbeat: 100ms}"})
    gcs = Receiver(lab.sock(), hello_port=p["gcs"])
    vehicle = lab.sock()
    sender = threading.Thread(target=paced_send, args=(frames, [(vehicle, (HOST, p["ap"]))]),
                              daemon=True)
    sender.start()
    ground.wait_log(r"link event: link lte up", timeout=10)
    wait_for(lambda: emu.counters_now()["lte"]["up"]["dropped_outage"] > 0, "the LTE outage")
    sent = {"unsigned": 0, "bad": 0, "to_gcs_port": 0}
    stop = threading.Event()

    def stranger():
        s = stranger_socket()
        plain, bad = FrameMaker(1, 1), badly_signed(1, 1)
        while not stop.is_set():
            for m, kind in ((plain, "unsigned"), (bad, "bad")):
                for f in (forged_heartbeat(m), arm(m), forged_report(m)):
                    s.sendto(f, (HOST, p["g_lte"]))
                    sent[kind] += 1
            s.sendto(forged_report(plain), (HOST, p["gcs"]))
            sent["to_gcs_port"] += 1
            stop.wait(0.2)
        s.close()

    t = threading.Thread(target=stranger, daemon=True)
    t.start()
    # This side's reception of it ("downlink": the ground hears the vehicle through the bond).
    ground.wait_log(r"link event: link lte downlink lost", timeout=15)
    time.sleep(3)  # 15 more rounds of forgeries on a link known dead
    stop.set()
    t.join()
    def counted():
        e = endpoint_status(tmp_path / "ground.sock", "lte")
        return e if (e["sig_unsigned"], e["sig_bad"]) == (sent["unsigned"], sent["bad"]) else None

    g_lte = wait_for(counted, "every forged frame counted", timeout=10)
    g_status = status_document(tmp_path / "ground.sock")
    g_bond, a_bond = g_status["bonds"][0], bond_status(tmp_path / "air.sock")
    log = ground.log()
    at_gcs = [f for _, f in gcs.frames if is_forged(f)]
    at_vehicle = [f for f in drain(vehicle) if is_forged(f)]
    print(f"\nstranger sent {sent}; ground lte: sig_unsigned {g_lte['sig_unsigned']}, sig_bad "
          f"{g_lte['sig_bad']}, last heard {g_lte['last_rx_ms_ago']} ms ago; standby ground "
          f"{g_bond['standby']['state']} ({g_bond['standby']['to_active']} to active), air "
          f"{a_bond['standby']['state']} ({a_bond['standby']['to_active']}); reports from the "
          f"GCS port dropped {g_status['standby_reports_dropped']}; forged frames at the GCS "
          f"{len(at_gcs)}, at the vehicle {len(at_vehicle)}")
    assert at_gcs == [] and at_vehicle == []
    assert g_bond["standby"]["to_active"] == 0 and g_bond["standby"]["state"] == "standby"
    assert a_bond["standby"]["to_active"] == 0 and a_bond["standby"]["state"] == "standby"
    assert g_status["standby_reports_dropped"] == sent["to_gcs_port"]
    assert g_lte["sig_replay"] == 0
    assert g_lte["last_rx_ms_ago"] >= 5000, "the forged HEARTBEATs kept no dead link alive"
    # Every event of the LTE link, whichever way it names (the way is known once the
    # vehicle's HEARTBEAT came): first heard, lost once, never back.
    lte_events = re.findall(r"link event: link lte ((?:downlink |uplink |far side )?)"
                            r"(\w+) \(", log)
    assert [what for _, what in lte_events] == ["up", "lost"], re.findall(r"link event: .*", log)
    assert lte_events[1][0] == "downlink ", "this side's own reception of the vehicle's"
    sender.join()
    assert ground.stop() == 0 and air.stop() == 0


# --- a flood -------------------------------------------------------------------------------------

def test_a_flood_of_forged_frames_costs_no_legitimate_frame(lab, tmp_path, key_file):
    """4 s of the vehicle's stream over both links while a stranger sends the ground's LTE port
    20,000 forged frames (half unsigned, half signed with another key), 5,000 a second: the
    GCS gets every frame once, each link's every copy verified, each forged frame counted."""
    frames = unique_stream(4, seed=33)
    p, ground, air, emu, _ = make_pair(lab, tmp_path, key_file, dict(delay="20ms"),
                                       dict(delay="30ms"))
    gcs = Receiver(lab.sock(), hello_port=p["gcs"])
    vehicle = lab.sock()
    plain, bad = FrameMaker(1, 1), badly_signed(1, 1)
    forged = [forged_heartbeat(plain if i % 2 else bad) for i in range(200)]
    stop = threading.Event()
    flood_sent = [0]

    def flood():
        s = stranger_socket()
        start = time.monotonic()
        while flood_sent[0] < 20000 and not stop.is_set():
            for f in forged[:50]:
                s.sendto(f, (HOST, p["g_lte"]))
            flood_sent[0] += 50
            time.sleep(max(0.0, start + flood_sent[0] / 5000 - time.monotonic()))
        s.close()

    t = threading.Thread(target=flood, daemon=True)
    t.start()
    paced_send(frames, [(vehicle, (HOST, p["ap"]))])
    t.join()
    n, sent = len(frames), flood_sent[0]
    wait_for(lambda: (e := endpoint_status(tmp_path / "ground.sock", "lte"))["sig_unsigned"] +
             e["sig_bad"] == sent, "every forged frame counted", timeout=15)
    # Every copy: each frame on each link, and the count markers the air side wrote on them
    # (signed too), as the emulators took them.
    counters, carried = wait_for(
        lambda: verified_all(emu, tmp_path, tmp_path / "ground.sock", stream_index(frames), n),
        "every copy verified", timeout=15)
    for link in LINKS:
        carried[link].check(n)
        assert carried[link].dropped == set(), f"{link} lost nothing"
    markers = sum(len(carried[link].markers) for link in LINKS)
    assert bond_status(tmp_path / "ground.sock")["signing"]["verified"] == 2 * n + markers
    gcs.wait_quiet(0.5)
    got = [f for f in gcs.stop() if tlog.sysid(f) == 1 and not is_forged(f)]
    missing, extra = multiset_diff([f for _, f in frames], got)
    g_lte = endpoint_status(tmp_path / "ground.sock", "lte")
    print(f"\nflood: {sent} forged frames ({g_lte['sig_unsigned']} unsigned, {g_lte['sig_bad']} "
          f"badly signed counted), {n} legitimate: GCS got {len(got)}, missing "
          f"{sum(missing.values())}, extra {sum(extra.values())}; every copy verified "
          f"({2 * n} and {markers} count markers); kernel drops {g_lte['rx_overflows']}")
    assert not missing and not extra
    assert g_lte["rx_overflows"] == 0
    assert ground.stop() == 0 and air.stop() == 0


# --- signing one link of two ---------------------------------------------------------------------

def test_a_bond_signing_only_lte_delivers_each_frame_once(lab, tmp_path, key_file):
    """`links: [lte]`: the radio carries frames as they came, LTE signed; the ground's dedup
    (`key: frame`) matches the two copies of each frame, since the signature comes off once
    it verified."""
    frames = unique_stream(3, seed=34)
    p, ground, air, emu, _ = make_pair(lab, tmp_path, key_file, dict(delay="20ms"),
                                       dict(delay="60ms"), links=["lte"])
    gcs, vehicle = stream_through(lab, p, frames)
    n = len(frames)
    index = stream_index(frames)

    def lte_verified():
        """LTE's markers once it took every frame and the ground verified all it forwarded,
        its count markers (signed too) included."""
        c = emu.counters_now()
        u = c["lte"]["up"]
        if u["forwarded"] != u["received"]:
            return None
        carried = carried_now(emu, tmp_path, c, index)
        if not carried["lte"].complete(n):
            return None
        verified = bond_status(tmp_path / "ground.sock")["signing"]["verified"]
        return carried["lte"].markers if verified == u["forwarded"] else None

    lte_markers = wait_for(lte_verified, "LTE's copies verified")
    gcs.wait_quiet(0.5)
    got = [f for f in gcs.stop() if tlog.sysid(f) == 1]
    missing, extra = multiset_diff([f for _, f in frames], got)
    status = status_document(tmp_path / "ground.sock")
    dedup = next(f for f in status["filters"] if f["plugin"] == "dedup")["status"]
    a_radio, a_lte = (endpoint_status(tmp_path / "air.sock", k) for k in ("radio", "lte"))
    print(f"\n{n} frames, GCS got {len(got)} (missing {sum(missing.values())}, extra "
          f"{sum(extra.values())}); air tx_signed radio {a_radio['tx_signed']}, lte "
          f"{a_lte['tx_signed']}; ground signing {status['bonds'][0]['signing']}")
    assert not missing and not extra
    # tx_signed counts the frames routed; the count markers are signed as they are written
    assert (a_radio["tx_signed"], a_lte["tx_signed"]) == (0, n)
    assert len(lte_markers) > 0
    assert status["bonds"][0]["signing"]["links"] == ["lte"]
    assert sum(l.get("duplicates", 0) for l in dedup["links"]) == n, "each second copy dropped"
    assert ground.stop() == 0 and air.stop() == 0


# --- an independent check of the wire ------------------------------------------------------------

def test_pymavlink_verifies_what_mavbond_signed(lab, tmp_path, key_file):
    """The radio's signed datagrams, as the ground received them, parsed by pymavlink with the
    bond's key (its signing: stream timestamps, the one-minute rule against its own clock):
    every signature good. With another key: every one bad."""
    frames = unique_stream(2, seed=35)
    p, ground, air, emu, sniffers = make_pair(lab, tmp_path, key_file, dict(delay="20ms"),
                                              dict(delay="20ms"), tee=("radio",))
    stream_through(lab, p, frames)
    # The radio's copies: each frame's, and the count markers the air side signed for the
    # link, as the emulator took them; then the tee's (what the ground received) as many.
    counters, carried = wait_for(
        lambda: verified_all(emu, tmp_path, tmp_path / "ground.sock", stream_index(frames),
                             len(frames)), "the radio's copies")
    radio = carried["radio"]
    radio.check(len(frames))
    wait_for(lambda: len(sniffers["radio"].datagrams) == len(radio.forwarded),
             "the tee's copies")
    captured = sniffers["radio"].stop()
    assert captured == radio.forwarded == radio.datagrams, "the radio lost nothing"
    results = {}
    for name, key in (("bond key", key_of(key_file)), ("another key", os.urandom(32))):
        mav = mav2.MAVLink(None)
        mav.signing.secret_key = key
        mav.signing.timestamp = int((time.time() - 1420070400) * 100000)
        mav.robust_parsing = True
        got = []
        for dg in captured:
            got += [m for m in mav.parse_buffer(dg) or [] if m.get_type() != "BAD_DATA"]
        results[name] = (mav.signing.goodsig_count, mav.signing.badsig_count, len(got))
    print(f"\npymavlink on {len(captured)} signed frames ({len(frames)} of the stream, "
          f"{len(radio.markers)} count markers): (good, bad, decoded) {results}")
    assert results["bond key"] == (len(captured), 0, len(captured))
    assert results["another key"][0] == 0 and results["another key"][1] == len(captured)
    for dg in captured:
        assert dg[2] & 1 and dg[-13] == 0xBD, "signed, with the bond's link id"
    assert ground.stop() == 0 and air.stop() == 0


# --- keygen and the start-up warning ---------------------------------------------------------------

def test_keygen_makes_a_key_the_daemon_takes_and_never_overwrites(tmp_path, mavbondctl, mavbond_bin):
    path = tmp_path / "k" / "bond.key"
    path.parent.mkdir()
    r = subprocess.run([mavbondctl, "keygen", "--owner", "nobody", str(path)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    st = path.stat()
    text = path.read_text()
    print(f"\n{r.stdout.strip()}\nmode {oct(st.st_mode & 0o777)}, uid {st.st_uid}")
    assert st.st_mode & 0o777 == 0o600 and st.st_uid == 65534
    assert re.fullmatch(r"[0-9a-f]{64}\n", text)
    again = subprocess.run([mavbondctl, "keygen", str(path)], capture_output=True, text=True)
    assert again.returncode == 73 and "not overwritten" in again.stderr
    assert path.read_text() == text
    other = keygen(mavbondctl, tmp_path / "k" / "other.key")
    assert other.read_text() != text, "random"
    nouser = subprocess.run([mavbondctl, "keygen", "--owner", "no-such-user", str(tmp_path / "x")],
                            capture_output=True, text=True)
    assert nouser.returncode == 67 and not (tmp_path / "x").exists()
    # The daemon reads it (as root here: the owner is no matter), and names the command when
    # the file is missing.
    config = tmp_path / "c.yaml"
    body = (f"endpoints:\n  - {{name: a, type: udp, mode: server, address: {HOST}:{free_port()}, "
            f"bond: b}}\nbonds:\n  - {{name: b, signing: {{key_file: {other}}}}}\n")
    config.write_text(body)
    ok = subprocess.run([mavbond_bin, "--check-config", "-c", str(config)], capture_output=True,
                        text=True)
    assert ok.returncode == 0, ok.stderr
    config.write_text(body.replace(str(other), str(tmp_path / "missing.key")))
    missing = subprocess.run([mavbond_bin, "--check-config", "-c", str(config)],
                             capture_output=True, text=True)
    print(missing.stderr.strip())
    assert missing.returncode == 78
    assert f"make one with: mavbondctl keygen {tmp_path / 'missing.key'}" in missing.stderr


def test_listeners_anyone_may_reach_unsigned_are_named_at_start(tmp_path, key_file, mavbond_bin):
    """--check-config (nothing is bound): a UDP and a TCP server on every interface without
    signing are named; on loopback, with an endpoint's signing or its bond's, they are not."""
    config = tmp_path / "c.yaml"
    config.write_text(
        "endpoints:\n"
        "  - {name: open_udp, type: udp, mode: server, address: 0.0.0.0:14550}\n"
        "  - {name: open_tcp, type: tcp, mode: server, address: '[::]:5760'}\n"
        "  - {name: local, type: udp, mode: server, address: 127.0.0.1:14551}\n"
        f"  - {{name: own, type: udp, mode: server, address: 0.0.0.0:14552, signing: {{key_file: {key_file}}}}}\n"
        f"  - {{name: lax, type: udp, mode: server, address: 0.0.0.0:14553, signing: {{key_file: {key_file}, require: false}}}}\n"
        "  - {name: bonded, type: udp, mode: server, address: 0.0.0.0:14560, bond: vehicle}\n"
        "  - {name: radio, type: udp, mode: client, address: 127.0.0.1:14570, bond: vehicle}\n"
        f"bonds:\n  - {{name: vehicle, signing: {{key_file: {key_file}}}}}\n")
    r = subprocess.run([mavbond_bin, "--check-config", "-c", str(config)], capture_output=True,
                       text=True)
    named = re.findall(r"endpoint '(\w+)' listens on (\S+) without signing", r.stderr)
    print(f"\n{r.stderr.strip()}")
    assert r.returncode == 0
    assert named == [("open_udp", "0.0.0.0:14550"), ("open_tcp", "[::]:5760"),
                     ("lax", "0.0.0.0:14553")]
