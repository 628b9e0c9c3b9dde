"""Where the furnished sample's books keep their light, texel by texel, in Cycles and in the final
gather (issue 19, docs/gather.md "Narrow gaps"): every book texel classed by the face it lies on
(the top, the front facing the room, the back, a side) and, on the sides, by whether its centre
lies in the slot the neighbour book (or the case's side) covers, and how deep: the distance to
the slot's open front, open top, open back, and to the board it stands on, in gap widths h.
Needs the cached furnished reference of cycles_compare.py.

    .venv/bin/python benchmarks/books_texels.py [variant ...]

A variant is name=dict(texel_gather keywords) (default: main's bake setting, two levels + 4
iterations, 128 rays, 16 shadow rays); each gathers at the books' texels only, on one draft FE
solution. Writes benchmarks/out/books_texels.npz (per texel: class, depths, Cycles, each variant) and
books_texels.json (the table: each class's share of the books' light in Cycles and ours).
"""

import os
import sys
import time

import numpy as np

import books_common as BC
from hr_testing import cycles_ref as C
from hr_addon.core.gather import texel_gather

BASE = BC.BASE
variants = BC.variants(sys.argv[1:])
rs, (a, b), s, dyn, ours = BC.furnished()
con = s.h.contacts
H = 0.002  # the books' gap

books = [n for n in rs.objects if "_book" in n]
box = BC.book_boxes(rs)


def neighbour(n, side):
    return BC.neighbour(box, n, side)


rows = []
for n in books:
    at = rs.atlases[n]
    cen = np.flatnonzero(at.s_centre)
    x = at.s_point[cen]
    patch = ours.samples[n][0][cen]
    nrm = s.patches.normal[patch]
    lo, hi = box[n]
    ref = ((a[n] + b[n]) / 2)[at.s_texel[cen]]
    rho = s.patches.reflectance[:, patch].T
    cls = np.full(len(cen), -1)
    ax = np.abs(nrm).argmax(1)
    sg = np.sign(nrm[np.arange(len(nrm)), ax])
    cls[(ax == 2) & (sg > 0)] = 0  # top
    cls[(ax == 1) & (sg < 0)] = 1  # front (room side: y decreasing)
    cls[(ax == 1) & (sg > 0)] = 2  # back
    cls[ax == 0] = 3  # side
    cls[(ax == 2) & (sg < 0)] = 4  # bottom (on the board)
    dep = np.full((len(cen), 4), np.inf)  # front, top, back, bottom, in units of H, inside the overlap
    inside = np.zeros(len(cen), bool)
    for side in (0, 1):
        sel = np.flatnonzero((ax == 0) & ((sg > 0) == bool(side)))
        nb = neighbour(n, side)
        if nb is None or not len(sel):
            continue
        olo, ohi = np.maximum(lo, nb[0]), np.minimum(hi, nb[1])
        p = x[sel]
        ins = (p[:, 1] > olo[1]) & (p[:, 1] < ohi[1]) & (p[:, 2] > olo[2]) & (p[:, 2] < ohi[2])
        inside[sel] = ins
        dep[sel, 0] = (p[:, 1] - olo[1]) / H
        dep[sel, 1] = (ohi[2] - p[:, 2]) / H
        dep[sel, 2] = (ohi[1] - p[:, 1]) / H
        dep[sel, 3] = (p[:, 2] - olo[2]) / H
    cov0 = con.covered(x, patch)
    rows.append(
        dict(
            obj=np.full(len(cen), books.index(n)),
            cls=cls,
            inside=inside,
            dep=dep,
            cov=cov0,
            ref=ref,
            rho=rho,
            x=x,
            patch=patch,
            axes=at.s_axes[cen],
            tris=at.s_tri[cen],
        )
    )
D = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
print(f"{len(books)} books, {len(D['cls'])} texels", flush=True)

out = {k: D[k] for k in ("obj", "cls", "inside", "dep", "cov", "ref", "rho")}
for name, kw in variants.items():
    t0 = time.process_time()
    g = texel_gather(dyn, D["patch"], D["x"], axes=D["axes"], tris=D["tris"], **{**BASE, **kw})
    v = g.evaluate(dyn, "reflected")
    out[name] = v
    print(f"variant {name} {kw}: {g.n} samples, {time.process_time() - t0:.0f} s CPU", flush=True)


table = {}


def report(name):
    ref, v = D["ref"].mean(1), out[name].mean(1)
    ok = np.isfinite(ref)
    tot_r, tot_o = ref[ok].sum(), v[ok].sum()
    gap = 100 * (tot_o / tot_r - 1)
    print(f"\n[{name}] books (texel sums, grey): Cycles {tot_r:.2f}, ours {tot_o:.2f} ({gap:+.1f}%)")
    cls, ins = D["cls"], D["inside"]
    dmin = D["dep"].min(1)
    which = D["dep"].argmin(1)
    groups = [
        ("top", cls == 0),
        ("front", cls == 1),
        ("back", cls == 2),
        ("bottom", cls == 4),
        ("side, exposed", (cls == 3) & ~ins),
    ]
    edges = ["front", "top", "back", "bottom"]
    for lo_, hi_ in ((0, 5), (5, 10), (10, 20), (20, 50), (50, 1e9)):
        for e in range(4):
            groups.append(
                (
                    f"side in slot, nearest edge {edges[e]}, {lo_:g}-{hi_:g} h",
                    (cls == 3) & ins & (which == e) & (dmin >= lo_) & (dmin < hi_),
                )
            )
    print(f"{'class':48s} texels  Cycles share  ours share  ours/Cycles  covered(centre)")
    for lab, m in groups:
        m = m & ok
        if not m.any():
            continue
        r, o = ref[m].sum(), v[m].sum()
        table.setdefault(name, {})[lab] = {"texels": int(m.sum()), "cycles": r / tot_r, "ours": o / tot_r}
        print(
            f"{lab:48s} {m.sum():6d}  {100 * r / tot_r:6.2f}%     {100 * o / tot_r:6.2f}%    "
            f"{o / max(r, 1e-30):6.3f}      {D['cov'][m].mean():.2f}"
        )


for name in variants:
    report(name)
np.savez(os.path.join(BC.HERE, "out", "books_texels.npz"), **out)  # per texel (not kept in git)
# the shares of the books' light in Cycles and ours, per class (JSON, kept)
C.write_json(os.path.join(BC.HERE, "out", "books_texels.json"), {"variants": variants, "classes": table})
