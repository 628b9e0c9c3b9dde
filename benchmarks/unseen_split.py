"""The two-rooms views' per-object errors split (session 31, branch unseen, docs/accuracy.md): direct
against indirect light, and the outputs' resolution against the light gathered. Reads camera_compare
renders (benchmarks/out/camera_<run>/renders.npz), bpy-free.

    .venv/bin/python benchmarks/unseen_split.py --full unseen_a --direct unseen_a_direct \
        [--fine unseen_a_texel0.02] [--json benchmarks/out/unseen_split_a.json]
    .venv/bin/python benchmarks/unseen_split.py --table unseen_a,unseen_b_medium,... [--exclude doorway]

--table: camera_compare's per-view figures (compare(): lit objects, error of each object's mean,
median, share within 5%, pooled bias, the same over interior pixels) recomputed from the runs'
renders without the --exclude objects (the two rooms' doorway, whose reversed faces the references
show black: hr_testing/two_rooms.py), one line per run and output; --json: them as JSON.

--full: a camera_compare run (Cycles with 64 bounces, our bake); --direct: bias_split.py's
`--variant direct` of the same view (Cycles with no bounces, our indirect term zeroed), both with
the same outputs. Per lit object (camera_compare's lit list, MIN_PIXELS), pixels pooled, RGB summed:
- total: ours / Cycles - 1;
- its two parts, which add up to it: direct (ours_d - cyc_d) / cyc and indirect
  ((ours - ours_d) - (cyc - cyc_d)) / cyc; the share of direct light in Cycles (cyc_d / cyc);
- --fine: the same object in a finer texture run (texture output at small texels, the light
  gathered at nearly every visible point): what is left there is the light gathered (transport,
  the gather), the rest of the output's error is its resolution (its samples' spacing).
Prints the lit objects outside 5% per output, worst first, and the medians of |part|.
"""

import argparse
import json
import os
import re

import numpy as np
from camera_compare import MIN_PIXELS, OUT


def load(run):
    z = np.load(os.path.join(OUT, f"camera_{run}", "renders.npz"))
    d = {k: z[k].astype(np.float64).sum(-1) for k in z.files if k not in ("index", "names")}
    d["ref"] = (d.pop("ref1") + d.pop("ref2")) / 2
    return d, z["index"], list(z["names"])


def sums(img, ob, n_obj):
    return np.bincount(ob.ravel(), img.ravel(), n_obj + 1)[1:]


def table(runs, exclude, path=None):
    """compare()'s summaries of each run without the objects in `exclude` (see the docstring)."""
    from camera_compare import interior, per_object
    from hr_testing import cycles_ref as C

    out = {}
    for run in runs:
        z = np.load(os.path.join(OUT, f"camera_{run}", "renders.npz"))
        names = [n if n not in exclude else None for n in z["names"]]
        ob = z["index"]
        ref = (z["ref1"].astype(np.float64) + z["ref2"]) / 2
        pref = {n: v for n, v in per_object(ref, ob, names).items() if n is not None}
        lit = C.lit_objects(pref)
        inner = interior(ob)
        for k in [k for k in ("vertex", "texture") if k in z.files]:
            row = out.setdefault(run, {})[k] = {}
            for part, mask in (("all", None), ("interior", inner)):
                po = per_object(z[k].astype(np.float64), ob, names, mask)
                pr = per_object(ref, ob, names, mask)
                per = {n: C.metrics(po[n], pr[n]) for n in pr if n is not None}
                row[part] = C.object_summary(per, [n for n in lit if n in per])
                if part == "all":
                    row["worst"] = sorted(
                        ((n, per[n]["bias"], per[n]["texels"]) for n in lit), key=lambda t: -abs(t[1])
                    )[:10]
            a, i = row["all"], row["interior"]
            print(
                f"{run:24s} {k:8s} {a['objects']:4d} lit: median {100 * a['median']:.2f}%, within 5% "
                f"{100 * a['within_5']:.0f}%, pooled bias {100 * a['pooled_bias']:+.2f}%; interior "
                f"{i['objects']} objects, median {100 * i['median']:.2f}%, "
                f"within 5% {100 * i['within_5']:.0f}%"
            )
    if path:
        with open(path, "w") as fh:
            json.dump({"exclude": sorted(exclude), "runs": out}, fh, indent=1)
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--table", help="runs (camera_<run>/renders.npz) whose summaries to print")
    p.add_argument("--exclude", default="doorway", help="objects left out of --table's figures")
    p.add_argument("--full")
    p.add_argument("--direct")
    p.add_argument("--fine", help="a finer texture run of the same view (resolution against the light)")
    p.add_argument("--tol", type=float, default=0.05)
    p.add_argument("--json")
    a = p.parse_args()
    if a.table:
        return table(a.table.split(","), set(a.exclude.split(",")), a.json)
    full, ob, names = load(a.full)
    dire, ob_d, _ = load(a.direct)
    n = len(names)
    count = np.bincount(ob.ravel(), minlength=n + 1)[1:]
    cyc, cyc_d = sums(full["ref"], ob, n), sums(dire["ref"], ob, n)
    cmp_json = json.load(open(os.path.join(OUT, "camera_" + _tag_of(a.full) + ".json")))["views"][a.full]
    skip = set(a.exclude.split(","))
    lit = [
        i
        for i, nm in enumerate(names)
        if nm in set(cmp_json["lit"]) and nm not in skip and count[i] >= MIN_PIXELS
    ]
    fine = None
    if a.fine:
        f, ob_f, _ = load(a.fine)
        fine = sums(f["texture"], ob_f, n) / sums(f["ref"], ob_f, n) - 1
    out = {"full": a.full, "direct": a.direct, "fine": a.fine, "objects": {}, "summary": {}}
    for k in [k for k in ("vertex", "texture") if k in full and k in dire]:
        ours, ours_d = sums(full[k], ob, n), sums(dire[k], ob, n)
        tot = ours / cyc - 1
        dpart = (ours_d - cyc_d) / cyc
        ipart = ((ours - ours_d) - (cyc - cyc_d)) / cyc
        share = cyc_d / cyc
        for i in lit:
            o = out["objects"].setdefault(
                names[i], {"pixels": int(count[i]), "direct_share": float(share[i])}
            )
            o[k] = dict(total=float(tot[i]), direct=float(dpart[i]), indirect=float(ipart[i]))
            if fine is not None:
                o["fine_texture"] = float(fine[i])
        li = np.array(lit)
        miss = li[np.abs(tot[li]) > a.tol]
        out["summary"][k] = s = dict(
            objects=len(li),
            within=float(np.mean(np.abs(tot[li]) <= a.tol)),
            median_abs_total=float(np.median(np.abs(tot[li]))),
            median_abs_direct=float(np.median(np.abs(dpart[li]))),
            median_abs_indirect=float(np.median(np.abs(ipart[li]))),
            pooled_direct=float(np.sum(ours_d[li] - cyc_d[li]) / np.sum(cyc[li])),
            pooled_indirect=float(np.sum((ours - ours_d - cyc + cyc_d)[li]) / np.sum(cyc[li])),
            misses=len(miss),
            misses_mostly_direct=int(np.sum(np.abs(dpart[miss]) > np.abs(ipart[miss]))),
        )
        if fine is not None:
            s["misses_fine_within"] = int(np.sum(np.abs(fine[miss]) <= a.tol))
        print(
            f"{a.full} {k}: {len(li)} lit objects, {100 * s['within']:.0f}% within {100 * a.tol:.0f}%, "
            f"median |total| {100 * s['median_abs_total']:.2f}% (|direct part| "
            f"{100 * s['median_abs_direct']:.2f}%, |indirect part| {100 * s['median_abs_indirect']:.2f}%), "
            f"pooled direct {100 * s['pooled_direct']:+.2f}%, indirect {100 * s['pooled_indirect']:+.2f}%; "
            f"{len(miss)} misses, {s['misses_mostly_direct']} mostly direct"
            + (
                f", {s['misses_fine_within']} within {100 * a.tol:.0f}% at fine texels"
                if fine is not None
                else ""
            )
        )
        for i in sorted(miss, key=lambda i: -abs(tot[i])):
            print(
                f"  {names[i]:22s} {100 * tot[i]:+6.1f}% = direct {100 * dpart[i]:+6.1f} + indirect "
                f"{100 * ipart[i]:+6.1f} (direct share {100 * share[i]:3.0f}%, {count[i]} px)"
                + (f"; fine texels {100 * fine[i]:+6.1f}%" if fine is not None else "")
            )
    by = {}
    for nm in out["objects"]:
        by.setdefault(re.sub(r"\d+", "#", nm), []).append(nm)
    out["classes"] = by
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


def _tag_of(run):
    """The camera_<tag>.json holding a run: the newest JSON whose views include it."""
    best = None
    for f in os.listdir(OUT):
        if f.startswith("camera_") and f.endswith(".json"):
            try:
                views = json.load(open(os.path.join(OUT, f))).get("views", {})
            except (ValueError, OSError):
                continue
            t = os.path.getmtime(os.path.join(OUT, f))
            if run in views and (best is None or t > best[0]):
                best = (t, f[len("camera_") : -len(".json")])
    if best is None:
        raise SystemExit(f"no camera_*.json holds {run}")
    return best[1]


if __name__ == "__main__":
    main()
