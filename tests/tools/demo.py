"""scripts/demo: a real recording through two bonded, lossy telemetry links, and what the ground
station got.

Topology (all on 127.0.0.1, every box a real process or socket):

    vehicle (replayed tlog) --udp--> [mavbond air] ==radio: 2% loss in bursts, 15 ms==> [mavbond ground] --udp--> GCS
                                                   ==LTE: 1% loss, 80 ms +-10 ms=====>  dedup + stats

The air gateway sends every frame on both links (tx: broadcast); the ground gateway's dedup
turns the two copies back into one stream. Every second a row shows each link's loss so far
against the loss the GCS sees; the summary compares the delivered loss with the independence
bound (the product of the links' loss rates) and checks that nothing arrived twice and every
delivered frame is byte-identical to one the vehicle sent. The links are emulated by
tests/tools/linkemu.py (in-process), seeded, so a run is reproducible up to timing.

`--gateway` runs the earlier demo instead: one mavbond, a replay, several GCS peers.
With no ../shared/data/tlogs next to the project, a synthetic ArduPilot-like stream is used.
"""
from __future__ import annotations

import argparse
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import tlog  # noqa: E402
from synth import ardupilot_stream  # noqa: E402  (sets MAVLINK20)
from pymavlink.dialects.v20 import all as mavlink  # noqa: E402

DEFAULT_TLOG = "ardupilot-sub-real-2023-qgc-small.tlog"


def tlog_dir() -> str:
    return os.environ.get("MAVBOND_TLOG_DIR", os.path.join(ROOT, "..", "shared", "data", "tlogs"))


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def load_stream(path: str | None, seconds: float):
    """(source description, [(t_us, frame)]) from a recording, or the synthetic fallback."""
    if path is None:
        candidate = os.path.join(tlog_dir(), DEFAULT_TLOG)
        path = candidate if os.path.exists(candidate) else None
    if path is None:
        print(f"note: no recording at {tlog_dir()} (a clone without ../shared): "
              f"using a synthetic ArduPilot-like stream at 124 frames/s")
        return "synthetic ArduPilot-like stream", list(ardupilot_stream(seconds))
    frames = [(t, f) for t, f in tlog.iter_frames(path)]
    if frames and frames[0][0] is None:  # raw stream: pace at 300 frames/s
        frames = [(int(i * 1e6 / 300), f) for i, (_, f) in enumerate(frames)]
    return os.path.basename(path), frames


def gateway_main(args) -> int:
    """The plain gateway replay (--gateway)."""
    source, frames = load_stream(args.tlog, args.seconds)
    p_vehicle, p_gcs, p_tcp = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    conf = f"""# written by scripts/demo
log_level: info
report_interval: 5s
endpoints:
  - {{name: vehicle, type: udp, mode: server, address: 127.0.0.1:{p_vehicle}}}
  - {{name: gcs, type: udp, mode: server, address: 127.0.0.1:{p_gcs}}}
  - {{name: logger, type: tcp, mode: server, address: 127.0.0.1:{p_tcp}}}
"""
    workdir = tempfile.mkdtemp(prefix="mavbond-demo-")
    conf_path = os.path.join(workdir, "mavbond.yaml")
    with open(conf_path, "w") as f:
        f.write(conf)
    log_path = os.path.join(workdir, "mavbond.log")
    log = open(log_path, "w")
    daemon = subprocess.Popen([args.mavbond, "-c", conf_path], stderr=log)
    try:
        return run(args, source, frames, daemon, log_path, p_vehicle, p_gcs, p_tcp)
    finally:
        if daemon.poll() is None:
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(timeout=5)
        log.close()


def run(args, source, frames, daemon, log_path, p_vehicle, p_gcs, p_tcp) -> int:
    def udp():
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.setblocking(False)
        return s

    vehicle, qgc, mavproxy = udp(), udp(), udp()
    deadline = time.monotonic() + 5
    while True:  # the daemon is up once its TCP port accepts
        try:
            logger = socket.create_connection(("127.0.0.1", p_tcp), timeout=0.2)
            break
        except OSError:
            if time.monotonic() > deadline or daemon.poll() is not None:
                print(open(log_path).read())
                raise SystemExit("mavbond did not start")
            time.sleep(0.05)
    logger.setblocking(False)
    # A GCS is learned from what it sends: both say hello with a HEARTBEAT first.
    for sock, comp in ((qgc, 190), (mavproxy, 191)):
        m = mavlink.MAVLink(None, srcSystem=255, srcComponent=comp)
        sock.sendto(m.heartbeat_encode(6, 8, 0, 0, 4).pack(m), ("127.0.0.1", p_gcs))
    time.sleep(0.2)

    receivers = {"qgc (udp)": qgc, "mavproxy (udp)": mavproxy, "vehicle (udp)": vehicle}
    got = {name: [] for name in list(receivers) + ["logger (tcp)"]}
    tcp_buf = bytearray()
    sent_vehicle, sent_gcs = [], []

    def drain():
        nonlocal tcp_buf
        for name, s in receivers.items():
            while True:
                try:
                    got[name].append(s.recv(4096))
                except BlockingIOError:
                    break
        try:
            while True:
                chunk = logger.recv(65536)
                if not chunk:
                    break
                tcp_buf += chunk
        except BlockingIOError:
            pass
        while tcp_buf:
            n = tlog.frame_length(tcp_buf)
            if n is None or n > len(tcp_buf):
                break
            got["logger (tcp)"].append(bytes(tcp_buf[:n]))
            del tcp_buf[:n]

    t0_rec = frames[0][0] if frames else 0
    start = time.monotonic()
    next_print = start + 1
    print(f"replaying {source}: {len(frames)} frames at {args.speed:g}x "
          f"(at most {args.seconds:g} s)\n")
    print(f"{'t':>4}  {'sent':>7}  " + "  ".join(f"{n:>15}" for n in got))
    for t_us, frame in frames:
        due = start + (t_us - t0_rec) / 1e6 / args.speed
        now = time.monotonic()
        if due - start > args.seconds:
            break
        if due > now:
            drain()
            time.sleep(max(0.0, min(due - time.monotonic(), 0.05)))
        if tlog.sysid(frame) >= 250:
            qgc.sendto(frame, ("127.0.0.1", p_gcs))
            sent_gcs.append(frame)
        else:
            vehicle.sendto(frame, ("127.0.0.1", p_vehicle))
            sent_vehicle.append(frame)
        if time.monotonic() >= next_print:
            drain()
            print(f"{time.monotonic() - start:4.0f}  {len(sent_vehicle) + len(sent_gcs):7}  " +
                  "  ".join(f"{len(v):15}" for v in got.values()), flush=True)
            next_print += 1
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        drain()
        time.sleep(0.05)

    daemon.send_signal(signal.SIGTERM)
    daemon.wait(timeout=5)
    counters = [line.split("stats ", 1)[1].strip() for line in open(log_path)
                if "stats endpoint=" in line]
    counters = counters[-3:]

    good_vehicle = [f for f in sent_vehicle if tlog.crc_ok(f) is not False]
    good_gcs = [f for f in sent_gcs if tlog.crc_ok(f) is not False]
    print(f"\nsent: {len(sent_vehicle)} frames from the vehicle side "
          f"({len(sent_vehicle) - len(good_vehicle)} with a bad CRC), "
          f"{len(sent_gcs)} from the GCS side ({len(sent_gcs) - len(good_gcs)} with a bad CRC)\n")
    # What each receiver should get, by the routing rule: a frame with a target goes where
    # that target was heard (the exact component first, then the system), a broadcast or an
    # unknown target everywhere but its source.
    heard = {"qgc (udp)": {(255, 190)}, "mavproxy (udp)": {(255, 191)}, "logger (tcp)": set(),
             "vehicle (udp)": {(tlog.sysid(f), tlog.compid(f)) for f in good_vehicle}}
    decoder = mavlink.MAVLink(None)
    decoder.robust_parsing = True

    def destinations(frame, source):
        others = [n for n in heard if n != source]
        try:
            msg = decoder.decode(bytearray(frame))
        except Exception:  # unknown id: no target known, routed as a broadcast
            return others
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        if ts == 0:
            return others
        for exact in ((True, False) if tc else (False,)):
            hit = [n for n in others
                   if any(s == ts and (not exact or c == tc) for s, c in heard[n])]
            if hit:
                return hit
        return others

    expected = {name: [] for name in got}
    targeted = 0
    for frame in good_vehicle:
        dests = destinations(frame, "vehicle (udp)")
        targeted += len(dests) < 3
        for n in dests:
            expected[n].append(frame)
    for frame in good_gcs:
        for n in destinations(frame, "qgc (udp)"):
            expected[n].append(frame)
    sent_gcs_set = set(sent_gcs)
    print(f"{targeted} vehicle frames carried a target that was heard on one GCS only\n")
    print(f"{'receiver':<16} {'frames':>8} {'bytes':>9}  {'as routed, in order, byte-identical':<36} sources")
    ok_all = True
    for name, frames_in in got.items():
        # Order is kept per direction; how the two directions interleave is up to timing.
        from_vehicle = [f for f in frames_in if tlog.sysid(f) < 250]
        from_gcs = [f for f in frames_in if f in sent_gcs_set]
        want = expected[name]
        same = (from_vehicle == [f for f in want if tlog.sysid(f) < 250] and
                from_gcs == [f for f in want if tlog.sysid(f) >= 250])
        mine = from_vehicle + from_gcs
        verdict = "yes" if same else f"NO ({len(mine)} got, {len(want)} expected)"
        ok_all &= same
        sources = Counter((tlog.sysid(f), tlog.compid(f)) for f in frames_in)
        top = ", ".join(f"{s}/{c}:{n}" for (s, c), n in sources.most_common(4))
        print(f"{name:<16} {len(frames_in):>8} {sum(map(len, frames_in)):>9}  {verdict:<36} {top}")
    print("\nmavbond's counters (frames with a bad CRC are dropped and counted, never forwarded):")
    for c in counters:
        print("  " + c)
    print("\nresult:", "every good frame arrived where it should, once, in order" if ok_all
          else "MISMATCH (see above)")
    return 0 if ok_all else 1




# --- the bonding demo -----------------------------------------------------------------------

def plugin_dir_for(binary: str) -> str:
    """--plugin-dir for a build tree's binary (<build>/src/mavbond): <build>/plugins, where the
    build puts every NAME.so; "" for an installed mavbond (its compiled-in plugin_dir)."""
    build = os.path.dirname(os.path.dirname(os.path.abspath(binary)))
    plugins = os.path.join(build, "plugins")
    return plugins if os.path.isfile(os.path.join(plugins, "dedup.so")) else ""


def start_mavbond(binary, workdir, name, conf, plugin_dir):
    path = os.path.join(workdir, f"{name}.yaml")
    with open(path, "w") as f:
        f.write(conf)
    log_path = os.path.join(workdir, f"{name}.log")
    log = open(log_path, "w")
    args = [binary, "-c", path] + (["--plugin-dir", plugin_dir] if plugin_dir else [])
    proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    deadline = time.monotonic() + 5
    while "running with" not in open(log_path).read():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"mavbond ({name}) did not start:\n" + open(log_path).read())
        time.sleep(0.02)
    return proc, log, log_path


def stop_mavbond(proc, log):
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    log.close()


def timestamp_of(decoder, frame):
    try:
        msg = decoder.decode(bytearray(frame))
    except Exception:
        return None
    for field in ("time_boot_ms", "time_usec"):
        if field in msg.get_fieldnames():
            return getattr(msg, field)
    return None


def bond_main(args) -> int:
    from linkemu import LinkEmulator  # noqa: PLC0415

    source, stream = load_stream(args.tlog, args.seconds)
    t0_rec = stream[0][0] if stream else 0
    vehicle_frames = [((t - t0_rec) / 1e6 / args.speed, f) for t, f in stream
                      if tlog.sysid(f) < 250]
    vehicle_frames = [(t, f) for t, f in vehicle_frames if t < args.seconds]
    bad_crc = sum(1 for _, f in vehicle_frames if tlog.crc_ok(f) is False)
    if bad_crc:  # a gateway drops them on input: not part of the bonded stream
        print(f"note: {bad_crc} frames of the recording have a bad CRC; they are left out")
        vehicle_frames = [(t, f) for t, f in vehicle_frames if tlog.crc_ok(f) is not False]
    workdir = tempfile.mkdtemp(prefix="mavbond-demo-")
    plugin_dir = args.plugin_dir or plugin_dir_for(args.mavbond)
    have_stats = bool(plugin_dir) and os.path.exists(os.path.join(plugin_dir, "stats.so"))
    p_auto, p_gcs, la, lb, ga, gb = (free_port() for _ in range(6))
    csv_path = os.path.join(workdir, "ground-stats.csv")
    stats_filter = (f"  - {{plugin: stats, interval: 1s, csv: {csv_path}}}\n" if have_stats else "")
    ground_conf = f"""# written by scripts/demo: the ground-side gateway
log_level: info
endpoints:
  - {{name: radio, type: udp, mode: server, address: 127.0.0.1:{ga}, bond: vehicle}}
  - {{name: lte, type: udp, mode: server, address: 127.0.0.1:{gb}, bond: vehicle}}
  - {{name: gcs, type: udp, mode: server, address: 127.0.0.1:{p_gcs}}}
bonds:
  - {{name: vehicle, tx: broadcast, renumber: false}}   # the demo knows deliveries by their bytes
filters:
  - {{plugin: dedup, bonds: [vehicle]}}
{stats_filter}"""
    air_conf = f"""# written by scripts/demo: the air-side gateway
log_level: info
endpoints:
  - {{name: autopilot, type: udp, mode: server, address: 127.0.0.1:{p_auto}}}
  - {{name: radio, type: udp, mode: client, address: 127.0.0.1:{la}, bond: ground}}
  - {{name: lte, type: udp, mode: client, address: 127.0.0.1:{lb}, bond: ground}}
bonds:
  - {{name: ground, tx: broadcast, renumber: false}}
filters:
  - {{plugin: dedup, bonds: [ground]}}
"""
    procs = []
    emus = []
    try:
        procs.append(start_mavbond(args.mavbond, workdir, "ground", ground_conf, plugin_dir))
        # radio: Gilbert-Elliott bursts, about 2% loss on average; LTE: slower, 1% loss
        radio = LinkEmulator(listen=f"127.0.0.1:{la}", forward=f"127.0.0.1:{ga}", seed=args.seed,
                             ge="0.005,0.3,0.01,0.5", delay="15ms", record_drops=True)
        lte = LinkEmulator(listen=f"127.0.0.1:{lb}", forward=f"127.0.0.1:{gb}",
                           seed=args.seed + 1, loss="1%", delay="80ms", jitter="10ms",
                           record_drops=True)
        emus = [radio.start(), lte.start()]
        procs.append(start_mavbond(args.mavbond, workdir, "air", air_conf, plugin_dir))
        return bond_run(args, source, vehicle_frames, radio, lte, p_auto, p_gcs, procs,
                        csv_path if have_stats else None, workdir)
    finally:
        for e in emus:
            e.stop()
        for proc, log, _ in procs:
            stop_mavbond(proc, log)


def bond_run(args, source, frames, radio, lte, p_auto, p_gcs, procs, csv_path, workdir) -> int:
    def udp():
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        return s

    vehicle, gcs = udp(), udp()
    gcs_mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    def hello():
        gcs.sendto(gcs_mav.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs_mav), ("127.0.0.1", p_gcs))
        gcs_mav.seq = (gcs_mav.seq + 1) % 256

    hello()
    time.sleep(0.2)
    delivered = []        # frames the GCS got, in order
    sent = []             # (time, frame) the vehicle sent
    pending = Counter()   # delivered, not yet matched to a sent frame
    matched = lost = 0
    cursor = 0

    def drain():
        while True:
            try:
                dg = gcs.recv(65536)
            except BlockingIOError:
                break
            for r in tlog.iter_records_bytes(dg, raw=True):
                if r.kind == "frame" and tlog.sysid(r.data) < 250:
                    delivered.append(r.data)
                    pending[r.data] += 1
        while True:  # what reaches the vehicle (the GCS's heartbeats) is not counted here
            try:
                vehicle.recv(65536)
            except BlockingIOError:
                break

    def settle(cutoff):
        """Matches the frames sent before `cutoff` against what was delivered."""
        nonlocal cursor, matched, lost
        while cursor < len(sent) and sent[cursor][0] < cutoff:
            f = sent[cursor][1]
            if pending[f] > 0:
                pending[f] -= 1
                matched += 1
            else:
                lost += 1
            cursor += 1

    def link_loss(emu):
        c = emu.counters()["up"]
        return c["received"], sum(v for k, v in c.items() if k.startswith("dropped_"))

    print(f"replaying {source}: {len(frames)} vehicle frames over {args.seconds:g} s "
          f"({len(frames) / max(args.seconds, 1e-9):.0f} frames/s) at {args.speed:g}x")
    print("links: radio = 15 ms, Gilbert-Elliott bursts (~2% loss); LTE = 80 +-10 ms, 1% loss")
    print("air mavbond -> both links (broadcast) -> ground mavbond (dedup) -> GCS\n")
    print(f"{'t':>4} {'sent':>6} | {'radio lost':>14} | {'LTE lost':>14} | "
          f"{'both (bound)':>13} | {'GCS got':>7} {'missing (incl. stale)':>21}")
    start = time.monotonic()
    next_row, next_hello = start + 1, start + 1
    for t, frame in frames:
        due = start + t
        while True:
            now = time.monotonic()
            if now >= next_row:
                drain()
                settle(now - 0.5)
                rr, rl = link_loss(radio)
                lr, ll = link_loss(lte)
                pr, pl = rl / max(rr, 1), ll / max(lr, 1)
                print(f"{now - start:4.0f} {len(sent):6} | {rl:5} {pr:7.2%} | {ll:5} {pl:7.2%} | "
                      f"{pr * pl:13.4%} | {len(delivered):7} {lost:12} {lost / max(cursor, 1):8.3%}",
                      flush=True)
                next_row += 1
            if now >= next_hello:
                hello()
                next_hello += 1
            if now >= due:
                break
            drain()
            time.sleep(min(due - now, 0.02))
        vehicle.sendto(frame, ("127.0.0.1", p_auto))
        sent.append((time.monotonic(), frame))
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        drain()
        time.sleep(0.05)
    settle(float("inf"))
    duplicates = sum(pending.values())  # delivered beyond what was sent

    # ground truth from the emulators: which datagrams each link dropped
    n = len(sent)
    cr, cl = radio.counters()["up"], lte.counters()["up"]
    dr = {d["index"] for d in radio.drops() if d["direction"] == "up" and d["reason"] != "corrupted"}
    dl = {d["index"] for d in lte.drops() if d["direction"] == "up" and d["reason"] != "corrupted"}
    aligned = cr["received"] == n and cl["received"] == n
    both = dr & dl
    only_lte = {i for i in dr if i not in dl}  # the radio lost them, the LTE carried them
    pr, pl = len(dr) / max(n, 1), len(dl) / max(n, 1)
    sent_frames = [f for _, f in sent]
    # The delivered stream, without the frames only the LTE carried (late by ~65 ms), is the
    # vehicle's stream in order; those late ones are timestamped samples dropped as stale
    # (a newer one was already delivered) or frames slotted in late.
    reached = [sent_frames[i] for i in range(n) if i not in both]
    late = Counter(sent_frames[i] for i in only_lte) if aligned else Counter()
    in_order_rest = [f for f in delivered if not (late[f] > 0)]
    want_rest = [f for f in reached if not (late[f] > 0)]
    decoder = mavlink.MAVLink(None)
    decoder.robust_parsing = True
    missing = Counter(reached) - Counter(delivered)
    stale = sum(k for f, k in missing.items() if timestamp_of(decoder, f) is not None)
    identical = all(f in set(sent_frames) for f in delivered)

    print(f"\nsummary ({source}, {args.seconds:g} s)")
    print(f"  frames sent by the vehicle     {n}")
    print(f"  radio lost                     {len(dr):6}  {pr:8.3%}  (emulator counters: "
          f"{cr['received']} in, {cr['forwarded']} out)")
    print(f"  LTE lost                       {len(dl):6}  {pl:8.3%}  (emulator counters: "
          f"{cl['received']} in, {cl['forwarded']} out)")
    print(f"  independence bound             {pr * pl * n:8.2f} frames  {pr * pl:8.4%}  "
          f"(radio loss x LTE loss)")
    print(f"  lost on both links             {len(both):6}  {len(both) / max(n, 1):8.4%}")
    print(f"  delivered to the GCS           {len(delivered):6}")
    print(f"  delivered loss                 {n - len(delivered) + duplicates:6}  "
          f"{(n - len(delivered) + duplicates) / max(n, 1):8.4%}  (of which lost on both "
          f"links {len(both)}, stale samples dropped on purpose {stale}, other "
          f"{sum(missing.values()) - stale - 0})")
    print(f"  delivered loss from the links  {len(both):6}  {len(both) / max(n, 1):8.4%}  "
          f"(frames no link carried; against the bound {pr * pl:.4%})")
    print(f"  duplicates delivered           {duplicates:6}")
    print(f"  byte-identical to the vehicle's frames: {'yes' if identical else 'NO'}; in order "
          f"(apart from the {sum(late.values())} frames only the LTE carried, ~65 ms late): "
          f"{'yes' if in_order_rest == want_rest else 'NO'}")
    if not aligned:
        print("  note: an emulator saw a different number of datagrams than the vehicle sent; "
              "per-frame ground truth is approximate")
    if csv_path and os.path.exists(csv_path):
        rows = open(csv_path).read().splitlines()
        print(f"\nground gateway's stats plugin ({csv_path}), last rows:")
        header = rows[0] if rows else ""
        print("  " + header)
        last_t = rows[-1].split(",")[0] if len(rows) > 1 else None
        for r in rows[1:]:
            if r.split(",")[0] == last_t:
                print("  " + r)
    elif csv_path is None:
        print("\n(the stats plugin is not built: no per-link figures from the gateway itself)")
    print(f"\nconfigs and logs: {workdir}")
    for _, _, log_path in procs:
        for line in open(log_path):
            if "[filter:" in line and ("warning" in line or "notice" in line):
                print("  " + os.path.basename(log_path) + ": " + line.rstrip())
    ok = duplicates == 0 and identical and (not aligned or sum(missing.values()) == stale)
    print("\nresult:", "every frame that reached the ground on some link was delivered once, "
          "byte-identical" if ok else "MISMATCH (see above)")
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gateway", action="store_true",
                    help="the plain gateway replay (one mavbond, several GCS peers) instead")
    ap.add_argument("--tlog", help="recording to replay (default: %s)" % DEFAULT_TLOG)
    ap.add_argument("--speed", type=float, help="replay speed-up (default 1x; --gateway: 10x)")
    ap.add_argument("--seconds", type=float, help="stop after this long (default 30; "
                                                   "--gateway: 20)")
    ap.add_argument("--seed", type=int, default=1, help="the link emulators' seed (default 1)")
    ap.add_argument("--plugin-dir", help="where the plugins are (default: found next to the "
                                         "binary's build tree)")
    ap.add_argument("--mavbond", default=os.environ.get(
        "MAVBOND_BIN", os.path.join(ROOT, "build", "src", "mavbond")))
    args = ap.parse_args()
    if args.gateway:
        args.speed = args.speed or 10.0
        args.seconds = args.seconds or 20.0
        return gateway_main(args)
    args.speed = args.speed or 1.0
    args.seconds = args.seconds or 30.0
    return bond_main(args)


if __name__ == "__main__":
    sys.exit(main())
