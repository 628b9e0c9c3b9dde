"""Where the books of the daylight room (issue 20) or of the furnished sample under its ceiling
panel (issue 19) lose light against Cycles, by face (books_common.FACE) and, on the sides facing a
neighbour book, by the height over the overlap's top in gap widths (docs/gather.md, "The books lit
from above and from the side"). Reads our per-texel values from a saved run (furnished_lights.py's
benchmarks/out/furnished_lights_NAME_ours.npz, or furnished_vs_cycles.py's --save npz) and the
cached Cycles references (two seeds); runs nothing of ours.

    .venv/bin/python benchmarks/books_daylight.py [--room daylight|panel] [--ours PATH]
        [--var gather_refl] [--ours2 PATH]

Per class: the class's share of the lit books' light in Cycles, ours / Cycles, and the class's part
of the books' deficit (points of all the lit books' light); the same over the books the run finds
below -5% (the failing ones, points of their own light); the slot and side-above classes by height
band; D/C: our direct light (the daylight run's sun and sky) over Cycles' light. --ours2: a second
run's values beside the first (a variant).
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import books_common as BC  # noqa: E402
import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402

H = 0.002  # the books' gap
BANDS = ((-np.inf, 0), (0, 2), (2, 5), (5, 10), (10, 20), (20, 50), (50, np.inf))


def classes(rs, books, box):
    """{book: (class (N,), height over the overlap's top in gap widths (N,))} per texel, from the
    texel's centre sample: the face of the book's box it lies on, as books_common.book_texels."""
    out = {}
    for n in books:
        x = BC.texel_centres(rs.atlases[n])
        lo, hi = box[n]
        d = np.stack(
            [
                x[:, 0] - lo[0],
                hi[0] - x[:, 0],
                x[:, 1] - lo[1],
                hi[1] - x[:, 1],
                x[:, 2] - lo[2],
                hi[2] - x[:, 2],
            ],
            1,
        )
        face = np.nanargmin(np.abs(np.where(np.isfinite(d), d, np.inf)), 1)  # -x +x -y(front) +y -z +z
        cls = np.select([face == 5, face == 2, face == 3, face == 4], [0, 1, 2, 3], 4)
        z = np.full(len(x), np.nan)
        for side in (0, 1):
            sel = np.flatnonzero(face == side)
            nb = BC.neighbour(box, n, side)
            if nb is None or not len(sel):
                continue
            p = x[sel]
            top = min(hi[2], nb[1][2])
            iny = (p[:, 1] > max(lo[1], nb[0][1])) & (p[:, 1] < min(hi[1], nb[1][1]))
            dz = hi[2] - nb[1][2]
            c = np.where(dz < -1e-4, 5, np.where(dz > 1e-4, 6, 7))
            cls[sel] = np.where(iny, np.where(p[:, 2] < top, c, 8), 9)
            z[sel] = (p[:, 2] - top) / H
        out[n] = (cls, z)
    return out


def load_ours(path, var):
    z = np.load(path)
    return {k.split("|")[0]: z[k].astype(np.float64) for k in z.files if k.endswith("|" + var)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--room", default="daylight", choices=("daylight", "panel"))
    ap.add_argument("--ours", default=os.path.join(HERE, "out", "furnished_lights_s14main_ours.npz"))
    ap.add_argument("--ours2", default="")
    ap.add_argument("--var", default="gather_refl")
    ap.add_argument(
        "--portal",
        action="store_true",
        help="the portal reference's three seeds (the default before: two plain World seeds)",
    )
    args = ap.parse_args()
    if args.room == "daylight":
        import furnished_lights as FL
        from hr_testing import cycles_lights as CL

        scene, info = CL.daylight_scene("20k", args.portal)
        rs = C.prepare(scene, texel_rel=FL.TEXEL_REL)
        key = FL.ref_key("20k", args.portal)
        refs = [FL.reference(rs, key, 128, s, False)[0] for s in ((1, 2, 3) if args.portal else (1, 2))]
    else:
        cfg = CC.SCENES["furnished"]
        rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
        refs = [CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], s)[0] for s in CC.REF_SEEDS[:2]]
    ref3 = {n: sum(r[n] for r in refs) / len(refs) for n in rs.objects}
    ref = {n: v.mean(1) for n, v in ref3.items()}
    runs = [load_ours(args.ours, args.var)] + ([load_ours(args.ours2, args.var)] if args.ours2 else [])
    # our direct light (the daylight run's lights), for its share of each class
    dl = [load_ours(args.ours, v) for v in ("direct_SUN", "direct_SKY")]
    direct = {n: sum(d[n] for d in dl).mean(1) for n in dl[0]} if all(dl) else None
    box = BC.book_boxes(rs)
    pooled = np.nanmean(np.concatenate([ref[n] for n in rs.objects]))
    books = [n for n in box if n in ref and np.isfinite(ref[n]).any() and np.nanmean(ref[n]) > 0.05 * pooled]
    cl = classes(rs, books, box)
    err = {n: np.nanmean(runs[0][n].mean(1)) / np.nanmean(ref[n]) - 1 for n in books}
    fail = [n for n in books if err[n] < -0.05]
    print(f"{len(books)} lit books, {len(fail)} below -5% (run 1)")

    def rows(names, per_book):
        R = np.concatenate([ref[n] for n in names])
        OS = [np.concatenate([run[n].mean(1) for n in names]) for run in runs]
        Dd = np.concatenate([direct[n] for n in names]) if direct else np.full(len(R), np.nan)
        K = np.concatenate([cl[n][0] for n in names])
        Z = np.concatenate([cl[n][1] for n in names])
        ok = np.isfinite(R) & np.all([np.isfinite(o) for o in OS], 0)
        # per-book weights: each book's texels weigh 1 / its light (points of its own light)
        w = np.ones(len(R))
        if per_book:
            w = np.concatenate([np.full(len(ref[n]), 1 / np.nansum(ref[n]) / len(names)) for n in names])
        tot = np.sum(w[ok] * R[ok])
        out = []
        for c, name in enumerate(BC.FACE):
            s = ok & (K == c)
            if not s.any():
                continue
            bands = [("", s)]
            if c in (5, 6, 7, 8):
                D = Z if c == 8 else -Z  # the height above the overlap's top, or the depth below it
                bands += [
                    (f"  {lo:g}..{hi:g} h", s & (D >= lo) & (D < hi))
                    for lo, hi in BANDS
                    if (s & (D >= lo) & (D < hi)).any()
                ]
            for lab, m in bands:
                rc = np.sum(w[m] * R[m])
                out.append(
                    (
                        lab or name,
                        int(m.sum()),
                        rc / tot,
                        [np.sum(w[m] * o[m]) / rc for o in OS],
                        [100 * np.sum(w[m] * (o[m] - R[m])) / tot for o in OS],
                        np.sum(w[m] * Dd[m]) / rc,
                    )
                )
        return out

    for title, names, pb in (
        ("all lit books (share of their light)", books, False),
        ("failing books (mean over books of points of the book's own light)", fail, True),
    ):
        print(f"\n{title}")
        print(
            f"{'class':38s} {'texels':>7s} {'share':>6s} {'D/C':>6s} "
            + " ".join(f"{'ours/C r' + str(i + 1):>10s} {'pts':>6s}" for i in range(len(runs)))
        )
        for lab, k, sh, rat, pts, dc in rows(names, pb):
            print(
                f"{lab:38s} {k:7d} {100 * sh:5.1f}% {dc:6.3f} "
                + " ".join(f"{r:10.3f} {p:+6.2f}" for r, p in zip(rat, pts))
            )

    # what-if: the per-book error (cycles_ref.metrics' mre, RGB) with one class's texels set to
    # Cycles' (that class exact), over the lit books: median, share within 5%
    print("\nwhat if a class were exact (run 1): lit books' median error, within 5%")
    groups = [
        ("none", ()),
        ("tops", (0,)),
        ("slots (5, 6, 7)", (5, 6, 7)),
        ("sides above (8)", (8,)),
        ("tops + sides above", (0, 8)),
        ("all but fronts, backs", (0, 4, 5, 6, 7, 8, 9)),
    ]

    # and with the class only scaled so that its pooled light is Cycles' (a uniform gain: what a
    # fix of the class's bias alone would give, its per-book scatter left)
    def pooled_gain(cs):
        m = [
            np.isin(cl[n][0], cs) & np.isfinite(ref3[n]).all(1) & np.isfinite(runs[0][n]).all(1)
            for n in books
        ]
        return sum(ref3[n][k].sum(0) for n, k in zip(books, m)) / sum(
            runs[0][n][k].sum(0) for n, k in zip(books, m)
        )

    groups += [
        (f"{lab} scaled x{np.mean(pooled_gain(cs)):.3f}", cs, pooled_gain(cs)) for lab, cs in groups[1:5]
    ]
    for lab, cs, *gain in groups:
        e = []
        for n in books:
            o = runs[0][n].copy()
            m = np.isin(cl[n][0], cs)
            o[m] = o[m] * gain[0] if gain else ref3[n][m]
            mm = C.metrics(o, ref3[n])
            e.append(mm["mre"])
        e = np.array(e)
        print(f"   {lab:24s} median {100 * np.median(e):.1f}%, within 5% {100 * np.mean(e < 0.05):.0f}%")


if __name__ == "__main__":
    main()
