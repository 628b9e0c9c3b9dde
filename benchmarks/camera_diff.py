"""Two camera_compare.py runs of the same views side by side (session 31, branch unseen2,
docs/accuracy.md): per view and output, the lit objects, median error, share within 5% and pooled
bias of each run; the signed errors of the --objects named; the objects whose signed error moved
more than --moved (points), largest first.

    .venv/bin/python benchmarks/camera_diff.py benchmarks/out/camera_s31_unseen_flip_f1.json \
        benchmarks/out/camera_s31_unseen2_flip_f1.json --objects shelf_back,bed_frame,bottle \
        [--moved 1.0] [--json benchmarks/out/s31_unseen2_diff_f1.json]

An --objects entry that names no object is a pattern: every lit object whose name holds it (the
bottles: their median and range). bpy-free; the JSONs only.
"""

import argparse
import json

import numpy as np


def _pc(x):
    return f"{100 * x:+.1f}%"


def _fig(s):
    return f"{100 * s['within_5']:.0f}% / {100 * s['median']:.2f}% / {100 * s['pooled_bias']:+.2f}%"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("before")
    p.add_argument("after")
    p.add_argument("--objects", default="")
    p.add_argument("--moved", type=float, default=1.0, help="points of signed error")
    p.add_argument("--json")
    a = p.parse_args()
    runs = [json.load(open(x))["views"] for x in (a.before, a.after)]
    out = {"before": a.before, "after": a.after, "views": {}}
    for vn in [v for v in runs[0] if v in runs[1]]:
        va, vb = runs[0][vn], runs[1][vn]
        lit = [n for n in va["lit"] if n in vb["lit"]]
        row = out["views"][vn] = {}
        for k in ("vertex", "texture"):
            sa, sb = va["summary"].get(f"{k}|all"), vb["summary"].get(f"{k}|all")
            if not (sa and sb):
                continue
            err = {n: [r["objects"][n][k]["bias"] for r in (va, vb)] for n in lit if k in va["objects"][n]}
            named = {}
            for q in [q for q in a.objects.split(",") if q]:
                sel = [q] if q in err else [n for n in err if q in n]
                if sel:
                    e = np.array([err[n] for n in sel])
                    named[q] = {
                        "objects": len(sel),
                        "median": np.round(np.median(e, 0), 4).tolist(),
                        "min": np.round(e.min(0), 4).tolist(),
                        "max": np.round(e.max(0), 4).tolist(),
                    }
            moved = sorted(
                ((n, e) for n, e in err.items() if abs(e[1] - e[0]) * 100 > a.moved),
                key=lambda t: -abs(t[1][1] - t[1][0]),
            )
            cpu = [r["cpu_seconds"].get(f"bake_{k}") for r in (va, vb)]
            keys = ("objects", "median", "within_5", "pooled_bias")
            row[k] = {
                "summary": [{q: s[q] for q in keys} for s in (sa, sb)],
                "named": named,
                "moved": dict(moved),
                "bake_cpu": cpu,
            }
            print(f"{vn} {k}: within 5% / median / pooled bias {_fig(sa)} -> {_fig(sb)}; bake CPU {cpu}")
            for q, v in named.items():
                ends = [f"{_pc(v['min'][i])}..{_pc(v['max'][i])}" for i in (0, 1)]
                print(
                    f"    {q} ({v['objects']}): median {_pc(v['median'][0])} -> {_pc(v['median'][1])}, "
                    f"range {ends[0]} -> {ends[1]}"
                )
            shown = ", ".join(f"{n} {_pc(e[0])} -> {_pc(e[1])}" for n, e in moved[:14])
            print(f"    moved > {a.moved:g} points ({len(moved)}): {shown}")
    if a.json:
        json.dump(out, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    main()
