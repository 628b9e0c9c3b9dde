"""The vertex output's misses split by whether the texture output misses the same object (vx28,
issue 19): for each lit object outside TOL in a vertex run of camera_compare, its error in a
texture run of the same view. Misses the texture output shares are transport / gather (the light
gathered is off); misses only the vertex output has are its display sampling (the corner values).

    .venv/bin/python benchmarks/miss_split.py VERTEX_JSON TEXTURE_JSON [--tol 0.05] [--out NAME]

VERTEX_JSON / TEXTURE_JSON: benchmarks/out/camera_<tag>.json; views matched by their name's first
two words (furnished_wide, furnished_close). Prints per view and class (books, boards, sides, walls
and floor, other) the counts; --out writes benchmarks/out/<NAME>.json with every miss."""

import argparse
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))


def klass(name):
    if re.match(r"case\d+_book", name):
        return "books"
    if re.match(r"case\d+_board", name):
        return "boards"
    if re.match(r"case\d+_side", name):
        return "sides"
    if name.startswith(("wall", "floor", "ceiling")):
        return "walls"
    return "other"


def views(path, output):
    out = {}
    for vn, v in json.load(open(path))["views"].items():
        key = "_".join(vn.split("_")[:2])
        errs = {n: o[output]["mre"] for n, o in v["objects"].items() if output in o and n in set(v["lit"])}
        bias = {n: o[output]["bias"] for n, o in v["objects"].items() if output in o and n in set(v["lit"])}
        out[key] = (errs, bias, {n: o["pixels"] for n, o in v["objects"].items()})
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("vertex")
    p.add_argument("texture")
    p.add_argument("--tol", type=float, default=0.05)
    p.add_argument("--out")
    a = p.parse_args()
    V, T = views(a.vertex, "vertex"), views(a.texture, "texture")
    dump = {}
    for key in V:
        if key not in T:
            continue
        (ev, bv, px), (et, bt, _) = V[key], T[key]
        rows = []
        for n, e in ev.items():
            if e > a.tol and n in et:
                rows.append(
                    dict(
                        name=n, klass=klass(n), vertex=bv[n], texture=bt[n], pixels=px[n], both=et[n] > a.tol
                    )
                )
        print(
            f"{key}: {len(ev)} lit objects, {len(rows)} vertex misses "
            f"({100 * (1 - len(rows) / len(ev)):.1f}% within {a.tol:.0%})"
        )
        for k in ("books", "boards", "sides", "walls", "other", "all"):
            r = [x for x in rows if k == "all" or x["klass"] == k]
            n_all = sum(1 for n in ev if k == "all" or klass(n) == k)
            both = sum(x["both"] for x in r)
            print(
                f"  {k:7s} {n_all:4d} objects  misses {len(r):3d}: texture too {both:3d}, vertex only "
                f"{len(r) - both:3d}"
            )
        vo = [x for x in rows if not x["both"]]
        lo = sum(x["vertex"] < 0 for x in vo)
        print(f"  vertex-only misses dark / bright: {lo} / {len(vo) - lo}")
        dump[key] = rows
    if a.out:
        json.dump(dump, open(os.path.join(HERE, "out", a.out + ".json"), "w"), indent=1)


if __name__ == "__main__":
    sys.exit(main())
