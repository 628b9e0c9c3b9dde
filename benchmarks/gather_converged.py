"""How many of a stored gather's top-level samples sit where the gather is converged, by geometry
(the irradiance cache's criterion, Ward 1988): a sample whose hemisphere's harmonic mean hit
distance R is large against its distance to its neighbours on the same plane reads nearly the
same row as they do (their error term ||x - x_i|| / R_i below a). bpy-free, on a stored build
(bench_gather_events.py --cache); the stored rows are not changed.

Every top-level sample that gathers (not covered) traces its own rays again (its stored rays, seed,
directions and origin: FinalGather.gather_batch's) for the hits' distances t, all hits counted
(back faces and covered points too; misses as infinitely far): R = rays / sum(1 / t). Neighbours:
the samples whose transport patch lies on the same plane (normal and offset rounded), by distance.
For each a and group size k: the share of samples (and of their rays) whose (k-1)-th nearest
neighbour on the plane lies within a x R (the sample's own R) - such a sample could share one
stratified ray set with k-1 neighbours. The samples averaged into one corner already share its rays
(layouts.shared_rays): they are not counted as each other's neighbours.

    .venv/bin/python benchmarks/gather_converged.py /work/cache/STORE [--json OUT.json] [--mask M.npz]

--mask: the qualifying samples per (k, a), for gather_fewer_rays.py.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from bench_gather_events import load_store  # noqa: E402
from hr_addon.core.gather.sampling import cosine_directions  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("store")
ap.add_argument("--a", default="0.05,0.1,0.2,0.3", help="the error bounds a (||x - x_i|| / R < a)")
ap.add_argument("--k", default="2,4", help="group sizes")
ap.add_argument("--json", default=None)
ap.add_argument("--mask", default=None, help="npz: per (k, a) the qualifying top-level samples (n,) bool")
args = ap.parse_args()

c0 = time.process_time()
s, g, _ = load_store(Path(args.store) / pc.FILENAME)
pc.use_threads(s, g, 1)
pt = s.patches
n = g.n
rr = np.full(n, g.rays) if g.sample_rays is None else np.asarray(g.sample_rays)
live = np.flatnonzero(~g.dark)
print(f"{n:,} top-level samples, {len(live):,} gather, {int(rr[live].sum()):,} rays", flush=True)

# the hits' distances: each sample's own rays again (as gather_batch traces them)
inv = np.zeros(n)  # sum over the sample's rays of 1 / t (misses 0)
near_t = np.full(n, np.inf)  # the nearest hit
STEP = 4096
for R in np.unique(rr[live]):
    idx = live[rr[live] == R]
    for a in range(0, len(idx), STEP):
        j = idx[a : a + STEP]
        d = cosine_directions(g.normals[j], g.keys[j], int(R), g.seed, stream=0).reshape(-1, 3)
        org = np.repeat(g._origins(j), int(R), 0)
        prim, t = g.first_hit(org, d)
        t = np.where(prim >= 0, t, np.inf).reshape(len(j), int(R))
        inv[j] = (1.0 / np.maximum(t, 1e-9)).sum(1)
        near_t[j] = t.min(1)
Rh = np.where(inv > 0, rr / np.maximum(inv, 1e-300), np.inf)
print(f"traced: {time.process_time() - c0:.1f} s CPU", flush=True)

# samples averaged into one corner (LoopGather's inset layout) already share its rays
# (layouts.shared_rays): they are one group, never each other's neighbours here
own = np.arange(n)
if getattr(g, "average", None) is not None:
    li, lj = g.average[:2]
    a_, b_ = g.loop_index[li], g.loop_index[lj]
    while True:  # the connected components' least index
        lab = own.copy()
        np.minimum.at(lab, a_, own[b_])
        np.minimum.at(lab, b_, own[a_])
        lab = lab[lab]
        if np.array_equal(lab, own):
            break
        own = lab
corner = own[live]

# planes of the samples' transport patches
nrm = pt.normal[g.patch[live]]
off = np.einsum("ij,ij->i", nrm, pt.corners[g.patch[live], 0])
key = np.column_stack([np.round(nrm * 1e3), np.round(off / (g.unit * 64))]).astype(np.int64)
_, grp = np.unique(key, axis=0, return_inverse=True)
grp = grp.ravel()
order = np.argsort(grp, kind="stable")
bounds = np.r_[0, np.cumsum(np.bincount(grp))]
print(f"corner groups: {len(np.unique(corner)):,} of {len(live):,} samples", flush=True)
sizes = np.diff(bounds)
print(
    f"{len(sizes):,} planes, largest {sizes.max():,} samples, sum n^2 {float((sizes**2).sum()):.3g}",
    flush=True,
)

A = [float(x) for x in args.a.split(",")]
K = [int(x) for x in args.k.split(",")]
kmax = max(K)
nn = np.full((len(live), kmax - 1), np.inf)  # distances to the nearest kmax - 1 neighbours on the plane
P = g.points[live]
for gi in np.flatnonzero(sizes > 1):
    m = order[bounds[gi] : bounds[gi + 1]]
    q = P[m]
    step = max(1, (1 << 21) // len(m))  # (rows of a block: its (step, len(m), 3) temporaries small)
    for a in range(0, len(m), step):
        d2 = ((q[a : a + step, None] - q[None]) ** 2).sum(-1)
        d2[corner[m[a : a + step], None] == corner[m][None]] = np.inf  # (not itself, nor its corner's)
        kk = min(kmax - 1, len(m) - 1)
        part = np.sqrt(np.sort(np.partition(d2, kk - 1, 1)[:, :kk], 1))
        nn[m[a : a + step], :kk] = part
print(f"neighbours: {time.process_time() - c0:.1f} s CPU", flush=True)

res = dict(
    samples=int(n),
    gather_samples=int(len(live)),
    rays=int(rr[live].sum()),
    planes=int(len(sizes)),
    R_quantiles_m={str(q): float(np.quantile(Rh[live], q)) for q in (0.05, 0.25, 0.5, 0.75, 0.95)},
    nn1_quantiles_m={str(q): float(np.quantile(nn[:, 0], q)) for q in (0.05, 0.25, 0.5, 0.75, 0.95)},
    rays_per_sample={str(int(r)): int((rr[live] == r).sum()) for r in np.unique(rr[live])},
    share={},
)
w = rr[live].astype(float)
masks = {}
for k in K:
    for a in A:
        ok = nn[:, k - 2] < a * Rh[live]
        masks[f"k{k}_a{a}"] = np.zeros(n, bool)
        masks[f"k{k}_a{a}"][live[ok]] = True
        res["share"][f"k{k}_a{a}"] = dict(samples=float(ok.mean()), rays=float(w[ok].sum() / w.sum()))
        print(f"k {k}, a {a}: {ok.mean():.1%} of the samples, {w[ok].sum() / w.sum():.1%} of the rays")
print(f"R (harmonic mean hit distance) quantiles: {res['R_quantiles_m']}")
print(f"nearest neighbour on the plane quantiles: {res['nn1_quantiles_m']}")
print(f"rays per sample: {res['rays_per_sample']}")
res["cpu"] = time.process_time() - c0
if args.mask:
    np.savez(args.mask, R=Rh, **masks)
if args.json:
    Path(args.json).write_text(json.dumps(res, indent=1))
