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

A job of scripts/compare (`--only priorities`; its section and plot in results.md), or by hand:
.venv/bin/python tests/compare/priorities.py --mavbond build/src/mavbond [--seconds 60]
Per run: command round trip p50/p99/max, commands without an ack, the radio's queue drops and
the delivered rate of each message against what the vehicle sent."""
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

from analyze import percentile  # noqa: E402

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


def ms(values, q: float) -> float:
    """A percentile of round trips (ms); nan when none came back."""
    v = percentile(values, q)
    return float("nan") if v is None else v


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
    def name(mid):
        return mav2.mavlink_map[mid].msgname if mid in mav2.mavlink_map else str(mid)
    return {"commands": len(gcs.sent_at), "no_ack": len(gcs.sent_at) - len(gcs.rtt),
            "rtt_ms": sorted(x * 1000 for x in gcs.rtt.values()),
            "sent": {name(m): n for m, n in vehicle.sent.items()},
            "got": {name(m): gcs.got[m] for m in vehicle.sent},
            "radio_queue_drops": counters["up"]["dropped_queue"],
            "budget": {k: v for k, v in stats.get("radio", {}).items()
                       if k.startswith(("control_", "telemetry_", "bulk_"))}}


def run_pair(mavbond: str, seconds: float, workdir: Path) -> dict:
    """Both runs, on the same stream and the same seeded radio: {"plain": .., "budget": ..}."""
    runs = {}
    for label, budget in (("plain", False), ("budget", True)):
        wd = workdir / label
        wd.mkdir(parents=True, exist_ok=True)
        runs[label] = run(mavbond, budget, seconds, wd)
    return {"seconds": seconds, "radio_bytes_per_s": RADIO["rate"] / 8,
            "queue_bytes": RADIO["queue_bytes"], "tx_rate": BUDGET,
            "command_every_ms": COMMAND_EVERY * 1000, "runs": runs}


def report_lines(raw: dict) -> list:
    """The two runs as markdown: round trips and lost commands, then each message's rate."""
    secs, runs = raw["seconds"], raw["runs"]
    offered = sum(runs["plain"]["sent"].values()) / secs
    lines = [f"A radio alone that carries {raw['radio_bytes_per_s']:.0f} B/s (a SiK at 57600 "
             f"with error correction; {raw['queue_bytes']} B queue, tail drop), offered an "
             f"ArduPilot-like {offered:.0f} frames/s (about 4,540 B/s) for {secs:.0f} s; the GCS "
             f"sends a COMMAND_LONG every {raw['command_every_ms']:.0f} ms and the vehicle acks "
             f"each at once. The same stream and the same seeded radio for both runs.", "",
             "| air side | commands | without an ack | round trip p50 / p99 / max | "
             "radio queue drops |", "|---|---:|---:|---:|---:|"]
    for label, r in runs.items():
        rtt = r["rtt_ms"]
        name = "no budget" if label == "plain" else f"`tx_rate: {raw['tx_rate']}`"
        lines.append(f"| {name} | {r['commands']} | {r['no_ack']} | {ms(rtt, 0.5):.0f} / "
                     f"{ms(rtt, 0.99):.0f} / {max(rtt, default=0):.0f} ms | "
                     f"{r['radio_queue_drops']} |")
    lines += ["", "| message | sent by the vehicle | at the GCS, no budget | at the GCS, "
              "with the budget |", "|---|---:|---:|---:|"]
    for msg, n in sorted(runs["plain"]["sent"].items(), key=lambda kv: (-kv[1], kv[0])):
        lines.append(f"| {msg} | {n / secs:.1f}/s | {runs['plain']['got'][msg] / secs:.1f}/s | "
                     f"{runs['budget']['got'][msg] / secs:.1f}/s |")
    b = runs["budget"]["budget"]
    if b:
        lines += ["", "The air gateway's own count with the budget: " + ", ".join(
            f"{k} {v}" for k, v in b.items() if not k.endswith("_bytes") and v)]
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mavbond", default=str(REPO / "build" / "src" / "mavbond"))
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="mavbond-priorities-") as d:
        raw = run_pair(args.mavbond, args.seconds, Path(d))
    print("\n".join(report_lines(raw)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
