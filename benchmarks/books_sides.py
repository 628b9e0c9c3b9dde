"""The bookcases' side boards against Cycles, texel by texel (docs/gather.md "Narrow gaps"): each
case's side0 faces its rows' first books 1 cm away (a slot of h = 1 cm). Every side texel is
classed by the face it lies on (inner: facing the books, outer, front, top, back) and, on the
inner face, by whether its centre is in a slot; the slot samples' gathered light is split into
the rays that leave the slot through one of its mouths and those that hit a surface inside it
before (the board strip between side and book, the slot's closed bottom), by tracing the
gather's own rays again. Needs the cached furnished reference of cycles_compare.py.

    .venv/bin/python benchmarks/books_sides.py [variant ...]

A variant is name=dict(texel_gather keywords) (default: main's bake setting, two levels + 4
iterations, 128 rays, 16 shadow rays), gathered at the side boards' texels only, on one draft FE
solution. Besides the gather's own output it prints two alternatives computed from the same
samples: "mouth-only" (the slot samples read only the rays that leave through a mouth, over the
mouths' first-bounce view factor at their gather point in 3D) and "first bounce only" (the slot's
transfer without the bounces between its walls), per object and for the slot texels by the mouth
nearest their centre. Writes benchmarks/out/books_sides.json (the per-object figures).
"""

import os
import sys
import time

import numpy as np

import books_common as BC
from hr_testing import cycles_ref as C
from hr_addon.core.boxes import csr_rows
from hr_addon.core.slots import slot_mouth
from hr_addon.core.gather import texel_gather
from hr_addon.core.gather.final import _csr_matvec
from hr_addon.core.gather.layouts import texel_samples
from hr_addon.core.gather.points import locate_below
from hr_addon.core.gather.sampling import cosine_directions

BASE = BC.BASE
variants = BC.variants(sys.argv[1:])
rs, (a, b), s, dyn, ours = BC.furnished()
con = s.h.contacts
pt = s.patches

objs = sorted(n for n in rs.objects if "_side" in n)
X, P, AX, TR, REF, OBJ, CLS = [], [], [], [], [], [], []
FACES = ("inner", "outer", "front", "top", "back", "bottom")
for k, n in enumerate(objs):
    at = rs.atlases[n]
    cen = np.flatnonzero(at.s_centre)
    patch = ours.samples[n][0][cen]
    nrm = pt.normal[patch]
    inward = 1.0 if n.endswith("side0") else -1.0  # side0 faces +x (the books), side1 -x
    cls = np.full(len(cen), 5)
    cls[nrm[:, 0] * inward > 0.5] = 0
    cls[nrm[:, 0] * inward < -0.5] = 1
    cls[nrm[:, 1] < -0.5] = 2
    cls[nrm[:, 2] > 0.5] = 3
    cls[nrm[:, 1] > 0.5] = 4
    X.append(at.s_point[cen])
    P.append(patch)
    AX.append(at.s_axes[cen])
    TR.append(at.s_tri[cen])
    REF.append(((a[n] + b[n]) / 2)[at.s_texel[cen]].mean(1))
    OBJ.append(np.full(len(cen), k))
    CLS.append(cls)
X, P, AX, TR, REF, OBJ, CLS = (np.concatenate(v) for v in (X, P, AX, TR, REF, OBJ, CLS))
in_slot = np.zeros(len(X), bool)
cv = np.flatnonzero(con.covered(X, P))
con.close_mouths(s.backend.occluded)
in_slot[cv] = con.slots(X[cv], P[cv])[1] > 0
print(f"{len(objs)} side boards, {len(X)} texels, {in_slot.sum()} with their centre in a slot", flush=True)


def split_slot_rays(g, pts0):
    """For the slot samples of gather g (gain != 1), their gathered indirect light I split into
    (through a mouth, inside the slot) by tracing g's own rays again; pts0: the samples before the
    slot samples moved to their gather points. Returns (rows, I_mouth (r, 3), I_in (r, 3), E0 (r,):
    the mouths' first-bounce view factor at the gather point over all the chain's mouths, x_q/h)."""
    rows = np.flatnonzero(~g.dark & (np.abs(g.gain - 1).max(1) > 0))
    chain = con.slots(pts0[rows], g.patch[rows])[3]
    q = g.points[rows]
    xq, hq = con.slots(q, g.patch[rows])[:2]
    V = g.leaf_values(dyn)
    Im, Ii = np.zeros((len(rows), 3)), np.zeros((len(rows), 3))
    R = np.full(len(rows), g.rays) if g.sample_rays is None else g.sample_rays[rows]
    for r in np.unique(R):
        sel = np.flatnonzero(R == r)
        j = rows[sel]
        d = cosine_directions(g.normals[j], g.keys[j], int(r), g.seed, stream=0).reshape(-1, 3)
        org = np.repeat(g.origins[j], r, 0)
        prim, t = g.first_hit(org, d)
        ok = prim >= 0
        patch = np.where(ok, pt.triangle_patch[np.maximum(prim, 0)], 0)
        ok &= np.einsum("ij,ij->i", d, pt.normal[patch]) < 0
        val = np.zeros((len(d), 3))
        i = np.flatnonzero(ok)
        hit = org[i] + t[i, None] * d[i]
        leaf = locate_below(s.h, patch[i], hit, g.n_hr)
        lit = ~s.h.dark(leaf, hit)
        val[i[lit]] = V[leaf[lit]]
        # through a mouth: the ray's path, projected on the sample's plane, crosses one of the
        # chain's mouths before its hit (misses leave the slot)
        far = np.where(prim >= 0, t, 10.0)
        end = org + far[:, None] * d
        gi = con.plane[np.repeat(g.patch[j], r)]
        a2 = con._to2d(gi, org[:, None])[:, 0]
        b2 = con._to2d(gi, end[:, None])[:, 0]
        ch = np.repeat(chain[sel], r)
        M = con.slot_mouths()
        pr, sg = csr_rows(M["start"], ch)
        m = M["open"][sg]
        pr, sg = pr[m], sg[m]
        p, e = a2[pr], b2[pr] - a2[pr]
        c, f = M["a"][sg], M["b"][sg] - M["a"][sg]
        den = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
        w = c - p
        tt = (w[:, 0] * f[:, 1] - w[:, 1] * f[:, 0]) / np.where(den == 0, 1, den)
        uu = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / np.where(den == 0, 1, den)
        cross = (den != 0) & (tt >= 0) & (tt <= 1) & (uu >= 0) & (uu <= 1)
        out = (np.bincount(pr, cross, len(ch)) > 0) | (prim < 0)
        for cc in range(3):
            Im[sel, cc] = np.bincount(np.repeat(np.arange(len(j)), r), val[:, cc] * out, len(j)) / r
            Ii[sel, cc] = np.bincount(np.repeat(np.arange(len(j)), r), val[:, cc] * ~out, len(j)) / r
    z = np.zeros((len(rows), 3))
    E0 = con.slot_transfer(q, g.patch[rows], chain, z, np.zeros_like(pt.reflectance))[:, 0]
    return rows, Im, Ii, E0, slot_mouth(xq / np.maximum(hq, 1e-300))


report = {}
for name, kw in variants.items():
    t0 = time.process_time()
    kw = {**BASE, **kw}
    g = texel_gather(dyn, P, X, axes=AX, tris=TR, **kw)
    pts0 = texel_samples(dyn, P, X, AX, 4, kw.get("seed", 0), kw.get("open_edge", 5.0), TR)[0]
    v = g.evaluate(dyn, "reflected").mean(1)
    print(f"variant {name} {kw}: {g.n} samples, {time.process_time() - t0:.0f} s CPU", flush=True)
    # sample level: direct, indirect, the slot samples' split
    D = g.direct_and_emission(dyn)[0]
    Ind = _csr_matvec(g.indptr, g.leaf_columns(), g.w, g.leaf_values(dyn), rays=g.row_rays)
    rows, Im, Ii, E0, F2 = split_slot_rays(g, pts0)
    inc = (D + Ind) * (g.gain if g.gain is not None else 1.0)
    inc[g.dark] = 0
    # the alternative: only the light through the mouths, over their first-bounce view factor at the
    # gather point in 3D (E0) instead of the endless mouth's (F2)
    alt = inc.copy()
    alt[rows] = (D[rows] + Im) * g.gain[rows] * (F2 / np.maximum(E0, 1e-12))[:, None]
    alt_out = g.outputs(g.rho * alt).mean(1)
    # the first bounce only: the slot's transfer without the bounces between its walls
    ch0 = con.slots(pts0[rows], g.patch[rows])[3]
    E = con.slot_transfer(pts0[rows], g.patch[rows], ch0, g.rho[rows], pt.reflectance)
    z = np.zeros((len(rows), 3))
    E1 = con.slot_transfer(pts0[rows], g.patch[rows], ch0, z, np.zeros_like(pt.reflectance))
    fb = inc.copy()
    fb[rows] *= E1 / np.maximum(E, 1e-30)
    fb_out = g.outputs(g.rho * fb).mean(1)
    # the slot texels by the mouth nearest their centre (the side boards stand along x: front -y,
    # back +y, top +z)
    foot = con.slots(X, P)[2]
    dv = foot - X
    near = np.where(np.abs(dv[:, 2]) > np.abs(dv[:, 1]), 1, np.where(dv[:, 1] < 0, 0, 2))
    # the retraced rays are the gather's own: their sum is its indirect light at those samples
    print(
        f"  retraced / gathered indirect, slot samples: {(Im + Ii).sum() / max(Ind[rows].sum(), 1e-30):.4f}"
    )
    share_in = (Ii.sum() / max((D[rows] + Im + Ii).sum(), 1e-30)) if len(rows) else 0.0
    print(
        f"  {len(rows)} slot samples; of their gathered light (D + I) {100 * share_in:.1f}% hits inside "
        f"the slot; E0 / endless mouth at their gather points: median {np.median(E0 / F2):.2f}, "
        f"10-90% {np.percentile(E0 / F2, 10):.2f}-{np.percentile(E0 / F2, 90):.2f}",
        flush=True,
    )
    slot_out = np.bincount(g.group, np.isin(np.arange(g.n), rows), g.n_out) > 0
    print(f"  {'object':14s} {'Cycles':>8s} {'ours':>7s} {'mouth-only':>10s} | slot texels")
    rep = {}
    for k, n in enumerate(objs):
        m = OBJ == k
        si = m & slot_out
        r, o, al = REF[m].mean(), v[m].mean(), alt_out[m].mean()
        rs_ = REF[si].sum() / m.sum() if si.any() else 0.0
        rep[n] = dict(
            cycles=r,
            ours=o / r - 1,
            mouth_only=al / r - 1,
            slot_texels=int(si.sum()),
            slot_cycles=REF[si].sum() / REF[m].sum(),
            slot_ours=v[si].sum() / REF[m].sum(),
            slot_mouth_only=alt_out[si].sum() / REF[m].sum(),
        )
        so, sa = v[si].sum() / m.sum() / r, alt_out[si].sum() / m.sum() / r
        print(
            f"  {n:14s} {r:8.5f} {100 * (o / r - 1):+6.1f}% {100 * (al / r - 1):+9.1f}% | {si.sum():3d} "
            f"texels: Cycles {100 * rs_ / r:5.1f}% of the object's light, ours {100 * so:5.1f}%, "
            f"mouth-only {100 * sa:5.1f}%",
            flush=True,
        )
    by_mouth = {}
    for k, lab in enumerate(("front", "top", "back")):
        for c0, lab0 in ((1, "case1/2 side0"), (0, "case0/3 side0")):
            m = (
                slot_out
                & (near == k)
                & np.isin(OBJ, [objs.index(f"case{c}_side0") for c in ((1, 2) if c0 else (0, 3))])
            )
            if m.any():
                by_mouth[f"{lab}, {lab0}"] = dict(
                    texels=int(m.sum()), ours=v[m].sum() / REF[m].sum(), first=fb_out[m].sum() / REF[m].sum()
                )
                print(
                    f"  slot texels nearest the {lab:5s} mouth, {lab0}: {m.sum():3d}, ours/Cycles "
                    f"{v[m].sum() / REF[m].sum():.3f}, first bounce only {fb_out[m].sum() / REF[m].sum():.3f}"
                )
    for f, lab in enumerate(FACES):
        m = CLS == f
        if m.any():
            print(
                f"  face {lab:7s} {m.sum():5d} texels: ours/Cycles {v[m].sum() / REF[m].sum():.3f}, "
                f"mouth-only {alt_out[m].sum() / REF[m].sum():.3f}"
            )
    report[name] = dict(objects=rep, slot_samples=len(rows), share_inside=share_in, by_mouth=by_mouth)
C.write_json(os.path.join(BC.HERE, "out", "books_sides.json"), {"variants": variants, "report": report})
