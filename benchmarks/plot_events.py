"""Chart of benchmarks/out/events.json (from bench_events.py): time per event against error, log-log.

One point per method and quality setting: x = mean CPU time per event over all events of all scenarios,
y = RMS over the evaluated events of the error of the light's contribution (reflected radiance, with
minus without the shapes, RMSE over sample points against NAIVE at reference quality). Also prints the
table used in docs/events.md.

    .venv/bin/python benchmarks/plot_events.py [--json benchmarks/out/events.json]
        [--png benchmarks/events_speed_accuracy.png]
"""

import argparse
import json
import os
from collections import defaultdict

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COLORS = {
    "NAIVE": "tab:red",
    "FE": "tab:blue",
    "FE warm": "tab:cyan",
    "AR": "tab:green",
    "AUTO": "tab:purple",
    "AUTO bf=1e-2": "tab:pink",
}
MARKERS = {"coarse": "o", "draft": "s", "medium": "D"}


def label_log_axis(axis):
    """Labelled ticks on a log axis in plain numbers (matplotlib labels only the decades, often one
    or two in a narrow range): 1, 1.5, 2, 2.5, ... x 10^k within one decade, 1, 2, 3, 5, 7 within
    three, 1, 2, 5 beyond. Call after the data are drawn."""
    import numpy as np
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter, NullLocator

    lo, hi = sorted(axis.get_view_interval())
    decades = np.log10(hi / lo)
    subs = (
        np.arange(1, 10, 0.5)
        if decades < 1.2
        else (1, 2, 3, 5, 7)
        if decades < 3
        else (1, 2, 5)
        if decades < 3.6
        else (1, 3)
    )
    axis.set_major_locator(LogLocator(base=10, subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_locator(NullLocator())
    axis.set_minor_formatter(NullFormatter())


def aggregate(data):
    """(variant, quality) -> dict(time, err_delta, err_total, nodes_added, ratio) over all scenarios;
    ratio = total NAIVE time / total time of the method over the same events (same run)."""
    acc = defaultdict(lambda: defaultdict(list))
    for sc in data["scenarios"]:
        for run in sc["runs"]:
            a = acc[(run["variant"], run["quality"])]
            a["scenes"].append(sc["scene"])
            for i, e in enumerate(run["events"]):
                a["time"].append(e.get("cpu_seconds", e["seconds"]))
                a["naive_time"].append(e.get("cpu_seconds", e["seconds"]) * run["naive_ratio"][i])
                a["nodes_added"].append(e["nodes_added"])
                if "err_delta_rmse" in e:
                    a["ed"].append(e["err_delta_rmse"])
                    a["et"].append(e["err_total_rmse"])
    out = {}
    for k, a in acc.items():
        out[k] = {
            "time": float(np.mean(a["time"])),
            "err_delta": float(np.sqrt(np.mean(np.square(a["ed"])))),
            "err_total": float(np.sqrt(np.mean(np.square(a["et"])))),
            "ratio": float(np.sum(a["naive_time"]) / np.sum(a["time"])),
            "nodes_added": int(np.max(a["nodes_added"])),
            "scenes": sorted(set(a["scenes"])),
        }
    return out


def table(data):
    lines = [
        "| scenario | quality | method | CPU s/event | naive/method | delta RMSE | delta max | total RMSE | nodes+ | emission L1 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for sc in data["scenarios"]:
        for run in sc["runs"]:
            ev = run["events"]
            ix = [i for i, e in enumerate(ev) if "err_delta_rmse" in e]
            sec = [e.get("cpu_seconds", e["seconds"]) for e in ev]
            t = np.mean(sec)
            r = sum(x * q for x, q in zip(sec, run["naive_ratio"])) / sum(sec)
            ed = np.sqrt(np.mean([ev[i]["err_delta_rmse"] ** 2 for i in ix]))
            em = max(ev[i]["err_delta_max"] for i in ix)
            et = np.sqrt(np.mean([ev[i]["err_total_rmse"] ** 2 for i in ix]))
            l1 = max(e["emission_l1"] for e in ev)
            lines.append(
                f"| {sc['scene']} | {run['quality']} | {run['variant']} | {t:.3f} | {r:.1f} | {ed:.4f} | "
                f"{em:.3f} | {et:.4f} | {max(e['nodes_added'] for e in ev)} | {100 * l1:.1f}% |"
            )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", default=os.path.join(ROOT, "benchmarks", "out", "events.json"))
    ap.add_argument("--png", default=os.path.join(ROOT, "benchmarks", "events_speed_accuracy.png"))
    ap.add_argument("--date", default="", help="when the JSON was measured, shown in the title")
    args = ap.parse_args()
    with open(args.json) as f:
        data = json.load(f)
    agg = aggregate(data)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9.5, 5.6))
    # No text at the points (they overlap: FE, FE warm and AR send the same light). Colour = method,
    # marker = quality; methods on the same spot are drawn as concentric markers, the larger first.
    size = {"FE": 230, "FE warm": 150, "AR": 80, "NAIVE": 80, "AUTO": 80, "AUTO bf=1e-2": 80}
    scenes = {q: set() for q in MARKERS}
    for (variant, quality), a in sorted(agg.items(), key=lambda kv: -size.get(kv[0][0], 80)):
        scenes.setdefault(quality, set()).update(a["scenes"])
        ax.scatter(
            a["time"],
            a["err_delta"],
            s=size.get(variant, 80),
            color=COLORS.get(variant, "k"),
            marker=MARKERS.get(quality, "x"),
            edgecolor="k",
            linewidth=0.6,
            zorder=3,
        )
    for variant, c in COLORS.items():
        ax.scatter([], [], color=c, label=variant, edgecolor="k", linewidth=0.5, s=60)
    all_scenes = set().union(*scenes.values())
    for q, m in MARKERS.items():
        only = "" if scenes.get(q, set()) == all_scenes else " (" + ", ".join(sorted(scenes[q])) + " only)"
        ax.scatter([], [], color="w", edgecolor="k", marker=m, label=f"base: {q}{only}", s=60)
    ax.scatter(
        [], [], color="w", edgecolor="w", label="FE, FE warm, AR on one spot:\nconcentric, FE outermost"
    )
    ax.set_xscale("log")
    ax.margins(x=0.12, y=0.08)
    ax.set_yscale("log")
    ax.set_xlabel("mean CPU time per light event (s)")
    ax.set_ylabel("error of the light's contribution: RMSE (radiance)")
    ax.set_title(
        "Dynamic light events: cornell + office + 30-frame beam\n"
        "error vs NAIVE at reference quality; lower left is better"
        + (f"; measured {args.date}" if args.date else ""),
        fontsize=10,
    )
    label_log_axis(ax.yaxis)
    label_log_axis(ax.xaxis)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(args.png, dpi=130)
    print(f"wrote {args.png}")
    print(table(data))
    print()
    for (variant, quality), a in sorted(agg.items(), key=lambda kv: (kv[0][1], kv[1]["time"])):
        print(
            f"{quality:7s} {variant:13s} {a['time']:.3f} s/event  naive/method {a['ratio']:6.1f}  "
            f"delta RMSE {a['err_delta']:.4f}  total RMSE {a['err_total']:.4f}  nodes+ {a['nodes_added']}"
        )


if __name__ == "__main__":
    main()
