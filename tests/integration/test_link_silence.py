"""A vehicle that pauses its stream is no silent link (routing/link_silence.h), end to end: two
gateways as the shipped pair has them (a radio and a metered LTE link between them, each a
link emulator, link events on both sides, the ground telling a GCS), an ArduPilot-like stream
into the air gateway that stops for 1.5 s, 3 s and 6 s while both links are healthy (ArduCopter
SITL pauses for up to 1.4 s now and then: the ground's standby reported the radio silent, the
metered link left standby and the air side logged 35 link events in ten minutes), then the
radio cut both ways for 6 s while the stream flows.

Evidence is the daemons' own: the air gateway's standby counters (no failover before the cut,
one for it), both logs (no link change logged before the cut; the cut found by a report the
far side sent on LTE that the radio did not bring), and the STATUSTEXTs the GCS received (one
"lost", one "back"). The cut's detection latency is printed, from the emulator's cut to the
GCS's STATUSTEXT."""
from __future__ import annotations

import re
import signal
import threading
import time
from datetime import datetime

from helpers import HOST, free_port, mav2, status_document, udp_client, udp_server
from bonding_helpers import Receiver, synth, tlog, wait_for

PAUSES = [(8.0, 1.5), (15.5, 3.0), (24.5, 6.0)]   # (stream time, length) s
CUT_AT, CUT_FOR = 40.0, 6.0                       # s on the emulator's clock
STREAM_START = 1.0                                # s on the emulator's clock
STREAM_SECONDS = 58.0                             # the last frame, stream time
CHANGE = re.compile(r"link event: (?:link \S+ (?:\w+ )?(?:lost|back) |bond \S+: active link now )")


def paused_stream(seed: int):
    """ArduPilot's stream (synth), times in s, stopped for each of PAUSES: its frames after a
    pause come that much later, numbered on (an autopilot that paused, not one that lost)."""
    out, shift = [], 0.0
    pauses = list(PAUSES)
    for t_us, f in synth.ardupilot_stream(STREAM_SECONDS, seed=seed):
        t = t_us / 1e6 + shift
        while pauses and t >= pauses[0][0]:
            shift += pauses[0][1]
            t += pauses[0][1]
            pauses.pop(0)
        if t <= STREAM_SECONDS:
            out.append((t, f))
    return out


class Sender(threading.Thread):
    """Sends the stream at its pace from `start` (monotonic) on."""

    def __init__(self, sock, addr, frames, start):
        super().__init__(daemon=True)
        self.sock, self.addr, self.frames, self.start_at = sock, addr, frames, start
        self.stopping = threading.Event()

    def run(self):
        for t, f in self.frames:
            if self.stopping.is_set():
                return
            delay = self.start_at + t - time.monotonic()
            if delay > 0.002:
                time.sleep(delay)
            self.sock.sendto(f, self.addr)

    def stop(self):
        self.stopping.set()
        self.join()


def logged_at(line: str) -> float:
    """A log line's time ("2026-12-01 21:14:45.453 mavbond: ...", local) on time.monotonic()'s
    clock."""
    wall = datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S.%f").timestamp()
    return wall - time.time() + time.monotonic()


def mavbond_texts(rx: Receiver):
    """(arrival, text) of every STATUSTEXT of mavbond's a receiver got."""
    out = []
    for t, f in list(rx.frames):
        if tlog.msgid(f) == 253:
            m = mav2.MAVLink(None).decode(bytearray(f))
            if m.text.startswith("mavbond:"):
                out.append((t, m.text))
    return out


def pair(lab, tmp_path, name, seeds, radio=None):
    """The shipped pair's shape: a ground gateway (GCS port, radio and metered LTE links) and
    an air gateway (the autopilot's port), the links emulated (`radio`: the radio's extra
    options), link events on both sides. Returns (ports, ground, emulators, air, the air's
    status socket, the GCS)."""
    p = {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "e_radio", "e_lte")}
    events = {"link_events": "{silent_after: 1s}"}
    ground = lab.gateway([udp_server("radio", p["g_radio"], bond="vehicle"),
                          udp_server("lte", p["g_lte"], bond="vehicle", cost="metered"),
                          udp_server("gcs", p["gcs"])],
                         bonds=[{"name": "vehicle", "tx": "broadcast"}],
                         filters=[{"plugin": "dedup", "bonds": ["vehicle"]}], name="ground",
                         status_socket=str(tmp_path / "ground.sock"), **events)
    emu = lab.emu_group([dict(name="radio", listen_port=p["e_radio"], forward_ports=p["g_radio"],
                              seed=seeds[0], delay="20ms", **(radio or {})),
                         dict(name="lte", listen_port=p["e_lte"], forward_ports=p["g_lte"],
                              seed=seeds[1], delay="60ms", jitter="15ms")],
                        name=name)
    air_sock = tmp_path / "air.sock"
    air = lab.gateway([udp_server("ap", p["ap"]),
                       udp_client("radio", p["e_radio"], bond="vehicle"),
                       udp_client("lte", p["e_lte"], bond="vehicle", cost="metered")],
                      bonds=[{"name": "vehicle", "tx": "broadcast", "resend": "1s"}],
                      filters=[{"plugin": "dedup", "bonds": ["vehicle"]}], name="air",
                      status_socket=str(air_sock), **events)
    return p, ground, emu, air, air_sock, Receiver(lab.sock(), hello_port=p["gcs"])


def test_a_paused_stream_is_no_silence_and_a_cut_is_one_lost_one_back(lab, tmp_path):
    p, ground, emu, air, air_sock, gcs = pair(lab, tmp_path, "silence", (61, 62),
                                              {"outage": f"{CUT_AT}s+{CUT_FOR}s"})
    frames = paused_stream(seed=12)
    sender = Sender(lab.sock(), (HOST, p["ap"]), frames, emu.t_start + STREAM_START)
    sender.start()
    try:
        # The pauses are over and the stream has flowed 4 s again; the cut is still to come.
        healthy_until = emu.t_start + STREAM_START + PAUSES[-1][0] + PAUSES[-1][1] + 4.0
        assert healthy_until < emu.t_start + CUT_AT - 2.0
        time.sleep(max(0.0, healthy_until - time.monotonic()))
        healthy = status_document(air_sock)["bonds"][0]["standby"]
        logged = {name: [l for l in g.log().splitlines() if CHANGE.search(l)]
                  for name, g in (("air", air), ("ground", ground))}
        texts = mavbond_texts(gcs)
        print(f"\n[silence] pauses {PAUSES} (stream s) while healthy: air standby "
              f"{healthy['state']}, to_active {healthy['to_active']}, reports received "
              f"{healthy['reports_received']}; link changes logged: air "
              f"{len(logged['air'])}, ground {len(logged['ground'])}; mavbond STATUSTEXTs at "
              f"the GCS {len(texts)}")
        assert healthy["to_active"] == 0 and healthy["state"] == "standby", healthy
        assert logged == {"air": [], "ground": []}, logged
        assert texts == [], texts

        # The cut: one lost, one back, each once, and one failover.
        cut = emu.t_start + CUT_AT
        lost_text = "mavbond: link radio lost (bond vehicle, 1 of 2 up)"
        back_text = "mavbond: link radio back (bond vehicle, 2 of 2 up)"
        wait_for(lambda: any(x == lost_text for _, x in mavbond_texts(gcs)),
                 "the GCS to be told the radio is lost", timeout=CUT_AT + 30.0)
        wait_for(lambda: any(x == back_text for _, x in mavbond_texts(gcs)),
                 "the GCS to be told the radio is back", timeout=CUT_FOR + 30.0)
        sender.join(timeout=STREAM_SECONDS + 30.0)
        gcs.wait_quiet(1.0)
        after = status_document(air_sock)["bonds"][0]["standby"]
    finally:
        sender.stop()
    texts = mavbond_texts(gcs)
    lost_at = next(t for t, x in texts if x == lost_text)
    back_at = next(t for t, x in texts if x == back_text)
    ground_log = ground.log()
    found = [l for l in ground_log.splitlines() if "link event: link radio downlink lost" in l]
    active = [l for l in air.log().splitlines() if "metered links active" in l]
    print(f"[silence] radio cut at {CUT_AT:.0f} s for {CUT_FOR:.0f} s: the GCS told "
          f"\"lost\" {lost_at - cut:.2f} s after the cut began, \"back\" "
          f"{back_at - (cut + CUT_FOR):.2f} s after it ended; the air side active "
          f"{logged_at(active[0]) - cut:.2f} s after the cut began (its log), to_active "
          f"{after['to_active']}, resent {after['resent']}; the ground found it "
          f"{logged_at(found[0]) - cut:.2f} s after: "
          f"{found[0].split('link event: ')[-1] if found else None}")
    assert [x for _, x in texts] == [lost_text, back_text], texts
    assert after["to_active"] == 1, after
    # Found by what the far side wrote on every link, not by the radio's gap alone.
    assert len(found) == 1 and "the far side's report on lte" in found[0], found
    for g in (air, ground):
        assert len([l for l in g.log().splitlines() if CHANGE.search(l)]) == 4, g.log()


FROZEN_AT, FROZEN_FOR = (6.0, 13.0), 4.0         # s on the emulator's clock


def test_a_gateway_frozen_longer_than_a_silence_finds_no_link_lost_on_waking(lab, tmp_path):
    """The air gateway stopped (SIGSTOP) for 4 s, twice, while both links carry everything: what came
    meanwhile waits in its sockets, so on waking (SIGCONT) it has no link to call lost (the
    kernel held it so for 5.8 s in the operator stage, and it called LTE lost, then back 0.1 s
    later). The ground, which heard nothing from it for 4 s, rightly may: it is not judged."""
    p, ground, emu, air, air_sock, gcs = pair(lab, tmp_path, "frozen", (63, 64))
    frames = [(t_us / 1e6, f) for t_us, f in synth.ardupilot_stream(20.0, seed=13)]
    sender = Sender(lab.sock(), (HOST, p["ap"]), frames, emu.t_start + STREAM_START)
    sender.start()
    try:
        for at in FROZEN_AT:  # twice: each wakeup, not only the first, waits for its poll
            time.sleep(max(0.0, emu.t_start + at - time.monotonic()))
            air.proc.send_signal(signal.SIGSTOP)
            time.sleep(FROZEN_FOR)
            air.proc.send_signal(signal.SIGCONT)
        time.sleep(3.0)
        loop = status_document(air_sock)["event_loop"]
    finally:
        sender.stop()
    own = [l for l in air.log().splitlines() if CHANGE.search(l) and " lost " in l
           and "as the far side reports" not in l]
    far = [l for l in ground.log().splitlines() if CHANGE.search(l)]
    print(f"\n[frozen] the air gateway stopped {FROZEN_FOR:.0f} s, twice: it woke "
          f"{loop['latest_wakeup_ms']} ms late; links it called lost on its own: {own}; the "
          f"ground's changes (true: it heard nothing): {len(far)}")
    # The daemon's own clock saw the freeze, and it called nothing lost for it.
    assert loop["latest_wakeup_ms"] >= 1000 * FROZEN_FOR - 200 and loop["late_wakeups"] >= 2, loop
    assert own == [], own
