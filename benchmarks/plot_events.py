"""Chart of benchmarks/out/events.json and events_gathered.json (from bench_events.py, classic and
--gather): time per event against error, log-log, one panel each.

One point per method and quality setting: x = mean CPU time per event over all events of all scenarios,
y = RMS over the evaluated events of the error of the light's contribution (reflected radiance, with
minus without the shapes, RMSE over sample points). Classic (Final Gather off, the hierarchy's leaves):
against NAIVE at reference quality. Gathered (Final Gather on, the bake's default): time = the event +
the gathered output's update; filled markers against the independent gathered reference (NAIVE at
REFERENCE, its own leaves, 1,024 rays, two seeds, host visibility off), hollow markers the
transport's part alone (against the method's own gather reading NAIVE at REFERENCE); dotted lines:
the floor a perfect transport reaches through each quality's gather. Also prints the tables used in
docs/events.md. --note: a caption under the chart (e.g. which scenarios come from an older run).

    .venv/bin/python benchmarks/plot_events.py [--json benchmarks/out/events.json]
        [--gathered benchmarks/out/events_gathered.json] [--png benchmarks/events_speed_accuracy.png]
        [--date DATE] [--note TEXT]
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
                a["gather_time"].append(e.get("gather_cpu_seconds", 0.0))
                if "err_delta_rmse" in e:
                    a["ed"].append(e["err_delta_rmse"])
                    a["et"].append(e["err_total_rmse"])
                    a["etr"].append(e.get("err_transport_rmse", np.nan))
    out = {}
    for k, a in acc.items():
        out[k] = {
            "time": float(np.mean(a["time"])),
            "err_delta": float(np.sqrt(np.mean(np.square(a["ed"])))),
            "err_total": float(np.sqrt(np.mean(np.square(a["et"])))),
            "gather_time": float(np.mean(a["gather_time"])),
            "err_transport": float(np.sqrt(np.mean(np.square(a["etr"])))),
            "ratio": float(np.sum(a["naive_time"]) / np.sum(a["time"])),
            "nodes_added": int(np.max(a["nodes_added"])),
            "scenes": sorted(set(a["scenes"])),
        }
    return out


def table(data):
    lines = [
        "| scenario | quality | method | CPU s/event | naive/method | delta RMSE | delta max | total RMSE "
        "| nodes+ | emission L1 |",
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


def gathered_table(data):
    """The gathered run's table: per scenario, quality and method; then per scenario and quality the
    floor (the quality's gather reading NAIVE at REFERENCE, against the independent reference) and the
    reference's own noise (RMSE of its two seeds' difference / 2: the noise of their mean)."""
    lines = [
        "| scenario | quality | method | CPU s/event | of it gather | naive/method | delta RMSE "
        "| transport RMSE | delta max | nodes+ |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for sc in data["scenarios"]:
        for run in sc["runs"]:
            ev = run["events"]
            ix = [i for i, e in enumerate(ev) if "err_delta_rmse" in e]
            sec = [e["cpu_seconds"] for e in ev]
            t, tg = np.mean(sec), np.mean([e["gather_cpu_seconds"] for e in ev])
            r = sum(x * q for x, q in zip(sec, run["naive_ratio"])) / sum(sec)
            ed = np.sqrt(np.mean([ev[i]["err_delta_rmse"] ** 2 for i in ix]))
            etr = np.sqrt(np.mean([ev[i]["err_transport_rmse"] ** 2 for i in ix]))
            em = max(ev[i]["err_delta_max"] for i in ix)
            lines.append(
                f"| {sc['scene']} | {run['quality']} | {run['variant']} | {t:.3f} | {tg:.3f} | {r:.1f} | "
                f"{ed:.4f} | {etr:.4f} | {em:.3f} | {max(e['nodes_added'] for e in ev)} |"
            )
    lines += [
        "",
        "| scenario | quality | floor RMSE | floor, shapes by shadow rays | reference noise RMSE "
        "| contribution RMS |",
        "|---|---|---|---|---|---|",
    ]
    for sc in data["scenarios"]:
        rf = sc["reference"]
        noise = np.sqrt(np.mean([v[0] ** 2 for v in rf["seed_diff"].values()])) / 2
        size = np.sqrt(np.mean([v**2 for v in rf["contribution_rms"].values()]))
        for qr in sc["qualities"]:
            fl = np.sqrt(np.mean([v[0] ** 2 for v in qr["floor"].values()]))
            off = qr.get("floor_hostvis_off")  # (since session 29: the floor with host visibility off)
            fo = f"{np.sqrt(np.mean([v[0] ** 2 for v in off.values()])):.4f}" if off else "-"
            lines.append(f"| {sc['scene']} | {qr['quality']} | {fl:.4f} | {fo} | {noise:.4f} | {size:.4f} |")
    return "\n".join(lines)


def floors(data):
    """quality -> RMS over every scenario's evaluated events of the floor (see gathered_table)."""
    acc = defaultdict(list)
    for sc in data["scenarios"]:
        for qr in sc.get("qualities", []):
            acc[qr["quality"]] += [v[0] for v in qr["floor"].values()]
    return {q: float(np.sqrt(np.mean(np.square(v)))) for q, v in acc.items()}


def draw(ax, agg, hollow=False):
    """The points of one panel (colour = method, marker = quality); hollow: the transport error too."""
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
        if hollow:
            ax.scatter(
                a["time"],
                a["err_transport"],
                s=size.get(variant, 80),
                facecolor="none",
                edgecolor=COLORS.get(variant, "k"),
                marker=MARKERS.get(quality, "x"),
                linewidth=1.4,
                zorder=3,
            )
    return scenes


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", default=os.path.join(ROOT, "benchmarks", "out", "events.json"))
    ap.add_argument(
        "--gathered",
        default=os.path.join(ROOT, "benchmarks", "out", "events_gathered.json"),
        help="bench_events.py --gather's JSON (its panel; skipped when the file does not exist)",
    )
    ap.add_argument("--png", default=os.path.join(ROOT, "benchmarks", "events_speed_accuracy.png"))
    ap.add_argument("--date", default="", help="when the JSON was measured, shown in the title")
    ap.add_argument("--note", default="", help="a caption under the chart")
    args = ap.parse_args()
    with open(args.json) as f:
        data = json.load(f)
    gathered = None
    if args.gathered and os.path.exists(args.gathered):
        with open(args.gathered) as f:
            gathered = json.load(f)
    agg = aggregate(data)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 1 if gathered is None else 2
    # one scale for both panels: the gathered output's time and error read on the classic's
    fig, axes = plt.subplots(
        1, panels, figsize=(9.5 if panels == 1 else 15.5, 6.2), squeeze=False, sharey=True, sharex=True
    )
    ax = axes[0, 0]
    # No text at the points (they overlap: FE, FE warm and AR send the same light). Colour = method,
    # marker = quality; methods on the same spot are drawn as concentric markers, the larger first.
    scenes = draw(ax, agg)
    ax.set_title(
        "Final Gather off (the hierarchy's leaves)\nerror vs NAIVE at reference quality"
        + (f"; measured {args.date}" if args.date else ""),
        fontsize=10,
    )
    ax.set_ylabel("error of the light's contribution: RMSE (radiance)")
    if gathered is not None:
        gx = axes[0, 1]
        gagg = aggregate(gathered)
        gscenes = draw(gx, gagg, hollow=True)
        fl = floors(gathered)
        for v in fl.values():
            gx.axhline(v, color="0.4", ls=":", lw=1.2, zorder=1)
        gx.annotate(
            "floor: the gather reading NAIVE at reference quality\n("
            + ", ".join(f"{q} {v:.4f}" for q, v in fl.items())
            + ")",
            (0.99, min(fl.values())),
            xycoords=("axes fraction", "data"),
            ha="right",
            va="top",
            fontsize=7,
            color="0.3",
        )
        gx.set_title(
            "Final Gather on (the default): event + gathered output update\n"
            "filled: vs gathered reference; hollow: the transport's part alone",
            fontsize=10,
        )
        for q, v in gscenes.items():
            scenes.setdefault(q, set()).update(v)
    all_scenes = set().union(*scenes.values())
    for a in axes[0]:
        a.set_xscale("log")
        a.margins(x=0.12, y=0.08)
        a.set_yscale("log")
        a.set_xlabel("mean CPU time per light event (s)")
        label_log_axis(a.yaxis)
        label_log_axis(a.xaxis)
        a.grid(True, which="both", alpha=0.3)
    lx = axes[0, -1]
    for variant, c in COLORS.items():
        lx.scatter([], [], color=c, label=variant, edgecolor="k", linewidth=0.5, s=60)
    for q, m in MARKERS.items():
        only = "" if scenes.get(q, set()) == all_scenes else " (" + ", ".join(sorted(scenes[q])) + " only)"
        lx.scatter([], [], color="w", edgecolor="k", marker=m, label=f"base: {q}{only}", s=60)
    lx.scatter(
        [], [], color="w", edgecolor="w", label="FE, FE warm, AR on one spot:\nconcentric, FE outermost"
    )
    if gathered is not None:
        lx.scatter(
            [],
            [],
            color="0.5",
            edgecolor="k",
            s=60,
            label="gathered, filled: error vs the\ngathered reference",
        )
        lx.scatter(
            [],
            [],
            facecolor="none",
            edgecolor="0.3",
            linewidth=1.4,
            s=60,
            label="gathered, hollow: the transport's\npart (vs the same gather on\n"
            "NAIVE at reference quality)",
        )
    lx.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle("Dynamic light events: cornell + office + 30-frame beam; lower left is better", fontsize=11)
    if args.note:
        fig.text(0.01, 0.005, args.note, fontsize=8, ha="left", va="bottom", color="0.25")
    fig.tight_layout(rect=(0, 0.03 if args.note else 0, 1, 1))
    fig.savefig(args.png, dpi=130)
    print(f"wrote {args.png}")
    print(table(data))
    print()
    for (variant, quality), a in sorted(agg.items(), key=lambda kv: (kv[0][1], kv[1]["time"])):
        print(
            f"{quality:7s} {variant:13s} {a['time']:.3f} s/event  naive/method {a['ratio']:6.1f}  "
            f"delta RMSE {a['err_delta']:.4f}  total RMSE {a['err_total']:.4f}  nodes+ {a['nodes_added']}"
        )
    if gathered is not None:
        print()
        print(gathered_table(gathered))
        print()
        for (variant, quality), a in sorted(gagg.items(), key=lambda kv: (kv[0][1], kv[1]["time"])):
            print(
                f"gathered {quality:7s} {variant:13s} {a['time']:.3f} s/event "
                f"(gather {a['gather_time']:.3f})  "
                f"naive/method {a['ratio']:6.1f}  delta RMSE {a['err_delta']:.4f}  "
                f"transport RMSE {a['err_transport']:.4f}"
            )
        print("floors:", {q: round(v, 4) for q, v in floors(gathered).items()})


if __name__ == "__main__":
    main()
