"""Issue 20's Cornell spot (cycles_lights.add_light("SPOT")): is the second level's 2 x 2 point
quadrature of what each HR leaf gathers what darkens the surfaces lit by the spot's bounce?

Builds run()'s solution and texel gather (medium, FE, two levels + 4 iterations), then integrates
what each HR leaf gathers again with n x n Gauss points (a level-one FinalGather at those points,
the second level's rays per point, reading the same converged leaf values), and per leaf compares
the two means of the gathered light. Then iterates the second level with the dense quadrature as
the gather does with its own and evaluates the texels with those leaf values: the change of each
surface's mean is what the 2 x 2 quadrature costs. No Cycles here (the errors against Cycles:
benchmarks/cycles_lights.py).

Run: .venv/bin/python benchmarks/spot_second_level.py [n=8] [KIND=SPOT]"""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(n_dense=8, kind="SPOT"):
    from hr_addon.core import formfactor as ff
    from hr_addon.core.gather import FinalGather
    from hr_addon.core.gather.final import _csr_matvec
    from hr_testing.cycles_lights import solve

    sv = solve(kind)
    rs, system, dyn, g = sv.rs, sv.system, sv.dyn, sv.gather
    g2 = g.second
    used, gw = g._second_map
    h = system.h
    k2 = gw.shape[1]

    # the converged leaf values the texels read, and the second level's direct light per leaf
    V = g.solution_values(dyn)
    Y2 = g.leaf_values(dyn)
    D2 = g2.direct_and_emission(dyn)[0].reshape(len(used), k2, 3)[:, 0]  # node_incident: per leaf

    t0 = time.process_time()
    x, gw_d = ff.quadrature(h.corners[used], h.nv[used], n_dense)
    kd = x.shape[1]
    gd = FinalGather(
        system,
        x.reshape(-1, 3),
        np.repeat(h.normal[used], kd, 0),
        np.repeat(h.patch[used], kd),
        rays=g2.rays,
        shadow_rays=g2.shadow_rays,
        seed=g2.seed + 101,
    )
    dense_s = time.process_time() - t0
    rho = g2.rho.reshape(len(used), k2, 3)[:, 0]

    def leaf_mean(G, wq, Y):
        k = wq.shape[1]
        w = wq * ~G.dark.reshape(len(used), k)
        w = w / np.maximum(w.sum(1, keepdims=True), 1e-300)
        read = _csr_matvec(G.indptr, G.leaf_columns(), G.w, Y, rays=G.row_rays)
        return np.einsum("uk,ukc->uc", w, read.reshape(len(used), k, 3))

    I2, Id = leaf_mean(g2, gw, Y2), leaf_mean(gd, gw_d, Y2)  # gathered from the same leaf values
    # the dense second level iterated as the gather's own (1 + iterations passes from V)
    Yd = V.copy()
    for _ in range(1 + g.iterations):
        Ynew = V.copy()
        Ynew[used] = rho * (D2 + leaf_mean(gd, gw_d, Yd))
        Yd = Ynew
    D, _ = g.direct_and_emission(dyn)

    def texels(Y):
        inc = D + _csr_matvec(g.indptr, g.leaf_columns(), g.w, Y, rays=g.row_rays)
        inc[g.dark] = 0.0
        return g.outputs(g.rho * g.scaled(inc))

    t2, td = texels(Y2), texels(Yd)
    check = np.abs(t2 - g.evaluate(dyn, "reflected")).max() / max(np.abs(t2).max(), 1e-30)

    # per surface: leaves' gathered light (dense / 2 x 2, area-weighted) overall and on the leaves
    # within one leaf size of another surface's plane at an angle (a corner's near field)
    area = h.area[used]
    names = rs.objects
    cen = {n: len(np.flatnonzero(rs.atlases[n].s_centre)) for n in names}
    out = {"dense_points": n_dense**2, "dense_precompute_cpu_s": round(dense_s, 1), "check": check}
    out["hr_leaves"] = int(len(used))
    s = 0
    surf = {}
    for n in names:
        m = cen[n]
        a, b = t2[s : s + m].mean(0), td[s : s + m].mean(0)
        surf[n] = {"texels_dense_vs_2x2": round(float(np.mean(b / a - 1)), 4)}
        s += m
    out["surfaces"] = surf
    # leaves by the gathered light's change, where they are: distance from the leaf centre to the
    # nearest point of another plane's leaves over the leaf's size
    c = h.corners[used][:, :4].mean(1)
    size = np.sqrt(area)
    gi, gd_ = I2.mean(1), Id.mean(1)
    rel = np.where(gi > 0, gd_ / np.maximum(gi, 1e-30) - 1, 0)

    def wsum(sel):  # area-weighted change of the gathered light
        return float((area[sel] * (gd_[sel] - gi[sel])).sum() / max((area[sel] * gi[sel]).sum(), 1e-30))

    nrm = h.normal[used]
    near = np.zeros(len(used), bool)
    for j in range(0, len(used), 512):  # nearest leaf centre on a plane at an angle
        cj = c[j : j + 512]
        d = np.linalg.norm(cj[:, None] - c[None], axis=2)
        angled = np.abs(nrm[j : j + 512] @ nrm.T) < 0.5
        d = np.where(angled, d, np.inf)
        near[j : j + 512] = d.min(1) < 1.5 * np.maximum(size[j : j + 512], size[np.argmin(d, 1)])
    out["leaves_gathered_dense_vs_2x2"] = {
        "all": round(wsum(slice(None)), 4),
        "corner_near_field": round(wsum(near), 4),
        "elsewhere": round(wsum(~near), 4),
        "share_of_leaves_near": round(float(near.mean()), 3),
        "rel_p5_p50_p95": [round(float(v), 4) for v in np.percentile(rel[gi > 0], [5, 50, 95])],
        "rel_p5_p50_p95_near": [round(float(v), 4) for v in np.percentile(rel[near & (gi > 0)], [5, 50, 95])],
    }
    # the spread of the 2 x 2 points' gathered light per leaf, as a leaf-local criterion
    I2pts = _csr_matvec(g2.indptr, g2.leaf_columns(), g2.w, Y2, rays=g2.row_rays)
    I2pts = I2pts.reshape(len(used), k2, 3).mean(2)
    spread = (I2pts.max(1) - I2pts.min(1)) / np.maximum(I2pts.max(1), 1e-30)
    for thr in (0.2, 0.3, 0.5):
        sel = spread > thr
        out[f"spread_gt_{thr}"] = {
            "share": round(float(sel.mean()), 3),
            "gathered_dense_vs_2x2": round(wsum(sel), 4),
            "rest": round(wsum(~sel), 4),
        }
    print("RESULT " + json.dumps(out), flush=True)
    np.savez(
        Path(__file__).resolve().parent / "out" / f"spot_second_level_{kind}_{n_dense}.npz",
        used=used, I2=I2, Id=Id, area=area, centre=c, normal=nrm, near=near, spread=spread,
    )  # fmt: skip


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a = sys.argv[1:]
    main(int(a[0]) if a else 8, a[1] if len(a) > 1 else "SPOT")
