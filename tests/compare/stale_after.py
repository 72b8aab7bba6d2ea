"""dedup's stale_after, from measurements: the same arrivals through six dedup gateways at once
(stale_after 0, 100 ms, 250 ms, 500 ms, 1 s, and drop_stale off), on the scenarios where
lateness matters. For each: how many samples dedup dropped as stale (its own counter), the
delivered loss against the independence bound (the product of the links' loss rates: what no
link carried, if losses are independent), and the largest step back in time_boot_ms /
time_usec that a GCS saw (how far a delivered sample was behind one delivered before it).

What a setting trades: a late copy of a sample that another link lost is either delivered (the
GCS sees time step back by its lateness) or dropped (a lost frame). stale_after 0 was the old
rule: any sample older than the newest delivered was dropped. The gateways are not frozen
here: this is about what the links add in normal operation."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import analyze
import lab
import scenarios as S

SETTINGS = {  # name: (dedup options, stale_after in ns for the analysis)
    "0": ({"stale_after": "0s"}, 0),
    "100ms": ({"stale_after": "100ms"}, 100_000_000),
    "250ms": ({"stale_after": "250ms"}, 250_000_000),
    "500ms": ({"stale_after": "500ms"}, 500_000_000),
    "1s": ({"stale_after": "1s"}, 1_000_000_000),
    "off": ({"drop_stale": False}, None),
}
DEFAULT = "250ms"

# The issue's case: at 1,000 samples/s a copy from a link 30 ms behind is 30 samples late.
STAMPED_1KHZ = S.Scenario(
    "stamped_1khz", "1,000 timestamped frames/s, the second link 30 ms behind", 10,
    [S.Link("a", "1 %, 10 ms", 91, {"loss": "1%", "delay": "10ms"}),
     S.Link("b", "1 %, 40 ms", 92, {"loss": "1%", "delay": "40ms"})],
    stream="stamped_1khz")

CASES = [dataclasses.replace(S.get("skew"), seconds=20),
         dataclasses.replace(S.get("radio_lte"), seconds=20),
         dataclasses.replace(S.get("three"), seconds=20),
         dataclasses.replace(S.get("repeats_1khz"), seconds=10),
         STAMPED_1KHZ]
SECONDS = sum(c.seconds for c in CASES)


def run(mavbond: str, plugin_dir: str, stream_source: str, workdir: Path, log=print) -> dict:
    out = {"settings": list(SETTINGS), "default": DEFAULT, "cases": {}}
    for sc in CASES:
        links = [l.name for l in sc.links]
        modes = {name: (links, [{"plugin": "dedup", "bonds": ["vehicle"], **opts}])
                 for name, (opts, _) in SETTINGS.items()}
        raw = lab.run(sc, mavbond, plugin_dir, lab.stream_for(sc, stream_source),
                      workdir / sc.name, modes=modes, stall=False, log=log)
        timestamped = sum(s is not None for s in raw["sample"])
        case = {"title": sc.title, "seconds": sc.seconds, "n": raw["n"], "stream": raw["stream"],
                "links": {l.name: l.label for l in sc.links}, "timestamped": timestamped,
                "results": {}}
        for name, (_, ns) in SETTINGS.items():
            x = analyze.mode_metrics(raw, name, stale_after_ns=ns if ns is not None else 1 << 62)
            case["results"][name] = {
                k: x[k] for k in ("stale_counted", "stale_seen", "delivered_loss", "not_delivered",
                                  "bound", "lost_all", "link_loss", "duplicates", "good_dropped",
                                  "step_back_ms")}
            case["results"][name]["problems"] = analyze.dedup_verdict(x, stalled=False)
        log(f"[stale] {sc.name}: " + "; ".join(
            f"{k} stale {r['stale_counted']} loss {r['delivered_loss']:.4%} back "
            f"{r['step_back_ms']:.0f} ms" for k, r in case["results"].items()))
        out["cases"][sc.name] = case
    return out
