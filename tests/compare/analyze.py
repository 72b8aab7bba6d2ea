"""Figures from one scenario's raw record (lab.run): per mode, what each link lost (from the
emulator's drop logs), what the GCS got (matched to what the vehicle sent), per second and in
total, what each link switch cost, and the strict verdict on dedup: no duplicate delivered,
no good frame dropped.

A frame some link carried that dedup did not deliver is a good frame dropped, unless it is a
timestamped sample that dedup dropped as stale: more than stale_after behind the newest
sample of its (sysid, compid, msgid) that was delivered. The daemon's own count of those
(`stale` in its status) must equal the number of such frames missing."""
from __future__ import annotations

import bisect
import math
from collections import Counter
from typing import Dict, List, Optional

STALE_AFTER_NS = 250_000_000   # dedup's default stale_after, which the scenarios keep


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


def step_back_ms(raw: dict, deliveries) -> float:
    """The largest step back in time_boot_ms / time_usec a GCS saw: how far a delivered
    sample was behind the newest of its stream delivered before it."""
    newest: Dict[int, int] = {}
    worst = 0
    for i, _ in deliveries:
        s = raw["sample"][i]
        if s is None:
            continue
        stream, ns = s
        if stream in newest:
            worst = max(worst, newest[stream] - ns)
            newest[stream] = max(newest[stream], ns)
        else:
            newest[stream] = ns
    return worst / 1e6


def mode_metrics(raw: dict, mode: str, stale_after_ns: int = STALE_AFTER_NS) -> dict:
    n = raw["n"]
    sent = raw["sent"]
    m = raw["modes"][mode]
    links = m["links"]
    lost = {name: {i for i, _ in m["drops"][name]} for name in links}
    reasons = {name: dict(Counter(why for _, why in m["drops"][name])) for name in links}
    aligned = all(m["received_by_link"][name] == n for name in links)
    lost_all = set.intersection(*lost.values()) if lost else set()
    # Which deliveries are exactly one frame (see lab.match): latency and order are measured
    # on those only; counts are exact for all.
    run_size = Counter(raw["alike"])
    exact = [run_size[raw["alike"][i]] == 1 for i in range(n)]

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
        if not exact[i]:
            continue
        s = source[i]
        if i < highest.get(s, -1):
            out_of_order += 1
        else:
            highest[s] = i
    delivered = len(first)
    not_delivered = [i for i in range(n) if i not in first]
    carried_lost = [i for i in not_delivered if i not in lost_all]
    latency = [(first[i] - sent[i]) * 1e3 for i in first if exact[i]]

    # Stale: a carried sample missing because a newer one of its stream, delivered, is more
    # than stale_after ahead of it (dedup's rule; its samples are ints, so is this check).
    newest: Dict[int, int] = {}
    for i in first:
        if raw["sample"][i] is not None:
            stream, ns = raw["sample"][i]
            newest[stream] = max(newest.get(stream, ns), ns)
    stale_seen = [i for i in carried_lost if raw["sample"][i] is not None
                  and newest.get(raw["sample"][i][0], -1) - raw["sample"][i][1] > stale_after_ns]
    dedup = m.get("dedup")
    stale_counted = sum(l["stale"] for l in dedup["links"]) if dedup else None

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
    if dedup:
        per_second["stale"] = series(stale_seen)

    link_loss = {name: len(lost[name]) / n for name in links}
    bound = math.prod(link_loss.values()) if len(links) > 1 else link_loss[links[0]]
    freezes = m.get("freezes", [])
    return {
        "mode": mode, "links": links, "n": n, "aligned": aligned,
        "link_loss": link_loss, "link_reasons": reasons,
        "lost_all": len(lost_all), "bound": bound,
        "delivered": delivered, "delivered_loss": (n - delivered) / n,
        "not_delivered": len(not_delivered), "carried_lost": len(carried_lost),
        "stale_seen": len(stale_seen), "stale_counted": stale_counted,
        # dedup's own measure of how far behind the first copy each link's copies come
        "lag_ms": {link_of(l["name"], links): l["lag_ms"] for l in dedup["links"]}
        if dedup else {},
        "good_dropped": len(carried_lost) - len(stale_seen),
        "duplicates": duplicates, "out_of_order": out_of_order, "foreign": m["foreign"],
        "exact_share": sum(exact) / n if n else 1.0,
        "latency_p50": percentile(latency, 0.5), "latency_p99": percentile(latency, 0.99),
        "latency_max": max(latency) if latency else None,
        "step_back_ms": step_back_ms(raw, m["deliveries"]),
        "switches": switches,
        "switch_lost": sum(s["lost"] for s in switches),
        "freezes": freezes, "frozen_s": sum(b - a for a, b in freezes),
        "stall_error": m.get("stall_error"), "held_back": m.get("held_back"),
        "rx_overflows": sum(m.get("rx_overflows", {}).values()),
        "gcs_drops": m.get("gcs_drops", 0), "exit_code": m.get("exit_code", 0),
        "per_second": per_second,
    }


def scenario_metrics(raw: dict) -> Dict[str, dict]:
    return {mode: mode_metrics(raw, mode) for mode in raw["modes"]}


def evidence_problems(x: dict, stalled: bool) -> List[str]:
    """Why a mode's record cannot be judged: the figures rest on every link having seen
    every frame (the drop logs index the stream), nothing lost outside the emulator (the
    gateway's and the GCS socket's kernel counters), a clean exit, and freezes that happened
    and left a backlog (the daemon's own count of frames held back for arrival order)."""
    out = []
    if not x["aligned"]:
        out.append("a link did not get every frame, so its drop log does not index the stream")
    if x["rx_overflows"]:
        out.append(f"{x['rx_overflows']} datagrams overflowed the gateway's receive buffers")
    if x["gcs_drops"]:
        out.append(f"{x['gcs_drops']} datagrams overflowed the GCS socket")
    if x["foreign"]:
        out.append(f"{x['foreign']} deliveries match nothing the vehicle sent")
    if x["exit_code"]:
        out.append(f"the ground gateway exited with {x['exit_code']}")
    if stalled:
        if x["stall_error"]:
            out.append(f"the stall injector failed: {x['stall_error']}")
        elif not x["freezes"]:
            out.append("the gateway was never frozen")
        elif not x["held_back"]:
            out.append("the freezes left no backlog to merge (0 frames held back)")
    return out


def dedup_verdict(x: dict, stalled: bool) -> List[str]:
    """Why dedup's run fails the strict standard: [] when it passes."""
    out = evidence_problems(x, stalled)
    if x["duplicates"]:
        out.append(f"{x['duplicates']} duplicates delivered")
    if x["good_dropped"]:
        out.append(f"{x['good_dropped']} good frames dropped (some link carried them, dedup "
                   f"did not deliver them, and they are not samples stale_after behind)")
    if x["stale_counted"] != x["stale_seen"]:
        out.append(f"dedup counted {x['stale_counted']} stale samples dropped, "
                   f"{x['stale_seen']} such samples are missing")
    return out
