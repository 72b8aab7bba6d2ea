"""What the paper's dedup window costs: false drops of legitimate repeats, measured.

MAVLink's sequence byte wraps every 256 frames, so at 1,000 frames/s byte-identical frames recur
every 0.256 s, well inside a 5 s window. Two ground gateways run side by side on the same
datagrams (lab.run: two emulated links teed to both, 5 % loss each, the second 300 ms behind,
i.e. more than one sequence cycle; frozen like the scenarios' gateways unless --no-stall): one
with the paper's settings (murmur3_32, 5 s, drop_stale false), one with mavbond's defaults
(murmur3_128, 2 s). The stream is 256 frames whose bytes repeat forever (the worst case).
Ground truth comes from the emulator's drop logs: every instance that reached the gateway on
some link should be delivered once (counted per frame: which instance of a repeat a delivery
was, its bytes cannot tell, but not one more or fewer).

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

import analyze
import lab
import scenarios as S
from helpers import FrameMaker  # noqa: E402  (tests/integration, on the path through lab)

import mmh3  # noqa: E402

RATE = 1000
SECONDS = 10
LINKS = [S.Link("link_a", "5 %, 10 ms", 3, {"loss": "5%", "delay": "10ms"}),
         S.Link("link_b", "5 %, 300 ms", 4, {"loss": "5%", "delay": "300ms"})]
DELAY = {"link_a": 0.010, "link_b": 0.300}   # for the naive matchers' arrivals
CONFIGS = {
    "paper": ({"window": "5s", "hash": "murmur3_32", "drop_stale": False}, 5.0),
    "default": ({}, 2.0),
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
            for l in DELAY:
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


def run(mavbond: str, plugin_dir: str, workdir: Path, stall: bool = True, log=print) -> dict:
    cycle = identical_cycle()
    n = RATE * SECONDS
    schedule = [(i / RATE, cycle[i % 256]) for i in range(n)]
    sc = S.Scenario("window", "the dedup window", SECONDS, LINKS)
    links = [l.name for l in LINKS]
    modes = {name: (links, [{"plugin": "dedup", "bonds": ["vehicle"], **opts}])
             for name, (opts, _) in CONFIGS.items()}
    raw = lab.run(sc, mavbond, plugin_dir, ("a 256-frame cycle of identical bytes", schedule),
                  workdir, modes=modes, stall=stall, log=log)
    result = {"n": n, "rate": RATE, "seconds": SECONDS, "stall": stall,
              "links": {l.name: l.opts for l in LINKS}, "configs": {}}
    for name, (opts, window) in CONFIGS.items():
        x = analyze.mode_metrics(raw, name)
        m = raw["modes"][name]
        drops = {l: {i for i, _ in m["drops"][l]} for l in links}
        # the same arrivals through the naive matchers (arrival = sent + the link's delay)
        arrivals = sorted((raw["sent"][i] + DELAY[l], l, schedule[i][1])
                          for l in links for i in range(n) if i not in drops[l])
        reached = n - x["lost_all"]
        result["configs"][name] = {
            "filter": opts, "lost": {l: len(d) for l, d in drops.items()},
            "lost_all": x["lost_all"], "reached": reached,
            "delivered": x["delivered"] + x["duplicates"], "false_drops": x["carried_lost"],
            "duplicates": x["duplicates"], "problems": analyze.evidence_problems(x, stall),
            "naive_hash_set_false_drops": reached - hash_set_model(arrivals, window),
            "naive_counter_false_drops": reached - counter_model(arrivals, window),
            "window_s": window,
        }
        log(f"[window] {name}: {result['configs'][name]}")
    t = time.monotonic()
    result["collisions_hour"] = hash_collisions(3600, RATE, (5.0, 2.0))
    result["collision_seconds"] = 3600
    log(f"[window] 32-bit collisions over an hour at {RATE}/s: "
        f"{result['collisions_hour']} ({time.monotonic() - t:.0f} s)")
    return result


if __name__ == "__main__":
    import json
    print(json.dumps(run(sys.argv[1], sys.argv[2], Path(sys.argv[3])), indent=1))
