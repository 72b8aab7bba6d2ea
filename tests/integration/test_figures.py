"""Every loss figure mavbond shows equals what the links really did.

Two gateways as the shipped pair has them: the air side with an autopilot (the test), a radio
whose transmit budget thins telemetry, a metered LTE link in standby and a third member that
is dead; the ground side with the same three, a GCS and dedup + stats. Each link is a link
emulator (tests/tools/linkemu.py) that records exactly what it dropped, and tees what it
forwarded up (air to ground) to a sniffer, so the datagram index of every count marker is
known: the count a marker carries is its own index in the emulator (the air side wrote every
datagram the emulator received, one frame each), and the frames a link lost between two of
its markers are the emulator's drops between their indices.

The run: the radio loses 3% and is cut for 6 s (the LTE link leaves standby and stays
active: failback_after is longer than the run), the LTE link then loses 1% and is cut for
10 s, the GCS disconnects and comes back from a new port with its sequence numbers from 0.
Judged at the end, from the daemons' status sockets, /metrics and `mavbondctl watch`:
each link's loss (what the far side wrote on it against what arrived) equals the emulator's
drops, a link that never carried anything is down, the LTE link in standby is shown as
standby with the loss of what it carries, the air side's delivered stream lost nothing (no
frame was lost on every link, the GCS reconnect included), and a thinned radio is no failing
radio: the metered link left standby once, for the cut."""
from __future__ import annotations

import json
import os
import random
import re
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from bonding_helpers import tlog, unique_stream
from helpers import HOST, FrameMaker, known_defect, free_port, status_document, udp_client, udp_server
from test_metrics import scrape, tcp_port
from test_standby import Sniffer, Stream, frames_of, msgid, wait_for

NAMED_VALUE_INT = 252
BONDS = [{"name": "vehicle", "tx": "broadcast", "failback_after": "60s"}]


marker_of = tlog.count_marker


class Gcs(threading.Thread):
    """A ground station on the ground gateway's GCS port: a HEARTBEAT every 200 ms from its
    own socket, with its own sequence counter; reconnect() starts over from a new socket (a
    new port) at sequence 0, as a restarted GCS does."""

    def __init__(self, port: int):
        super().__init__(daemon=True)
        self.port, self.stop_flag, self.lock = port, threading.Event(), threading.Lock()
        self.reconnects = 0
        self._open()

    def _open(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((HOST, 0))
        self.sock.setblocking(False)
        self.maker = FrameMaker(255, 190)
        self.seq = 0

    def reconnect(self):
        with self.lock:
            self.sock.close()
            self._open()
            self.reconnects += 1

    def run(self):
        while not self.stop_flag.wait(0.2):
            with self.lock:
                self.maker.mav.seq = self.seq % 256  # pymavlink's pack() leaves it alone
                self.seq += 1
                self.sock.sendto(self.maker.heartbeat(6), (HOST, self.port))
                try:
                    while self.sock.recv(65536):
                        pass
                except (BlockingIOError, OSError):
                    pass

    def stop(self):
        self.stop_flag.set()
        self.join()
        self.sock.close()


def ctl(mavbond_bin: str, sock: Path, *args) -> str:
    r = subprocess.run([str(Path(mavbond_bin).with_name("mavbondctl")), "-s", str(sock), *args],
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    return r.stdout


WATCH_ROW = re.compile(r"^(?P<mark>[* ]) (?P<name>\S+)\s+(?P<bond>\S+)\s+(?P<state>\S+)\s+"
                       r"(?P<loss>\S+)\s+(?P<by>\S+)\s+(?P<rate>\S+)\s+(?P<ago>\S+)$")


def watch_rows(text: str) -> dict:
    rows = {}
    for line in text.splitlines():
        assert len(line) <= 80, f"a watch line past 80 columns: {line!r}"
        m = WATCH_ROW.match(line)
        if m and m["name"] != "LINK":
            rows[m["name"]] = m.groupdict()
    return rows


def stats_link(doc: dict, endpoint: str) -> dict:
    stats = next(f["status"] for f in doc["filters"] if f["plugin"] == "stats")
    (link,) = [l for l in stats["links"] if l["endpoint"] == endpoint]
    return link


def truth(doc: dict, link: str, sniffed: list, dropped: set) -> tuple:
    """What the receiver's figures of `link` must be in its status document `doc`: (expected,
    lost, indices of the first and the last count marker it had). It had the first rx_frames
    frames the emulator forwarded (the tee got them in the same order), every one of them
    written and arrived; lost, what the emulator dropped between the first marker it took and
    the last it had (a loss after that one the next marker tells)."""
    (endpoint,) = [e for e in doc["endpoints"] if e["name"] == link]
    had = sniffed[:endpoint["rx_frames"]]
    assert len(had) == endpoint["rx_frames"], "the tee got less than the receiver"
    counts = [m[0] for m in (marker_of(f) for f in had) if m]
    assert counts, "no count marker came through"
    first, last = counts[0], counts[-1]
    lost = sum(1 for i in dropped if first < i < last)
    return len(had) + lost, lost, (first, last)


def test_every_loss_figure_equals_what_the_emulators_dropped(lab, mavbond_bin, tmp_path):
    p = {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "g_sat", "e_radio", "e_lte",
                                  "e_sat", "s_radio", "s_lte")}
    m_port = tcp_port()
    g_sock, a_sock = tmp_path / "ground.sock", tmp_path / "air.sock"
    filters = [{"plugin": "dedup", "bonds": ["vehicle"], "window": "2s"}, {"plugin": "stats"}]
    ground = lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                          udp_server("lte", p["g_lte"], bond="vehicle", cost="metered"),
                          udp_server("sat", p["g_sat"], bond="vehicle"),
                          udp_server("gcs", p["gcs"])],
                         bonds=BONDS, filters=filters, name="ground", status_socket=str(g_sock),
                         metrics=f"{{listen: {HOST}:{m_port}}}")
    sniffers = {}
    for link in ("radio", "lte"):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        sock.bind((HOST, p["s_" + link]))
        sniffers[link] = Sniffer(sock)
        sniffers[link].start()
    emu = lab.emu_group([
        dict(name="radio", listen_port=p["e_radio"], forward_ports=[p["g_radio"], p["s_radio"]],
             seed=51, up_loss="3%", delay="20ms", outage="6s+6s"),
        dict(name="lte", listen_port=p["e_lte"], forward_ports=[p["g_lte"], p["s_lte"]],
             seed=52, up_loss="1%", delay="40ms", outage="16s+10s"),
        dict(name="sat", listen_port=p["e_sat"], forward_ports=p["g_sat"], seed=53, loss="100%"),
    ], name="figures")
    air = lab.gateway([udp_server("ap", p["ap"]),
                       # about half of what the autopilot sends fits: the budget thins telemetry
                       udp_client("radio", p["e_radio"], bond="vehicle", tx_rate="4kB/s"),
                       udp_client("lte", p["e_lte"], bond="vehicle", cost="metered"),
                       udp_client("sat", p["e_sat"], bond="vehicle")],
                      bonds=BONDS, filters=filters, name="air", status_socket=str(a_sock))
    gcs = Gcs(p["gcs"])
    gcs.start()
    frames = unique_stream(32, seed=21)
    stream = Stream(lab.sock(), (HOST, p["ap"]), frames)
    stream.start()
    t0 = emu.t_start

    # In standby (before the radio cut): the LTE link carries control only, shown as standby
    # with the loss of what it carries; the thinned radio is healthy.
    wait_for(lambda: time.monotonic() - t0 > 4.5, "standby to settle")
    standby_watch = ctl(mavbond_bin, g_sock, "watch", "--count", "1")
    # Mid-stream, between two markers: the figures count the frames since the last one too.
    mid_doc = status_document(g_sock)
    sb = status_document(a_sock)["bonds"][0]["standby"]
    assert sb["state"] == "standby" and sb["to_active"] == 0, sb
    wait_for(lambda: time.monotonic() - t0 > 14, "the GCS reconnect time")
    gcs.reconnect()
    # During the LTE cut: the LTE link is down.
    wait_for(lambda: time.monotonic() - t0 > 22, "the LTE cut")
    cut_watch = ctl(mavbond_bin, g_sock, "watch", "--count", "1")
    stream.join()  # the whole stream sent
    wait_for(lambda: time.monotonic() - t0 > 34, "the last markers after the stream")

    # watch, /metrics and the status read the same markers when no marker came in between:
    # two status documents that agree on every link's figures around them say so.
    for _ in range(20):
        ground_doc = status_document(g_sock)
        metrics = scrape(m_port)
        final_watch = ctl(mavbond_bin, g_sock, "watch", "--count", "1")
        again = status_document(g_sock)
        if all(stats_link(ground_doc, l) == stats_link(again, l) for l in ("radio", "lte")):
            break
    else:
        raise AssertionError("a marker came between every two readings")
    air_doc = status_document(a_sock)
    status_text = ctl(mavbond_bin, g_sock, "status")
    emu.counters_now()  # flushes its drop logs
    time.sleep(0.5)     # the sniffers have what the emulator forwarded by then
    gcs.stop()
    print(f"\n[figures] ground watch in standby:\n{standby_watch}\n[figures] during the LTE cut:\n"
          f"{cut_watch}\n[figures] at the end:\n{final_watch}\n{status_text}")

    rows = {"standby": watch_rows(standby_watch), "cut": watch_rows(cut_watch),
            "final": watch_rows(final_watch)}
    table = []
    for link in ("radio", "lte"):
        fig = stats_link(ground_doc, link)
        assert fig["basis"] == "markers", fig
        sniffed = list(sniffers[link].frames)
        expected, lost, (first, last) = truth(ground_doc, link, sniffed, emu.dropped(link, "up"))
        mid = stats_link(mid_doc, link)
        mid_truth = truth(mid_doc, link, sniffed, emu.dropped(link, "up"))
        print(f"[figures] ground {link} mid-stream: expected {mid['expected']}, lost "
              f"{mid['lost']}; the emulator: {mid_truth[0]} written up to the last frame in, "
              f"{mid_truth[1]} dropped up to the last marker")
        assert (mid["expected"], mid["lost"]) == mid_truth[:2], (link, mid, mid_truth)
        # Every marker carried its own index in the emulator: the frames written before it.
        counts = [m[0] for m in (marker_of(f) for f in sniffed) if m]
        kept = sorted(set(range(max(counts) + 1)) - emu.dropped(link, "up"))
        index_of = {}
        k = 0
        for f in sniffed:
            if k < len(kept):
                index_of[id(f)] = kept[k]
            k += 1
        for f in sniffed:
            m = marker_of(f)
            if m and id(f) in index_of:
                assert m[0] == index_of[id(f)], (link, m[0], index_of[id(f)])
        pct = 100.0 * lost / fig["expected"]
        served_exp = metrics["samples"][("mavbond_stats_link_expected_frames_total",
                                         (("basis", "markers"), ("bond", "vehicle"),
                                          ("filter", "stats"), ("link", link)))]
        served_rec = metrics["samples"][("mavbond_stats_link_received_frames_total",
                                         (("basis", "markers"), ("bond", "vehicle"),
                                          ("filter", "stats"), ("link", link)))]
        table.append((link, fig["expected"], lost, fig["lost"], pct, fig["loss_pct"],
                      served_exp - served_rec, rows["final"][link]["loss"]))
        assert (fig["expected"], fig["lost"]) == (expected, lost), (link, fig, lost, first, last)
        assert abs(fig["loss_pct"] - pct) < 0.0006, (fig, pct)
        assert served_exp == fig["expected"] and served_exp - served_rec == lost
        # watch: the same figure, and what it is read from
        assert rows["final"][link]["loss"] == f"{pct:.2f}%", rows["final"][link]
        assert rows["final"][link]["by"] == "markers"
    for name, exp, lost, shown, pct, shown_pct, served, watched in table:
        print(f"[figures] ground {name}: expected {exp}, emulator dropped {lost} ({pct:.3f}%), "
              f"status {shown} ({shown_pct:.3f}%), /metrics {served:.0f}, watch {watched}")

    # The dead link: down, no figure (nothing was ever expected on it).
    for when in ("standby", "cut", "final"):
        assert rows[when]["sat"]["state"] == "down" and rows[when]["sat"]["loss"] == "-", rows[when]
    # Standby: the LTE link shown as standby, its loss that of what it carries.
    assert rows["standby"]["lte"]["state"] == "standby", rows["standby"]
    assert rows["standby"]["radio"]["state"] == "up", rows["standby"]
    # The LTE cut: the LTE link down while it lasts.
    assert rows["cut"]["lte"]["state"] == "down", rows["cut"]
    assert rows["final"]["lte"]["state"] == "up" and rows["final"]["radio"]["state"] == "up"
    # The ground's state in /metrics says the same.
    for link, state in (("radio", "up"), ("lte", "up"), ("sat", "down")):
        assert metrics["samples"][("mavbond_endpoint_state", (
            ("bond", "vehicle"), ("endpoint", link), ("kind", "udp-server"), ("state", state)))] == 1

    # A thinned radio is no failing one: the metered link left standby once, for the cut.
    sb = air_doc["bonds"][0]["standby"]
    air_radio = next(e for e in air_doc["endpoints"] if e["name"] == "radio")
    thinned = air_radio["tx_budget"]["telemetry"]["thinned"]
    print(f"[figures] air radio budget thinned {thinned} telemetry frames; air standby {json.dumps(sb)}")
    assert thinned > 1000, "the budget did not thin the radio"
    assert sb["to_active"] == 1 and sb["state"] == "active", sb

    # Ground to air: the air side's figures of the two links equal the emulators' drops (all
    # in the cuts, between markers), and its delivered stream lost nothing, GCS reconnect and
    # all: no frame was lost on every link.
    for link in ("radio", "lte"):
        fig = stats_link(air_doc, link)
        dropped = len(emu.dropped(link, "down"))
        print(f"[figures] air {link}: expected {fig['expected']}, lost {fig['lost']}, emulator "
              f"dropped {dropped}")
        assert fig["basis"] == "markers" and fig["lost"] == dropped, (fig, dropped)
    air_bond = next(f["status"] for f in air_doc["filters"] if f["plugin"] == "stats")["bonds"][0]
    print(f"[figures] air bond: delivered {air_bond['delivered']}, lost "
          f"{air_bond['delivered_lost']} ({air_bond['delivered_loss_pct']:.3f}%), GCS reconnects "
          f"{gcs.reconnects}")
    assert air_bond["delivered_lost"] == 0, air_bond


# --- the delivered loss, where the air side thins nothing ----------------------------------

def test_the_delivered_loss_is_what_every_link_lost(lab, mavbond_bin, tmp_path):
    """An air side that hands every frame to both links (no budget): the ground's delivered
    loss is exactly the vehicle's frames that neither link's emulator forwarded (its tee says
    what it did), random loss on each and a second when both are cut included."""
    p = {k: free_port() for k in ("ap", "g_radio", "g_lte", "e_radio", "e_lte", "s_radio", "s_lte")}
    g_sock = tmp_path / "ground.sock"
    filters = [{"plugin": "dedup", "bonds": ["vehicle"]}, {"plugin": "stats"}]
    bonds = [{"name": "vehicle", "tx": "broadcast"}]
    lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                 udp_server("lte", p["g_lte"], bond="vehicle")],
                bonds=bonds, filters=filters, name="ground", status_socket=str(g_sock))
    sniffers = {}
    for link in ("radio", "lte"):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        sock.bind((HOST, p["s_" + link]))
        lab.socks.append(sock)
        sniffers[link] = Sniffer(sock)
        sniffers[link].start()
    lab.emu_group([
        dict(name="radio", listen_port=p["e_radio"], forward_ports=[p["g_radio"], p["s_radio"]],
             seed=91, up_loss="5%", delay="20ms", outage="4s+2s"),
        dict(name="lte", listen_port=p["e_lte"], forward_ports=[p["g_lte"], p["s_lte"]],
             seed=92, up_loss="5%", delay="60ms", outage="5s+2s"),
    ], name="both")
    lab.gateway([udp_server("ap", p["ap"]),
                 udp_client("radio", p["e_radio"], bond="vehicle"),
                 udp_client("lte", p["e_lte"], bond="vehicle")],
                bonds=bonds, filters=filters, name="air")
    frames = unique_stream(10, seed=25)
    stream = Stream(lab.sock(), (HOST, p["ap"]), frames)
    stream.start()
    stream.join()
    time.sleep(3.0)  # the links carried what they still held; every hole waited long enough
    doc = status_document(g_sock)
    carried = {bytes(f) for link in ("radio", "lte") for f in sniffers[link].stop()}
    lost = sum(1 for _, f in frames if bytes(f) not in carried)
    bond = next(f["status"] for f in doc["filters"] if f["plugin"] == "stats")["bonds"][0]
    print(f"\n[delivered] {len(frames)} frames sent, {lost} on no link; the ground: delivered "
          f"{bond['delivered']}, lost {bond['delivered_lost']} ({bond['delivered_loss_pct']:.3f}%)")
    assert lost > 20, "too few frames lost on both links to tell"
    assert bond["delivered_lost"] == lost, bond
    assert abs(bond["delivered_loss_pct"] - 100.0 * lost / len(frames)) < 0.0006, bond


# --- a GCS that quits and comes back --------------------------------------------------------

@known_defect(21, "under the whole scripts/test (2 cores, four runs side by side) the ASan daemon's figures after a GCS restart miss the links' truth (passes alone)")
def test_a_gcs_that_quit_and_came_back_is_no_loss(lab, mavbond_bin, tmp_path):
    """MAVProxy's way, through the shipped pair's radio and metered LTE: a GCS quits at
    sequence 192 and a new one starts 6 s later at 0, a step of 64 forward that reads as 63
    frames lost. The emulators drop nothing and the links kept bringing the ground's own
    frames meanwhile: the air side's delivered stream lost nothing."""
    p = {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "e_radio", "e_lte")}
    a_sock = tmp_path / "air.sock"
    filters = [{"plugin": "dedup", "bonds": ["vehicle"]}, {"plugin": "stats"}]
    bonds = [{"name": "vehicle", "tx": "broadcast"}]
    lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                 udp_server("lte", p["g_lte"], bond="vehicle", cost="metered"),
                 udp_server("gcs", p["gcs"])], bonds=bonds, filters=filters, name="ground")
    emu = lab.emu_group([dict(name="radio", listen_port=p["e_radio"], forward_ports=p["g_radio"],
                              seed=81, delay="20ms"),
                         dict(name="lte", listen_port=p["e_lte"], forward_ports=p["g_lte"],
                              seed=82, delay="40ms")], name="quiet")
    lab.gateway([udp_server("ap", p["ap"]),
                 udp_client("radio", p["e_radio"], bond="vehicle"),
                 udp_client("lte", p["e_lte"], bond="vehicle", cost="metered")],
                bonds=bonds, filters=filters, name="air", status_socket=str(a_sock))
    vehicle = Stream(lab.sock(), (HOST, p["ap"]), unique_stream(14, seed=24))
    vehicle.start()

    def gcs(first: int, last: int, every: float):
        sock = lab.sock()
        maker = FrameMaker(255, 230)
        for seq in range(first, last + 1):
            maker.mav.seq = seq  # pymavlink's pack() leaves it alone
            sock.sendto(maker.heartbeat(6), (HOST, p["gcs"]))
            time.sleep(every)

    wait_for(lambda: vehicle.sent > 100, "the vehicle's stream")
    gcs(0, 192, 0.02)   # the first GCS, then it quits
    time.sleep(6.0)
    gcs(0, 20, 0.2)     # the next one, its counter from 0
    vehicle.join()
    time.sleep(2.0)     # every hole has waited long enough
    doc = status_document(a_sock)
    drops = {link: emu.counters(link)["down"] for link in ("radio", "lte")}
    bond = next(f["status"] for f in doc["filters"] if f["plugin"] == "stats")["bonds"][0]
    renumber = doc["bonds"][0].get("renumber")
    print(f"\n[quiet] air bond: delivered {bond['delivered']}, lost {bond['delivered_lost']}; "
          f"the emulators down: {drops}; renumbering {renumber}")
    assert all(d["forwarded"] == d["received"] for d in drops.values()), drops
    assert bond["delivered_lost"] == 0, bond


# --- a NAT rebinding ------------------------------------------------------------------------

@pytest.mark.parametrize("signed", [True, False], ids=["signed", "unsigned"])
def test_a_peer_a_nat_moved_is_one_account_in_every_figure(lab, mavbond_bin, tmp_path, signed):
    """The ground hears the air side's LTE link from a new port mid-stream, and its account goes
    on from the old one's: in a signed bond the new address is taken at once (its first
    datagram, which may hold a count marker, is read before the move is known); unsigned, the
    move is judged after the old address fell quiet, by which time the new one has taken count
    markers of its own. Either way the link's loss in the status socket and in /metrics (one
    series per endpoint, present and past peers) equals the emulator's drops over the whole
    run, counted once."""
    from linkemu import LinkGroup
    from test_signed_bond import keygen, signing

    p = {k: free_port() for k in ("ap", "gcs", "g_lte", "s_lte")}
    m_port = tcp_port()
    g_sock = tmp_path / "ground.sock"
    bonds = [{"name": "vehicle", "tx": "broadcast"}]
    if signed:
        key = keygen(str(Path(mavbond_bin).with_name("mavbondctl")), tmp_path / "bond.key")
        bonds[0]["signing"] = signing(key, ["lte"])
    filters = [{"plugin": "dedup", "bonds": ["vehicle"]}, {"plugin": "stats"}]
    ground = lab.gateway([udp_server("lte", p["g_lte"], bond="vehicle"), udp_server("gcs", p["gcs"])],
                         bonds=bonds, filters=filters, name="ground", status_socket=str(g_sock),
                         metrics=f"{{listen: {HOST}:{m_port}}}")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    sock.bind((HOST, p["s_lte"]))
    lab.socks.append(sock)
    sniffer = Sniffer(sock)
    sniffer.start()
    emu = LinkGroup([dict(name="lte", listen=f"{HOST}:0",
                          forward=[f"{HOST}:{p['g_lte']}", f"{HOST}:{p['s_lte']}"], seed=71,
                          up_loss="2%", delay="20ms")], record_drops=True, out=open(os.devnull, "w"))
    emu.start()
    try:
        link = emu.link("lte")
        lab.gateway([udp_server("ap", p["ap"]),
                     udp_client("lte", link.listen_addr[1], bond="vehicle")],
                    bonds=bonds, filters=filters, name="air")
        stream = Stream(lab.sock(), (HOST, p["ap"]), unique_stream(8, seed=23))
        stream.start()
        wait_for(lambda: stream.sent > len(stream.frames) // 2, "half the stream")
        emu.request_rebind("lte")
        ground.wait_log(r"a NAT rebinding", timeout=10)
        stream.join()
        time.sleep(2.5)  # the last markers after the stream
        for _ in range(20):
            doc = status_document(g_sock)
            metrics = scrape(m_port)
            again = status_document(g_sock)
            if stats_link(doc, "lte") == stats_link(again, "lte"):
                break
        else:
            raise AssertionError("a frame came between every two readings")
        time.sleep(0.3)  # the tee has what the emulator forwarded by then
        dropped = {r["index"] for r in link.drops()
                   if r["direction"] == "up" and r["reason"] != "corrupted"}
    finally:
        emu.stop()
    expected, lost, _ = truth(doc, "lte", sniffer.stop(), dropped)
    fig = stats_link(doc, "lte")
    labels = (("basis", "markers"), ("bond", "vehicle"), ("filter", "stats"), ("link", "lte"))
    served_exp = metrics["samples"][("mavbond_stats_link_expected_frames_total", labels)]
    served_rec = metrics["samples"][("mavbond_stats_link_received_frames_total", labels)]
    served_ratio = metrics["samples"][("mavbond_stats_link_loss_ratio", labels)]
    print(f"\n[rebind] the emulator: {expected} written up to the last frame in, {lost} dropped; "
          f"status {fig['name']}: expected {fig['expected']}, lost {fig['lost']}; /metrics: "
          f"expected {served_exp:.0f}, received {served_rec:.0f}, ratio {served_ratio:.5f}")
    assert fig["name"] == f"lte@{HOST}:{link.source_addr[1]}", "the new address took over"
    assert (fig["expected"], fig["lost"]) == (expected, lost), (fig, expected, lost)
    assert (served_exp, served_exp - served_rec) == (expected, lost)
    assert abs(100 * served_ratio - fig["loss_pct"]) < 0.0006


# --- a SiK radio pair on ptys -------------------------------------------------------------

def split_frames(buf: bytearray) -> list:
    """The whole MAVLink frames at the front of `buf`, taken out of it (mavbond and the radios
    write nothing else)."""
    out = []
    while len(buf) >= 3:
        n = (12 + buf[1] + (13 if buf[2] & 1 else 0)) if buf[0] == 0xFD else 8 + buf[1]
        if len(buf) < n:
            break
        out.append(bytes(buf[:n]))
        del buf[:n]
    return out


class SikRadios(threading.Thread):
    """Two SiK radios, one on each gateway's pty: what a gateway writes to its radio comes in
    over a 57600-baud line (LINE bytes a second), goes into that radio's transmit buffer
    (BUFFER bytes), is aired at AIR bytes a second and comes out of the other radio; a frame
    that does not fit the buffer is lost, and so is one in fifty in the air (seeded). Each
    radio puts its own RADIO_STATUS (MAVLink 1, system 51, component 68: its free buffer) into
    its side's stream once a second, as SiK does. `taken[side]`: every frame a radio took from
    its gateway, in order, with whether it was lost.

    The model keeps its own clock of the line and the air: a pty has no baud rate, so bytes a
    stalled model (a loaded machine) reads at once came in one after another at the line's
    rate since its last read, and the buffer drained meanwhile; taken as one burst at the
    instant of the read, they overflowed a buffer no real radio would have."""
    BUFFER, AIR, AIR_LOSS, LINE = 4096, 3600, 0.02, 5760

    def __init__(self, air, ground):
        super().__init__(daemon=True)
        self.ptys = {"air": air, "ground": ground}
        self.stop_flag = threading.Event()
        self.pending = {s: bytearray() for s in self.ptys}
        self.queue = {s: [] for s in self.ptys}
        self.level = {s: 0 for s in self.ptys}
        self.taken = {s: [] for s in self.ptys}
        self.reports = {s: 0 for s in self.ptys}
        self.fm = FrameMaker(51, 68, v1=True)
        self.rng = random.Random("sik")

    def run(self):
        other = {"air": "ground", "ground": "air"}
        last = next_report = time.monotonic()
        credit = {s: 0.0 for s in self.ptys}
        aired_to = {s: last for s in self.ptys}   # the air simulated up to here
        wire_to = {s: last for s in self.ptys}    # the line's last byte came in here

        def air(side, t):
            q = self.queue[side]
            if t <= aired_to[side]:
                return
            credit[side] = min(credit[side] + (t - aired_to[side]) * self.AIR, self.BUFFER)
            aired_to[side] = t
            while q and len(q[0]) <= credit[side]:
                f = q.pop(0)
                credit[side] -= len(f)
                self.level[side] -= len(f)
                self.ptys[other[side]].write_all(f)
            if not q:
                credit[side] = 0.0

        while not self.stop_flag.is_set():
            now = time.monotonic()
            for side, pty in self.ptys.items():
                try:
                    self.pending[side] += os.read(pty.master, 65536)
                except (BlockingIOError, OSError):
                    pass
                for f in split_frames(self.pending[side]):
                    # In at the line's rate, from the last read on at the earliest (the
                    # line may run ahead of the model's clock: a tty's output queue).
                    t = max(wire_to[side], last) + len(f) / self.LINE
                    wire_to[side] = t
                    air(side, t)
                    lost = (self.level[side] + len(f) > self.BUFFER or
                            self.rng.random() < self.AIR_LOSS)
                    self.taken[side].append((f, lost))
                    if not lost:
                        self.queue[side].append(f)
                        self.level[side] += len(f)
                air(side, now)
            last = now
            if now >= next_report:
                for side, pty in self.ptys.items():
                    txbuf = round(100 * (self.BUFFER - self.level[side]) / self.BUFFER)
                    pty.write_all(self.fm.pack(self.fm.mod.MAVLink_radio_status_message(
                        150, 140, txbuf, 40, 35, 0, 0)))
                    self.reports[side] += 1
                next_report += 1.0
            time.sleep(0.005)


@known_defect(21, "under the whole scripts/test from a clean clone (2 CPUs saturated, 2026-12-02) the metered link went active, plain and under ASan: the air side took the radio for failing; in the same run the operator stage's pty models stood still for seconds in the kernel (tests/README), the likely cause here too, not shown for this model")
def test_a_saturated_sik_radio_that_loses_nothing_is_not_failing(lab, pty_pair, tmp_path):
    """The shipped pair's radio: a SiK pair on ptys (3,600 B/s in the air, a 4 KiB buffer),
    `radio_status: sik` on the air side only (as the example has it), a metered LTE link, an
    autopilot stream of ~124 frames/s that the radio cannot carry. The air side's budget
    follows the radio's reports; the ground side's radio puts its own RADIO_STATUS into the
    stream, which is no frame the air side wrote. The ground's figure of the radio equals
    what the radio lost of what it was given, and the metered link stays in standby: a
    saturated radio that delivers what it is given is not failing."""
    air_pty, ground_pty = pty_pair(), pty_pair()
    p = {k: free_port() for k in ("ap", "gcs", "g_lte", "e_lte")}
    g_sock, a_sock = tmp_path / "ground.sock", tmp_path / "air.sock"
    filters = [{"plugin": "dedup", "bonds": ["vehicle"], "window": "2s"}, {"plugin": "stats"}]
    bonds = [{"name": "vehicle", "tx": "broadcast"}]
    ground = lab.gateway([{"name": "radio", "type": "uart", "device": ground_pty.path,
                           "baud": 57600, "bond": "vehicle"},
                          udp_server("lte", p["g_lte"], bond="vehicle", cost="metered"),
                          udp_server("gcs", p["gcs"])],
                         bonds=bonds, filters=filters, name="ground", status_socket=str(g_sock))
    emu = lab.emu_group([dict(name="lte", listen_port=p["e_lte"], forward_ports=p["g_lte"],
                              seed=61, delay="40ms")], name="lte")
    air = lab.gateway([udp_server("ap", p["ap"]),
                       {"name": "radio", "type": "uart", "device": air_pty.path, "baud": 57600,
                        "bond": "vehicle", "radio_status": "sik"},
                       udp_client("lte", p["e_lte"], bond="vehicle", cost="metered")],
                      bonds=bonds, filters=filters, name="air", status_socket=str(a_sock))
    for g in (ground, air):
        g.wait_log(r"\[uart:radio\] .* open at 57600 baud")
    radios = SikRadios(air_pty, ground_pty)
    radios.start()
    gcs = Gcs(p["gcs"])
    gcs.start()
    frames = unique_stream(15, seed=22)
    stream = Stream(lab.sock(), (HOST, p["ap"]), frames)
    stream.start()
    # Standby as the stream still flows (once it stops the radio is silent, and the metered
    # link rightly leaves standby).
    wait_for(lambda: stream.sent >= len(frames) - 124, "the stream's last second")
    sb = status_document(a_sock)["bonds"][0]["standby"]
    stream.join()
    time.sleep(2.5)  # the radio airs what it holds; the last markers follow it
    for _ in range(20):
        ground_doc = status_document(g_sock)
        taken = list(radios.taken["air"])
        again = status_document(g_sock)
        if stats_link(ground_doc, "radio") == stats_link(again, "radio"):
            break
    air_doc = status_document(a_sock)
    radios.stop_flag.set()
    radios.join()
    gcs.stop()
    emu.stop()

    fig = stats_link(ground_doc, "radio")
    assert fig["basis"] == "markers", fig
    # A marker's count is its place among the frames the radio took (the air side wrote all
    # of them to its UART, nothing else). The ground had the first of those the radio
    # delivered, as many as it counts arrived (its own radio's reports are none of them); what
    # the radio lost between the first marker the ground took and the last it had is the
    # truth.
    markers = [(i, m[0]) for i, (f, lost) in enumerate(taken) if not lost and (m := marker_of(f))]
    assert all(i == count for i, count in markers), markers[:5]
    had = [i for i, (f, lost) in enumerate(taken) if not lost][:fig["expected"] - fig["lost"]]
    first, last = markers[0][0], max(i for i, _ in markers if i <= had[-1])
    lost = sum(1 for i in range(first + 1, last) if taken[i][1])
    lost_all = sum(1 for _, l in taken if l)
    budget = next(e for e in air_doc["endpoints"] if e["name"] == "radio")["tx_budget"]
    ground_radio = next(e for e in ground_doc["endpoints"] if e["name"] == "radio")
    print(f"\n[sik] {len(frames)} frames offered; the air radio took {len(taken)}, lost "
          f"{lost_all} (a full buffer, the air; {lost} between the markers); the ground: expected "
          f"{fig['expected']}, lost {fig['lost']} ({fig['loss_pct']:.3f}%), its own radio's "
          f"reports {radios.reports['ground']} (not counted), rx_frames "
          f"{ground_radio['rx_frames']}; air budget now {budget['rate']} B/s, telemetry thinned "
          f"{budget['telemetry']['thinned']}; air standby {json.dumps(sb)}")
    assert lost > radios.reports["ground"], "too few losses to tell a radio's report from a frame"
    assert fig["lost"] == lost, (fig, lost)
    assert budget["telemetry"]["thinned"] > len(frames) // 10, "the radio was not saturated"
    assert sb["state"] == "standby" and sb["to_active"] == 0, sb
