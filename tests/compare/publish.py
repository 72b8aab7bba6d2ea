"""--publish: copies a run's PNGs to tests/compare/results/, writes its results.md there with
the findings (how the runs are made, the paper's scenario, switchover, the dedup window, exact
under stress, stale_after) after the summary, and rewrites the README's "## Results" section
(only that one: it ends at the next "## ") with the headline: the summary table, its plot and
dedup's verdict. With --readme-out FILE the README section goes to FILE instead, and README.md
is left alone."""
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


def summary_table(rep) -> list:
    """Delivered loss per scenario and mode."""
    mets, pct = rep["mets"], C.pct
    L = ["| scenario | loss per link | independence bound | one link alone | linkswitch | "
         "dedup |", "|---|---|---:|---:|---:|---:|"]
    for r in rep["summary"]:
        m = mets[r["name"]]
        links = ", ".join(pct(v) for v in m["dedup"]["link_loss"].values())
        L.append(f"| {r['name']}: {r['title']} | {links} | {pct(r['bound'], 4)} | "
                 + " | ".join(pct(r[mo], 3) for mo in S.MODES) + " |")
    return L


def verdict(rep) -> str:
    """dedup's strict verdict over every scenario, in one sentence."""
    mets = rep["mets"]
    ds = [mets[r["name"]]["dedup"] for r in rep["summary"]]
    dups = sum(d["duplicates"] for d in ds)
    good = sum(d["good_dropped"] for d in ds)
    stale = sum(d["stale_counted"] for d in ds)
    text = (f"In the {len(ds)} scenarios dedup delivered {dups} duplicates and dropped {good} "
            f"good frames"
            + (" while every ground gateway was frozen (SIGSTOP/SIGCONT) 150 ms every 2 to 2.5 s "
               "and once for a whole second, as a busy companion computer freezes it"
               if rep["stalled"] else "")
            + ".")
    if not dups and not good:
        text = text[:-1] + ": every frame some link carried was delivered once"
        text += (f", except {stale} late {'sample' if stale == 1 else 'samples'} dropped on "
                 f"purpose as stale (`stale_after`)." if stale else ".")
    return text


def priorities_sentence(rep) -> str:
    """The slow radio alone (priorities.py), with and without a budget, in one sentence."""
    raw = rep.get("priorities")
    if not raw:
        return ""
    import priorities  # noqa: PLC0415
    plain, budget = raw["runs"]["plain"], raw["runs"]["budget"]

    def p50(r):
        return priorities.ms(r["rtt_ms"], 0.5)
    return (f" A radio alone offered more than it carries (`priorities`): commands' round trip "
            f"{p50(plain) / 1000:.2f} s and {plain['no_ack']} of {plain['commands']} without an "
            f"ack; with `tx_rate` on its air side, {p50(budget) / 1000:.2f} s and "
            f"{budget['no_ack']}.")


def standby_sentence(rep) -> str:
    """The radio bonded with a metered LTE link (standby.py), in one sentence per the goal."""
    raw = rep.get("standby")
    if not raw:
        return ""
    import standby  # noqa: PLC0415
    parts = []
    for name, c in raw["conditions"].items():
        b, s = c["modes"]["broadcast"], c["modes"]["standby"]
        parts.append(f"{name} {C.pct(s['delivered_loss'], 2)} against "
                     f"{C.pct(b['delivered_loss'], 2)} at "
                     f"{s['lte_bytes'] / b['lte_bytes'] * 100:.0f} % of the LTE bytes")
    met = [n for n, c in raw["conditions"].items() if all(standby.goal(c))]
    return (f" A 57600 radio with a metered LTE link in standby (`standby`): delivered loss "
            + "; ".join(parts) + " of `tx: broadcast`'s; the goal (within 1.5x of broadcast's "
            f"loss at under 10 % of its LTE bytes) met in {len(met)} of "
            f"{len(raw['conditions'])}.")


def headline(rep, runtime: float) -> str:
    """The README's "## Results": what was compared, the summary table and plot, the verdict,
    and where the rest is."""
    L = ["## Results", "",
         "Which is better for a given pair of links: deduplication, link switching, or just one "
         f"link? `scripts/compare` runs the paper's conditions and {len(rep['summary']) - 1} "
         "more with real processes (mavbond gateways, a seeded link emulator, a recorded "
         "ArduSub dive replayed at its own pace), one link alone, `linkswitch` and `dedup` side "
         "by side on the same datagrams. Delivered loss (what the GCS did not get, of the "
         "frames the vehicle sent):", ""]
    L += summary_table(rep)
    L += ["", "![delivered loss by scenario](tests/compare/results/summary.png)", "",
          verdict(rep) + priorities_sentence(rep) + standby_sentence(rep) + " How the runs are made, every scenario's "
          "table and plot, switchover, the dedup window, `stale_after` and the slow radio, from "
          "the data: [tests/compare/results/results.md](tests/compare/results/results.md).", ""]
    # The links-as-budgets jobs' plots, when they ran: the slow radio alone, radio + metered LTE.
    plots = [f"![{job}](tests/compare/results/{job}.png)" for job in ("priorities", "standby")
             if rep.get(job)]
    if plots:
        L += [" ".join(plots), ""]
    L += ["```sh",
          f"scripts/compare             # every scenario ({runtime / 60:.0f} min on 2 cores); "
          "--publish refreshes results/ and this section",
          "```", ""]
    return "\n".join(L)


def findings(rep, runtime: float, checks) -> str:
    """What results.md says beyond the run's tables: how the runs are made, the paper's
    scenario, switchover, the dedup window, exact under stress and stale_after."""
    mets, window, st = rep["mets"], rep["window"], rep.get("stale")
    pct = C.pct
    L = ["## How the runs are made", "",
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
         "scripts/compare --publish     # and refresh tests/compare/results/ and the README's "
         "Results",
         "```", "",
         "Every scenario's table below gives per-link loss, duplicates, good frames dropped, "
         "stale drops, order, switchover, latency and freezes. The latency tails (p99 near a "
         "second) are the freezes: frames wait in the kernel while the gateway is stopped.", ""]

    p = mets.get("paper")
    if p:
        sc = S.get("paper")
        d, ls = p["dedup"], p["linkswitch"]
        best = min(ls["link_loss"].values())
        L += ["## The paper's scenario, from the data", "",
              f"Two links with 1 % random loss each, {sc.seconds:g} s of stream (its table and "
              f"plot are in the paper section below; Fig. 5.1 and 5.2 of the paper are the "
              f"plot's lower two panels).", ""]
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
        for what, ok, detail in checks:
            if what.startswith("paper"):
                L.append(f"- {'yes' if ok else 'NO'}: {what} ({detail})")
        L.append("")

    o = mets.get("outage")
    if o and o["linkswitch"]["switches"]:
        sw = o["linkswitch"]["switches"][0]
        sc = S.get("outage")
        L += ["## Switchover, from the data", ""]
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
                  f"{len(bl['switches'])} time{'' if len(bl['switches']) == 1 else 's'} and "
                  f"delivered {pct(bl['delivered_loss'], 3)}, "
                  f"{rel} ({pct(best, 3)}); it judges loss only over a full window of at least "
                  f"100 frames and switches only to a clearly better backup, so two links of "
                  f"similar loss stay put. dedup delivered "
                  f"{pct(b['dedup']['delivered_loss'], 3)}.", ""]

    if window:
        wp, wd = window["configs"]["paper"], window["configs"]["default"]
        why = []
        for name in ("skew", "radio57600", "radio_lte", "three"):
            lags = {l: v for l, v in mets.get(name, {}).get("dedup", {}).get("lag_ms", {}).items()
                    if v is not None}
            if lags:
                slow = max(lags, key=lags.get)
                why.append(f"{name} {slow} {lags[slow]:.0f} ms")
        L += ["## The dedup window, from the data", ""]
        L += ["The window only has to outlast the largest skew between a bond's links"
              + (" (dedup's own measure of how far behind the first copy the slowest link's "
                 "copies came, `lag_ms`: " + ", ".join(why) + ")" if why else "")
              + ". LTE and satellite paths spike past 1 s under load, so the default is 2 s. "
              "Matching by identity (a frame's position in its source's stream, not its "
              "arrival time) makes a longer window safe; what a window costs is memory "
              "(`max_entries`) and how late a copy may come and still be caught.", ""]
        L += [f"Measured (the table is in the last section, on the paper's 5 s and 32-bit "
              f"hash): with mavbond's matching neither the paper's settings nor the default "
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

    L += ["## Exact under stress", "",
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
        L += ["A late copy of a sample another link lost is either delivered (the GCS sees "
              "the sample's time step back by its lateness) or dropped as stale (a frame "
              "lost). The `stale_after` sweep runs six dedup gateways on the same datagrams, "
              "not frozen, one per setting (its table is the section \"stale_after, from the "
              "data\" below). " + stale_verdict(st), ""]
    L += ["```sh",
          "scripts/compare                            # every scenario frozen, the stale_after "
          f"sweep ({runtime / 60:.0f} min on 2 cores)",
          "scripts/compare --only repeats_1khz,stale  # one scenario and the sweep",
          ".venv/bin/python -m pytest tests/integration/test_stalls.py -s   # frozen against "
          "unfrozen",
          "```", ""]
    return "\n".join(L)


def with_findings(run: str, text: str) -> str:
    """The run's results.md with `text` after its summary (before the first scenario)."""
    i = run.find("\n## Summary\n")
    j = run.find("\n## ", i + 1) if i >= 0 else -1
    if j < 0:
        return run.rstrip("\n") + "\n\n" + text
    return run[:j + 1] + text + "\n" + run[j + 1:]


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


def replace_section(readme: str, heading: str, text: str) -> str:
    """`readme` with its "## heading" section replaced by `text` (up to the next "## "); a
    missing one goes before Performance, How it works or Building by hand, else at the end."""
    m = re.search(rf"^## {re.escape(heading)}\n.*?(?=^## |\Z)", readme, flags=re.S | re.M)
    if m:
        return readme[:m.start()] + text + "\n" + readme[m.end():].lstrip("\n")
    for anchor in ("## Performance", "## How it works", "## Building by hand"):
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
    run = (out / "results.md").read_text()
    (RESULTS / "results.md").write_text(
        with_findings(run, wrap(findings(rep, runtime, checks))))
    results = wrap(headline(rep, runtime))
    if readme_out:
        Path(readme_out).write_text(results)
        print(f"published: {RESULTS}; the README's Results section in {readme_out}")
        return
    readme = REPO / "README.md"
    readme.write_text(replace_section(readme.read_text(), "Results", results))
    print(f"published: {RESULTS} and README.md (## Results)")
