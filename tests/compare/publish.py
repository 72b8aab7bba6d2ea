"""--publish: copies a run's results.md and PNGs to tests/compare/results/ and rewrites the
README's "## Results" and "## Exact under stress" sections from that run (only those: each
ends at the next "## "; a missing "Exact under stress" goes right after "Results"). With
--readme-out FILE the two sections go to FILE instead, and README.md is left alone."""
from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Optional

import compare as C
import scenarios as S

REPO = C.REPO
RESULTS = C.RESULTS
MAX_PNG = 200 * 1024

# What the issue "Exact under stress" recorded before dedup matched copies by identity and the
# daemon merged backlogs in arrival order (for the record, beside this run's figures).
BEFORE = {"paper": "25 duplicates, 2 good dropped", "skew": "38 duplicates",
          "radio_lte": "10 duplicates", "repeats_1khz": "26 duplicates, 6 dropped"}


def section(rep, runtime: float, checks) -> str:
    mets, window = rep["mets"], rep["window"]
    pct = C.pct
    L = ["## Results", "",
         "Which is better for a given pair of links: deduplication, link switching, or just one "
         f"link? `scripts/compare` answers it for the paper's conditions and "
         f"{len(rep['summary']) - 1} more, with real processes: an air-side mavbond, one link "
         "emulator process carrying every path (`tests/tools/linkemu.py --group`, seeded) and a "
         "ground-side mavbond per mode, and the ArduSub dive of `scripts/demo` replayed at its "
         "own pace (its autopilot, about 118 frames/s; `--stream synth` gives the synthetic "
         "124 frames/s stream, `--stream FILE.tlog` your own recording; `repeats_1khz` has a "
         "stream of its own). Every scenario runs one link alone, `linkswitch` and `dedup` "
         "(both with their defaults) side by side: the emulator tees each link to the ground "
         "gateway of every mode that uses it, so all three get the same datagrams, lost and "
         "delayed alike."
         + (" Every ground gateway is frozen 150 ms every 2 to 2.5 s and once for a whole "
            "second, as a busy companion computer freezes it (`--no-stall`: never); see "
            "[Exact under stress](#exact-under-stress)." if rep["stalled"] else "")
         + " Per-link loss comes from the emulator's drop logs, stale drops from dedup's own "
         "counter, the rest from what the GCS received.", "",
         "```sh",
         f"scripts/compare               # everything: tables and plots into build/compare/ "
         f"({runtime / 60:.0f} min on 2 cores)",
         "scripts/compare --only paper  # one scenario (--list names them); --scale 0.25 for "
         "a quick look",
         "scripts/compare --no-stall    # without freezing the gateways",
         "scripts/compare --publish     # and refresh tests/compare/results/ and this section",
         "```", ""]
    L += ["Delivered loss (what the GCS did not get, of the frames the vehicle sent):", "",
          "| scenario | loss per link | independence bound | one link alone | linkswitch | "
          "dedup |", "|---|---|---:|---:|---:|---:|"]
    for r in rep["summary"]:
        m = mets[r["name"]]
        links = ", ".join(pct(v) for v in m["dedup"]["link_loss"].values())
        L.append(f"| {r['name']}: {r['title']} | {links} | {pct(r['bound'], 4)} | "
                 + " | ".join(pct(r[mo], 3) for mo in S.MODES) + " |")
    L += ["", "![delivered loss by scenario](tests/compare/results/summary.png)", ""]

    p = mets.get("paper")
    if p:
        sc = S.get("paper")
        d, ls = p["dedup"], p["linkswitch"]
        best = min(ls["link_loss"].values())
        L += ["### The paper's scenario", "",
              f"Two links with 1 % random loss each, {sc.seconds:g} s of stream "
              f"(Fig. 5.1 and 5.2 of the paper are the lower two panels):", ""]
        L += C.scenario_table(sc, p) + [""]
        exact = ("exactly the frames both links lost" if d["not_delivered"] == d["lost_all"]
                 else f"{d['lost_all']} of them lost on both links")
        stay = ("never had a reason to leave link1, so it" if not ls["switches"]
                else f"switched {len(ls['switches'])} times and")
        L += [f"dedup lost {d['not_delivered']} of {d['n']} frames "
              f"({pct(d['delivered_loss'], 4)}), {exact}"
              + (": every frame that some link carried was delivered once" if
                 d["not_delivered"] == d["lost_all"] else "")
              + f". The independence bound is {pct(d['bound'], 4)} ({d['bound'] * d['n']:.1f} "
              f"frames); how often the two seeded loss patterns overlap is chance. linkswitch "
              f"{stay} delivered {pct(ls['delivered_loss'], 3)}, against "
              f"{pct(best, 3)} on the best link: the paper's finding. The paper reports 10 % "
              f"to 30 % less loss with deduplication; with exact matching the loss left is what "
              f"no link carried.", ""]
        L += ["![the paper's scenario](tests/compare/results/paper.png)", ""]
        for what, ok, detail in checks:
            if what.startswith("paper"):
                L.append(f"- {'yes' if ok else 'NO'}: {what} ({detail})")
        L.append("")

    o = mets.get("outage")
    if o and o["linkswitch"]["switches"]:
        sw = o["linkswitch"]["switches"][0]
        sc = S.get("outage")
        L += ["### Switchover, from the data", ""]
        L += [f"In the outage scenario link1 is dead for {sc.outages['link1'][1]:g} s. "
              f"`linkswitch` (switch_after 1s) logged its switch {sw['detection_ms']:.0f} ms "
              f"after the last frame link1 delivered (1 s of silence plus at most one 50 ms "
              f"check, counted in the kernel's receive times, so a frozen gateway does not "
              f"mistake its own freeze for silence); the GCS got nothing for "
              f"{sw['gap_ms']:.0f} ms and lost {sw['lost']} frames that link2 carried "
              f"meanwhile, {o['linkswitch']['switch_lost']} in all switches. dedup has no "
              f"switchover: it lost {o['dedup']['not_delivered']} frames, the ones link2 lost "
              f"while link1 was down (lost on both: {o['dedup']['lost_all']}). One link alone "
              f"lost the whole outage ({pct(o['single']['delivered_loss'], 1)}).", ""]
        b = mets.get("bursty")
        if b:
            bl = b["linkswitch"]
            best = min(bl["link_loss"].values())
            rel = ("slightly below its best link's" if bl["delivered_loss"] < best
                   else "no better than its best link's")
            L += [f"On bursty links switching is a gamble: with two radios fading independently "
                  f"({', '.join(pct(v) for v in bl['link_loss'].values())}), linkswitch switched "
                  f"{len(bl['switches'])} times and delivered {pct(bl['delivered_loss'], 3)}, "
                  f"{rel} ({pct(best, 3)}); it judges loss only over a full window of at least "
                  f"100 frames and switches only to a clearly better backup, so two links of "
                  f"similar loss stay put. dedup delivered "
                  f"{pct(b['dedup']['delivered_loss'], 3)}.", ""]
        L += ["![outage](tests/compare/results/outage.png)", ""]

    if window:
        wp, wd = window["configs"]["paper"], window["configs"]["default"]
        why = []
        for name in ("skew", "radio57600", "radio_lte", "three"):
            lags = {l: v for l, v in mets.get(name, {}).get("dedup", {}).get("lag_ms", {}).items()
                    if v is not None}
            if lags:
                slow = max(lags, key=lags.get)
                why.append(f"{name} {slow} {lags[slow]:.0f} ms")
        L += ["### The dedup window, from the data", ""]
        L += ["The window only has to outlast the largest skew between a bond's links"
              + (" (dedup's own measure of how far behind the first copy the slowest link's "
                 "copies came, `lag_ms`: " + ", ".join(why) + ")" if why else "")
              + ". LTE and satellite paths spike past 1 s under load, so the default is 2 s. "
              "Matching by identity (a frame's position in its source's stream, not its "
              "arrival time) makes a longer window safe; what a window costs is memory "
              "(`max_entries`) and how late a copy may come and still be caught.", ""]
        L += C.window_section(window) + [""]
        L += [f"Measured: with mavbond's matching neither the paper's settings nor the default "
              f"dropped a legitimate repeat ({wp['false_drops']} and {wd['false_drops']} false "
              f"drops of {wp['reached']} instances that reached the gateway). The paper's "
              f"method, a hash set over the window, would have dropped "
              f"{wp['naive_hash_set_false_drops']} of them with 5 s: every repeat of a frame "
              f"seen in the last 5 s, which at 1,000 frames/s is almost the whole stream. "
              f"Counting arrivals per link instead loses "
              f"{wp['naive_counter_false_drops']}: whenever the fast link lost an instance, "
              f"the slow link's copy of it was counted against the next one. The remaining "
              f"cost of the paper's choice is the 32-bit hash: with 5 s at 1,000 distinct "
              f"frames/s, {window['collisions_hour'].get('5s')} collisions in an hour, each a "
              f"good frame dropped by a hash set (mavbond compares keys only at the same "
              f"position of the same source, where the links carry copies of one frame); 128 "
              f"bits make it impossible in practice.", ""]
    L += [f"Every scenario's table (per-link loss, duplicates, good frames dropped, stale "
          f"drops, order, switchover, latency, freezes) and plot: "
          f"[tests/compare/results/results.md](tests/compare/results/results.md). The latency "
          f"tails (p99 near a second) are the freezes: frames wait in the kernel while the "
          f"gateway is stopped.", ""]
    return "\n".join(L)


def stress_section(rep, runtime: float) -> str:
    """The README's "Exact under stress": dedup's strict verdict per scenario with the
    freezes, and stale_after from the measurements."""
    mets, st = rep["mets"], rep.get("stale")
    pct = C.pct
    L = ["## Exact under stress", "",
         "A companion computer busy with video or a log upload stops the daemon now and then. "
         "The frames keep coming: the kernel queues them on each link's socket (`rx_buffer`) "
         "with their receive time, and after the stall the daemon merges a bond's backlogs in "
         "arrival order, so dedup sees what it would have seen, only later. What it decides "
         "does not depend on timing: a copy is matched to its frame by identity (its position "
         "in its source's stream), not by when it comes."
         " `scripts/compare` freezes every ground gateway (SIGSTOP/SIGCONT) 150 ms every 2 to "
         "2.5 s and once for a whole second, in every scenario, and judges dedup strictly: a "
         "frame some link carried that dedup did not deliver is a good frame dropped, unless "
         "it is a timestamped sample more than `stale_after` behind one of its stream that was "
         "delivered, and dedup's own `stale` counter must count exactly those. One duplicate, "
         "one good frame dropped, one datagram a socket overflowed, and the run fails, naming "
         "the scenario; no run is ever repeated. `tests/integration/test_stalls.py` does the "
         "same on seven bonded scenarios, a frozen and an unfrozen gateway side by side on the "
         "same datagrams: they deliver the same frames in the same order.", ""]
    if rep["stalled"]:
        L += ["| scenario | frames | freezes (frozen) | held back for arrival order | "
              "duplicates | good frames dropped | stale drops | dedup delivered loss | "
              "independence bound | before (the issue) |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
        for r in rep["summary"]:
            d = mets[r["name"]]["dedup"]
            L.append(f"| {r['name']} | {d['n']} | {C.freezes(d)} | {d['held_back']} | "
                     f"**{d['duplicates']}** | **{d['good_dropped']}** | {d['stale_counted']} | "
                     f"{pct(d['delivered_loss'], 3)} | {pct(d['bound'], 4)} | "
                     f"{BEFORE.get(r['name'], '')} |")
        L += ["", "Datagrams that overflowed a socket of dedup's gateways or their GCS: "
              f"{sum(m['dedup']['rx_overflows'] + m['dedup']['gcs_drops'] for m in mets.values())}"
              ". What dedup lost beyond what no link carried is stale samples, by its own "
              "count.", ""]
    if st:
        default = st["default"]
        settings = st["settings"]
        names = {"0": "0 (old rule)", "off": "off"}
        L += ["### stale_after, from the data", "",
              "A late copy of a sample another link lost is either delivered (the GCS sees "
              "the sample's time step back by its lateness) or dropped as stale (a frame "
              "lost). Six dedup gateways on the same datagrams, not frozen, one per setting; "
              "each cell: delivered loss, samples dropped as stale, and the largest step back "
              "in time_boot_ms / time_usec the GCS saw:", "",
              "| scenario | bound | " + " | ".join(
                  f"**{names.get(k, k)}**" if k == default else names.get(k, k)
                  for k in settings) + " |",
              "|---|---:|" + "---:|" * len(settings)]
        for name, c in st["cases"].items():
            res = c["results"]
            cells = [f"{pct(res[k]['delivered_loss'], 3)}, {res[k]['stale_counted']} stale, "
                     f"{res[k]['step_back_ms']:.0f} ms" for k in settings]
            L.append(f"| {name} | {pct(res[default]['bound'], 4)} | " + " | ".join(cells) + " |")
        L += [""] + [f"- {name}: {c['title']}; "
                     + "; ".join(f"{l} {label}" for l, label in c["links"].items())
                     + f" ({c['seconds']:g} s)" for name, c in st["cases"].items()]
        L += ["", stale_verdict(st), ""]
    L += ["```sh",
          "scripts/compare                            # every scenario frozen, the stale_after "
          f"sweep ({runtime / 60:.0f} min on 2 cores)",
          "scripts/compare --only repeats_1khz,stale  # one scenario and the sweep",
          ".venv/bin/python -m pytest tests/integration/test_stalls.py -s   # frozen against "
          "unfrozen",
          "```", ""]
    return "\n".join(L)


def samples(k: int) -> str:
    return f"{k} sample" + ("" if k == 1 else "s")


def stale_verdict(st) -> str:
    """What the sweep says about the default, in numbers."""
    pct = C.pct
    res = {name: c["results"] for name, c in st["cases"].items()}
    d, old = st["default"], "0"
    clean = [n for n, r in res.items() if r[d]["stale_counted"] == 0]
    worst = max((res[n][d]["step_back_ms"] for n in clean), default=0)
    out = []
    if clean:
        out.append(f"With {d}, {', '.join(clean)} lost no sample to staleness: what a radio's "
                   f"queue and jitter and an LTE modem add passes (a GCS saw time step back by "
                   f"{worst:.0f} ms at most).")
    hurt = [n for n, r in res.items() if r[old]["stale_counted"] > r[d]["stale_counted"]]
    if hurt:
        out.append("The old rule (0) dropped real frames: " + "; ".join(
            f"{n} {samples(res[n][old]['stale_counted'])}, delivered loss "
            f"{pct(res[n][old]['delivered_loss'], 3)} against {pct(res[n][d]['delivered_loss'], 3)}"
            f" (bound {pct(res[n][d]['bound'], 4)})" for n in hurt) + ".")
    late = [n for n, r in res.items() if r[d]["stale_counted"]]
    if late:
        out.append(f"What {d} does drop is from a link far behind: " + "; ".join(
            f"{n} {samples(res[n][d]['stale_counted'])} (with drop_stale off the GCS would see "
            f"time step back {res[n]['off']['step_back_ms']:.0f} ms)" for n in late) + ".")
    return " ".join(out)


def wrap(text: str, width: int = 96) -> str:
    """Prose paragraphs wrapped like the rest of the README; tables, code, images kept."""
    import textwrap  # noqa: PLC0415
    out, code = [], False
    for line in text.split("\n"):
        if line.startswith("```"):
            code = not code
        if code or line.startswith(("|", "!", "#", "```")) or len(line) <= width:
            out.append(line)
        elif line.startswith("- "):
            out.extend(textwrap.wrap(line, width, subsequent_indent="  ",
                                     break_on_hyphens=False, break_long_words=False))
        else:
            out.extend(textwrap.wrap(line, width, break_on_hyphens=False,
                                     break_long_words=False))
    return "\n".join(out)


def replace_section(readme: str, heading: str, text: str, after: str = "Results") -> str:
    """`readme` with its "## heading" section replaced by `text` (up to the next "## "); a
    missing one goes after the "## after" section, or before Performance / Building by hand."""
    m = re.search(rf"^## {re.escape(heading)}\n.*?(?=^## )", readme, flags=re.S | re.M)
    if m:
        return readme[:m.start()] + text + "\n" + readme[m.end():]
    m = re.search(rf"^## {re.escape(after)}\n.*?(?=^## )", readme, flags=re.S | re.M)
    if m:
        return readme[:m.end()] + text + "\n" + readme[m.end():]
    for anchor in ("## Performance", "## Building by hand"):
        i = readme.find("\n" + anchor + "\n")
        if i >= 0:
            return readme[:i + 1] + text + "\n" + readme[i + 1:]
    return readme.rstrip("\n") + "\n\n" + text


def publish(out: Path, rep, runtime: float, checks, readme_out: Optional[str] = None) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    for f in RESULTS.glob("*.png"):
        f.unlink()
    for f in sorted(out.glob("*.png")):
        if f.stat().st_size > MAX_PNG:
            print(f"warning: {f.name} is {f.stat().st_size // 1024} KB")
        shutil.copy2(f, RESULTS / f.name)
    shutil.copy2(out / "results.md", RESULTS / "results.md")
    results = wrap(section(rep, runtime, checks))
    stress = wrap(stress_section(rep, runtime))
    if readme_out:
        Path(readme_out).write_text(results + "\n" + stress)
        print(f"published: {RESULTS}; README sections in {readme_out}")
        return
    readme = REPO / "README.md"
    text = replace_section(readme.read_text(), "Results", results)
    readme.write_text(replace_section(text, "Exact under stress", stress))
    print(f"published: {RESULTS} and README.md (## Results, ## Exact under stress)")
