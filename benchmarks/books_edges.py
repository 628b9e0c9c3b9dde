"""Where the furnished sample's books miss light against Cycles, by face and by the neighbours'
heights (issue 19, docs/gather.md "Narrow gaps"): each book's error split over its faces (top,
front, back, sides: the side below the overlap's top, in the slot, with the receiver shorter or
taller than the neighbour it faces, and the taller side's part above the neighbour's top), and for
the slot texels what `Contacts.slots` gives them (depth to the nearest mouth in gap widths against
the depth below the overlap's top). Needs the cached furnished reference of cycles_compare.py.

    .venv/bin/python benchmarks/books_edges.py [variant ...]

A variant is name=dict(texel_gather keywords) (default: main's bake setting); each gathers at the
books' texels only, on one draft FE solution. Writes benchmarks/out/books_edges.json.
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
con.close_mouths(s.backend.occluded)
H = 0.002  # the books' gap

books = [n for n in rs.objects if "_book" in n]
box = BC.book_boxes(rs)
ref = {n: (a[n] + b[n]) / 2 for n in books}

FACE = BC.FACE
X, P, AX, TR, REF, OBJ, CLS, ZREL = BC.book_texels(rs, s, ours, ref, books, box, H)
depth, hg = con.slots(X, P)[:2]
cov = con.covered(X, P)
print(f"{len(books)} books, {len(X)} texels", flush=True)

report = {}
for name, kw in variants.items():
    t0 = time.process_time()
    g = texel_gather(dyn, P, X, axes=AX, tris=TR, **{**BASE, **kw})
    v = g.evaluate(dyn, "reflected").mean(1)
    print(f"variant {name} {kw}: {g.n} samples, {time.process_time() - t0:.0f} s CPU", flush=True)
    tot = np.bincount(OBJ, REF, len(books))
    err = np.bincount(OBJ, v - REF, len(books)) / tot
    rep = {"faces": {}, "slot_by_depth": {}, "above_by_height": {}}
    # each face's part of the books' error: (ours - Cycles) summed over the face / Cycles' total
    dark = err < -0.05
    print(f"  books' light {100 * (v.sum() / REF.sum() - 1):+.1f}%; {dark.sum()} books below -5%, by face:")
    print(f"  {'face':38s} texels  Cycles share  ours/Cycles  error share (all) (books < -5%)")
    for f, lab in enumerate(FACE):
        m = CLS == f
        if not m.any():
            continue
        md = m & dark[OBJ]
        r = dict(
            texels=int(m.sum()),
            cycles=REF[m].sum() / REF.sum(),
            ratio=v[m].sum() / REF[m].sum(),
            err_all=(v[m] - REF[m]).sum() / REF.sum(),
            err_dark=(v[md] - REF[md]).sum() / REF[dark[OBJ]].sum(),
        )
        rep["faces"][lab] = r
        print(
            f"  {lab:38s} {m.sum():6d}  {100 * r['cycles']:6.2f}%      {r['ratio']:6.3f}     "
            f"{100 * r['err_all']:+6.2f}%   {100 * r['err_dark']:+6.2f}%"
        )
    for f in (5, 6, 7):
        for lo_, hi_ in ((0, 5), (5, 10), (10, 20), (20, 50), (50, 1e9)):
            m = (CLS == f) & (-ZREL >= lo_) & (-ZREL < hi_)
            if not m.any():
                continue
            x_ = depth[m] / np.maximum(hg[m], 1e-9)
            lab = f"{FACE[f]}, {lo_:g}-{hi_:g} h below the top"
            rep["slot_by_depth"][lab] = dict(
                texels=int(m.sum()),
                ratio=v[m].sum() / REF[m].sum(),
                covered=float(cov[m].mean()),
                in_slot=float((hg[m] > 0).mean()),
                mouth_depth_median=float(np.median(x_)),
            )
            print(
                f"  {lab:60s} {m.sum():5d} ours/Cycles {v[m].sum() / REF[m].sum():6.3f}, covered "
                f"{cov[m].mean():.2f}, in a slot {(hg[m] > 0).mean():.2f}, nearest mouth median "
                f"{np.median(x_):.1f} h"
            )
    for lo_, hi_ in ((0, 5), (5, 10), (10, 20), (20, 50), (50, 1e9)):
        m = (CLS == 8) & (ZREL >= lo_) & (ZREL < hi_)
        if m.any():
            lab = f"{lo_:g}-{hi_:g} h above"
            rep["above_by_height"][lab] = dict(texels=int(m.sum()), ratio=v[m].sum() / REF[m].sum())
            print(
                f"  side above the neighbour's top, {lab:16s} {m.sum():5d} ours/Cycles "
                f"{v[m].sum() / REF[m].sum():6.3f}"
            )
    rep["books"] = {n: float(err[k]) for k, n in enumerate(books)}
    report[name] = rep
    np.savez(
        os.path.join(BC.HERE, "out", f"books_edges_{name}.npz"),
        v=v,
        ref=REF,
        obj=OBJ,
        cls=CLS,
        zrel=ZREL,
        depth=depth,
        hg=hg,
        cov=cov,
    )
C.write_json(os.path.join(BC.HERE, "out", "books_edges.json"), {"variants": variants, "report": report})
