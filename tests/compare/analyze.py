"""Figures from one scenario's raw record (lab.run): per mode, what each link lost (from the
emulators' drop logs), what the GCS got (matched to what the vehicle sent), per second and in
total, and what each link switch cost."""
from __future__ import annotations

import bisect
import math
from typing import Dict, List, Optional


def percentile(values: List[float], q: float) -> Optional[float]:
    if not values:
        return None
    v = sorted(values)
    k = (len(v) - 1) * q
    lo, hi = math.floor(k), math.ceil(k)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def link_of(logged: str, links: List[str]) -> str:
    """'link1@127.0.0.1:40000' (a UDP server's peer) -> 'link1'."""
    return next((l for l in links if logged == l or logged.startswith(l + "@")), logged)


def mode_metrics(raw: dict, mode: str) -> dict:
    n = raw["n"]
    sent = raw["sent"]
    m = raw["modes"][mode]
    links = m["links"]
    lost = {name: {i for i, _ in m["drops"][name]} for name in links}
    reasons = {name: {} for name in links}
    for name in links:
        for _, why in m["drops"][name]:
            reasons[name][why] = reasons[name].get(why, 0) + 1
    aligned = all(m["received_by_link"][name] == n for name in links)
    lost_all = set.intersection(*lost.values()) if lost else set()

    # Out of order: delivered after a later frame of the same source (what a GCS sees as its
    # sequence number going back); frames of different components may interleave freely.
    first: Dict[int, float] = {}
    duplicates = out_of_order = 0
    highest: Dict[int, int] = {}
    source = raw["source"]
    for i, t in m["deliveries"]:
        if i in first:
            duplicates += 1
            continue
        first[i] = t
        s = source[i]
        if i < highest.get(s, -1):
            out_of_order += 1
        else:
            highest[s] = i
    delivered = len(first)
    not_delivered = [i for i in range(n) if i not in first]
    carried_lost = [i for i in not_delivered if i not in lost_all]
    stale_kind = sum(1 for i in carried_lost if raw["has_time"][i])
    latency = [(first[i] - sent[i]) * 1e3 for i in first]

    # Link switches: detection (from the last frame the old link delivered to the switch) and
    # the frames lost to it (the new link carried them, but they came before it was active).
    switches = []
    order = sorted(first.items(), key=lambda kv: kv[1])
    times = [t for _, t in order]
    # A switch logged after the stream ended is the end of the stream, not of a link.
    for t_sw, old, new, why in [s for s in m["switches"] if s[0] <= max(sent) + 0.5]:
        old_n, new_n = link_of(old, links), link_of(new, links)
        k = bisect.bisect_right(times, t_sw)
        before = order[k - 1] if k > 0 else None
        after = order[k] if k < len(order) else None
        lo = before[0] if before else -1
        hi = after[0] if after else n
        lost_sw = [i for i in range(lo + 1, hi) if i not in first
                   and i not in lost.get(new_n, set())]
        switches.append({
            "t": t_sw, "from": old_n, "to": new_n, "reason": why,
            "detection_ms": (t_sw - before[1]) * 1e3 if before else None,
            "gap_ms": (after[1] - before[1]) * 1e3 if before and after else None,
            "lost": len(lost_sw),
        })

    # per second of the stream (by when a frame left the vehicle)
    secs = int(math.ceil(max(sent) + 1e-9)) if sent else 0
    per_sec_n = [0] * secs
    for t in sent:
        per_sec_n[min(int(t), secs - 1)] += 1
    def series(indices) -> List[Optional[float]]:
        c = [0] * secs
        for i in indices:
            c[min(int(sent[i]), secs - 1)] += 1
        return [c[k] / per_sec_n[k] * 100 if per_sec_n[k] else None for k in range(secs)]
    per_second = {name: series(lost[name]) for name in links}
    per_second["delivered"] = series(not_delivered)

    link_loss = {name: len(lost[name]) / n for name in links}
    bound = math.prod(link_loss.values()) if len(links) > 1 else link_loss[links[0]]
    return {
        "mode": mode, "links": links, "n": n, "aligned": aligned,
        "link_loss": link_loss, "link_reasons": reasons,
        "lost_all": len(lost_all), "bound": bound,
        "delivered": delivered, "delivered_loss": (n - delivered) / n,
        "not_delivered": len(not_delivered), "carried_lost": len(carried_lost),
        "carried_lost_timestamped": stale_kind,
        "duplicates": duplicates, "out_of_order": out_of_order, "foreign": m["foreign"],
        "latency_p50": percentile(latency, 0.5), "latency_p99": percentile(latency, 0.99),
        "latency_max": max(latency) if latency else None,
        "switches": switches,
        "switch_lost": sum(s["lost"] for s in switches),
        "per_second": per_second,
    }


def scenario_metrics(raw: dict) -> Dict[str, dict]:
    return {mode: mode_metrics(raw, mode) for mode in raw["modes"]}
