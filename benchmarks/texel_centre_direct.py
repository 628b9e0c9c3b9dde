"""Issue 20's Cornell box lit by one Blender light (cycles_lights.add_light(KIND)): how much of a
surface's mean the texel-centre sampling of the light's direct light moves, against the texel's
area mean (n x n points over each texel on its polygon, as a Cycles bake spreads its samples over
the texel).

Our texel gather takes the direct light at each texel's centre (texels straddling a contact's
edge aside); Cycles integrates each texel. Where a sharp shadow edge runs along texel rows the
centres decide whole texels lit or dark. This computes each surface's reflected direct light
both ways (core.lights.unit_incident, 4 shadow rays per point, the Light's unit x scale x rho)
and prints (area mean - centre mean) / the surface's mean of our final gather.

Run: .venv/bin/python benchmarks/texel_centre_direct.py [KIND=SUN] [n=4]"""

import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(kind="SUN", n_sub=4):
    from hr_addon.core.gather.points import _insideness, _into_patch
    from hr_addon.core.lights import unit_incident
    from hr_testing.cycles_lights import solve

    sv = solve(kind)
    rs, system, ours, lights, g = sv.rs, sv.system, sv.ours, sv.lights, sv.res
    far = sv.gather.tmax  # shadow rays beyond the scene, as the gather's
    pt = system.patches
    eps = float(system.refiner.eps)
    u = (np.arange(n_sub) + 0.5) / n_sub - 0.5
    offs = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)  # in texel steps
    out = {"kind": kind, "sub_points": n_sub**2, "surfaces": {}}
    for name in rs.objects:
        at = rs.atlases[name]
        cen = np.flatnonzero(at.s_centre)
        patch = ours.samples[name][0][cen]
        nrm = pt.normal[patch]
        rho = pt.reflectance[:, patch].T
        x0 = at.s_point[cen]
        ax = at.s_axes[cen]
        xs = (x0[:, None] + np.einsum("kd,ndj->nkj", offs, ax)).reshape(-1, 3)
        # only the points on the texel's own polygon (a border texel's other points lie off the
        # surface, beyond the box), moved off its edges as the gather's samples are
        pp = np.repeat(patch, len(offs))
        on = (_insideness(pt.corners[pp][:, None], pt.normal[pp][:, None], xs)[:, 0] >= 0).reshape(
            len(cen), -1
        )
        xs = _into_patch(pt, pp, xs, sv.gather.eps * 50)
        centre = np.zeros((len(cen), 3))
        area = np.zeros((len(cen), 3))
        for L in lights.values():
            sc = np.asarray(L.scale, float)[None]
            centre += unit_incident(L, x0, nrm, system.backend, eps, rays=4, far=far)[:, None] * sc
            v = unit_incident(L, xs, np.repeat(nrm, len(offs), 0), system.backend, eps, rays=4, far=far)
            v = (v.reshape(len(cen), -1) * on).sum(1) / np.maximum(on.sum(1), 1)
            area += v[:, None] * sc
        total = np.nanmean(g[name]["gather_refl"], 0)
        d = (rho * (area - centre)).mean(0)
        out["surfaces"][name] = {
            "area_minus_centre_of_surface": round(float(np.mean(d / np.maximum(total, 1e-30))), 4),
            "direct_share": round(float(np.mean((rho * centre).mean(0) / np.maximum(total, 1e-30))), 3),
        }
    print("RESULT " + json.dumps(out), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a = sys.argv[1:]
    main(a[0] if a else "SUN", int(a[1]) if len(a) > 1 else 4)
