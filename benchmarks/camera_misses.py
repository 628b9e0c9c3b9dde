"""Where the vertex output misses from the camera: camera_compare.py's objects outside 5%, by class
(docs/accuracy.md, session 23, branch vx26).

    .venv/bin/python benchmarks/camera_misses.py benchmarks/out/camera_vx26.json \
        [--views furnished_close_vs0.25,furnished_wide_vs0.25] [--against OTHER.json:VIEW] [--json OUT]

Per view: each class (the object's name with its numbers as #: case#_book#_#, case#_side#, ...)
with its objects, those outside 5% (all pixels) and outside 5% on the interior pixels only (no
8-neighbour of another object: the anti-aliased edges out), the class's median signed error on
all and on interior pixels, and the reference's noise. --against: the same objects in another
run's view, per class the median change of the signed error and the objects that left / entered
the 5% band.
"""

import argparse
import json
import re
from collections import defaultdict

import numpy as np


def classes(view):
    lit = set(view["lit"])
    by = defaultdict(list)
    for name, r in view["objects"].items():
        if name in lit and "vertex" in r:
            by[re.sub(r"\d+", "#", name)].append(name)
    return by


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("json")
    p.add_argument("--views")
    p.add_argument("--against", help="OTHER.json:VIEW (one view: compare --views' first view with it)")
    p.add_argument("--json", dest="out")
    a = p.parse_args()
    d = json.load(open(a.json))["views"]
    views = a.views.split(",") if a.views else list(d)
    other = None
    if a.against:
        path, vn = a.against.rsplit(":", 1)
        other = json.load(open(path))["views"][vn]
    out = {}
    for vn in views:
        v = d[vn]
        res = {}
        print(f"{vn}: {len(v['lit'])} lit objects, within 5% {v['summary']['vertex|all']['within_5']:.1%}")
        for c, names in sorted(classes(v).items(), key=lambda kv: -len(kv[1])):
            o = v["objects"]
            err = np.array([o[n]["vertex"]["bias"] for n in names])
            inner = np.array([o[n].get("vertex_interior", o[n]["vertex"])["bias"] for n in names])
            noise = np.array([o[n]["ref_noise"] for n in names])
            miss = [n for n in names if o[n]["vertex"]["mre"] > 0.05]
            miss_in = [n for n in names if o[n].get("vertex_interior", o[n]["vertex"])["mre"] > 0.05]
            r = dict(
                objects=len(names),
                outside=len(miss),
                outside_interior=len(miss_in),
                median_signed=float(np.median(err)),
                median_signed_interior=float(np.median(inner)),
                ref_noise_median=float(np.median(noise)),
                worst=sorted(
                    ((n, round(o[n]["vertex"]["bias"], 4), o[n]["pixels"]) for n in miss), key=lambda t: t[1]
                )[:6],
            )
            line = (
                f"  {c:16s} {len(names):4d} objects, outside 5% {len(miss):3d} (interior {len(miss_in):3d}), "
                f"median signed {100 * r['median_signed']:+.2f}% "
                f"(interior {100 * r['median_signed_interior']:+.2f}%)"
            )
            if other is not None:
                both = [n for n in names if n in other["objects"] and "vertex" in other["objects"][n]]
                before = np.array([other["objects"][n]["vertex"]["bias"] for n in both])
                now = np.array([o[n]["vertex"]["bias"] for n in both])
                left = [
                    n for n in both if other["objects"][n]["vertex"]["mre"] <= 0.05 < o[n]["vertex"]["mre"]
                ]
                came = [
                    n for n in both if o[n]["vertex"]["mre"] <= 0.05 < other["objects"][n]["vertex"]["mre"]
                ]
                r.update(median_change=float(np.median(now - before)), left=len(left), entered=len(came))
                line += f"; against: change {100 * r['median_change']:+.2f}%, "
                line += f"left {len(left)}, entered {len(came)}"
            print(line)
            res[c] = r
        out[vn] = res
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
