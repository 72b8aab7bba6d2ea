"""A slow radio alone, carrying more than it can: command round trips with and without a
transmit budget (issue "Links with a budget", item 4's first measurement).

    vehicle --UDP--> [mavbond air] --radio: linkemu, 28.8 kbit/s, 4 KB queue--> [mavbond ground] --> GCS
    (124 frames/s,    tx_rate: 36000baud                                                          (COMMAND_LONG
     acks commands)   or none                                                                      every 250 ms)

The radio is a SiK at 57600 baud with error correction on, which halves what it carries:
3,600 bytes/s of frames. The vehicle streams an ArduPilot-like mix at 124 frames/s (about
4,500 B/s, 1.26 times that) and answers every COMMAND_LONG with a COMMAND_ACK at once. The GCS
sends a command every 250 ms and times each ack. Both runs get the same stream and the same
seeded radio. Without a budget, the acks queue behind telemetry in the radio's buffer and some
are dropped with it when it is full; with one, mavbond hands the radio only what it carries,
acks first, and thins telemetry to the newest sample of each message.

Run: .venv/bin/python tests/compare/priorities.py --mavbond build/src/mavbond [--seconds 30]
Prints, per run: command round trip p50/p99/max, commands without an ack, and the delivered
rate of each message against what the vehicle sent."""
from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
sys.path.insert(0, str(REPO / "tests" / "tools"))

from bonding_helpers import Emu, Gateway, udp_sock  # noqa: E402
from helpers import HOST, free_port, udp_client, udp_server  # noqa: E402
from pymavlink.dialects.v20 import all as mav2  # noqa: E402
from synth import ardupilot_stream  # noqa: E402

RADIO = {"rate": 28800, "queue_bytes": 4096, "delay": "5ms"}   # SiK 57600 with ECC
# What the radio carries, as a serial line's rate (10 bits a byte, no datagram headers charged:
# the headers of the UDP hop to the emulator never cross the air).
BUDGET = "36000baud"
COMMAND_EVERY = 0.25
ACK_WAIT = 5.0


def receive_messages(sock, stop: threading.Event, on_message) -> None:
    """Until `stop`: each MAVLink message received on `sock`, with its arrival time."""
    sock.settimeout(0.05)
    while not stop.is_set():
        try:
            data = sock.recv(65536)
        except OSError:
            continue
        now = time.monotonic()
        parser = mav2.MAVLink(None)
        parser.robust_parsing = True
        for b in data:
            m = parser.parse_char(bytes([b]))
            if m is not None:
                on_message(m, now)


class Vehicle:
    """Streams telemetry to the air gateway and acks each command at once."""

    def __init__(self, port: int, seconds: float):
        self.sock = udp_sock()
        self.addr = (HOST, port)
        self.stream = list(ardupilot_stream(seconds, seed=7))
        self.mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sent = Counter()
        self.acked = 0
        self.stop = threading.Event()

    def run_acks(self):
        receive_messages(self.sock, self.stop, self.on_message)

    def on_message(self, m, _now):
        if m.get_type() == "COMMAND_LONG":
            ack = mav2.MAVLink_command_ack_message(
                m.command, 0, 0, int(m.param1), m.get_srcSystem(), m.get_srcComponent())
            self.sock.sendto(bytes(ack.pack(self.mav)), self.addr)
            self.acked += 1

    def run_stream(self, start: float):
        for t_us, frame in self.stream:
            due = start + t_us / 1e6
            while time.monotonic() < due:
                time.sleep(0.001)
            self.sock.sendto(frame, self.addr)
            self.sent[frame_msgid(frame)] += 1


def frame_msgid(frame: bytes) -> int:
    return frame[7] | frame[8] << 8 | frame[9] << 16 if frame[0] == 0xFD else frame[5]


class Gcs:
    """Sends a HEARTBEAT each second and a COMMAND_LONG every 250 ms; times the acks."""

    def __init__(self, port: int):
        self.sock = udp_sock()
        self.addr = (HOST, port)
        self.mav = mav2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.sent_at = {}
        self.rtt = {}
        self.got = Counter()
        self.stop = threading.Event()

    def run_recv(self):
        receive_messages(self.sock, self.stop, self.on_message)

    def on_message(self, m, now):
        self.got[m.get_msgId()] += 1
        if m.get_type() == "COMMAND_ACK" and m.result_param2 in self.sent_at:
            self.rtt.setdefault(m.result_param2, now - self.sent_at[m.result_param2])

    def send(self, msg):
        self.sock.sendto(bytes(msg.pack(self.mav)), self.addr)

    def run_commands(self, seconds: float):
        k, start = 0, time.monotonic()
        next_hb = start
        while time.monotonic() - start < seconds:
            now = time.monotonic()
            if now >= next_hb:
                self.send(mav2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
                next_hb += 1.0
            if now - start >= 1.0:   # the vehicle's route is learned by then
                self.sent_at[k] = time.monotonic()
                self.send(mav2.MAVLink_command_long_message(1, 1, 511, 0, k, 0, 0, 0, 0, 0, 0))
                k += 1
            time.sleep(COMMAND_EVERY)


def pct(values, p):
    v = sorted(values)
    return v[min(len(v) - 1, int(p / 100 * len(v)))] if v else float("nan")


def run(mavbond: str, budget: bool, seconds: float, workdir: Path) -> dict:
    p = {k: free_port() for k in ("vehicle", "emu", "radio", "gcs")}
    emu = Emu(workdir, "radio", p["emu"], p["radio"], seed=3, **RADIO).start()
    radio = udp_client("radio", p["emu"], **({"tx_rate": BUDGET} if budget else {}))
    air = Gateway(mavbond, workdir, [udp_server("vehicle", p["vehicle"]), radio],
                  name="air", log_level="info").start()
    ground = Gateway(mavbond, workdir, [udp_server("radio", p["radio"]),
                                        udp_server("gcs", p["gcs"])],
                     name="ground", log_level="info").start()
    vehicle, gcs = Vehicle(p["vehicle"], seconds), Gcs(p["gcs"])
    threads = [threading.Thread(target=vehicle.run_acks, daemon=True),
               threading.Thread(target=gcs.run_recv, daemon=True)]
    for t in threads:
        t.start()
    # The vehicle speaks first, so that the air gateway knows it and the ground learns sysid 1.
    streamer = threading.Thread(target=vehicle.run_stream, args=(time.monotonic(),), daemon=True)
    streamer.start()
    gcs.run_commands(seconds - 1.0)
    streamer.join(seconds + 5)
    time.sleep(ACK_WAIT)
    vehicle.stop.set()
    gcs.stop.set()
    for t in threads:
        t.join(2)
    counters = emu.stop()
    stats = air.stats()
    for g in (air, ground):
        g.stop()
    rtts = list(gcs.rtt.values())
    return {"commands": len(gcs.sent_at), "acked": len(rtts), "rtt": rtts,
            "vehicle_acks": vehicle.acked, "sent": vehicle.sent, "got": gcs.got,
            "radio_queue_drops": counters["up"]["dropped_queue"], "air": stats.get("radio", {})}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mavbond", default=str(REPO / "build" / "src" / "mavbond"))
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mavbond-priorities-") as d:
        results = {}
        for budget in (False, True):
            wd = Path(d) / ("budget" if budget else "plain")
            wd.mkdir()
            results[budget] = run(args.mavbond, budget, args.seconds, wd)
    print(f"A radio of {RADIO['rate'] / 8:.0f} B/s ({RADIO['queue_bytes']} B queue), "
          f"{args.seconds:.0f} s of 124 frames/s (about 4,540 B/s), a command every "
          f"{COMMAND_EVERY * 1000:.0f} ms:")
    print(f"  {'run':<22} {'commands':>8} {'no ack':>7} {'rtt p50':>8} {'p99':>8} {'max':>8}"
          f" {'radio queue drops':>18}")
    for budget, r in results.items():
        rtt = [x * 1000 for x in r["rtt"]]
        name = f"tx_rate: {BUDGET}" if budget else "no budget"
        print(f"  {name:<22} {r['commands']:>8} {r['commands'] - r['acked']:>7} "
              f"{pct(rtt, 50):>6.0f}ms {pct(rtt, 99):>6.0f}ms {max(rtt, default=0):>6.0f}ms"
              f" {r['radio_queue_drops']:>18}")
    print("  delivered per message (frames/s at the GCS / sent by the vehicle):")
    names = {mid: mav2.mavlink_map[mid].msgname for mid in results[False]["sent"]
             if mid in mav2.mavlink_map}
    for mid, n in sorted(results[False]["sent"].items(), key=lambda kv: -kv[1]):
        row = "    " + f"{names.get(mid, mid):<24} sent {n / args.seconds:6.1f}/s"
        for budget, r in results.items():
            row += f"  {'budget' if budget else 'plain'} {r['got'][mid] / args.seconds:6.1f}/s"
        print(row)
    air = results[True]["air"]
    if air:
        print("  the air gateway's budget: " + ", ".join(
            f"{k}={v}" for k, v in air.items() if k.startswith(("control_", "telemetry_"))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
