#!/usr/bin/env python3
"""soak: the bonded setup under steady load for a long time, watching the daemon for leaks.

    source --udp--> linkemu "radio" (loss) --udp--> [radio ]  mavbond       --udp--> sink
           --udp--> linkemu "lte"   (loss) --udp--> [lte   ]  bond + dedup
                                                              + stats

The source sends every frame on both links (as an air-side gateway in `tx: broadcast` does);
the daemon's dedup turns the two copies back into one. Frames are ATTITUDE messages whose
time_boot_ms is the frame's index, so the sink knows exactly which frames arrived, which twice
and which never.

Every --interval seconds one line: elapsed time, the daemon's RSS and open descriptors (from
/proc), frames sent, delivered, duplicates and missing, and the daemon's own counters (from its
status socket). At the end the verdict: after a warm-up (the first interval, or the first 20%
of the run if that is longer), RSS may grow by at most --rss-margin KiB over its first
post-warm-up sample and the descriptor count must not change at all. Exit status 0 when both
hold, 1 otherwise (the curve is printed either way).

The sender builds frames without pymavlink (CRC-16/MCRF4XX is affine in the message bytes: a
frame that differs from a template in five bytes gets its CRC from five table lookups) and
sends --batch frames per datagram when one per datagram cannot keep up.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from typing import Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import tlog  # noqa: E402
from pymavlink.dialects.v20 import all as mavlink  # noqa: E402

HOST = "127.0.0.1"
ATTITUDE = 30


# --- frames ------------------------------------------------------------------------------------

class FrameFactory:
    """ATTITUDE frames from (1, 1); frame i has time_boot_ms = i and sequence byte i % 256."""

    TIME = 10  # offset of time_boot_ms (the payload's first field)

    def __init__(self):
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.template = bytes(mav.attitude_encode(0, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03).pack(mav))
        assert self.template[0] == 0xFD and self.template[4] == 0
        self.crc_at = len(self.template) - 2
        extra = tlog.crc_extras()[ATTITUDE]
        base = tlog.compute_crc(self.template, extra)
        self.base = base
        # The CRC's change when one byte of the template changes to v (xor: affine map).
        self.tables = {}
        for pos in (4, self.TIME, self.TIME + 1, self.TIME + 2, self.TIME + 3):
            table = []
            for v in range(256):
                b = bytearray(self.template)
                b[pos] = v
                table.append(tlog.compute_crc(bytes(b), extra) ^ base)
            self.tables[pos] = table
        self._t = [self.tables[p] for p in (4, self.TIME, self.TIME + 1, self.TIME + 2,
                                            self.TIME + 3)]
        for i in (0, 1, 255, 256, 65537, 123456789):  # against pymavlink itself
            mav.seq = i % 256
            want = bytes(mav.attitude_encode(i, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03).pack(mav))
            assert self.frame(i) == want, f"frame {i} differs from pymavlink's"

    def frame(self, i: int) -> bytes:
        b = bytearray(self.template)
        b[4] = i & 0xFF
        struct.pack_into("<I", b, self.TIME, i)
        s, t0, t1, t2, t3 = self._t
        crc = (self.base ^ s[i & 0xFF] ^ t0[i & 0xFF] ^ t1[(i >> 8) & 0xFF] ^
               t2[(i >> 16) & 0xFF] ^ t3[(i >> 24) & 0xFF])
        struct.pack_into("<H", b, self.crc_at, crc)
        return bytes(b)


def frame_index(frame: bytes) -> Optional[int]:
    """The index of one of our frames, or None for anything else."""
    if len(frame) >= 14 and frame[0] == 0xFD and frame[5] == 1 and frame[7] == ATTITUDE \
            and frame[8] == 0 and frame[9] == 0:
        return struct.unpack_from("<I", frame, FrameFactory.TIME)[0]
    return None


# --- the daemon and the emulators ----------------------------------------------------------

def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def plugin_dir_for(binary: str) -> str:
    build = os.path.dirname(os.path.dirname(os.path.abspath(binary)))
    plugins = os.path.join(build, "plugins")
    return plugins if os.path.isfile(os.path.join(plugins, "dedup.so")) else ""


def rss_kib(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def fd_count(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def cpu_seconds(pid: int) -> float:
    stat = open(f"/proc/{pid}/stat").read()
    f = stat[stat.rindex(")") + 2:].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def status(path: str, timeout: float = 5.0) -> dict:
    """The daemon's status document (its status socket answers once and closes)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(timeout)
        s.connect(path)
        buf = bytearray()
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            buf += chunk
    return json.loads(buf)


class Process:
    """A child process with its output in files; stopped with SIGTERM, killed if it must be."""

    def __init__(self, args: List[str], workdir: str, name: str, wait_for: str, where: str):
        self.name = name
        self.out_path = os.path.join(workdir, f"{name}.out")
        self.log_path = os.path.join(workdir, f"{name}.log")
        self._out = open(self.out_path, "wb")
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=self._out,
                                     stderr=self._log)
        path = self.log_path if where == "log" else self.out_path
        deadline = time.monotonic() + 10
        while wait_for not in open(path, errors="replace").read():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"{name} did not start:\n" +
                                 open(self.log_path, errors="replace").read())
            time.sleep(0.02)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._out.close()
        self._log.close()
        return self.proc.returncode


# --- the sink ------------------------------------------------------------------------------

class Sink:
    """Receives what the daemon delivers to the GCS side; says hello every second (a UDP
    server forgets a silent peer)."""

    def __init__(self, gcs_port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind((HOST, 0))
        self.sock.settimeout(0.1)
        self.gcs = (HOST, gcs_port)
        mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.hello = bytes(mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav))
        self.seen = bytearray(1 << 20)  # one byte per frame index; grows
        self.delivered = 0
        self.duplicates = 0
        self.foreign = 0
        self._stop = False
        self.sock.sendto(self.hello, self.gcs)
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        next_hello = time.monotonic() + 1
        recv = self.sock.recv
        while not self._stop:
            if time.monotonic() >= next_hello:
                self.sock.sendto(self.hello, self.gcs)
                next_hello += 1
            try:
                dg = recv(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            i = frame_index(dg)
            if i is None or len(dg) != 40:  # the daemon sends one frame per datagram
                self.foreign += 1
                continue
            if i >= len(self.seen):
                self.seen.extend(bytes(max(i + 1 - len(self.seen), len(self.seen))))
            if self.seen[i]:
                self.duplicates += 1
            else:
                self.seen[i] = 1
            self.delivered += 1

    def missing_before(self, n: int) -> int:
        """Frames with an index below n never delivered."""
        n = min(n, len(self.seen))
        return n - self.seen.count(1, 0, n)

    def stop(self):
        self._stop = True
        self._t.join(2)
        self.sock.close()


# --- the run ---------------------------------------------------------------------------------

def daemon_config(ports: Dict[str, int], status_path: str, window: str) -> str:
    return f"""# written by tests/tools/soak.py
log_level: info
report_interval: 10s
status_socket: {status_path}
endpoints:
  - {{name: radio, type: udp, mode: server, address: {HOST}:{ports['radio']}, bond: vehicle}}
  - {{name: lte, type: udp, mode: server, address: {HOST}:{ports['lte']}, bond: vehicle}}
  - {{name: gcs, type: udp, mode: server, address: {HOST}:{ports['gcs']}}}
bonds:
  - {{name: vehicle, tx: broadcast}}
filters:
  - {{plugin: dedup, bonds: [vehicle], window: {window}, drop_stale: false}}
  - {{plugin: stats, interval: 10s}}
"""


def counters_text(doc: dict) -> str:
    eps = {e["name"].split("@")[0]: e for e in doc["endpoints"]}
    parts = [f"{n} rx={eps[n]['rx_frames']}" for n in ("radio", "lte") if n in eps]
    if "gcs" in eps:
        parts.append(f"gcs tx={eps['gcs']['tx_frames']} drop={eps['gcs']['tx_dropped']}")
    for f in doc.get("filters", []):
        st = f.get("status") or {}
        if f["plugin"] == "dedup":
            links = st.get("links", [])
            parts.append(f"dedup dup={sum(l['duplicates'] for l in links)} "
                         f"stale={sum(l['stale'] for l in links)} entries={st.get('entries')}")
    return " ".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=600, help="how long (default 600)")
    ap.add_argument("--rate", type=float, default=10000, help="frames/s (default 10000)")
    ap.add_argument("--interval", type=float, default=60, help="report every S seconds "
                                                               "(default 60)")
    ap.add_argument("--loss", default="0.5%", help="each link's random loss (default 0.5%%)")
    ap.add_argument("--batch", type=int, default=0,
                    help="frames per datagram on the links (default: 1, or more when the "
                         "sender measures that it cannot keep up one per datagram)")
    ap.add_argument("--rss-margin", type=int, default=1024,
                    help="KiB RSS may grow after the warm-up (default 1024)")
    ap.add_argument("--window", default="500ms", help="dedup window (default 500ms)")
    ap.add_argument("--mavbond", default=os.environ.get(
        "MAVBOND_BIN", os.path.join(ROOT, "build", "src", "mavbond")))
    ap.add_argument("--plugin-dir", help="default: next to the binary's build tree")
    ap.add_argument("--workdir", help="default: a new temporary directory")
    args = ap.parse_args()
    if args.interval <= 0 or args.seconds <= 0 or args.rate <= 0:
        ap.error("--seconds, --rate and --interval must be positive")

    factory = FrameFactory()
    batch = args.batch or choose_batch(factory, args.rate)
    workdir = args.workdir or tempfile.mkdtemp(prefix="mavbond-soak-")
    os.makedirs(workdir, exist_ok=True)
    plugin_dir = args.plugin_dir or plugin_dir_for(args.mavbond)
    ports = {n: free_port() for n in ("radio", "lte", "gcs", "emu_radio", "emu_lte")}
    status_path = os.path.join(workdir, "status.sock")
    conf = os.path.join(workdir, "mavbond.yaml")
    with open(conf, "w") as f:
        f.write(daemon_config(ports, status_path, args.window))
    procs: List[Process] = []
    sink = None
    try:
        daemon = Process([args.mavbond, "-c", conf] +
                         (["--plugin-dir", plugin_dir] if plugin_dir else []),
                         workdir, "mavbond", "running with", "log")
        procs.append(daemon)
        for i, link in enumerate(("radio", "lte")):
            procs.append(Process([sys.executable, os.path.join(HERE, "linkemu.py"),
                                  "--listen", f"{HOST}:{ports['emu_' + link]}",
                                  "--forward", f"{HOST}:{ports[link]}", "--seed", str(i + 1),
                                  "--loss", args.loss], workdir, f"linkemu-{link}",
                                 "listening on", "log"))
        sink = Sink(ports["gcs"])
        time.sleep(0.3)  # the daemon has learned the sink
        return run(args, factory, batch, daemon, sink, ports, status_path, workdir)
    finally:
        if sink:
            sink.stop()
        for p in reversed(procs):
            p.stop()


def choose_batch(factory: FrameFactory, rate: float) -> int:
    """1 frame per datagram if this machine's Python sends two copies of `rate` frames/s with
    half of one CPU to spare, else the smallest batch that does."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((HOST, 0))
    target = (HOST, s.getsockname()[1])  # our own socket: nobody reads, the kernel drops
    try:
        for batch in (1, 2, 4, 8, 16):
            n = 4000
            t0 = time.perf_counter()
            for i in range(0, n, batch):
                dg = b"".join(factory.frame(j) for j in range(i, i + batch))
                s.sendto(dg, target)
                s.sendto(dg, target)
            per_s = n / (time.perf_counter() - t0)
            print(f"sender: {per_s:,.0f} frames/s at {batch} per datagram (two links)")
            if per_s >= 2 * rate:
                return batch
        return 16
    finally:
        s.close()


def run(args, factory, batch, daemon, sink, ports, status_path, workdir) -> int:
    pid = daemon.proc.pid
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    links = [(HOST, ports["emu_radio"]), (HOST, ports["emu_lte"])]
    print(f"soak: {args.seconds:g}s at {args.rate:g} frames/s ({batch} per datagram), each link "
          f"{args.loss} loss, report every {args.interval:g}s; workdir {workdir}")
    print(f"{'t_s':>6} {'rss_kib':>8} {'fds':>4} {'sent':>10} {'delivered':>10} {'dup':>6} "
          f"{'missing':>8} {'cpu%':>5}  daemon counters")
    samples = []
    sent = 0
    start = time.monotonic()
    next_report = start + args.interval
    cpu_last, t_last = cpu_seconds(pid), start
    frame = factory.frame
    sendto = out.sendto
    lag_max = 0.0
    while True:
        now = time.monotonic()
        elapsed = now - start
        if now >= next_report or elapsed >= args.seconds:
            doc = status(status_path)
            cpu = cpu_seconds(pid)
            # frames sent more than 1 s ago are settled: missing means lost for good
            settled = max(0, sent - int(args.rate))
            s = {"t": elapsed, "rss": rss_kib(pid), "fds": fd_count(pid), "sent": sent,
                 "delivered": sink.delivered, "dup": sink.duplicates,
                 "missing": sink.missing_before(settled),
                 "cpu": (cpu - cpu_last) / max(now - t_last, 1e-9)}
            cpu_last, t_last = cpu, now
            samples.append(s)
            print(f"{s['t']:6.0f} {s['rss']:8} {s['fds']:4} {s['sent']:10} {s['delivered']:10} "
                  f"{s['dup']:6} {s['missing']:8} {s['cpu']:5.0%}  {counters_text(doc)}",
                  flush=True)
            if daemon.proc.poll() is not None:
                print(f"mavbond exited with {daemon.proc.returncode}; log: {daemon.log_path}")
                return 1
            next_report += args.interval
            if elapsed >= args.seconds:
                break
        due = int(min(elapsed, args.seconds) * args.rate)
        lag_max = max(lag_max, (due - sent) / args.rate)
        # at most 50 ms of frames in one go, so the reports stay on time
        limit = min(due, sent + int(args.rate * 0.05))
        while sent + batch <= limit:
            dg = b"".join([frame(j) for j in range(sent, sent + batch)]) if batch > 1 \
                else frame(sent)
            for link in links:
                sendto(dg, link)
            sent += batch
        time.sleep(0.002)
    out.close()
    return judge(args, samples, lag_max)


def judge(args, samples, lag_max: float) -> int:
    warmup = max(args.interval, 0.2 * args.seconds)
    after = [s for s in samples if s["t"] >= warmup - 1e-6]
    print(f"\nsender: {samples[-1]['sent'] / samples[-1]['t']:,.0f} frames/s achieved "
          f"(target {args.rate:g}), at most {lag_max * 1000:.0f} ms behind")
    curve = "  ".join(f"{s['t']:.0f}s:{s['rss']}KiB/{s['fds']}fd" for s in samples)
    print(f"curve (RSS/descriptors): {curve}")
    if len(after) < 2:
        print(f"verdict: too short to judge (warm-up {warmup:g}s; need two samples after it)")
        return 1
    base = after[0]
    growth = max(s["rss"] for s in after) - base["rss"]
    fds = sorted({s["fds"] for s in after})
    ok_rss = growth <= args.rss_margin
    ok_fds = fds == [base["fds"]]
    print(f"after the {warmup:g}s warm-up: RSS {base['rss']} KiB -> max "
          f"{base['rss'] + growth} KiB (growth {growth} KiB, margin {args.rss_margin} KiB): "
          f"{'ok' if ok_rss else 'GREW'}; descriptors {base['fds']} -> {fds}: "
          f"{'ok' if ok_fds else 'CHANGED'}")
    print("verdict:", "pass" if ok_rss and ok_fds else "FAIL")
    # Its two checks (RSS, descriptors) in the form scripts/test counts.
    print(f"soak: {ok_rss + ok_fds} passed, {2 - ok_rss - ok_fds} failed")
    return 0 if ok_rss and ok_fds else 1


if __name__ == "__main__":
    sys.exit(main())
