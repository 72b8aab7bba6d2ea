"""Link events and mavbond's own identity, end to end: a real mavbond, a bond of two UDP links
fed by test senders (a vehicle's frames at 20 Hz), and a "GCS" on a UDP endpoint that decodes
what it receives with pymavlink (which checks every CRC). Stopping a sender silences a link.

Timing: each wait is bounded and ends by itself; the bounds are generous (seconds) where a
slow machine can only make things later, and the lower bounds (a message not before its rule
allows it) are exact minus one 100 ms tick."""
from __future__ import annotations

import re
import time
from typing import List, Optional

import pytest

from helpers import HOST, FrameMaker, free_port, mav2, udp_server
from bonding_helpers import Gateway, Receiver, Ticker, tlog, udp_sock

TICK = 0.1          # the monitor's period
SEV = {"WARNING": 4, "NOTICE": 5, "CRITICAL": 2}


def decode(frame: bytes):
    """pymavlink's decode of one frame (raises on a bad CRC)."""
    return mav2.MAVLink(None).decode(bytearray(frame))


class Lab:
    """gcs (UDP server) + radio and lte (UDP servers, bond `telemetry`) in one mavbond."""

    def __init__(self, binary, workdir, plugin_dir, tx="broadcast", filters=(), **top):
        self.gcs_port, self.radio_port, self.lte_port = free_port(), free_port(), free_port()
        eps = [udp_server("gcs", self.gcs_port),
               udp_server("radio", self.radio_port, bond="telemetry"),
               udp_server("lte", self.lte_port, bond="telemetry")]
        self.g = Gateway(binary, workdir, eps, bonds=[{"name": "telemetry", "tx": tx}],
                         filters=filters, plugin_dir=plugin_dir, **top).start()
        self.socks = {name: udp_sock() for name in ("gcs", "radio", "lte")}
        self.makers = {"radio": FrameMaker(1, 1), "lte": FrameMaker(1, 1)}
        self.tickers = {}
        # The link senders' own sockets also get what mavbond sends down each link.
        self.link_rx = {name: Receiver(self.socks[name]) for name in ("radio", "lte")}
        self.gcs = Receiver(self.socks["gcs"], hello_port=self.gcs_port)

    def start_link(self, name):
        port = self.radio_port if name == "radio" else self.lte_port
        maker = self.makers[name]
        self.tickers[name] = Ticker(self.socks[name], (HOST, port),
                                    lambda k: maker.attitude(int(time.monotonic() * 1000)), 0.05)

    def stop_link(self, name) -> float:
        self.tickers.pop(name).stop()
        return time.monotonic()

    def statustexts(self, rx: Optional[Receiver] = None) -> List[tuple]:
        """(arrival time, severity, text, sysid, compid, seq) of every STATUSTEXT received."""
        out = []
        for t, f in list((rx or self.gcs).frames):
            if tlog.msgid(f) == 253:
                m = decode(f)
                out.append((t, m.severity, m.text, m.get_srcSystem(), m.get_srcComponent(),
                            m.get_seq()))
        return out

    def wait_statustexts(self, count: int, timeout: float) -> List[tuple]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            got = self.statustexts()
            if len(got) >= count:
                return got
            time.sleep(0.02)
        raise AssertionError(f"expected {count} STATUSTEXT, got {self.statustexts()}; log:\n"
                             f"{self.g.log()}")

    def close(self):
        for t in self.tickers.values():
            t.stop()
        for r in [self.gcs, *self.link_rx.values()]:
            r.stop()
        self.g.kill()
        for s in self.socks.values():
            s.close()


@pytest.fixture
def make_lab(mavbond_bin, tmp_path, plugin_dir):
    labs = []

    def make(**kw):
        lab = Lab(mavbond_bin, tmp_path, plugin_dir, **kw)
        labs.append(lab)
        return lab

    yield make
    for lab in labs:
        lab.close()


def test_link_lost_back_and_last_link_lost(make_lab):
    """silent_after 500ms, min_interval 2s. lte stops: WARNING "lost (1 of 2 up)" from
    1/191 between 0.5 s and 3 s later; lte resumes: NOTICE "back", not before 2 s after the
    first message; lte then radio stop: WARNING, then CRITICAL "0 of 2 up". Each event is
    logged once."""
    lab = make_lab(identity="{sysid: 1, compid: 191}",
                   link_events="{silent_after: 500ms, min_interval: 2s}")
    lab.start_link("radio")
    lab.start_link("lte")
    time.sleep(1.5)
    assert lab.statustexts() == [], "links coming up for the first time are not news"

    stopped = lab.stop_link("lte")
    (t1, sev, text, sysid, compid, seq1), = lab.wait_statustexts(1, timeout=5)
    assert (sev, text) == (SEV["WARNING"], "mavbond: link lte lost (bond telemetry, 1 of 2 up)")
    assert (sysid, compid) == (1, 191)
    assert t1 - stopped >= 0.5 - TICK, "reported before the link was silent for silent_after"
    assert t1 - stopped < 3.0

    resumed = time.monotonic()
    lab.start_link("lte")
    got = lab.wait_statustexts(2, timeout=6)
    t2, sev, text, _, _, seq2 = got[1]
    assert (sev, text) == (SEV["NOTICE"], "mavbond: link lte back (bond telemetry, 2 of 2 up)")
    assert t2 - t1 >= 2.0 - TICK, "min_interval per link"
    assert t2 - resumed < 5.0
    assert seq2 == (seq1 + 1) % 256, "mavbond's own sequence counter"

    time.sleep(2.2)  # past min_interval for lte
    lab.stop_link("lte")
    got = lab.wait_statustexts(3, timeout=5)
    assert got[2][1:3] == (SEV["WARNING"], "mavbond: link lte lost (bond telemetry, 1 of 2 up)")
    lab.stop_link("radio")
    got = lab.wait_statustexts(4, timeout=5)
    assert got[3][1:3] == (SEV["CRITICAL"], "mavbond: radio lost (telemetry 0/2 up)")
    time.sleep(1.0)
    assert len(lab.statustexts()) == 4
    log = lab.g.log()
    assert len(re.findall(r"link event: link lte lost", log)) == 2
    assert len(re.findall(r"link event: link lte back", log)) == 1
    assert len(re.findall(r"link event: link radio lost", log)) == 1


def test_active_link_switch(make_lab):
    """tx: active with linkswitch (switch_after 500ms): radio is active; radio stops:
    the GCS gets "radio lost" and "bond telemetry switched to lte" (WARNING both); after
    the switch mavbond's own frames go down lte only (the bond's tx policy), never radio."""
    lab = make_lab(tx="active",
                   filters=[{"plugin": "linkswitch", "bonds": ["telemetry"],
                             "switch_after": "500ms", "priority": ["radio", "lte"]}],
                   identity="{sysid: 1, compid: 191}",
                   link_events="{silent_after: 500ms, min_interval: 2s}")
    lab.start_link("radio")
    time.sleep(0.3)
    lab.start_link("lte")
    time.sleep(1.5)
    lab.g.wait_log(r"link event: bond telemetry: active link radio", timeout=5)
    assert lab.statustexts() == []
    lab.stop_link("radio")
    got = lab.wait_statustexts(2, timeout=6)
    texts = sorted((sev, text) for _, sev, text, *_ in got)
    assert texts == sorted([(SEV["WARNING"], "mavbond: bond telemetry switched to lte"),
                            (SEV["WARNING"], "mavbond: radio lost (telemetry 1/2 up)")]), got
    time.sleep(0.5)
    on_lte = [x[2] for x in lab.statustexts(lab.link_rx["lte"])]
    on_radio = [x[2] for x in lab.statustexts(lab.link_rx["radio"])]
    assert "mavbond: bond telemetry switched to lte" in on_lte
    assert not any("switched" in t for t in on_radio), on_radio


def test_flapping_link_is_rate_limited(make_lab):
    """silent_after 300ms, min_interval 5s. lte stops (message 1: lost), then flaps twice
    within the next 3 s and ends silent: no message (the GCS was told "lost" and it is lost).
    Then lte resumes (message 2: back, at once: 5 s have passed), flaps once within the
    interval and ends up: nothing more. Exactly 2 messages; the log has every change."""
    lab = make_lab(identity="{sysid: 1, compid: 191}",
                   link_events="{silent_after: 300ms, min_interval: 5s}")
    lab.start_link("radio")
    lab.start_link("lte")
    time.sleep(1.0)
    lab.stop_link("lte")
    (t1, *_), = lab.wait_statustexts(1, timeout=5)
    for _ in range(2):
        lab.start_link("lte")
        time.sleep(0.4)
        lab.stop_link("lte")
        time.sleep(0.8)   # > silent_after + a tick: seen lost
    while time.monotonic() < t1 + 5.5:
        time.sleep(0.05)
    assert len(lab.statustexts()) == 1, lab.statustexts()

    lab.start_link("lte")
    got = lab.wait_statustexts(2, timeout=3)
    t2 = got[1][0]
    assert got[1][2] == "mavbond: link lte back (bond telemetry, 2 of 2 up)"
    lab.stop_link("lte")
    time.sleep(0.8)
    lab.start_link("lte")
    while time.monotonic() < t2 + 5.5:
        time.sleep(0.05)
    got = lab.statustexts()
    assert [x[2] for x in got] == ["mavbond: link lte lost (bond telemetry, 1 of 2 up)",
                                   "mavbond: link lte back (bond telemetry, 2 of 2 up)"]
    log = lab.g.log()
    assert len(re.findall(r"link event: link lte lost", log)) == 4
    assert len(re.findall(r"link event: link lte back", log)) == 4


def test_heartbeat_period_ids_and_type(make_lab):
    """identity heartbeat 500ms as 42/191: for 4 s the GCS gets HEARTBEATs from 42/191,
    MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, consecutive seq, about 2 per second."""
    lab = make_lab(identity="{sysid: 42, compid: 191, heartbeat: 500ms}")
    t0 = time.monotonic()
    time.sleep(4.0)
    t_end = time.monotonic()
    hbs = [(t, decode(f)) for t, f in list(lab.gcs.frames)
           if tlog.msgid(f) == 0 and tlog.sysid(f) == 42]
    assert hbs, "no HEARTBEAT from mavbond"
    for _, m in hbs:
        assert m.get_srcComponent() == 191
        assert m.type == mav2.MAV_TYPE_ONBOARD_CONTROLLER
        assert m.autopilot == mav2.MAV_AUTOPILOT_INVALID
    seqs = [m.get_seq() for _, m in hbs]
    assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:])), seqs
    # The GCS was learned 0.2 s after start: from then on, one every 0.5 s.
    span = t_end - t0 - 0.2
    assert int(span / 0.5) - 1 <= len(hbs) <= int(span / 0.5) + 1, (len(hbs), span)
    gaps = sorted(b - a for (a, _), (b, _) in zip(hbs, hbs[1:]))
    assert 0.4 <= gaps[len(gaps) // 2] <= 0.6, gaps
