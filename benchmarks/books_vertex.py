"""Where the furnished sample's vertex output (LoopGather, the extension's default output) loses the
books' light, by face class (books_daylight.classes: top, front, the sides in a 2 mm slot, the
side strips above a shorter neighbour), over the texels a camera sees (unburied.unburied_texels):
Cycles' mean, the texture output's (texel gather) and the vertex output's at the same texels, and
diagnostic vertex outputs that each leave one step out:

- raw: each corner its own sample's value (no averaging over welded faces, no shift);
- flat4: each face flat at the mean of its corners' samples (what the interpolation's weights
  (a quad: two triangles, corners 0 and 2 a third each, 1 and 3 a sixth) do to that mean);
- flattex: each face flat at the texture output's mean over the face (by area: what the best
  corner values of a face could give, the face's light, not its shape);
- flattexel: the same mean over the face's texels each counted once, as the per-object measure
  counts them (texels on a face's edge, part outside it, count fully).

Runs the bake's draft FE solution with the final gather's transport, as furnished_vs_cycles.py
'NAME=dict(gather=dict(rays=128, shadow_rays=16, levels=2, iterations=4, vertex=True),
transport="gather")'. Options: name=value pairs set module constants before the gather is built
(layouts.FIT=False, corner_fit.EVERY=True, corner_fit.EXTRA=16, ...).

    .venv/bin/python benchmarks/books_vertex.py [--json NAME] [corner_fit.EVERY=True ...]
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import books_common as BC  # noqa: E402
import books_daylight as BD  # noqa: E402
import cycles_compare as CC  # noqa: E402
from unburied import unburied_texels  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_addon.core import cluster as CL, farlinks as FL  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import corner_fit, layouts  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

GATHER = dict(rays=128, shadow_rays=16, levels=2, iterations=4)


def per_texel(rs, loops):
    """{object: (N, 3)} loop values (L, 3) interpolated over Blender's loop triangles at each
    texel's sub-samples and averaged (cycles_ref.gather_results' gvertex_total)."""
    tg = {t.name: t for t in rs.scene_in.targets}
    out = {}
    for n in rs.objects:
        at = rs.atlases[n]
        corner = tg[n].extract(loops, "CORNER").astype(np.float64)
        out[n] = at.texel_mean(np.einsum("sk,skc->sc", at.s_bary, corner[at.s_loops]))
    return out


def flat_per_face(rs, loops=None, texel=None, by_texel=False):
    """{object: (N, 3)} each face flat: at the mean of its corners' values (loops (L, 3)) or of
    the texel values texel {object: (N, 3)} over its sub-samples (by area), by_texel: over the
    texels whose centre lies on it, each once (as the per-object measure weights them)."""
    tg = {t.name: t for t in rs.scene_in.targets}
    out = {}
    for n in rs.objects:
        at = rs.atlases[n]
        P = at.n_poly
        if loops is not None:
            corner = tg[n].extract(loops, "CORNER").astype(np.float64)
            pl = np.unique(np.column_stack([np.repeat(at.s_poly, 3), at.s_loops.ravel()]), axis=0)
            cnt = np.bincount(pl[:, 0], minlength=P)
            face = np.stack([np.bincount(pl[:, 0], corner[pl[:, 1], c], P) for c in range(3)], 1)
        else:
            v = texel[n][at.s_texel]
            ok = np.isfinite(v).all(1) & (at.s_centre if by_texel else True)
            cnt = np.bincount(at.s_poly[ok], minlength=P)
            face = np.stack([np.bincount(at.s_poly[ok], v[ok, c], P) for c in range(3)], 1)
        face = face.astype(np.float64) / np.maximum(cnt, 1)[:, None]
        out[n] = at.texel_mean(face[at.s_poly])
    return out


def summary(vals, ref, mask, lit):
    """{part: object_summary} of per-texel values over the masked texels, lit objects."""
    per = {}
    for n in lit:
        m = C.metrics(vals[n], ref[n], mask[n])
        if m is not None:
            per[n] = m
    return {
        part: C.object_summary(per, [n for n in lit if keep(n)])
        for part, keep in (
            ("all", lambda n: True),
            ("books", lambda n: "_book" in n),
            ("others", lambda n: "_book" not in n),
        )
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default="", help="write benchmarks/out/books_vertex_NAME.json")
    ap.add_argument(
        "--save", default="", help="keep the per-texel values: benchmarks/out/books_vertex_NAME.npz"
    )
    ap.add_argument("set", nargs="*", help="module.CONSTANT=value (layouts, corner_fit)")
    args = ap.parse_args()
    for s in args.set:
        k, v = s.split("=", 1)
        mod, attr = k.split(".")
        setattr({"layouts": layouts, "corner_fit": corner_fit}[mod], attr, eval(v))
    cfg = CC.SCENES["furnished"]
    rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
    a, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
    b, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
    ref = {n: (a[n] + b[n]) / 2 for n in rs.objects}
    unb = unburied_texels(rs, 5e-5 * rs.diag)
    CL.GRAD_CONE = FL.GRAD_CONE = 0.03
    t0 = time.process_time()
    base = RadiositySystem(rs.scene_in.mesh, RefineParams.for_gather("draft"))
    dyn = DynamicRadiosity(base, method="FE", **DynamicRadiosity.gather_options("draft"))
    shapes = C.shape_proxies(rs, 1)
    dyn.apply(shapes)
    ours = C.Ours(rs, dyn.system, dyn)
    print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)
    cache = {}
    res, cost = C.gather_results(rs, ours, dyn, vertex=True, cache=cache, **GATHER)
    print("cost:", ", ".join(f"{k} {v:.4g}" for k, v in cost.items()), flush=True)
    lg = cache["loops"]
    v = lg.evaluate(dyn, "radiance")
    L = len(lg.loop_index)
    raw = np.zeros((L, 3))
    ok = lg.loop_index >= 0
    raw[ok] = np.where(lg.dark[lg.loop_index[ok]][:, None], 0.0, v[lg.loop_index[ok]])
    ev = ours.evaluate(shapes, smooth=False)
    emis = {n: ev[n]["emission"] for n in rs.objects}
    tex = {n: res[n]["gather_refl"] for n in rs.objects}
    outs = {
        "cycles": ref,
        "texture": tex,
        "vertex": {n: res[n]["gvertex_total"] - emis[n] for n in rs.objects},
        "raw": {n: x - emis[n] for n, x in per_texel(rs, raw).items()},
        "flat4": {n: x - emis[n] for n, x in flat_per_face(rs, loops=raw).items()},
        "flattex": {n: x - emis[n] for n, x in flat_per_face(rs, texel=tex).items()},
        "flattexel": {n: x - emis[n] for n, x in flat_per_face(rs, texel=tex, by_texel=True).items()},
    }
    mask = {n: unb[n] & np.isfinite(ref[n]).all(1) for n in rs.objects}
    pooled = np.mean(np.concatenate([ref[n][np.isfinite(ref[n]).all(1)] for n in rs.objects]))
    lit = [n for n in rs.objects if mask[n].any() and np.mean(ref[n][mask[n]]) > 0.05 * pooled]
    dump = {"set": args.set, "cost": cost, "summary": {}, "classes": {}}
    print(f"{len(lit)} lit objects ({sum('_book' in n for n in lit)} books), unburied texels")
    for k, vals in outs.items():
        if k == "cycles":
            continue
        s = dump["summary"][k] = summary(vals, ref, mask, lit)
        print(
            f"  {k:8s} within 5% "
            + " / ".join(f"{100 * s[p]['within_5']:.0f}" for p in s)
            + "%, median "
            + " / ".join(f"{100 * s[p]['median']:.1f}" for p in s)
            + "%, pooled bias "
            + " / ".join(f"{100 * s[p]['pooled_bias']:+.2f}" for p in s)
            + "% (all / books / others)",
            flush=True,
        )
    # per face class of the lit books: the class's share of Cycles' light and each output / Cycles
    box = BC.book_boxes(rs)
    books = [n for n in lit if n in box]
    cl = BD.classes(rs, books, box)
    grey = {k: {n: vals[n].mean(1) for n in books} for k, vals in outs.items()}
    total = sum(grey["cycles"][n][mask[n]].sum() for n in books)
    print(
        f"{len(books)} lit books per face class: share of Cycles' light, ours / Cycles - 1 (deficit points)"
    )
    for c, name in enumerate(BC.FACE):
        sel = {n: mask[n] & (cl[n][0] == c) for n in books}
        r = sum(grey["cycles"][n][sel[n]].sum() for n in books)
        if r <= 0:
            continue
        row = {"share": r / total, "texels": int(sum(sel[n].sum() for n in books))}
        for k in outs:
            if k == "cycles":
                continue
            o = sum(grey[k][n][sel[n]].sum() for n in books)
            row[k] = o / r - 1
            row[k + "_deficit"] = (o - r) / total
        dump["classes"][name] = row
        print(
            f"  {name:32s} {100 * row['share']:5.1f}% ({row['texels']} texels): "
            + ", ".join(
                f"{k} {100 * row[k]:+.1f}% ({100 * row[k + '_deficit']:+.2f})" for k in outs if k != "cycles"
            ),
            flush=True,
        )
    # the sides facing a neighbour book by the open strip above the neighbour, as a share of the
    # book's height (the corners' samples lie a quarter of the way in)
    print("lit books' sides by the strip above the neighbour (share of the height): ours / Cycles - 1")
    bands = (
        ("no neighbour", None),
        ("0 (taller)", (-1, 1e-9)),
        ("< 1/8", (1e-9, 1 / 8)),
        ("1/8 - 1/4", (1 / 8, 1 / 4)),
    )
    sums = {lab: {k: 0.0 for k in outs} | {"faces": 0} for lab, _ in bands + ((">= 1/4", (1 / 4, 2)),)}
    for n in books:
        x = BC.texel_centres(rs.atlases[n])
        lo, hi = box[n]
        for side in (0, 1):
            f = mask[n] & (np.abs(x[:, 0] - (hi[0] if side else lo[0])) < 1e-4)
            if not f.any():
                continue
            nb = BC.neighbour(box, n, side)
            strip = max(hi[2] - nb[1][2], 0) / (hi[2] - lo[2]) if nb is not None else None
            lab = (
                "no neighbour"
                if nb is None
                else next((b for b, r in bands[1:] if r[0] <= strip < r[1]), ">= 1/4")
            )
            sums[lab]["faces"] += 1
            for k in outs:
                sums[lab][k] += grey[k][n][f].sum()
    dump["sides"] = sums
    for lab, sm in sums.items():
        print(
            f"  {lab:13s} {sm['faces']:4d} faces, {100 * sm['cycles'] / total:4.1f}% of the light: "
            + ", ".join(f"{k} {100 * (sm[k] / sm['cycles'] - 1):+.1f}%" for k in outs if k != "cycles"),
            flush=True,
        )
    if args.save:
        np.savez_compressed(
            os.path.join(HERE, "out", f"books_vertex_{args.save}.npz"),
            **{f"{n}|{k}": vals[n].astype(np.float32) for k, vals in outs.items() for n in rs.objects},
            **{f"{n}|unburied": unb[n] for n in rs.objects},
        )
    if args.json:
        C.write_json(os.path.join(HERE, "out", f"books_vertex_{args.json}.json"), dump)


if __name__ == "__main__":
    main()
