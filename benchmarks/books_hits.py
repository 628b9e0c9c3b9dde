"""Which hits of the books' top and side-above texels read too dark (issue 19, docs/gather.md
"What is left is mostly outside the slots"): for the top texels and the side texels above a
shorter neighbour's top, the bake's gather (its direct D and indirect I) against Cycles' indirect
(Cycles' reflected radiance / rho - D), and a denser estimate this script makes itself: `rays`
hemisphere rays per texel, each reading the value of the point it hits (exact direct light there +
a gather over the second level's leaf values) instead of its HR leaf's second-level mean. The
indirect light is split by what the rays hit: the book's neighbours (top / side), the shelf's
boards, other books, the rest of the room, and hits on covered points.

    .venv/bin/python benchmarks/books_hits.py [rays=64] [hit_rays=32]

Writes benchmarks/out/books_hits.json."""

import os
import sys
import time

import numpy as np

import books_common as BC
from hr_testing import cycles_ref as C
from hr_addon.core.gather import FinalGather, _csr_matvec, cosine_directions

opt = dict(rays=64, hit_rays=32)
opt.update({k: int(v) for k, v in (a.split("=") for a in sys.argv[1:])})
rs, (a, b), s, dyn, ours = BC.furnished()
H = 0.002
books = [n for n in rs.objects if "_book" in n]
box = BC.book_boxes(rs)
ref = {n: (a[n] + b[n]) / 2 for n in books}
X, P, AX, TR, REF, OBJ, CLS, ZREL = BC.book_texels(rs, s, ours, ref, books, box, H, grey=False)
keep = np.isin(CLS, (0, 8))
X, P, REF, OBJ, CLS, ZREL = (v[keep] for v in (X, P, REF, OBJ, CLS, ZREL))
pt, h = s.patches, s.h
print(f"{len(X)} texels: {(CLS == 0).sum()} tops, {(CLS == 8).sum()} sides above", flush=True)

t0 = time.process_time()
g = FinalGather(dyn, X, pt.normal[P], P, **BC.BASE)
D = g.direct_and_emission(dyn)[0]
Ind = g.indirect(dyn)
Y = g.leaf_values(dyn)  # what a ray reads at an HR leaf: the second level's mean
rho = g.rho
Ic = REF / rho - D  # Cycles' indirect (its direct light is ours to 0.1%, docs/gather.md)
print(f"bake's gather: {time.process_time() - t0:.0f} s CPU", flush=True)

# the rays of this script: R per texel, their hits classified
R = opt["rays"]
dirs = cosine_directions(g.normals, g.keys, R, 12345, stream=0).reshape(-1, 3)
row = np.repeat(np.arange(g.n), R)
org = g.origins[row]
prim, t = g.first_hit(org, dirs)
ok = prim >= 0
hp = np.where(ok, pt.triangle_patch[np.maximum(prim, 0)], 0)
front = ok & (np.einsum("ij,ij->i", dirs, pt.normal[hp]) < 0)
i = np.flatnonzero(front)
hit = org[i] + t[i, None] * dirs[i]
hp = hp[i]
from hr_addon.core.gather import locate_below  # noqa: E402

leaf = locate_below(h, hp, hit, g.n_hr)
covered = h.dark(leaf, hit)
read = np.where(covered[:, None], 0.0, Y[leaf])  # what the bake's gather reads there

t0 = time.process_time()
gh = FinalGather(dyn, hit, pt.normal[hp], hp, rays=opt["hit_rays"], shadow_rays=16, seed=99)
inc = gh.direct_and_emission(dyn)[0] + _csr_matvec(gh.indptr, gh.leaf_columns(), gh.w, Y, rays=gh.row_rays)
inc[gh.dark] = 0.0
point = gh.rho * gh.scaled(inc)  # the value of the hit point itself
print(f"{len(hit)} hit points gathered: {time.process_time() - t0:.0f} s CPU", flush=True)

# what was hit: object of the hit patch against the texel's book
names = sorted(rs.poly_offset, key=rs.poly_offset.get)
first = np.array([rs.poly_offset[n] for n in names])
hobj = np.array(names, dtype=object)[np.searchsorted(first, pt.poly[hp], "right") - 1]
tb = np.array(books, dtype=object)[OBJ[row[i]]]
hn = pt.normal[hp]


def same_row(x, y):
    return x.rsplit("_", 1)[0] == y.rsplit("_", 1)[0]


def kind(k):
    o, bk = hobj[k], tb[k]
    if o == bk:
        return "own book"
    if "_book" in o:
        near = same_row(o, bk) and abs(int(o.rsplit("_", 1)[1]) - int(bk.rsplit("_", 1)[1])) == 1
        face = "top" if hn[k, 2] > 0.9 else ("side" if abs(hn[k, 0]) > 0.9 else "front/back/bottom")
        return f"{'neighbour' if near else 'other'} book, {face}"
    if o.startswith(bk.split("_")[0] + "_board"):
        return "shelf board, " + (
            "underside" if hn[k, 2] < -0.9 else "upper side" if hn[k, 2] > 0.9 else "edge"
        )
    if o.startswith(bk.split("_")[0] + "_side"):
        return "case side"
    return "room"


KIND = np.array([kind(k) for k in range(len(i))])
room = KIND == "room"
KIND[room] = np.char.add("room: ", np.array([o.split("_")[0] for o in hobj[room]], dtype=str))
ROW = BC.front_rows(X, OBJ)
cls_r = CLS[row[i]]
report = {"options": opt}
for c, lab, rows in BC.FRONT_GROUPS:
    m = (CLS == c) & np.isin(ROW, rows)
    gr = lambda v: v.mean(-1)  # noqa: E731
    I_leaf = np.bincount(row[i], gr(read), g.n) / R
    I_pt = np.bincount(row[i], gr(point), g.n) / R
    tot = gr(Ic[m]).sum()
    rep = dict(
        texels=int(m.sum()),
        cycles_reflected_over_ours=float(gr(REF[m]).sum() / gr(rho[m] * (D[m] + Ind[m])).sum()),
        direct_share_cycles=float(gr(D[m]).sum() / gr(REF[m] / rho[m]).sum()),
        indirect_bake_over_cycles=float(gr(Ind[m]).sum() / tot),
        indirect_these_rays_leaf_over_cycles=float(I_leaf[m].sum() / tot),
        indirect_these_rays_point_over_cycles=float(I_pt[m].sum() / tot),
        by_hit={},
    )
    print(f"\n{lab}: {m.sum()} texels; ours / Cycles reflected {1 / rep['cycles_reflected_over_ours']:.3f}")
    print(
        f"  indirect over Cycles': bake's gather {rep['indirect_bake_over_cycles']:.3f}, these rays "
        f"at leaf values {rep['indirect_these_rays_leaf_over_cycles']:.3f}, at the hit points "
        f"{rep['indirect_these_rays_point_over_cycles']:.3f}; "
        f"direct is {rep['direct_share_cycles']:.2f} of Cycles' incident"
    )
    sel = m[row[i]]
    print(f"  {'hit':34s} rays  leaf read  point    (point - leaf) / Cycles' indirect   covered")
    for k in sorted(set(KIND[sel])):
        q = sel & (KIND == k)
        lr, pv = gr(read[q]).sum() / R, gr(point[q]).sum() / R
        rep["by_hit"][k] = dict(
            rays=int(q.sum()),
            leaf=float(lr / tot),
            point=float(pv / tot),
            covered=float(covered[q].mean()),
        )
        print(
            f"  {k:34s} {q.sum() / m.sum() / R:5.3f} {lr / tot:8.4f} {pv / tot:8.4f}  {(pv - lr) / tot:+8.4f}"
            f"     {covered[q].mean():.2f}"
        )
    report[lab] = rep
C.write_json(os.path.join(BC.HERE, "out", "books_hits.json"), report)
