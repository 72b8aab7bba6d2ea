"""PNG plots in the style of the paper's Fig. 5.1 and 5.2: packet loss per second of each link
and of the delivered (filtered) stream, one panel per mode, with the gateway's freezes shaded
and dedup's stale drops per second; and a bar chart of the delivered loss across scenarios.
matplotlib, Agg backend (no display needed)."""
from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import scenarios as S  # noqa: E402

LINK_COLOURS = ["tab:blue", "tab:orange", "tab:green", "tab:purple"]
DELIVERED = "black"


def scenario_plot(sc: S.Scenario, metrics: Dict[str, dict], path: Path) -> None:
    modes = [m for m in S.MODES if m in metrics]
    fig, axes = plt.subplots(len(modes), 1, figsize=(8.5, 2.3 * len(modes) + 0.6),
                             sharex=True, squeeze=False)
    top = 0.0
    for m in modes:
        for name, ys in metrics[m]["per_second"].items():
            top = max(top, max((y for y in ys if y is not None), default=0))
    top = min(100.0, max(2.0, top * 1.1))
    for ax, m in zip(axes[:, 0], modes):
        mm = metrics[m]
        ps = mm["per_second"]
        for k, name in enumerate(mm["links"]):
            ys = ps[name]
            ax.plot(range(len(ys)), ys, color=LINK_COLOURS[k % 4], lw=1.1, alpha=0.8,
                    label=f"{name} ({mm['link_loss'][name]:.2%})")
        ys = ps["delivered"]
        ax.plot(range(len(ys)), ys, color=DELIVERED, lw=1.8,
                label=f"delivered ({mm['delivered_loss']:.3%})")
        if "stale" in ps:
            ys = ps["stale"]
            ax.plot(range(len(ys)), ys, color="tab:red", lw=1.0, ls=":",
                    label=f"stale drops ({mm['stale_counted']})")
        for k, (a, b) in enumerate(mm["freezes"]):
            ax.axvspan(a, b, color="tab:gray", alpha=0.25, lw=0,
                       label=f"frozen ({len(mm['freezes'])}x)" if k == 0 else None)
        ax.set_ylim(-top * 0.03, top)
        ax.set_ylabel("loss per s (%)")
        title = S.MODE_TITLES[m]
        if m == "single":
            title += f" ({mm['links'][0]})"
        ax.set_title(title, loc="left", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right", ncol=len(mm["links"]) + 3, framealpha=0.85)
        for sw in mm.get("switches", []):
            ax.axvline(sw["t"], color="red", lw=0.8, ls="--")
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"{sc.title}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def summary_plot(rows: List[dict], path: Path) -> None:
    """rows: {name, title, bound, single, linkswitch, dedup} with loss fractions."""
    fig, ax = plt.subplots(figsize=(9, 4.2))
    width = 0.26
    colours = {"single": "tab:gray", "linkswitch": "tab:red", "dedup": "tab:green"}
    floor = 1e-6  # 0.0001 %: where "nothing lost" is drawn on the log axis
    for k, m in enumerate(S.MODES):
        xs = [i + (k - 1) * width for i in range(len(rows))]
        ys = [max(r[m], floor) for r in rows]
        bars = ax.bar(xs, [y * 100 for y in ys], width, color=colours[m],
                      label=S.MODE_TITLES[m])
        for b, r in zip(bars, rows):
            v = r[m]
            ax.text(b.get_x() + b.get_width() / 2, b.get_height() * 1.15,
                    "0" if v == 0 else f"{v * 100:.2g}", ha="center", va="bottom", fontsize=7)
    for i, r in enumerate(rows):
        ax.plot([i + 0.5 * width, i + 1.5 * width], [max(r["bound"], floor) * 100] * 2,
                color="black", lw=2, label="independence bound" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_ylim(floor * 100 * 0.7, 100 * 3)
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels([r["name"] for r in rows])
    ax.set_ylabel("delivered loss (%), log scale")
    ax.set_title("Delivered loss by scenario (bar labels in %; 0 = nothing lost)", fontsize=11)
    ax.grid(axis="y", alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper right", ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def priorities_plot(raw: dict, path: Path) -> None:
    """A slow radio alone (priorities.py): each command's round trip, without and with a
    budget; each message's delivered rate against what the vehicle sent."""
    runs, secs = raw["runs"], raw["seconds"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2),
                                      gridspec_kw={"width_ratios": [1, 1.6]})
    styles = {"plain": ("tab:red", "no budget"),
              "budget": ("tab:green", f"tx_rate: {raw['tx_rate']}")}
    for label, (colour, title) in styles.items():
        r = runs[label]
        rtt = r["rtt_ms"]
        left.plot([100 * (i + 1) / len(rtt) for i in range(len(rtt))], rtt, color=colour,
                  label=f"{title}: {r['no_ack']} of {r['commands']} without an ack")
    left.set_yscale("log")
    left.set_xlabel("commands acked (%), fastest first")
    left.set_ylabel("round trip (ms), log scale")
    left.set_title("Command round trip", fontsize=10)
    left.grid(alpha=0.3, which="both")
    left.legend(fontsize=7, loc="center right")
    msgs = sorted(runs["plain"]["sent"], key=lambda m: (-runs["plain"]["sent"][m], m))
    xs = range(len(msgs))
    width = 0.28
    right.bar([x - width for x in xs], [runs["plain"]["sent"][m] / secs for m in msgs], width,
              color="tab:gray", label="sent by the vehicle")
    for k, (label, (colour, title)) in enumerate(styles.items()):
        right.bar([x + k * width for x in xs], [runs[label]["got"][m] / secs for m in msgs],
                  width, color=colour, label=f"at the GCS, {title}")
    right.set_xticks(list(xs))
    right.set_xticklabels(msgs, rotation=60, ha="right", fontsize=7)
    right.set_ylabel("frames/s")
    right.set_title("Delivered rate per message", fontsize=10)
    right.grid(axis="y", alpha=0.3)
    right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def standby_plot(raw: dict, path: Path) -> None:
    """The radio bonded with a metered LTE link (standby.py): per condition, each mode's
    delivered loss and LTE bytes per hour."""
    import standby  # noqa: PLC0415
    conds = list(raw["conditions"])
    modes = list(standby.MODES)
    colours = {"broadcast": "tab:blue", "standby": "tab:green", "standby_noresend": "tab:olive",
               "radio": "tab:gray"}
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / len(modes)
    for k, m in enumerate(modes):
        xs = [i + (k - (len(modes) - 1) / 2) * width for i in range(len(conds))]
        rows = [raw["conditions"][c]["modes"][m] for c in conds]
        label = standby.MODES[m][0].replace("`", "")
        left.bar(xs, [100 * r["delivered_loss"] for r in rows], width, color=colours[m],
                 label=label)
        right.bar(xs, [r["lte_bytes_per_hour"] / 1e6 for r in rows], width, color=colours[m],
                  label=label)
    for ax, title, unit in ((left, "Delivered loss", "% of the frames sent"),
                            (right, "LTE bytes (both directions, with headers)", "MB per hour")):
        ax.set_xticks(range(len(conds)))
        ax.set_xticklabels(conds)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(unit)
        ax.grid(axis="y", alpha=0.3)
    left.set_yscale("symlog", linthresh=0.1)
    left.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
