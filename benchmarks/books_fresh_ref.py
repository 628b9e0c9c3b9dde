"""Does a fresh Cycles bake of the furnished sample's books alone reproduce the cached reference
(cycles_compare's furnished_f1_s128_seed{1,2}, all objects baked) on the books' sides above a
shorter neighbour? Prints ours (a saved furnished_vs_cycles run's per-texel values) over the fresh
bake and over the cached one, and fresh over cached, by face side (docs/gather.md, "The books' -x
faces read 4% darker"). Written by branch asym (32 spp), run by the lead at 128 spp.

    .venv/bin/python benchmarks/books_fresh_ref.py SPP [OURS_NPZ]
"""

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
from hr_testing import cycles_ref as C  # noqa: E402

OUT = os.path.join(HERE, "out")


def main():
    spp = int(sys.argv[1])
    ours = sys.argv[2] if len(sys.argv) > 2 else os.path.join(OUT, "furnished_vs_cycles_books4_main_ours.npz")
    sc = CC.open_scene("furnished")
    names = [o.name for o in sc.objects if "_book" in o.name]
    rs = C.prepare(sc, texel_rel=1 / 150, only=names)
    t0 = time.process_time()
    ref, _, mask = C.bake(rs, spp, 1)
    print("bake cpu", time.process_time() - t0, flush=True)
    np.savez(
        os.path.join(OUT, f"books_fresh_ref_s{spp}.npz"),
        **{n: np.where(mask[n][:, None], ref[n], np.nan) for n in rs.objects},
    )
    saved = BD.load_ours(ours, "gather_refl")
    cz = [
        np.load(os.path.join(OUT, "cycles_cache", f"furnished_f1_s128_seed{k}_302a91bef6.npz"))
        for k in (1, 2)
    ]
    box = BC.book_boxes(rs)
    acc = np.zeros((2, 4))  # per side: ours, fresh, cached sums, texels
    for n in box:
        x = BC.texel_centres(rs.atlases[n])
        f = np.where(mask[n], ref[n].mean(1), np.nan)
        sv = saved[n].mean(1)
        r = (cz[0][n].astype(float) + cz[1][n].astype(float)).mean(1) / 2
        for side in (0, 1):
            nb = BC.neighbour(box, n, side)
            if nb is None:
                continue
            m = BC.side_above(x, *box[n], side, nb) & np.isfinite(f) & np.isfinite(r) & np.isfinite(sv)
            acc[side] += (sv[m].sum(), f[m].sum(), r[m].sum(), m.sum())
    for sd in (0, 1):
        a = acc[sd]
        side = "-+"[sd]
        print(f"{side}x: n {int(a[3])} ours/fresh C {a[0] / a[1]:.3f}", end="")
        print(f"  ours/cached C {a[0] / a[2]:.3f}", end="")
        print(f"  fresh/cached C {a[1] / a[2]:.3f}")


if __name__ == "__main__":
    main()
