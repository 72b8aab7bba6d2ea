"""A 57600-baud radio bonded with a metered LTE link: what the GCS loses and what LTE costs,
for the bond sending everything on both links (`tx: broadcast`), the LTE link in standby
(`cost: metered`, with and without the resend on failover) and the radio alone (issue "Links
with a budget", item 4's second measurement).

    vehicle --UDP--> [mavbond air] --radio: 57600 baud, 30 ms--> [mavbond ground, dedup] --> GCS
    (124 frames/s)                 --lte: 1 %, 60 ms +-15 ms-->

Per link condition (the paper's 1 % loss, a bursty radio, a 15 s radio outage) every mode runs
side by side: its own air and ground gateways and its own pair of emulated links (one linkemu
process, the same seeds and outage times for every mode), all fed the same stream at the same
moments. Delivered loss is what the GCS did not get of the frames the vehicle sent; LTE bytes
are what the LTE emulator received in both directions (with 28 bytes of IP and UDP headers a
datagram, as a carrier bills them), per hour of this stream. Every frame the vehicle sends is
unique (bonding_helpers.unique_stream), so a duplicate at the GCS is a duplicate.

A job of scripts/compare (`--only standby`; its section and plot in results.md), or by hand:
.venv/bin/python tests/compare/standby.py --mavbond build/src/mavbond [--scale 0.5]"""
from __future__ import annotations

import argparse
import json
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

from bonding_helpers import EmuGroup, Gateway, Receiver, tlog, udp_sock, unique_stream  # noqa: E402
from helpers import HOST, free_port, status_document, udp_client, udp_server  # noqa: E402

RADIO = {"rate": 46080, "queue_bytes": 4096, "delay": "30ms", "jitter": "10ms"}  # 57600 8N1
LTE = {"loss": "1%", "delay": "60ms", "jitter": "15ms"}
HEADERS = 28  # IPv4 + UDP, per datagram
# name: (title, radio options, radio outage (start s, length s) or None, seconds)
CONDITIONS = {
    "paper": ("the paper's 1 % loss on the radio", {"loss": "1%"}, None, 40.0),
    "bursty": ("a bursty radio (Gilbert-Elliott, ~3 %)", {"ge": "0.003,0.1,0,1"}, None, 40.0),
    "outage": ("the radio down for 15 s (1 % loss besides)", {"loss": "1%"}, (10.0, 15.0), 45.0),
}
# mode: (title, the air's bond members, the LTE member's extra keys, the bond's extra keys)
MODES = {
    "broadcast": ("`tx: broadcast`", ("radio", "lte"), {}, {}),
    "standby": ("standby (`cost: metered`)", ("radio", "lte"), {"cost": "metered"}, {}),
    "standby_noresend": ("standby, `resend: 0s`", ("radio", "lte"), {"cost": "metered"},
                         {"resend": "0s"}),
    "radio": ("the radio alone", ("radio",), {}, {}),
}


class Sender(threading.Thread):
    """The vehicle: the stream to every air gateway at once, at its own pace."""

    def __init__(self, frames, addrs):
        super().__init__(daemon=True)
        self.frames, self.addrs, self.sock = frames, addrs, udp_sock()

    def run(self):
        start = time.monotonic()
        for t, f in self.frames:
            delay = start + t - time.monotonic()
            if delay > 0.002:
                time.sleep(delay)
            for a in self.addrs:
                self.sock.sendto(f, a)


def run_condition(mavbond: str, plugin_dir: str, name: str, scale: float, workdir: Path) -> dict:
    title, radio_opts, outage, seconds = CONDITIONS[name]
    seconds = round(seconds * scale, 1)
    workdir.mkdir(parents=True, exist_ok=True)
    ports = {m: {k: free_port() for k in ("ap", "gcs", "g_radio", "g_lte", "e_radio", "e_lte")}
             for m in MODES}
    # The emulator starts first; the stream starts once every gateway is up, so the outage is
    # placed from the emulator's start plus that lead (measured, then given to linkemu).
    links = []
    for m, p in ports.items():
        r = dict(name=f"radio_{m}", listen_port=p["e_radio"], forward_ports=p["g_radio"],
                 seed=71, **RADIO, **radio_opts)
        links.append(r)
        if "lte" in MODES[m][1]:
            links.append(dict(name=f"lte_{m}", listen_port=p["e_lte"], forward_ports=p["g_lte"],
                              seed=72, **LTE))
    lead = 4.0  # seconds from the emulator's start to the stream's: the gateways start meanwhile
    if outage:
        for link in links:
            if link["name"].startswith("radio_"):
                link["outage"] = [f"{lead + outage[0] * scale:.2f}s+{outage[1] * scale:.2f}s"]
    emu = EmuGroup(workdir, name, links).start()
    t_emu = time.monotonic()
    gateways, receivers, status = [], {}, {}
    for m, (_, members, lte_keys, bond_keys) in MODES.items():
        p = ports[m]
        # Deliveries are matched by their bytes: the bonds do not renumber.
        bond = {"name": "vehicle", "tx": "broadcast", "renumber": False, **bond_keys}
        g_eps = [udp_server("radio", p["g_radio"], bond="vehicle")]
        a_eps = [udp_server("ap", p["ap"]), udp_client("radio", p["e_radio"], bond="vehicle")]
        if "lte" in members:
            g_eps.append(udp_server("lte", p["g_lte"], bond="vehicle", **lte_keys))
            a_eps.append(udp_client("lte", p["e_lte"], bond="vehicle", **lte_keys))
        g_eps.append(udp_server("gcs", p["gcs"]))
        status[m] = workdir / f"air-{m}.sock"
        gateways.append(Gateway(mavbond, workdir, g_eps, bonds=[bond],
                                filters=[{"plugin": "dedup", "bonds": ["vehicle"]}],
                                name=f"ground-{m}", plugin_dir=plugin_dir,
                                log_level="info").start())
        gateways.append(Gateway(mavbond, workdir, a_eps, bonds=[bond], name=f"air-{m}",
                                plugin_dir=plugin_dir, log_level="info",
                                status_socket=str(status[m])).start())
        receivers[m] = Receiver(udp_sock(), hello_port=p["gcs"])
    frames = unique_stream(seconds, seed=13)
    wait = t_emu + lead - time.monotonic()
    if wait > 0:
        time.sleep(wait)
    sender = Sender(frames, [(HOST, ports[m]["ap"]) for m in MODES])
    sender.start()
    sender.join()
    # The counters while the radio is still as the stream left it (silence after the stream
    # would put standby active, and that is not the stream's doing).
    air = {m: status_document(status[m])["bonds"][0].get("standby") for m in MODES}
    for r in receivers.values():
        r.wait_quiet(0.5)
    counters = emu.stop()
    for g in gateways:
        g.stop()
    sent = {f for _, f in frames}
    index = {f: i for i, (_, f) in enumerate(frames)}
    out = {"title": title, "seconds": seconds, "n": len(frames), "modes": {}}
    for m in MODES:
        got = [f for f in receivers[m].stop() if tlog.sysid(f) == 1 and tlog.compid(f) == 1]
        seen = Counter(f for f in got if f in sent)
        lte = counters.get(f"lte_{m}")
        lte_bytes = sum(d["bytes_received"] + HEADERS * d["received"] for d in lte.values()) \
            if lte else 0
        radio = counters[f"radio_{m}"]["up"]
        out["modes"][m] = {
            "delivered": len(seen), "duplicates": sum(seen.values()) - len(seen),
            # which messages came twice, and how far apart in the stream (frames)
            "duplicated": [[tlog.msgid(f), index[f]] for f, k in seen.items() if k > 1],
            "delivered_loss": 1 - len(seen) / len(frames),
            "lte_bytes": lte_bytes, "lte_bytes_per_hour": lte_bytes / seconds * 3600,
            "radio_loss": 1 - radio["forwarded"] / radio["received"] if radio["received"] else 0,
            "standby": air[m]}
    return out


def run(mavbond: str, plugin_dir: str, scale: float, workdir: Path) -> dict:
    return {"conditions": {n: run_condition(mavbond, plugin_dir, n, scale, workdir / n)
                           for n in CONDITIONS},
            "radio": RADIO, "lte": LTE}


def goal(c: dict) -> tuple:
    """(within 1.5x of broadcast's delivered loss, under 10 % of its LTE bytes) for standby."""
    b, s = c["modes"]["broadcast"], c["modes"]["standby"]
    loss_ok = s["delivered_loss"] <= 1.5 * b["delivered_loss"] or \
        (s["delivered"] >= b["delivered"] - 1)  # a frame either way is no ratio
    bytes_ok = s["lte_bytes"] < 0.10 * b["lte_bytes"]
    return loss_ok, bytes_ok


def pct(x: float) -> str:
    return "0" if x == 0 else f"{x * 100:.3f} %"


def report_lines(raw: dict) -> list:
    lines = ["A 57600-baud radio (46 kbit/s of payload, 4 KB queue, 30 ms +-10 ms) bonded with an "
             "LTE link (1 % loss, 60 ms +-15 ms), an ArduPilot-like 124 frames/s from the vehicle; "
             "the ground gateway runs dedup. Per condition the four modes run side by side on "
             "the same seeded links. LTE bytes: both directions, with IP and UDP headers, per "
             "hour of this stream. Goal: standby within 1.5x of broadcast's delivered loss at "
             "under 10 % of its LTE bytes.", "",
             "| condition | mode | delivered loss (frames) | duplicates | LTE MB/h | "
             "LTE bytes vs broadcast | switches to active / back | resent |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, c in raw["conditions"].items():
        b = c["modes"]["broadcast"]
        for m, r in c["modes"].items():
            sb = r.get("standby") or {}
            share = f"{r['lte_bytes'] / b['lte_bytes'] * 100:.1f} %" if b["lte_bytes"] and \
                m != "radio" else "-"
            sw = f"{sb['to_active']} / {sb['to_standby']}" if sb else "-"
            lines.append(f"| {name}: {c['title']} | {MODES[m][0]} | {pct(r['delivered_loss'])} "
                         f"({c['n'] - r['delivered']}) | {r['duplicates']} | "
                         f"{r['lte_bytes_per_hour'] / 1e6:.2f} | {share} | {sw} | "
                         f"{sb.get('resent', '-') if sb else '-'} |")
    lines.append("")
    for name, c in raw["conditions"].items():
        loss_ok, bytes_ok = goal(c)
        b, s = c["modes"]["broadcast"], c["modes"]["standby"]
        lines.append(f"- {name}: standby {pct(s['delivered_loss'])} against broadcast "
                     f"{pct(b['delivered_loss'])} ({'within' if loss_ok else 'NOT within'} 1.5x), "
                     f"{s['lte_bytes'] / b['lte_bytes'] * 100:.1f} % of its LTE bytes "
                     f"({'under' if bytes_ok else 'NOT under'} 10 %): goal "
                     f"{'met' if loss_ok and bytes_ok else 'missed'}.")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mavbond", default=str(REPO / "build" / "src" / "mavbond"))
    ap.add_argument("--plugin-dir", default=str(REPO / "build" / "plugins"))
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--workdir", help="keep the gateways' logs here (default: a temporary one)")
    ap.add_argument("--only", help="comma-separated conditions (default: all)")
    args = ap.parse_args()
    if args.only:
        for name in set(CONDITIONS) - set(args.only.split(",")):
            del CONDITIONS[name]
    with tempfile.TemporaryDirectory(prefix="mavbond-standby-") as d:
        raw = run(args.mavbond, args.plugin_dir, args.scale, Path(args.workdir or d))
    print("\n".join(report_lines(raw)))
    print(json.dumps({n: {m: {k: v for k, v in r.items() if k != "standby"}
                          for m, r in c["modes"].items()} for n, c in raw["conditions"].items()},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
