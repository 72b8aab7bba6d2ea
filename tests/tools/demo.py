"""scripts/demo: a real recording replayed through a running mavbond, and what arrived where.

Topology (all on 127.0.0.1):

    vehicle (replayed tlog) --udp--> [mavbond] --udp--> QGC-like GCS peer   (udp server)
                                              --udp--> MAVProxy-like peer (same udp server)
                                              --tcp--> logger             (tcp server)

Frames of the vehicle's systems go in through the `vehicle` endpoint; frames the recording's
GCS sent (sysid >= 250) go in from the first GCS peer, so both directions are exercised.
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tlog", help="recording to replay (default: %s)" % DEFAULT_TLOG)
    ap.add_argument("--speed", type=float, default=10.0, help="replay speed-up (default 10x)")
    ap.add_argument("--seconds", type=float, default=20.0, help="stop after this long (wall clock)")
    ap.add_argument("--mavbond", default=os.environ.get("MAVBOND_BIN", os.path.join(ROOT, "build", "src", "mavbond")))
    args = ap.parse_args()

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


if __name__ == "__main__":
    sys.exit(main())
