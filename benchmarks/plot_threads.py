"""Chart of a bench_threads.py JSON: per phase, the speed-up on 1 to 16 cores that Amdahl's law
gives from the profiled 1-thread run (serial CPU + the threaded maps' batches scheduled on N
workers, bench_threads.amdahl_table), and the measured 2-thread speed-up (wall, one run on a
shared machine) as points. Also prints the table of the model for docs/threads.md.

    .venv/bin/python benchmarks/plot_threads.py [--json benchmarks/out/threads_100k_quiet2.json]
        [--png docs/images/threads.png]
"""

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_threads import PHASE_KEYS, amdahl_table  # noqa: E402

CORES = list(range(1, 17))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", default=os.path.join(HERE, "out", "threads_100k_quiet2.json"))
    ap.add_argument("--png", default=os.path.join(HERE, "..", "docs", "images", "threads.png"))
    ap.add_argument("--build-json", default=None, help="a --build-only run: the build's measured point")
    args = ap.parse_args(argv)
    data = json.load(open(args.json))
    runs = data["runs"]
    prof = next(k for k, r in runs.items() if r.get("profiled"))
    names = [k for k in runs[prof] if k not in PHASE_KEYS]
    model = amdahl_table(runs[prof], names, CORES)
    two = next((k for k in runs if k.startswith("2@")), None)
    print(f"{data['size']} room, model from run {prof}: phase | CPU s | threaded | speed-up on 2, 4, 8, 16")
    for n, r in model.items():
        s = " | ".join(f"{r['speedup'][k]:.2f}" for k in (2, 4, 8, 16))
        print(f"| {n} | {r['cpu']:.2f} | {r['share']:.2f} | {s} |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    ax.plot(CORES, CORES, color="0.8", lw=1, ls="--", label="ideal")
    for i, (n, r) in enumerate(model.items()):
        c = "k" if n == "total" else f"C{i}"
        ax.plot(CORES, [r["speedup"][k] for k in CORES], color=c, lw=2.5 if n == "total" else 1.5, label=n)
        if two is None:
            continue
        # a 2-thread run that loaded the 1-thread run's system (--system) has no build to compare:
        # its build point comes from --build-json, and the total is over the other phases
        built = [k for k in names if not (k == "build" and runs[two].get("loaded"))]
        if n == "build" and n not in built:
            if args.build_json:
                b = json.load(open(args.build_json))["runs"]
                b1, b2 = (next(r for k, r in b.items() if k.startswith(f"{m}@")) for m in (1, 2))
                ax.plot([2], [b1["build"] / b2["build"]], "o", color=c, ms=5)
            continue
        wall = sum(runs[prof][k] for k in built) if n == "total" else runs[prof][n]
        wall2 = sum(runs[two][k] for k in built) if n == "total" else runs[two][n]
        ax.plot([2], [wall / wall2], "o", color=c, ms=5)
    ax.set_xlabel("cores")
    ax.set_ylabel("speed-up over one thread")
    ax.set_xlim(1, 16)
    ax.set_ylim(0.5, 16)
    ax.set_yscale("log", base=2)
    ax.set_title(
        f"{data['size']} furnished room: Amdahl model from the 1-thread profile (lines), "
        "measured on 2 (points)",
        fontsize=9,
    )
    ax.legend(fontsize=8, ncol=2, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.png, dpi=110)
    print("wrote", os.path.relpath(args.png))


if __name__ == "__main__":
    main()
