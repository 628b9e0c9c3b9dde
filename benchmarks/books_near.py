"""Do the books' front texels miss light because nearby hits read a leaf's mean? (issue 19,
docs/gather.md "What is left is mostly outside the slots"). For the books' top texels and the
side texels above a shorter neighbour's top: their light against Cycles, with the indirect light
estimated so that rays whose hit is nearer than `near` metres read the value of the point they
hit (exact direct light there + its own gather, recursively to `depth` levels) and farther rays
their HR leaf's second-level value as the bake does. depth 0 is the bake's estimate (at the rays
of this script); each level more takes the leaves' means one bounce further from the texel.

    .venv/bin/python benchmarks/books_near.py [near=0.1] [rays=64] [inner=8] [depth=2]

Writes benchmarks/out/books_near.json."""

import os
import sys
import time

import numpy as np

import books_common as BC
from hr_testing import cycles_ref as C
from hr_addon.core.gather import FinalGather, _csr_matvec, cosine_directions, locate_below

opt = dict(near=0.1, rays=64, inner=8, depth=2)
opt.update({k: type(opt[k])(v) for k, v in (a.split("=") for a in sys.argv[1:])})
rs, (a, b), s, dyn, ours = BC.furnished()
books = [n for n in rs.objects if "_book" in n]
ref = {n: (a[n] + b[n]) / 2 for n in books}
X, P, AX, TR, REF, OBJ, CLS, ZREL = BC.book_texels(
    rs, s, ours, ref, books, BC.book_boxes(rs), 0.002, grey=False
)
keep = np.isin(CLS, (0, 8))
X, P, REF, OBJ, CLS = (v[keep] for v in (X, P, REF, OBJ, CLS))
pt, h = s.patches, s.h
ROW = BC.front_rows(X, OBJ)

g0 = FinalGather(dyn, X, pt.normal[P], P, **BC.BASE)
Y = g0.leaf_values(dyn)  # the second level's values the bake's rays read
n_hr = g0.n_hr


def values_at(x, nrm, patch, depth, R, seed):
    """Reflected radiance (n, 3) at points: exact direct light + R rays, those nearer than `near`
    reading the value at their hit (depth - 1 levels on), the others (and all at depth 0) Y at
    their HR leaf; covered hits 0, covered points 0, slot points their transfer (FinalGather)."""
    g = FinalGather(dyn, x, nrm, patch, rays=1, shadow_rays=16, seed=seed)
    D = g.direct_and_emission(dyn)[0]
    if depth == 0:
        Ind = _csr_matvec(*_rows(g, R, seed)[:3], Y)
    else:
        dirs = cosine_directions(g.normals, g.keys, R, seed, stream=0).reshape(-1, 3)
        row = np.repeat(np.arange(g.n), R)
        row = row[~g.dark[row]]
        dirs = dirs[~np.repeat(g.dark, R)]
        org = g.origins[row]
        prim, t = g.first_hit(org, dirs)
        hp = pt.triangle_patch[np.maximum(prim, 0)]
        ok = (prim >= 0) & (np.einsum("ij,ij->i", dirs, pt.normal[hp]) < 0)
        row, t, hp, hit = row[ok], t[ok], hp[ok], org[ok] + t[ok, None] * dirs[ok]
        leaf = locate_below(h, hp, hit, n_hr)
        val = np.where(h.dark(leaf, hit)[:, None], 0.0, Y[leaf])
        close = np.flatnonzero(t < opt["near"])
        val[close] = values_at(hit[close], pt.normal[hp[close]], hp[close], depth - 1, opt["inner"], seed + 1)
        Ind = np.stack([np.bincount(row, val[:, c], g.n) for c in range(3)], 1) / R
    inc = D + Ind
    inc[g.dark] = 0.0
    return g.rho * g.scaled(inc)


def _rows(g, R, seed):
    """g's CSR rows over the HR leaves with R rays a sample (the bake's estimator)."""
    g.rays, g.seed = R, seed
    return g.merge([g.gather_batch(a_, b_) for a_, b_ in g.batches(R)])


gr = lambda v: v.mean(-1)  # noqa: E731
report = {"options": opt, "levels": {}}
base = g0.evaluate(dyn, "reflected")
for depth in range(opt["depth"] + 1):
    t0 = time.process_time()
    v = values_at(X, pt.normal[P], P, depth, opt["rays"], 4242)
    print(f"depth {depth}: {time.process_time() - t0:.0f} s CPU", flush=True)
    rep = {}
    for c, lab, rows in BC.FRONT_GROUPS:
        m = (CLS == c) & np.isin(ROW, rows)
        rep[lab] = dict(
            texels=int(m.sum()),
            bake=gr(base[m]).sum() / gr(REF[m]).sum(),
            ours=gr(v[m]).sum() / gr(REF[m]).sum(),
        )
        print(
            f"  {lab:28s} {m.sum():5d} texels: ours / Cycles {rep[lab]['ours']:.3f} "
            f"(the bake's gather {rep[lab]['bake']:.3f})"
        )
    report["levels"][depth] = rep
C.write_json(os.path.join(BC.HERE, "out", "books_near.json"), report)
