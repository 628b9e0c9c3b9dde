"""Issue 19 (branch ind28, docs/gather.md): the converged final gather against an independent
bpy-free path tracer on the furnished 20k room (hr_testing.furnished; the ceiling light panel as
the only emitter, two-sided surfaces as Cycles shows them, Russian roulette: unbiased).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/pt_check.py [--paths 128]

Compared at the same points: the top level's samples on the ceiling (lit only indirectly) and a
random subset of the second level's samples (where its passes' leaf values come from), per class
of object: the gather's converged value (12 passes and their tail) over the path tracer's, and
its direct light over the tracer's direct light (the same estimator's first term).
"""

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from hr_addon.core.events import surface_samples  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.params import RefineParams  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


class Tracer:
    def __init__(self, s, seed=1, nee=4, light="ceiling_light"):
        pt = s.patches
        self.be, self.pt = s.backend, pt
        self.tri_patch = pt.triangle_patch
        self.rho = pt.reflectance.T  # (K, 3)
        lid = list(pt.object_names).index(light)
        lp = np.flatnonzero(np.asarray(pt.object_id) == lid)
        assert len(lp) == 1 and pt.nv[lp[0]] == 4
        self.lc = pt.corners[lp[0]]
        self.ln = pt.normal[lp[0]]
        self.le = pt.emission[:, lp[0]]
        self.la = pt.area[lp[0]]
        self.rng = np.random.default_rng(seed)
        self.nee = nee
        lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
        self.tmax = 2 * float(np.linalg.norm(hi - lo))
        self.eps = 1e-5 * float(np.linalg.norm(hi - lo))

    def direct(self, x, n):
        """(N, 3) direct irradiance / pi from the panel at points x with normals n."""
        N, M = len(x), self.nee
        u, v = self.rng.random((2, N, M))
        c = self.lc
        y = c[0] + u[..., None] * (c[1] - c[0]) + v[..., None] * (c[3] - c[0])  # a parallelogram
        d = y - x[:, None]
        r2 = np.einsum("nmk,nmk->nm", d, d)
        r = np.sqrt(r2)
        cx = np.maximum(np.einsum("nmk,nk->nm", d, n) / r, 0)
        cl = np.maximum(-(d @ self.ln) / r, 0)
        w = cx * cl / (np.pi * r2) * self.la / M
        on = w > 0
        xs = np.broadcast_to(x[:, None] + self.eps * n[:, None], y.shape)
        vis = np.zeros_like(w)
        vis[on] = ~self.be.occluded(xs[on], y[on] - 1e-4 * (y[on] - xs[on]))
        return (w * vis).sum(1)[:, None] * self.le[None]

    def cosine(self, n):
        N = len(n)
        u1, u2 = self.rng.random((2, N))
        r, phi = np.sqrt(u1), 2 * np.pi * u2
        a = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        t = np.cross(n, a)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        b = np.cross(n, t)
        z = np.sqrt(np.maximum(1 - u1, 0))
        return (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * n

    def reflected(self, x, n, rho, paths):
        """(N, 3) reflected radiance rho (D + I) at x and the direct part rho D (path tracing)."""
        N = len(x)
        D = sum(self.direct(x, n) for _ in range(8)) / 8  # the points' own: 8 x nee panel samples
        acc = np.zeros((N, 3))
        for _ in range(paths):
            idx = np.arange(N)
            p, nn = x.copy(), n.copy()
            T = np.ones((N, 3))
            depth = 0
            while len(idx):
                d = self.cosine(nn)
                prim, t = self.be.first_hit(p + self.eps * nn, d, self.tmax)
                hit = prim >= 0
                idx, p, d, t, T, prim = idx[hit], p[hit], d[hit], t[hit], T[hit], prim[hit]
                if not len(idx):
                    break
                q = p + self.eps * nn[hit] + t[:, None] * d
                k = self.tri_patch[prim]
                hn = self.pt.normal[k]
                hn = np.where((np.einsum("ij,ij->i", hn, d) > 0)[:, None], -hn, hn)  # two-sided
                T = T * self.rho[k]
                acc[idx] += T * self.direct(q, hn)
                depth += 1
                if depth >= 3:  # Russian roulette
                    keep = self.rng.random(len(idx)) < np.minimum(T.max(1), 1.0)
                    pr = np.minimum(T.max(1), 1.0)
                    T = T / np.maximum(pr, 1e-300)[:, None]
                    idx, q, hn, T = idx[keep], q[keep], hn[keep], T[keep]
                p, nn = q, hn
        return rho * (D + acc / paths), rho * D


def klass(name):
    for c in ("ceiling_light", "ceiling", "wall", "floor", "case", "table", "chair", "box", "sofa"):
        if name.startswith(c):
            return c
    return "other"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--paths", type=int, default=128)
    ap.add_argument("--second", type=int, default=3000)
    ap.add_argument("--shadow-feps", type=float, default=None)
    ap.add_argument(
        "--top",
        default="ceiling",
        help="ceiling: the top level on the ceiling only; all: also "
        "one sample per patch everywhere else (32 rays), so the second level samples every leaf seen",
    )
    ap.add_argument("--nee", type=int, default=4, help="panel samples a path vertex (8 x that at the points)")
    ap.add_argument("--leaf-points", type=int, default=2, help="the second level's k x k samples per leaf")
    ap.add_argument("--near-points", type=int, default=4, help="near reads (0: off)")
    ap.add_argument("--kw", default="{}", help="FinalGather keywords as JSON (a variant of the gather)")
    ap.add_argument("--json", default=os.path.join(HERE, "out", "pt_check.json"))
    a = ap.parse_args()
    mesh, _ = furnished_room("20k")
    p = dataclasses.replace(RefineParams.for_gather("draft"), orient=True)
    if a.shadow_feps is not None:
        p = dataclasses.replace(p, shadow_feps=a.shadow_feps)
    s = RadiositySystem(mesh, p)
    s.solve()
    pt = s.patches
    cls = np.array([klass(n) for n in pt.object_names])[np.asarray(pt.object_id)]
    pts, patch, wts = surface_samples(pt, 2)
    keep = cls[patch] == "ceiling"
    pts, patch = pts[keep], patch[keep]
    rays = 128
    n_ceiling = len(pts)
    if a.top == "all":  # (the ceiling's samples first: those are compared)
        p2, k2, _ = surface_samples(pt, 1, min_k=1)
        o = (cls[k2] != "ceiling") & (cls[k2] != "ceiling_light")
        pts, patch = np.concatenate([pts, p2[o]]), np.concatenate([patch, k2[o]])
        rays = np.r_[np.full(n_ceiling, 128), np.full(int(o.sum()), 32)]
    g = FinalGather(
        s,
        pts,
        pt.normal[patch],
        patch,
        rays=128,
        shadow_rays=16,
        levels=2,
        iterations=12,
        sample_rays=None if a.top == "ceiling" else rays,
        leaf_points=a.leaf_points,
        near_points=a.near_points,
        **json.loads(a.kw),
    )
    lv = g._levels
    g._levels = lambda V, direct, tail=False, f=lv: f(V, direct, True)
    top = g.evaluate(s)  # E + rho (D + I): the ceiling does not emit
    g2 = g.second
    L = g._levels(g.solution_values(s), lambda x: x.direct_and_emission(s)[0])
    D2 = g2.direct_static()
    y = g2.rho * (D2 + g2._read(L))
    tr = Tracer(s, nee=a.nee)
    res = {}
    # the second level's reads of leaves without second-level samples (they read the transport's V)
    used = g._second_map[0]
    rows = len(L[0])
    ind = np.zeros((rows, 3))
    ind[: g.n_hr] = 1.0
    ind[used] = 0.0
    share_v = g2._read((ind, None, None, None))[:, 0] / np.maximum(
        g2._read((np.ones((rows, 3)), None, None, None))[:, 0], 1e-300
    )
    seen = np.flatnonzero(~g.dark[:n_ceiling])
    sel = seen[:: max(len(seen) // 600, 1)]
    ref, refD = tr.reflected(g.points[sel], g.normals[sel], g.rho[sel], a.paths)
    got = top[sel]
    res["ceiling_top"] = dict(
        n=len(sel),
        gather_over_pt=float(got.sum() / ref.sum() - 1),
        pt_direct_share=float(refD.sum() / ref.sum()),
    )
    print("ceiling top samples", res["ceiling_top"], flush=True)
    if not a.second:
        json.dump(dict(paths=a.paths, nee=a.nee, kw=a.kw, results=res), open(a.json, "w"), indent=1)
        return
    ok = np.flatnonzero(~g2.dark)
    rng = np.random.default_rng(3)
    sel2 = np.sort(rng.choice(ok, min(a.second, len(ok)), replace=False))
    ref2, refD2 = tr.reflected(g2.points[sel2], g2.normals[sel2], g2.rho[sel2], a.paths)
    c2 = cls[g2.patch[sel2]]
    for c in np.unique(c2):
        m = c2 == c
        res[c] = dict(
            n=int(m.sum()),
            y_over_pt=float(y[sel2][m].sum() / ref2[m].sum() - 1),
            direct_over_pt=float((g2.rho * D2)[sel2][m].sum() / refD2[m].sum() - 1),
            read_share_of_unsampled_leaves=float(share_v[sel2][m].mean()),
            indirect_over_pt=float((y - g2.rho * D2)[sel2][m].sum() / (ref2 - refD2)[m].sum() - 1),
        )
        print(c, res[c], flush=True)
    json.dump(
        dict(paths=a.paths, shadow_feps=p.shadow_feps, top=a.top, results=res), open(a.json, "w"), indent=1
    )


if __name__ == "__main__":
    main()
