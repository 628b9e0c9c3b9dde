"""The furnished sample's books, bounce by bounce, against Cycles (issues 19 and 20, docs/gather.md
"The books bounce by bounce"): Cycles' Diffuse bake of the books only (the rest of the room lights
them, frame 1) truncated at 0 bounces (direct light), 1 bounce (direct + one reflection) and 64
(full), two seeds each (what Cycles counts as a bounce: benchmarks/cycles_bounce_check.py), and the
bake's draft final gather (two levels + 4 iterations, 128 rays, 16 shadow rays) at the same
texels, truncated alike: its exact direct light D; D + the rays reading the second level's samples'
exact direct light only (its indirect zeroed); the full gather. Per class of texel
(books_common.FACE, the tops' front row and the sides above's front column apart): ours / Cycles
per bounce.

    .venv/bin/python benchmarks/books_bounces.py [--spp 32] [--bounces 0,1,64] [--seeds 1,2]
        [--bake-only] [--cases case0,case1] [--gather 'dict(leaf_points=4)' --name _lp4]

Cycles' bakes are cached in benchmarks/out/books_bounces_cache/ (git-ignored); --bake-only
stops after them. --gather: texel_gather keywords over the bake's (a variant). Writes
benchmarks/out/books_bounces[NAME].json."""

import argparse
import os
import time

import numpy as np

import books_common as BC
import cycles_compare as CC
from hr_testing import cycles_ref as C
from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import FinalGather, cosine_directions, texel_gather
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

ap = argparse.ArgumentParser()
ap.add_argument("--spp", type=int, default=32)
ap.add_argument("--bounces", default="0,1,64")
ap.add_argument("--seeds", default="1,2")
ap.add_argument("--bake-only", action="store_true")
ap.add_argument(
    "--hits", type=int, default=64, help="rays a texel for the exact one-bounce estimate (0: off)"
)
ap.add_argument("--cases", default="", help="bookcases whose books are compared (default: all)")
ap.add_argument("--gather", default="{}", help="texel_gather keywords over the bake's: 'dict(leaf_points=4)'")
ap.add_argument("--direct-area", action="store_true", help="the tops' direct light over the texel's area")
ap.add_argument("--name", default="", help="suffix of the output json")
opt = ap.parse_args()
BOUNCES = [int(b) for b in opt.bounces.split(",")]
SEEDS = [int(s) for s in opt.seeds.split(",")]
CACHE = os.path.join(BC.HERE, "out", "books_bounces_cache")

cfg = CC.SCENES["furnished"]
rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
cases = [c for c in opt.cases.split(",") if c]
books = [n for n in rs.objects if "_book" in n and (not cases or n.split("_")[0] in cases)]
key = CC._atlas_key(rs)
shapes = C.shape_proxies(rs, 1)
everything = rs.objects
rs.objects = books  # only the books are baked; the whole room lights them
cyc = {}
for b in BOUNCES:
    for seed in SEEDS:
        # named by the bookcases, not the book count (case0 and case3 both hold 169 books)
        which = "-".join(sorted(cases)) or "all"
        name = f"furnished_f1_{key}_{which}_{len(books)}books_b{b}_s{opt.spp}_seed{seed}.npz"
        path = os.path.join(CACHE, name)
        if os.path.exists(path):
            z = np.load(path)
            cyc[b, seed] = {n: z[n].astype(np.float64) for n in books}
            print(f"cycles bounces {b} seed {seed}: cached ({float(z['__cpu']):.0f} s CPU)", flush=True)
            continue
        vals, dt, mask = C.bake(rs, opt.spp, seed, bounces=b)
        for n in books:
            vals[n][~mask[n]] = np.nan
        os.makedirs(CACHE, exist_ok=True)
        np.savez(path, __cpu=dt["cpu"], **{n: v.astype(np.float32) for n, v in vals.items()})
        cyc[b, seed] = vals
        print(f"cycles bounces {b} seed {seed}: {dt['cpu']:.0f} s CPU", flush=True)
rs.objects = everything
if opt.bake_only:
    raise SystemExit

t0 = time.process_time()
s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
dyn = DynamicRadiosity(s, method="FE")
dyn.apply(shapes)
assert not dyn.lights  # light shapes only: no Blender light's bounce apart (FinalGather._light_bounce)
ours = C.Ours(rs, s, dyn)
print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)

# every bake's texels side by side (3 channels each) so that book_texels keeps the same texels
order = [(b, sd) for b in BOUNCES for sd in SEEDS]
ref = {n: np.hstack([cyc[k][n] for k in order]) for n in books}
box = BC.book_boxes(rs)
X, P, AX, TR, REF, OBJ, CLS, ZREL = BC.book_texels(rs, s, ours, ref, books, box, 0.002, grey=False)
REF = REF.reshape(len(REF), len(order), 3).mean(2)  # grey, per bake
print(f"{len(books)} books, {len(X)} texels", flush=True)

t0 = time.process_time()
GKW = {**BC.BASE, **eval(opt.gather)}
g = texel_gather(dyn, P, X, axes=AX, tris=TR, **GKW)
print(f"gather precompute: {time.process_time() - t0:.0f} s CPU, {g.n} samples", flush=True)
g2 = g.second
assert g2 is not None and g2.second is None  # two levels


def out(inc):
    inc = inc.copy()
    inc[g.dark] = 0.0
    return g.outputs(g.rho * g.scaled(np.maximum(inc, 0.0))).mean(1)


D = g.direct_and_emission(dyn)[0]
used = g._second_map[0]
# one bounce: the rays read the second level's samples' exact direct light only (a leaf without
# samples reads 0; the rays reading one: their share of the weights)
Y1 = g._leaf_means(g2.rho * g2.direct_and_emission(dyn)[0], np.zeros((g.n_hr, 3)))
gc = g.leaf_columns()
no_samples = (gc < g.n_hr) & ~np.isin(gc, used)  # (near hits read samples: n_hr + sample)
ew = g.entry_weights()
print(f"weight on leaves without second-level samples: {ew[no_samples].sum() / ew.sum():.2e}")
OURS = {0: out(D), 1: out(D + g._read((Y1, None, None, None))), 64: g.evaluate(dyn, "reflected").mean(1)}
# ours bounce by bounce: the second level's passes from a black solution (k passes: k bounces at
# the texels), against the full gather (4 iterations + the solution read after the last pass)
ladder, L, D2 = {}, (np.zeros((len(Y1), 3)), None, None, None), g2.direct_and_emission(dyn)[0]
for k in range(1, 2 + g.iterations):
    L = (g._leaf_means(g2.rho * (D2 + g2._read(L)), np.zeros((g.n_hr, 3))), None, None, None)
    ladder[k] = out(D + g._read(L))
assert np.allclose(ladder[1], OURS[1])
OURS.update({b: ladder[b] for b in BOUNCES if 1 < b < 64})
check = out(D + g.indirect(dyn))
print(f"full: evaluate against D + indirect: max abs diff {np.abs(check - OURS[64]).max():.1e}")

# the tops' rows and the sides above's columns from the book's front (as books_hits.py counts them)
groups = BC.front_groups(X, OBJ, CLS) + [(BC.FACE[c], CLS == c) for c in (1, 2, 3, 4, 5, 6, 7, 9)]


def cyc_sum(m, b):
    """Class sum of the seeds' mean, and its noise (the seeds' half difference, relative)."""
    v = [REF[m, order.index((b, sd))].sum() for sd in SEEDS]
    return float(np.mean(v)), float(abs(v[0] - v[-1]) / 2 / max(np.mean(v), 1e-30))


table = {}
tot = cyc_sum(groups[0][1], max(BOUNCES))[0]
hdr = "  ".join(f"b{b}: ours/Cyc (noise)" for b in BOUNCES)
inc = "  ".join(f"+b{b}" for b in BOUNCES[1:])
print(f"\n{'class':34s} texels  share  {hdr}   increments ours/Cycles: {inc}")
for lab, m in groups:
    if not m.any():
        continue
    row = {"texels": int(m.sum()), "cycles_share": cyc_sum(m, max(BOUNCES))[0] / tot}
    line = f"{lab:34s} {m.sum():6d} {100 * row['cycles_share']:5.1f}%"
    prev = None
    for b in BOUNCES:
        c, nz = cyc_sum(m, b)
        o = float(OURS[b][m].sum())
        r = o / c if c else float("nan")  # (the slots' deep texels get no direct light)
        row[f"b{b}"] = {"cycles": c, "ours": o, "ratio": r, "noise": nz}
        line += f"   {r:6.3f} ({100 * nz:4.1f}%)    "
    for b0, b1 in zip(BOUNCES, BOUNCES[1:]):
        dc = row[f"b{b1}"]["cycles"] - row[f"b{b0}"]["cycles"]
        do = row[f"b{b1}"]["ours"] - row[f"b{b0}"]["ours"]
        row[f"inc_b{b1}"] = {"cycles": dc, "ours": do, "ratio": do / dc if dc else float("nan")}
        line += f" {do / dc if dc else float('nan'):6.3f}"
    row["ours_by_bounce_of_full"] = {k: float(v[m].sum() / OURS[64][m].sum()) for k, v in ladder.items()}
    table[lab] = row
    print(line, flush=True)

print("\nours up to k bounces (the second level's passes from a black solution), of our full:")
for lab, m in groups:
    if m.any() and lab in table:
        print(
            f"{lab:34s} "
            + "  ".join(f"{k}: {v:.3f}" for k, v in table[lab]["ours_by_bounce_of_full"].items())
        )

# The first bounce read exactly at the hits (the tops and sides above, at their texels' centres):
# `hits` cosine rays a texel, each reading rho x the exact direct light (16 shadow rays) of the
# point it hits, not the second level's leaf mean there; back faces and misses read 0.
exact = {}
if opt.hits and {0, 1} <= set(BOUNCES):
    sel = np.flatnonzero(np.isin(CLS, (0, 8)))
    pt = s.patches
    t0 = time.process_time()
    gc = FinalGather(dyn, X[sel], pt.normal[P[sel]], P[sel], rays=1, shadow_rays=16)
    R = opt.hits
    dirs = cosine_directions(gc.normals, gc.keys, R, 4321, stream=0).reshape(-1, 3)
    row_ = np.repeat(np.arange(gc.n), R)
    org = gc.origins[row_]
    prim, t = gc.first_hit(org, dirs)
    hp = np.where(prim >= 0, pt.triangle_patch[np.maximum(prim, 0)], 0)
    i = np.flatnonzero((prim >= 0) & (np.einsum("ij,ij->i", dirs, pt.normal[hp]) < 0))
    gh = FinalGather(
        dyn, org[i] + t[i, None] * dirs[i], pt.normal[hp[i]], hp[i], rays=1, shadow_rays=16, seed=7
    )
    hit = gh.rho * gh.direct_and_emission(dyn)[0]
    one = (np.stack([np.bincount(row_[i], hit[:, c], gc.n) for c in range(3)], 1) / R * gc.rho).mean(1)
    print(f"exact first bounce at {len(i)} hits: {time.process_time() - t0:.0f} s CPU", flush=True)
    print(
        f"\n{'first bounce, centres':34s} texels  Cycles' +b1  gather's +b1 / Cycles'  exact at hits/Cycles'"
    )
    for lab, m in groups[1:5]:
        ms = m[sel]
        dc = cyc_sum(m, 1)[0] - cyc_sum(m, 0)[0]
        dg = float((OURS[1] - OURS[0])[m].sum())
        exact[lab] = {"cycles": dc, "gather": dg / dc, "exact_hits": float(one[ms].sum() / dc)}
        print(f"{lab:34s} {m.sum():6d} {dc:10.3f}   {dg / dc:10.3f}   {one[ms].sum() / dc:10.3f}", flush=True)
# the tops' direct light at the texel's centre and over its area (the atlas's sub-texel points
# inside the top, as Cycles' bake spreads its samples), against Cycles' bounces 0
if opt.direct_area and 0 in BOUNCES:
    cen_d, area_d, cyc0 = [], [], []
    for n in books:
        at = rs.atlases[n]
        patch = ours.samples[n][0]
        top = s.patches.normal[patch][:, 2] > 0.9
        tex = np.unique(at.s_texel[at.s_centre & top])
        sub = np.isin(at.s_texel, tex) & top
        gd = FinalGather(
            dyn, at.s_point[sub], s.patches.normal[patch[sub]], patch[sub], rays=1, shadow_rays=64
        )
        v = (gd.rho * gd.direct_and_emission(dyn)[0]).mean(1)
        st = at.s_texel[sub]
        am = np.bincount(st, v, at.n)[tex] / np.bincount(st, minlength=at.n)[tex]
        cm = np.zeros(at.n)
        cm[st[at.s_centre[sub]]] = v[at.s_centre[sub]]
        c0 = np.mean([cyc[0, sd][n][tex].mean(1) for sd in SEEDS], 0)
        ok = np.isfinite(c0)
        cen_d.append(cm[tex][ok]), area_d.append(am[ok]), cyc0.append(c0[ok])
    c0 = np.concatenate(cyc0).sum()
    print(
        f"\ntops' direct light / Cycles': at the centres {np.concatenate(cen_d).sum() / c0:.3f}, "
        f"over the texel's area {np.concatenate(area_d).sum() / c0:.3f} (64 shadow rays)",
        flush=True,
    )

C.write_json(
    os.path.join(BC.HERE, "out", f"books_bounces{opt.name}.json"),
    {
        "spp": opt.spp,
        "seeds": SEEDS,
        "bounces": BOUNCES,
        "books": len(books),
        "gather": GKW,
        "cases": cases,
        "classes": table,
        "first_bounce_exact_at_hits": exact,
    },
)
