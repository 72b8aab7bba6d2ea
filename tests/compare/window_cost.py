"""What the paper's dedup window costs: false drops of legitimate repeats, measured.

MAVLink's sequence byte wraps every 256 frames, so at 1,000 frames/s byte-identical frames recur
every 0.256 s, well inside a 5 s window. Two ground gateways run side by side on the same
frames and the same link conditions (two emulated links, 5 % loss each, the second 300 ms
behind, i.e. more than one sequence cycle): one with the paper's settings (murmur3_32, 5 s,
drop_stale false), one with mavbond's defaults (murmur3_128, 2 s). The stream is 256 frames
whose bytes repeat forever (the worst case). Ground truth comes from the emulators' drop logs:
every instance that reached the gateway on some link should be delivered once.

The same arrivals are then replayed through two naive matchers in Python, to show what exact
matching buys: the paper's hash set (a frame whose hash was seen within the window is a
duplicate) and a per-link arrival counter (an instance is new when this link has seen the key
more often than the gateway delivered it). A hash-level count of 32-bit collisions among an
hour of distinct frames at 1,000 frames/s completes the picture: in a plain hash set each
collision drops a good frame."""
from __future__ import annotations

import random
import sys
import time
from collections import Counter, deque
from pathlib import Path
from typing import Dict, List

import lab  # noqa: F401  (sets up sys.path)
from bonding_helpers import Emu, Gateway  # noqa: E402
from helpers import HOST, FrameMaker, free_port, udp_server  # noqa: E402
import tlog  # noqa: E402

import mmh3  # noqa: E402

RATE = 1000
SECONDS = 10
LINKS = {"link_a": {"loss": "5%", "delay": "10ms", "seed": 3},
         "link_b": {"loss": "5%", "delay": "300ms", "seed": 4}}
CONFIGS = {
    "paper": {"window": "5s", "hash": "murmur3_32", "drop_stale": False},
    "default": {},
}


def identical_cycle() -> List[bytes]:
    """256 frames of one source whose bytes recur every 256 frames (seq 0..255, fixed
    payloads: HEARTBEAT, SYS_STATUS and VFR_HUD, none with a timestamp)."""
    m = FrameMaker(1, 1)
    out = []
    for seq in range(256):
        m.mav.seq = seq
        k = seq % 3
        if k == 0:
            out.append(m.heartbeat())
        elif k == 1:
            out.append(m.pack(m.mod.MAVLink_sys_status_message(
                0x3FFFFF, 0x3FFFFF, 0x3FFFFF, 250, 12400, 1010, 87, 0, 0, 0, 0, 0, 0)))
        else:
            out.append(m.pack(m.mod.MAVLink_vfr_hud_message(0.5, 0.4, 90, 48, 20.0, 0.1)))
    assert len(set(out)) == 256
    return out


def hash_set_model(arrivals, window: float) -> int:
    """The paper's method: deliver unless the frame's hash was seen within `window`."""
    seen: Dict[bytes, float] = {}
    delivered = 0
    for t, _, f in arrivals:
        if f in seen and t - seen[f] < window:
            continue
        seen[f] = t
        delivered += 1
    return delivered


def counter_model(arrivals, window: float) -> int:
    """Per-link arrival counts: an arrival is new when its link has now seen the key more
    often than the gateway delivered it (counts forgotten `window` after the last arrival)."""
    per_link: Dict[tuple, int] = {}
    delivered_n: Dict[bytes, int] = {}
    last: Dict[bytes, float] = {}
    delivered = 0
    for t, link, f in arrivals:
        if f in last and t - last[f] >= window:
            delivered_n.pop(f, None)
            for l in LINKS:
                per_link.pop((l, f), None)
        last[f] = t
        c = per_link.get((link, f), 0) + 1
        per_link[(link, f)] = c
        if c > delivered_n.get(f, 0):
            delivered_n[f] = c
            delivered += 1
    return delivered


def hash_collisions(seconds: float, rate: int, windows, seed: int = 7) -> Dict[str, int]:
    """Distinct frame-sized inputs (an 8-byte counter and 28 random bytes) at `rate` for
    `seconds`: how many hit the 32-bit MurmurHash3 of another input still inside the window,
    which a plain hash set would drop. (128 bits: 2^-128 per pair, not worth the CPU.)"""
    out = {}
    n = int(seconds * rate)
    for w in windows:
        span = int(w * rate)
        rng = random.Random(seed)
        q: deque = deque()
        live: Counter = Counter()
        hits = 0
        for i in range(n):
            x = mmh3.hash(i.to_bytes(8, "little") + rng.randbytes(28))
            if live[x]:
                hits += 1
            live[x] += 1
            q.append(x)
            if len(q) > span:
                y = q.popleft()
                live[y] -= 1
                if not live[y]:
                    del live[y]
        out[f"{w:g}s"] = hits
    return out


def run(mavbond: str, plugin_dir: str, workdir: Path, log=print) -> dict:
    workdir.mkdir(parents=True, exist_ok=True)
    cycle = identical_cycle()
    n = RATE * SECONDS
    frames = [cycle[i % 256] for i in range(n)]
    gws, emus, gcs_socks = {}, {}, {}
    try:
        for name, filt in CONFIGS.items():
            ports = {l: free_port() for l in LINKS}
            p_gcs = free_port()
            eps = [udp_server(l, ports[l], bond="vehicle") for l in LINKS]
            eps.append(udp_server("gcs", p_gcs))
            g = Gateway(mavbond, workdir, eps, bonds=[{"name": "vehicle", "tx": "broadcast"}],
                        filters=[{"plugin": "dedup", "bonds": ["vehicle"], **filt}],
                        name=f"ground-{name}", plugin_dir=plugin_dir, log_level="info")
            gws[name] = g.start()
            for l, o in LINKS.items():
                opts = {k: v for k, v in o.items() if k != "seed"}
                emus[(name, l)] = lab.ParallelEmu(workdir, f"{name}-{l}", free_port(), ports[l],
                                                  seed=o["seed"], **opts)
            gcs_socks[name] = (lab.udp_sock(), p_gcs)
        for e in emus.values():
            e.launch()
        deadline = time.monotonic() + 10
        for e in emus.values():
            e.wait_started(deadline)
        for e in emus.values():
            e.release()

        class Rig:  # what lab.Collector needs
            def __init__(self, sock, port):
                self.gcs, self.p_gcs, self.mode = sock, port, "dedup"
                self.gcs.setblocking(False)
                self.received = []
        rigs = {name: Rig(*gcs_socks[name]) for name in CONFIGS}
        coll = lab.Collector(list(rigs.values()))
        coll.start()
        time.sleep(0.3)
        log(f"[window] {n} frames at {RATE}/s, a 256-frame cycle of identical bytes, "
            f"two gateways (paper, default)")
        senders = {k: lab.udp_sock() for k in emus}
        start = time.monotonic() + 0.05
        sent = []
        i = 0
        while i < n:
            now = time.monotonic()
            due = start + i / RATE
            if due > now + 0.001:
                time.sleep(min(due - now - 0.0005, 0.01))
                continue
            while i < n and start + i / RATE <= now + 0.001:
                sent.append(time.monotonic())
                for k, e in emus.items():
                    senders[k].sendto(frames[i], (HOST, e.listen_port))
                i += 1
        time.sleep(1.0)
        coll.stop_flag = True
        coll.join(2)
        result = {"n": n, "rate": RATE, "seconds": SECONDS, "links": LINKS, "configs": {}}
        for name in CONFIGS:
            for l in LINKS:
                emus[(name, l)].stop()  # the drop log is complete once it has exited
            drops = {l: emus[(name, l)].dropped() for l in LINKS}
            recv = {l: emus[(name, l)].counters()["up"]["received"] for l in LINKS}
            reached = [i for i in range(n) if not all(i in d for d in drops.values())]
            got = [f for _, f in rigs[name].received if tlog.sysid(f) == 1]
            want = Counter(frames[i] for i in reached)
            have = Counter(got)
            missing, extra = want - have, have - want
            # the same arrivals through the naive matchers (arrival = sent + the link's delay)
            delay = {"link_a": 0.010, "link_b": 0.300}
            arrivals = sorted((sent[i] + delay[l], l, frames[i])
                              for l in LINKS for i in range(n) if i not in drops[l])
            w = 5.0 if name == "paper" else 2.0
            result["configs"][name] = {
                "filter": CONFIGS[name], "received": recv,
                "lost": {l: len(d) for l, d in drops.items()},
                "lost_all": n - len(reached), "reached": len(reached),
                "delivered": len(got), "false_drops": sum(missing.values()),
                "duplicates": sum(extra.values()),
                "naive_hash_set_false_drops": len(reached) - hash_set_model(arrivals, w),
                "naive_counter_false_drops": len(reached) - counter_model(arrivals, w),
                "window_s": w,
            }
            log(f"[window] {name}: {result['configs'][name]}")
        t = time.monotonic()
        result["collisions_hour"] = hash_collisions(3600, RATE, (5.0, 2.0))
        result["collision_seconds"] = 3600
        log(f"[window] 32-bit collisions over an hour at {RATE}/s: "
            f"{result['collisions_hour']} ({time.monotonic() - t:.0f} s)")
        return result
    finally:
        for e in emus.values():
            e.kill()
        for g in gws.values():
            g.kill()


if __name__ == "__main__":
    import json
    print(json.dumps(run(sys.argv[1], sys.argv[2], Path(sys.argv[3])), indent=1))
