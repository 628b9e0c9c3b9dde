"""The artist room's per-object errors split by class and into direct and indirect light (branch
art30, docs/gather.md): reads two runs of benchmarks/unseen_vs_cycles.py on the same comparison
copy, the full one and `--variant direct` (our indirect term zeroed against Cycles bakes with max
bounces 0), and writes per object and per class the error of the mean of the direct light, of the
rest (indirect: full - direct on both sides) and of the whole, for the texel gather (texture) and
the real vertex bake.

    .venv/bin/python benchmarks/artist_split.py --full out/A_vs_cycles.json --direct out/B_vs_cycles.json \
        [--out benchmarks/out/art30_split.json]

Classes (CLASSES, from hr_testing/artist_room.py; an object can be in several): what the brief of
issue 19's session 26 names: small objects on surfaces, near an emitter (within about 1 m of a
light shape, a Blender light or the glowing lamp shade), linked duplicates, modified meshes
(Bevel, Subdivision Surface, Array, Solidify, Mirror), n-gon faces; and the rest of the room.
"""

import argparse
import json
import os

import numpy as np

CLASSES = {
    "Room": ["room (one-quad walls)"],
    "Floor": ["room (one-quad walls)", "modified"],
    "Table top": ["modified"],
    "Table leg": ["modified"],
    "Suzanne": ["small on a surface", "modified"],
    "Glass": ["small on a surface", "modified"],
    "Book": ["small on a surface"],
    "Book linked 1": ["small on a surface", "linked duplicate"],
    "Book linked 2": ["small on a surface", "linked duplicate"],
    "Chair seat": ["modified"],
    "Chair back slat": ["modified"],
    "Chair legs": ["modified"],
    "Chair mirrored seat": ["modified"],
    "Chair mirrored back slat": ["modified"],
    "Chair mirrored legs": ["modified"],
    "Shelf": ["modified"],
    "Rug": ["n-gon"],
    "Sofa": ["modified", "near an emitter"],
    "Sofa back": ["modified", "near an emitter"],
    "Painting": ["plane facing its wall"],
    "Sign": ["n-gon", "small on a surface"],
    "Lamp pole": ["near an emitter"],
    "Lamp shade": ["near an emitter"],
    "Crate": ["other"],
    "Crate small": ["small on a surface"],
}


def means(row):
    """(ours, ref) grey means of a metrics() row."""
    return float(np.mean(row["mean_ours"])), float(np.mean(row["mean_ref"]))


def split(full, direct, var):
    """{object: {total, direct, indirect, direct_share}} signed errors of the mean (ours / ref - 1)
    of the `var` row in both runs; indirect = (full - direct) on both sides."""
    out = {}
    for n, r in full["objects"].items():
        d = direct["objects"].get(n, {})
        if var not in r or var not in d:
            continue
        fo, fr = means(r[var])
        do, dr = means(d[var])
        io, ir = fo - do, fr - dr
        out[n] = {
            "total": fo / fr - 1 if fr > 0 else None,
            "direct": do / dr - 1 if dr > 0 else None,
            "indirect": io / ir - 1 if ir > 0 else None,
            "direct_share": dr / fr if fr > 0 else None,
            "texels": r[var]["texels"],
        }
    return out


def summary(per, names):
    """Median signed errors and pooled biases (texel-weighted, grey) over `names`."""
    ll = [n for n in names if n in per and per[n]["total"] is not None]
    if not ll:
        return None
    out = {"objects": len(ll)}
    for k in ("total", "direct", "indirect"):
        v = [per[n][k] for n in ll if per[n][k] is not None]
        out[f"median_{k}"] = float(np.median(v)) if v else None
    out["median_direct_share"] = float(np.median([per[n]["direct_share"] for n in ll]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", required=True)
    ap.add_argument("--direct", required=True)
    ap.add_argument("--out")
    a = ap.parse_args()
    full, direct = json.load(open(a.full)), json.load(open(a.direct))
    lit = full["lit"]
    res = {"full": a.full, "direct": a.direct, "objects": {}, "classes": {}}
    for var in ("texture", "texture_unburied", "real_texture_unburied", "real_vertex"):
        per = split(full, direct, var)
        res["objects"][var] = per
        print(f"\n{var}: signed error of the mean, total / direct / indirect (Cycles' direct share)")
        for n in sorted(per, key=lambda n: -(per[n]["total"] or 0)):
            p = per[n]
            f = [
                f"{100 * p[k]:+6.1f}%" if p[k] is not None else "   -  "
                for k in ("total", "direct", "indirect")
            ]
            print(
                f"  {n:26s} {'lit ' if n in lit else 'dark'} {' '.join(f)}  ({p['direct_share'] or 0:.2f}) "
                + ", ".join(CLASSES.get(n, []))
            )
        cls = {}
        for n in lit:
            for c in CLASSES.get(n, ["other"]):
                cls.setdefault(c, []).append(n)
        cls["all lit"] = list(lit)
        res["classes"][var] = {c: summary(per, ns) for c, ns in cls.items()}
        for c, s in res["classes"][var].items():
            if s:
                print(
                    f"  [{c}] {s['objects']} objects: median total {100 * s['median_total']:+.1f}%, direct "
                    f"{100 * s['median_direct']:+.1f}%, indirect {100 * s['median_indirect']:+.1f}%, "
                    f"direct share {s['median_direct_share']:.2f}"
                )
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        json.dump(res, open(a.out, "w"), indent=1)


if __name__ == "__main__":
    main()
