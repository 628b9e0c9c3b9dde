"""Where a book texel's direct light is read (issues 19 and 20, docs/gather.md "Where the books'
direct light is read"): the furnished sample's books, the bake's draft gather (two levels + 4
iterations, 128 rays, 16 shadow rays) at their texels, its direct light from the emitters (light
shapes and the static emitters) swapped at the texels it gathers at their centre (not dark, not in
a slot: texel_edges.edge_direct's texels) for
  (a) the centre (the gather's own, 16 shadow rays),
  (b) the mean over sub x sub jittered points where Cycles' bake samples the texel
      (bakepoints.texel_points: the middle half, inside the centre's triangle), --sub-rays each,
  (c) texel_edges' rule applied to the emitters: (b) only where the texel's four corners
      (texel_points clamped, --corner-rays each) and centre differ by more than EDGE_TOL of
      their maximum, the centre elsewhere.
Against Cycles' books-only bakes cached by books_bounces.py (bounces 0 = direct, 64 = full; two
seeds): per face class and per book; and the whole room's per-object errors of
furnished_vs_cycles (--room json, refl_gather) with each book's mean moved by what (b) / (c) add.

    .venv/bin/python benchmarks/books_texel_direct.py [--cases case2,case3] [--sub 4]
        [--sub-rays 16] [--corner-rays 16] [--room benchmarks/out/furnished_vs_cycles_fgfacing.json]

Writes benchmarks/out/books_texel_direct[NAME].json."""

import argparse
import json
import os
import time

import numpy as np

import books_common as BC
import cycles_compare as CC
from hr_testing import cycles_ref as C
from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import FinalGather, texel_gather
from hr_addon.core.gather.bakepoints import texel_points
from hr_addon.core.gather.sampling import hash_uniform
from hr_addon.core.gather.texel_edges import CORNERS, EDGE_TOL
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

ap = argparse.ArgumentParser()
ap.add_argument("--cases", default="", help="bookcases (default: all four)")
ap.add_argument("--sub", type=int, default=4, help="points per side of a texel for (b)")
ap.add_argument("--sub-rays", type=int, default=16)
ap.add_argument("--corner-rays", type=int, default=16)
ap.add_argument("--spp", type=int, default=64, help="the cached Cycles bakes' spp")
ap.add_argument("--room", default=os.path.join(BC.HERE, "out", "furnished_vs_cycles_fgfacing.json"))
ap.add_argument("--name", default="")
opt = ap.parse_args()
CACHE = os.path.join(BC.HERE, "out", "books_bounces_cache")
SEEDS = (1, 2)

cfg = CC.SCENES["furnished"]
rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
cases = [c for c in opt.cases.split(",") if c] or sorted(
    {n.split("_")[0] for n in rs.objects if "_book" in n}
)
books = [n for n in rs.objects if "_book" in n and n.split("_")[0] in cases]
key = CC._atlas_key(rs)
shapes = C.shape_proxies(rs, 1)

# Cycles' books-only bakes (books_bounces.py), per bookcase: bounces 0 and 64, seeds 1 and 2
cyc = {}
for case in cases:
    bk = [n for n in rs.objects if n.startswith(case + "_book")]
    z = [
        os.path.join(CACHE, f"furnished_f1_{key}_{case}_{len(bk)}books_b{b}_s{opt.spp}_seed{sd}.npz")
        for b in (0, 64)
        for sd in SEEDS
    ]
    # books_bounces.py --cases CASE names its files by the case; the check stays for older files
    if all(map(os.path.exists, z)) and all(bk[0] in np.load(p).files for p in z):
        zz = [np.load(p) for p in z]
        cyc.update({n: np.hstack([q[n].astype(np.float64) for q in zz]) for n in bk})
    print(f"{case}: {len(bk)} books, Cycles' bakes {'cached' if bk[0] in cyc else 'not cached'}")

t0 = time.process_time()
s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
dyn = DynamicRadiosity(s, method="FE")
dyn.apply(shapes)
ours = C.Ours(rs, s, dyn)
print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)

# books without a cached bake: a zero reference (kept by book_texels; left out of the comparisons)
ref = {n: cyc.get(n, np.zeros((rs.atlases[n].n, 12))) for n in books}
box = BC.book_boxes(rs)
X, P, AX, TR, REF, OBJ, CLS, _ = BC.book_texels(rs, s, ours, ref, books, box, 0.002, grey=False)
REF = REF.reshape(len(REF), 4, 3).mean(2)  # grey: b0 seed 1, 2, b64 seed 1, 2
CYC0, CYC64 = REF[:, :2].mean(1), REF[:, 2:].mean(1)
HAS = np.array([books[o] in cyc for o in OBJ])
print(f"{len(books)} books, {len(X)} texels ({HAS.sum()} with Cycles' bakes)", flush=True)

t0 = time.process_time()
g = texel_gather(dyn, P, X, axes=AX, tris=TR, **BC.BASE)
print(f"gather precompute: {time.process_time() - t0:.0f} s CPU, {g.n} samples", flush=True)


def out(inc):
    inc = inc.copy()
    inc[g.dark] = 0.0
    return g.outputs(g.rho * g.scaled(np.maximum(inc, 0.0))).mean(1)


D = g.direct_and_emission(dyn)[0]
FULL = g.evaluate(dyn, "reflected").mean(1)
# the texels edge_direct looks at: gathered at their centre, not covered, not in a slot
rows, cen, axes, tris = g.texel_area
live = ~g.dark[rows]
if g.gain is not None:
    live &= (g.gain[rows] == 1).all(1)
j = np.flatnonzero(live)
r, patch = rows[j], g.patch[rows[j]]
cen, axes, tris = cen[j], axes[j], None if tris is None else tris[j]
print(f"texels gathered at their centre, lit: {len(j)} of {len(X)}", flush=True)


def direct_at(pts, k, rays, seed):
    """(len(j), 3) mean direct light of the emitters over k points per texel (pts (len(j), k, 3))."""
    nrm = np.repeat(s.patches.normal[patch], k, 0)
    gd = FinalGather(dyn, pts.reshape(-1, 3), nrm, np.repeat(patch, k), rays=1, shadow_rays=rays, seed=seed)
    return gd.direct_and_emission(dyn)[0].reshape(len(j), k, 3).mean(1)


# (b) the texel's area where Cycles' bake samples it (the jitter of edge_direct)
t0 = time.process_time()
k2 = opt.sub**2
gx, gy = np.meshgrid(np.arange(opt.sub), np.arange(opt.sub), indexing="ij")
grid = np.stack([gx.ravel(), gy.ravel()], 1)
f = (grid[None] + hash_uniform(g.seed, g.keys[r], 2500, 2 * k2).reshape(-1, k2, 2)) / opt.sub
AREA = direct_at(texel_points(cen, axes, tris, f), k2, opt.sub_rays, 11)
cpu_b = time.process_time() - t0
# (c) edge texels: corners and centre (the gather's own value) differ by more than EDGE_TOL
t0 = time.process_time()
cp = texel_points(cen, axes, tris, np.broadcast_to(CORNERS, (len(j), 4, 2)), clamp=True)
nrm4 = np.repeat(s.patches.normal[patch], 4, 0)
gc = FinalGather(
    dyn, cp.reshape(-1, 3), nrm4, np.repeat(patch, 4), rays=1, shadow_rays=opt.corner_rays, seed=12
)
v = np.concatenate([gc.direct_and_emission(dyn)[0].mean(1).reshape(-1, 4), D[r].mean(1)[:, None]], 1)
hi = v.max(1)
edge = hi - v.min(1) > EDGE_TOL * hi
cpu_c = time.process_time() - t0
print(
    f"(b) {k2} points x {opt.sub_rays} shadow rays at {len(j)} texels: {cpu_b:.2f} s CPU; (c) corners "
    f"x {opt.corner_rays} rays: {cpu_c:.2f} s CPU, {edge.sum()} edge texels ({100 * edge.mean():.0f}%); "
    f"(b) at those only: ~{cpu_b * edge.mean():.2f} s CPU",
    flush=True,
)
DIR = {"a": out(D)}
Db = D.copy()
Db[r] = AREA
DIR["b"] = out(Db)
Dc = D.copy()
Dc[r[edge]] = AREA[edge]
DIR["c"] = out(Dc)
TOT = {k: FULL - DIR["a"] + d for k, d in DIR.items()}

groups = BC.front_groups(X, OBJ, CLS) + [
    ("fronts", CLS == 1),
    ("sides, no neighbour book", CLS == 4),
    ("sides, front/back overhang", CLS == 9),
]
inrows = np.zeros(len(X), bool)
inrows[g.group[r] if g.group is not None else r] = True
edge_t = np.zeros(len(X), bool)
edge_t[(g.group[r] if g.group is not None else r)[edge]] = True
res = {
    "cases": cases,
    "books": len(books),
    "texels": len(X),
    "sub": opt.sub,
    "sub_rays": opt.sub_rays,
    "corner_rays": opt.corner_rays,
    "cpu": {"b_all": cpu_b, "corners": cpu_c},
    "centre_texels": int(len(j)),
    "edge_texels": int(edge.sum()),
    "classes": {},
}
print(f"\nbooks with Cycles' bakes ({', '.join(c for c in cases if any(n.startswith(c) for n in cyc))}):")
print(
    f"{'class':30s} texels  swapped  edge   direct / Cycles' direct: (a) centre (b) area (c) edges   "
    f"all light / Cycles': (a) (b) (c)  [seeds' half difference]"
)
for lab, m in groups:
    m = m & HAS
    if not m.any():
        continue
    c0, c64 = CYC0[m].sum(), CYC64[m].sum()
    nz0 = abs(REF[m, 0].sum() - REF[m, 1].sum()) / 2 / c0 if c0 else np.nan
    nz64 = abs(REF[m, 2].sum() - REF[m, 3].sum()) / 2 / c64
    row = {
        "texels": int(m.sum()),
        "swapped": int((m & inrows).sum()),
        "edge": int((m & edge_t).sum()),
        "direct": {k: float(DIR[k][m].sum() / c0) for k in DIR},
        "all": {k: float(TOT[k][m].sum() / c64) for k in TOT},
        "noise_direct": float(nz0),
        "noise_all": float(nz64),
    }
    res["classes"][lab] = row
    print(
        f"{lab:30s} {m.sum():6d} {row['swapped']:6d} {row['edge']:6d}      "
        + "  ".join(f"{row['direct'][k]:.3f}" for k in "abc")
        + f" [{100 * nz0:.1f}%]        "
        + "  ".join(f"{row['all'][k]:.3f}" for k in "abc")
        + f" [{100 * nz64:.1f}%]",
        flush=True,
    )

# per book (books with Cycles' bakes): within 5% of Cycles' direct light / of its full bake
ob = np.array(
    [o for o in np.unique(OBJ[HAS]) if CYC0[OBJ == o].sum() > 0]
)  # (books with no direct light left out)
per = {}
for k in "abc":
    d = np.array([DIR[k][OBJ == o].sum() / CYC0[OBJ == o].sum() for o in ob])
    t = np.array([TOT[k][OBJ == o].sum() / CYC64[OBJ == o].sum() for o in ob])
    per[k] = {
        "direct_within_5": int((np.abs(d - 1) < 0.05).sum()),
        "all_within_5": int((np.abs(t - 1) < 0.05).sum()),
        "direct_median": float(np.median(d)),
        "all_median": float(np.median(t)),
    }
res["per_book"] = {"books": int(len(ob)), **per}
print(
    f"\nper book ({len(ob)} books): "
    + "; ".join(
        f"({k}) direct within 5% {per[k]['direct_within_5']} (median {per[k]['direct_median']:.3f}), "
        f"all light "
        f"{per[k]['all_within_5']} (median {per[k]['all_median']:.3f})"
        for k in "abc"
    )
)

# the whole room's lit objects (furnished_vs_cycles' refl_gather errors): each book's mean moved
# by what (b) / (c) add to it here (grey: the json keeps the mean over RGB of the signed error)
if os.path.exists(opt.room):
    room = json.load(open(opt.room))
    lit = room["lit"]
    e0 = {n: room["objects"][n]["refl_gather"]["bias"] for n in lit}
    mr = {n: float(np.mean(room["objects"][n]["refl_gather"]["mean_ref"])) for n in lit}
    mre = {n: room["objects"][n]["refl_gather"]["mre"] for n in lit}
    idx = {n: i for i, n in enumerate(books)}
    rr = {
        "json": os.path.basename(opt.room),
        "lit": len(lit),
        "json_within_5": float(np.mean([mre[n] < 0.05 for n in lit])),
    }
    for k in "abc":
        e = []
        for n in lit:  # (a) and objects not moved: the json's own error
            moved = k != "a" and n in idx and (OBJ == idx[n]).any()
            e.append(abs(e0[n] + (DIR[k] - DIR["a"])[OBJ == idx[n]].mean() / mr[n]) if moved else mre[n])
        e = np.array(e)
        bk = np.array(["_book" in n for n in lit])
        rr[k] = {
            "within_5": float(np.mean(e < 0.05)),
            "books_within_5": float(np.mean(e[bk] < 0.05)),
            "median": float(np.median(e)),
            "books_moved_in": int(np.sum((e < 0.05) & (np.array([mre[n] for n in lit]) >= 0.05))),
            "books_moved_out": int(np.sum((e >= 0.05) & (np.array([mre[n] for n in lit]) < 0.05))),
        }
    res["room"] = rr
    print(
        f"\nroom ({rr['lit']} lit objects, {rr['json']}: within 5% {100 * rr['json_within_5']:.0f}%); "
        f"books of "
        f"{', '.join(cases)} moved: "
        + "; ".join(
            f"({k}) within 5% {100 * rr[k]['within_5']:.1f}% (books {100 * rr[k]['books_within_5']:.1f}%), "
            f"median {100 * rr[k]['median']:.2f}%, {rr[k]['books_moved_in']} objects into the band, "
            f"{rr[k]['books_moved_out']} out"
            for k in "abc"
        )
    )
C.write_json(os.path.join(BC.HERE, "out", f"books_texel_direct{opt.name}.json"), res)
