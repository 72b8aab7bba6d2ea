"""scripts/compare: dedup against link switching against one link, on the same stream and the
same emulated link conditions, with tables and plots.

    compare.py [--out build/compare] [--only paper,outage] [--jobs 2] [--stream auto|synth|FILE]
               [--scale 0.5] [--no-stall] [--publish [--readme-out FILE]]

Each scenario (scenarios.py) runs in its own worker process (lab.py: real mavbond gateways and
a link emulator, the three modes side by side, every ground gateway frozen on a schedule
unless --no-stall); at most --jobs at a time (2 on 2 cores: each worker's processes need about
half a core). The dedup window experiment (window_cost.py), the stale_after sweep
(stale_after.py), a slow radio alone with and without a transmit budget (priorities.py) and
the slow radio bonded with a metered LTE link (standby.py) are four more jobs. Then the figures (analyze.py) go into OUT/results.md and
the plots (plots.py) into OUT/*.png. --publish (publish.py) copies the PNGs and results.md, with
the findings added after its summary, to tests/compare/results/, and rewrites the README's
"## Results" section, the headline, from this run (or writes it to --readme-out).

Exits 1 when dedup is not exact somewhere: a duplicate delivered, a good frame dropped (a frame
some link carried that is not a sample dedup dropped as stale, by its own count), or a record
that cannot be judged (a socket overflowed, a freeze that did not happen); it names the
scenario and why. No run is ever repeated."""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import lab  # noqa: E402  (sets sys.path for the test helpers)
import scenarios as S  # noqa: E402

REPO = lab.REPO
RESULTS = HERE / "results"


def pct(x, digits=2) -> str:
    if x is None:
        return "-"
    return "0" if x == 0 else f"{x * 100:.{digits}f} %"


def ms(x) -> str:
    return "-" if x is None else f"{x:.0f}" if x >= 10 else f"{x:.1f}"


# --- workers ------------------------------------------------------------------------------

# The jobs beside the scenarios, and about how long each takes.
JOBS = {"window": 45, "stale": 95, "priorities": 140, "standby": 150}


def worker(args) -> int:
    out = Path(args.out)
    (out / "raw").mkdir(parents=True, exist_ok=True)
    workdir = out / "work" / args.worker
    if workdir.exists():
        shutil.rmtree(workdir)
    if args.worker == "window":
        import window_cost  # noqa: PLC0415
        raw = window_cost.run(args.mavbond, args.plugin_dir, workdir, stall=args.stall)
    elif args.worker == "stale":
        import stale_after  # noqa: PLC0415
        raw = stale_after.run(args.mavbond, args.plugin_dir, args.stream, workdir)
    elif args.worker == "priorities":
        import priorities  # noqa: PLC0415
        raw = priorities.run_pair(args.mavbond, round(60 * args.scale, 1), workdir)
    elif args.worker == "standby":
        import standby  # noqa: PLC0415
        raw = standby.run(args.mavbond, args.plugin_dir, args.scale, workdir)
    else:
        sc = S.get(args.worker)
        sc = dataclasses.replace(sc, seconds=round(sc.seconds * args.scale, 1),
                                 outages={k: (a * args.scale, b * args.scale)
                                          for k, (a, b) in sc.outages.items()})
        raw = lab.run(sc, args.mavbond, args.plugin_dir, lab.stream_for(sc, args.stream),
                      workdir, stall=args.stall)
    (out / "raw" / f"{args.worker}.json").write_text(json.dumps(raw))
    return 0


def run_jobs(args, names) -> float:
    t0 = time.monotonic()
    out = Path(args.out)

    def one(name):
        t = time.monotonic()
        cmd = [sys.executable, str(Path(__file__)), "--worker", name, "--out", str(out),
               "--mavbond", args.mavbond, "--plugin-dir", args.plugin_dir,
               "--stream", args.stream, "--scale", str(args.scale),
               "--stall" if args.stall else "--no-stall"]
        r = subprocess.run(cmd, stdin=subprocess.DEVNULL)
        print(f"==> {name}: {'done' if r.returncode == 0 else 'FAILED'} in "
              f"{time.monotonic() - t:.0f} s", flush=True)
        return r.returncode

    with ThreadPoolExecutor(args.jobs) as pool:
        codes = list(pool.map(one, names))
    if any(codes):
        raise SystemExit("some runs failed (see above)")
    return time.monotonic() - t0


# --- report -------------------------------------------------------------------------------

def freezes(x) -> str:
    return f"{len(x['freezes'])} ({x['frozen_s']:.1f} s)" if x["freezes"] else "0"


def scenario_table(sc, mets) -> list:
    lines = ["| mode | frames sent | loss per link | delivered loss | lost on every link | "
             "duplicates delivered | good frames dropped | stale drops | out of order | "
             "lost in switchover | latency p50 / p99 (ms) | freezes (frozen) |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in S.MODES:
        if m not in mets:
            continue
        x = mets[m]
        links = ", ".join(f"{n} {pct(v)}" for n, v in x["link_loss"].items())
        sw = str(x["switch_lost"]) if m == "linkswitch" else "-"
        dedup = m == "dedup"
        lines.append(f"| {S.MODE_TITLES[m]} | {x['n']} | {links} | {pct(x['delivered_loss'], 3)} "
                     f"| {x['lost_all']} | {x['duplicates']} | "
                     f"{x['good_dropped'] if dedup else '-'} | "
                     f"{x['stale_counted'] if dedup else '-'} | {x['out_of_order']} | {sw} | "
                     f"{ms(x['latency_p50'])} / {ms(x['latency_p99'])} | {freezes(x)} |")
    return lines


def scenario_notes(sc, mets) -> list:
    out = []
    d = mets.get("dedup")
    if d:
        ratio = d["delivered_loss"] / d["bound"] if d["bound"] else None
        out.append(f"Independence bound (product of the links' loss rates): **{pct(d['bound'], 4)}**"
                   f" ({d['bound'] * d['n']:.1f} frames); dedup delivered loss "
                   f"**{pct(d['delivered_loss'], 4)}** ({d['not_delivered']} frames"
                   + (f", {ratio:.2f}x the bound" if ratio is not None else "") + "). "
                   f"Frames lost on every link: {d['lost_all']}; frames some link carried that "
                   f"dedup did not deliver: {d['carried_lost']}, of which timestamped samples "
                   f"more than stale_after behind a delivered one: {d['stale_seen']} (dedup's "
                   f"`stale` counter: {d['stale_counted']}); good frames dropped: "
                   f"**{d['good_dropped']}**; duplicates delivered: **{d['duplicates']}**. "
                   f"Largest step back in a sample's time the GCS saw: "
                   f"{d['step_back_ms']:.0f} ms.")
        if d["freezes"]:
            out.append(f"Each ground gateway was frozen {len(d['freezes'])} times, "
                       f"{d['frozen_s']:.1f} s in all (dedup's); dedup's gateway held back "
                       f"{d['held_back']} frames for arrival order after the freezes, its "
                       f"sockets overflowed {d['rx_overflows']} times, the GCS socket "
                       f"{d['gcs_drops']}.")
        if d["exact_share"] < 1:
            out.append(f"Only {d['exact_share']:.0%} of the frames are unique within "
                       f"{lab.HORIZON:g} s: latency and order are measured on those; the "
                       f"counts on all (which instance of a recurring frame a delivery was, "
                       f"its bytes cannot tell).")
    ls = mets.get("linkswitch")
    if ls:
        best = min(ls["link_loss"].values())
        verdict = "no better than" if ls["delivered_loss"] >= best - 1e-12 else "BETTER than"
        out.append(f"linkswitch delivered {pct(ls['delivered_loss'], 3)}: {verdict} its best "
                   f"link ({pct(best, 3)}); {len(ls['switches'])} switch(es), "
                   f"{ls['carried_lost']} frames lost that another link carried.")
        for s in ls["switches"][:6]:
            det = f"{s['detection_ms']:.0f} ms" if s["detection_ms"] is not None else "-"
            gap = f"{s['gap_ms']:.0f} ms" if s["gap_ms"] is not None else "-"
            out.append(f"  - at {s['t']:.1f} s {s['from']} -> {s['to']} ({s['reason']}): "
                       f"{det} after the last frame delivered from {s['from']}; delivery gap "
                       f"{gap}; {s['lost']} frames lost that {s['to']} carried")
        if len(ls["switches"]) > 6:
            out.append(f"  - ... {len(ls['switches']) - 6} more")
    return out


def window_section(w) -> list:
    if not w:
        return []
    p, d = w["configs"]["paper"], w["configs"]["default"]
    lines = [
        f"{w['n']} frames at {w['rate']}/s, a cycle of 256 byte-identical frames (every frame "
        f"recurs every 0.256 s); link_a 5 % loss 10 ms, link_b 5 % loss 300 ms (more than one "
        f"cycle behind). Two ground gateways on the same datagrams"
        + (", both frozen on the same schedule as the scenarios'" if w.get("stall") else "")
        + ".",
        "",
        "| dedup config | reached the gateway | delivered | false drops (legitimate repeats lost) "
        "| duplicates | naive hash set, same window | naive per-link counter |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, c, label in (("paper", p, "paper: murmur3_32, 5 s, drop_stale false"),
                           ("default", d, "mavbond default: murmur3_128, 2 s")):
        lines.append(f"| {label} | {c['reached']} | {c['delivered']} | **{c['false_drops']}** | "
                     f"{c['duplicates']} | {c['naive_hash_set_false_drops']} | "
                     f"{c['naive_counter_false_drops']} |")
    coll = w.get("collisions_hour", {})
    if coll:
        lines += ["", f"32-bit hash collisions among an hour of distinct frames at {w['rate']}/s "
                  f"(3.6 M frames, measured with mmh3): {coll.get('5s')} inside a 5 s window, "
                  f"{coll.get('2s')} inside a 2 s window. In a plain hash set each one drops a "
                  f"good frame; at 128 bits the chance is 2^-128 per pair."]
    return lines


def stale_table(st) -> list:
    """One row per case and setting: stale drops, delivered loss against the bound, the
    largest step back a GCS saw."""
    if not st:
        return []
    names = {"0": "0 (the old rule)", "off": "drop_stale off"}
    lines = ["| scenario | stale_after | samples dropped as stale | delivered loss | "
             "independence bound | largest step back a GCS saw (ms) |",
             "|---|---|---:|---:|---:|---:|"]
    for case_name, c in st["cases"].items():
        for k, r in c["results"].items():
            label = names.get(k, k) + (" (default)" if k == st["default"] else "")
            bold = "**" if k == st["default"] else ""
            lines.append(f"| {case_name} | {bold}{label}{bold} | {r['stale_counted']} | "
                         f"{pct(r['delivered_loss'], 3)} ({r['not_delivered']}) | "
                         f"{pct(r['bound'], 4)} | {r['step_back_ms']:.0f} |")
    return lines


def stale_section(st) -> list:
    if not st:
        return []
    lines = ["Six dedup gateways on the same datagrams (one emulator process teeing every link "
             "to each), not frozen: what the links add in normal operation. Delivered loss in "
             "% (frames); the bound is what no link carried if losses are independent. "
             "The step back is how far a delivered sample's time_boot_ms / time_usec was "
             "behind the newest of its stream already delivered.", ""]
    for name, c in st["cases"].items():
        links = "; ".join(f"{l}: {label}" for l, label in c["links"].items())
        lines.append(f"- {name}: {c['title']} ({c['seconds']:g} s, {c['n']} frames, "
                     f"{c['timestamped']} timestamped; {links})")
    return lines + [""] + stale_table(st)


def build_report(out: Path, names, runtime: float, args) -> dict:
    import analyze  # noqa: PLC0415
    import plots  # noqa: PLC0415
    raws = {n: json.loads((out / "raw" / f"{n}.json").read_text()) for n in names
            if (out / "raw" / f"{n}.json").exists()}
    window = raws.pop("window", None)
    stale = raws.pop("stale", None)
    prio = raws.pop("priorities", None)
    standby_raw = raws.pop("standby", None)
    mets = {n: analyze.scenario_metrics(r) for n, r in raws.items()}
    stalled = any(r["stall"] for r in raws.values())
    lines = ["# mavbond: dedup vs link switching vs one link", ""]
    streams = sorted({r["stream"] for r in raws.values()})
    lines += [f"Streams: {'; '.join(streams) or '-'}. Run: `scripts/compare` ({runtime:.0f} s, "
              f"{os.cpu_count()} cores). Per-link loss comes from the link emulator's drop logs; "
              f"delivered loss, duplicates, order and latency from what the GCS received "
              f"(latency includes the emulated link delay); stale drops from dedup's own "
              f"counter (status socket)."
              + (" Every ground gateway frozen (SIGSTOP/SIGCONT) 150 ms every 2 to 2.5 s and "
                 "once for 1 s (6 s into the stream), on one seeded schedule per scenario."
                 if stalled else " No freezes (--no-stall)."), ""]
    summary_rows = []
    lines += ["## Summary", "",
              "| scenario | loss per link | independence bound | one link alone | linkswitch | "
              "dedup | dedup: duplicates / good dropped / stale drops | freezes per gateway |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for sc in S.SCENARIOS:
        if sc.name not in mets:
            continue
        m = mets[sc.name]
        d = m.get("dedup") or next(iter(m.values()))
        links = ", ".join(f"{pct(v)}" for v in d["link_loss"].values())
        row = {"name": sc.name, "title": sc.title, "bound": d["bound"]}
        for mode in S.MODES:
            row[mode] = m[mode]["delivered_loss"] if mode in m else 0.0
        summary_rows.append(row)
        lines.append(f"| {sc.name}: {sc.title} | {links} | {pct(d['bound'], 4)} | "
                     + " | ".join(pct(row[mo], 3) for mo in S.MODES)
                     + f" | {d['duplicates']} / {d['good_dropped']} / {d['stale_counted']} | "
                     f"{freezes(d)} |")
    lines.append("")
    for sc in S.SCENARIOS:
        if sc.name not in mets:
            continue
        link_desc = "; ".join(f"{l.name}: {l.label}" for l in sc.links)
        lines += [f"## {sc.name}: {sc.title}", "", f"{sc.note} Links: {link_desc}. "
                  f"One link alone is {sc.links[0].name}. Stream: {raws[sc.name]['stream']}.", ""]
        lines += scenario_table(sc, mets[sc.name]) + [""]
        lines += scenario_notes(sc, mets[sc.name]) + [""]
        lines += [f"![{sc.name}]({sc.name}.png)", ""]
        plots.scenario_plot(sc, mets[sc.name], out / f"{sc.name}.png")
    if summary_rows:
        plots.summary_plot(summary_rows, out / "summary.png")
        lines += ["## Across scenarios", "", "![summary](summary.png)", ""]
    if stale:
        lines += ["## stale_after, from the data", ""] + stale_section(stale) + [""]
    if window:
        lines += ["## The dedup window: what the paper's 5 s and 32-bit hash cost", ""]
        lines += window_section(window) + [""]
    if prio:
        import priorities  # noqa: PLC0415
        lines += ["## A slow radio alone: commands first (tx_rate)", ""]
        lines += priorities.report_lines(prio) + ["", "![priorities](priorities.png)", ""]
        plots.priorities_plot(prio, out / "priorities.png")
    if standby_raw:
        import standby  # noqa: PLC0415
        lines += ["## The radio with a metered LTE link: standby (cost: metered)", ""]
        lines += standby.report_lines(standby_raw) + ["", "![standby](standby.png)", ""]
        plots.standby_plot(standby_raw, out / "standby.png")
    (out / "results.md").write_text("\n".join(lines))
    (out / "metrics.json").write_text(json.dumps(
        {"runtime_s": runtime, "window": window, "stale": stale, "priorities": prio,
         "standby": standby_raw,
         "scenarios": {n: {mo: {k: v for k, v in x.items() if k != "per_second"}
                           for mo, x in m.items()} for n, m in mets.items()}}, indent=1))
    print("\n".join(lines))
    return {"mets": mets, "window": window, "stale": stale, "priorities": prio,
            "standby": standby_raw, "raws": raws,
            "summary": summary_rows, "stalled": stalled}


def checks(rep) -> list:
    """(what, ok, detail): dedup exact in every scenario, job and setting (analyze's strict
    verdict), and the paper's findings on its scenario."""
    import analyze  # noqa: PLC0415
    mets, out = rep["mets"], []
    for sc in S.SCENARIOS:
        d = mets.get(sc.name, {}).get("dedup")
        if d:
            problems = analyze.dedup_verdict(d, rep["stalled"])
            out.append((f"{sc.name}: dedup delivered every frame a link carried exactly once",
                        not problems, "; ".join(problems) or
                        f"0 duplicates, 0 good frames dropped, {d['stale_counted']} stale"))
    st = rep.get("stale")
    for case, c in (st or {}).get("cases", {}).items():
        for k, r in c["results"].items():
            if r["problems"]:
                out.append((f"stale_after {k} on {case}: dedup exact", False,
                            "; ".join(r["problems"])))
    w = rep.get("window")
    for name, c in (w or {}).get("configs", {}).items():
        out.append((f"window ({name}): no legitimate repeat lost, no duplicate",
                    not c["false_drops"] and not c["duplicates"] and not c["problems"],
                    "; ".join(c["problems"]) or f"{c['false_drops']} false drops, "
                    f"{c['duplicates']} duplicates"))
    pr = (rep.get("priorities") or {}).get("runs")
    if pr:
        b = pr["budget"]
        out.append(("priorities: with a budget every command acked, no radio queue drop",
                    b["no_ack"] == 0 and b["radio_queue_drops"] == 0,
                    f"{b['no_ack']} of {b['commands']} without an ack, "
                    f"{b['radio_queue_drops']} queue drops (without a budget: "
                    f"{pr['plain']['no_ack']}, {pr['plain']['radio_queue_drops']})"))
    for name, c in ((rep.get("standby") or {}).get("conditions") or {}).items():
        dups = {m: r["duplicates"] for m, r in c["modes"].items()}
        out.append((f"standby {name}: no duplicate delivered in any mode (resent frames "
                    f"included)", not any(dups.values()),
                    ", ".join(f"{m} {n}" for m, n in dups.items())))
    p = mets.get("paper")
    if p and "dedup" in p:
        d = p["dedup"]
        ok = d["delivered_loss"] <= 3 * d["bound"] or d["not_delivered"] <= 3 * max(
            d["bound"] * d["n"], 1 / 3)
        out.append(("paper: dedup delivered loss within 3x of the independence bound", ok,
                    f"{pct(d['delivered_loss'], 4)} vs bound {pct(d['bound'], 4)}"))
    if p and "linkswitch" in p:
        ls = p["linkswitch"]
        best = min(ls["link_loss"].values())
        out.append(("paper: linkswitch no better than its best link",
                    ls["delivered_loss"] >= best - 1e-12,
                    f"{pct(ls['delivered_loss'], 3)} vs best link {pct(best, 3)}"))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "build" / "compare"))
    ap.add_argument("--only", help="comma-separated scenario names (and/or 'window', 'stale', "
                                   "'priorities', 'standby')")
    ap.add_argument("--jobs", type=int, default=2, help="runs at a time (default 2)")
    ap.add_argument("--stream", default="auto",
                    help="auto (the ArduSub recording in ../shared/data/tlogs, else synthetic), "
                         "synth, or a .tlog to replay")
    ap.add_argument("--scale", type=float, default=1.0,
                    help="scale every scenario's length (0.25 for a quick look)")
    ap.add_argument("--stall", action=argparse.BooleanOptionalAction, default=True,
                    help="freeze every ground gateway 150 ms every 2-2.5 s and once for 1 s "
                         "(default on; --no-stall: never)")
    ap.add_argument("--publish", action="store_true",
                    help="copy results.md (with the findings) and the PNGs to "
                         "tests/compare/results/ and rewrite the README's Results section")
    ap.add_argument("--readme-out", metavar="FILE",
                    help="with --publish: write the Results section to FILE instead of "
                         "rewriting README.md")
    ap.add_argument("--mavbond", default=os.environ.get(
        "MAVBOND_BIN", str(REPO / "build" / "src" / "mavbond")))
    ap.add_argument("--plugin-dir")
    ap.add_argument("--report-only", action="store_true",
                    help="no runs: tables and plots again from the raw records in --out")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--list", action="store_true", help="list the scenarios")
    args = ap.parse_args()
    if args.list:
        for sc in S.SCENARIOS:
            print(f"{sc.name:<13} {sc.seconds:>4g} s  {sc.title}")
        print(f"{'window':<13} {'10':>4} s  the dedup window and hash: false drops measured")
        import stale_after  # noqa: PLC0415
        print(f"{'stale':<13} {stale_after.SECONDS:>4g} s  stale_after 0 to 1 s and off, "
              f"on {len(stale_after.CASES)} streams")
        print(f"{'priorities':<13} {'120':>4} s  a slow radio alone, with and without tx_rate: "
              f"command round trips")
        print(f"{'standby':<13} {'130':>4} s  the slow radio with a metered LTE link: broadcast, "
              f"standby, the radio alone")
        return 0
    if not args.plugin_dir:
        args.plugin_dir = str(Path(args.mavbond).resolve().parent.parent / "plugins")
    if args.worker:
        return worker(args)
    try:
        import matplotlib  # noqa: F401, PLC0415
    except ImportError:
        raise SystemExit("matplotlib is missing from this Python (scripts/setup.sh installs it "
                         "into .venv)") from None
    names = [s.name for s in S.SCENARIOS] + list(JOBS)
    if args.only:
        want = args.only.split(",")
        bad = [w for w in want if w not in names]
        if bad:
            ap.error(f"unknown scenario(s) {bad}; --list shows them")
        names = [n for n in names if n in want]
    # longest first, so two at a time finish together
    length = {s.name: s.seconds for s in S.SCENARIOS}
    length.update(JOBS)
    names.sort(key=lambda n: -length[n])
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.report_only:
        runtime = float((out / "runtime.txt").read_text())
    else:
        for n in names:
            (out / "raw" / f"{n}.json").unlink(missing_ok=True)
        runtime = run_jobs(args, names)
        (out / "runtime.txt").write_text(f"{runtime:.1f}\n")
    rep = build_report(out, names, runtime, args)
    results = checks(rep)
    for what, ok, detail in results:
        print(f"{'ok  ' if ok else 'FAIL'} {what}: {detail}")
    print(f"\nresults: {out / 'results.md'} and {out}/*.png ({runtime:.0f} s)")
    if args.publish:
        import publish  # noqa: PLC0415
        publish.publish(out, rep, runtime, results, readme_out=args.readme_out)
    failed = [(what, detail) for what, ok, detail in results if not ok]
    for what, detail in failed:
        print(f"FAILED: {what}: {detail}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
