"""Issue 19's -1.5% common to every output, made precise (branch bias27, docs/gather.md): per class
of object (walls, ceiling, floor, furniture, books) and by how much of an object's light is direct,
the median signed error per object and the pooled bias, over all pixels and interior pixels, from
camera_compare's / bias_split's saved renders (benchmarks/out/camera_<view>/renders.npz).

    .venv/bin/python benchmarks/bias_classes.py [--views furnished_wide,furnished_close]
        [--runs texture:{view}_texel0.02,vertex:{view}] [--direct {view}_direct] [--name NAME]

--runs: output:folder pairs per view ({view} is replaced; JSON keys folder:output|pixels|class);
the lit objects, the interior mask and the error are camera_compare's (cycles_ref.lit_objects,
interior, metrics' bias: ours / Cycles - 1 per channel, mean over RGB). Direct share: Cycles'
direct-light-only render (bias_split --variant direct, its references) over the full reference,
per object (mean over pixels, grey). The lit books' pixels apart: edge pixels, those bordering
another book, interior pixels (book_edges).
Writes benchmarks/out/bias27_classes.json.
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
OUT = os.path.join(HERE, "out")


def klass(n):
    if "_book" in n:
        return "books"
    if n.startswith("wall"):
        return "walls"
    if n in ("ceiling", "floor"):
        return n
    return "furniture"


def load(folder):
    z = np.load(os.path.join(OUT, f"camera_{folder}", "renders.npz"))
    return {k: z[k] for k in z.files}


def book_edges(img, ref, ob, names, lit):
    """The lit books' light by where their pixels lie: edge pixels (an 8-neighbour shows another
    object), those bordering another book, interior pixels. {part: (ours / Cycles - 1 over the
    part's grey sums, the part's share of the books' deficit in points of their light, pixels)}."""
    H, W = ob.shape
    p = np.pad(ob, 1, mode="edge")
    nb = np.zeros_like(ob)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            q = p[dy : dy + H, dx : dx + W]
            nb = np.where((nb == 0) & (q != ob), q, nb)
    keep = np.array([False] + [("_book" in n and n in lit) for n in names])
    book = np.array([False] + ["_book" in n for n in names])
    sel = keep[ob]
    go, gr = img.mean(-1), ref.mean(-1)
    tot = gr[sel].sum()
    edge = sel & (nb > 0)
    parts = {"all": sel, "edge": edge, "book-book": edge & book[nb], "interior": sel & (nb == 0)}
    return {
        k: (float(go[m].sum() / gr[m].sum() - 1), float((go - gr)[m].sum() / tot), int(m.sum()))
        for k, m in parts.items()
    }


def main():
    import camera_compare as cc
    from hr_testing import cycles_ref as C

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--views", default="furnished_wide,furnished_close")
    p.add_argument("--runs", default="texture:{view}_texel0.02,vertex:{view}")
    p.add_argument("--direct", default="{view}_direct", help="bias_split's direct variant folder")
    p.add_argument("--name", default="bias27_classes")
    a = p.parse_args()
    dump = {}
    for view in a.views.split(","):
        runs = [r.split(":") for r in a.runs.split(",")]
        base = load(runs[0][1].format(view=view))
        names = list(base["names"])
        ob = base["index"]
        ref = (base["ref1"].astype(np.float64) + base["ref2"]) / 2
        inner = cc.interior(ob)
        pref = cc.per_object(ref, ob, names)
        lit = [n for n in C.lit_objects(pref) if n != "ceiling_light"]
        share = {}
        dpath = os.path.join(OUT, f"camera_{a.direct.format(view=view)}", "renders.npz")
        if os.path.exists(dpath):
            dz = np.load(dpath)
            dref = (dz["ref1"].astype(np.float64) + dz["ref2"]) / 2
            pd = cc.per_object(dref, ob, names)
            share = {n: float(pd[n].mean() / pref[n].mean()) for n in lit}
        vd = dump[view] = {"lit": len(lit)}
        for out, folder in runs:
            z = load(folder.format(view=view))
            img = z[out].astype(np.float64)
            be = vd[f"{folder.format(view=view)}:{out}|book_edges"] = book_edges(img, ref, ob, names, lit)
            print(
                f"{view:15s} {out:7s} {folder.format(view=view)}: lit books' pixels "
                + ", ".join(
                    f"{k} {100 * v[0]:+.2f}% ({100 * v[1]:+.2f} pts, {v[2]} px)" for k, v in be.items()
                )
            )
            for part, mask in (("all", None), ("interior", inner)):
                po, pr = cc.per_object(img, ob, names, mask), cc.per_object(ref, ob, names, mask)
                per = {n: C.metrics(po[n], pr[n]) for n in lit if n in pr}
                groups = {}
                for n in per:
                    groups.setdefault(klass(n), []).append(n)
                    if share:
                        s = share[n]
                        g = "direct < 5%" if s < 0.05 else ("direct 5-40%" if s < 0.4 else "direct >= 40%")
                        groups.setdefault(g, []).append(n)
                groups["all"] = list(per)
                for g, sel in sorted(groups.items()):
                    st = C.object_summary(per, sel)
                    vd[f"{folder.format(view=view)}:{out}|{part}|{g}"] = st
                    print(
                        f"{view:15s} {out:7s} {part:8s} {g:14s} {st['objects']:3d} objects: median signed "
                        f"{100 * st['median_signed']:+6.2f}%  pooled {100 * st['pooled_bias']:+6.2f}%  "
                        f"within 5% {100 * st['within_5']:3.0f}%"
                    )
        if share:
            vd["direct_share"] = share
            med = np.median(list(share.values()))
            print(f"{view}: direct share of the lit objects' light, median {med:.3f}")
    from hr_testing.cycles_ref import write_json

    write_json(os.path.join(OUT, f"{a.name}.json"), dump)


if __name__ == "__main__":
    main()
