"""Issue 19 (branch ind28, docs/gather.md): direct light in a penumbra against its exact value, bpy-free.

    .venv/bin/python benchmarks/penumbra_check.py [--paths 64]

A 1 m square emitter at z = 1 (facing down), a floor at z = 0, a thin plate at z = 0.5 covering
y < 0 (a straight edge along x). A floor point (x, y) sees the emitter's part beyond the plate's
edge projected from it, y' > -y (the emitter clipped by a half-plane): its exact direct light is
point_to_polygon of that clipped square. Compared along a line across the penumbra: the final
gather's direct light (FinalGather.direct_static: exact unoccluded form factor x the share of its
shadow rays unoccluded) and pt_check.Tracer's (area samples on the emitter, each kernel-weighted).
"""

import argparse
import dataclasses
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from hr_addon.core import formfactor as ff  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.geometry import MeshInput  # noqa: E402
from hr_addon.core.params import RefineParams  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from pt_check import Tracer  # noqa: E402


def scene():
    v = np.array(
        [
            [-0.5, -0.5, 1.0],
            [0.5, -0.5, 1.0],
            [0.5, 0.5, 1.0],
            [-0.5, 0.5, 1.0],  # emitter (down)
            [-3, -3, 0.0],
            [3, -3, 0.0],
            [3, 3, 0.0],
            [-3, 3, 0.0],  # floor (up)
            [-3, -3, 0.5],
            [3, -3, 0.5],
            [3, 0.0, 0.5],
            [-3, 0.0, 0.5],  # plate (up; two-sided occluder)
        ]
    )
    polys = [[0, 3, 2, 1], [4, 5, 6, 7], [8, 9, 10, 11]]
    rho = np.array([[0.0] * 3, [0.0] * 3, [0.0] * 3])
    em = np.array([[1.0] * 3, [0.0] * 3, [0.0] * 3])
    return MeshInput.from_polygons(v, polys, rho, em, np.array([0, 1, 2]), ["light", "floor", "plate"])


def exact(pts):
    out = np.empty(len(pts))
    for i, p in enumerate(pts):
        y0 = min(max(-p[1], -0.5), 0.5)  # the plate's edge (y = 0 at z = 0.5) seen from p, on the emitter
        c = np.array([[-0.5, y0, 1.0], [-0.5, 0.5, 1.0], [0.5, 0.5, 1.0], [0.5, y0, 1.0]])
        out[i] = (
            0.0
            if y0 >= 0.5
            else ff.point_to_polygon(p[None], np.array([[0, 0, 1.0]]), c[None], np.array([4]))[0]
        )
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shadow-rays", type=int, default=16)
    a = ap.parse_args()
    s = RadiositySystem(scene(), dataclasses.replace(RefineParams.preset("draft"), contacts=False))
    s.solve()
    ys = np.linspace(-0.6, 0.6, 481)
    pts = np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], 1)
    fl = list(s.patches.object_names).index("floor")
    patch = np.full(len(pts), np.flatnonzero(np.asarray(s.patches.object_id) == fl)[0])
    g = FinalGather(s, pts, np.tile([0, 0, 1.0], (len(pts), 1)), patch, rays=16, shadow_rays=a.shadow_rays)
    D = g.direct_static()[:, 0]
    tr = Tracer(s, light="light", nee=64)
    T = sum(tr.direct(pts, np.tile([0, 0, 1.0], (len(pts), 1))) for _ in range(64))[:, 0] / 64
    X = exact(pts)
    pen = (X > 1e-9) & (X < X.max() * 0.999)
    print(
        f"penumbra points {pen.sum()}: gather / exact - 1 {D[pen].sum() / X[pen].sum() - 1:+.4f}, "
        f"tracer / exact - 1 {T[pen].sum() / X[pen].sum() - 1:+.4f}"
    )
    print(
        f"lit points: gather {D[~pen & (X > 0)].sum() / X[~pen & (X > 0)].sum() - 1:+.4f}, "
        f"tracer {T[~pen & (X > 0)].sum() / X[~pen & (X > 0)].sum() - 1:+.4f}"
    )
    for i in range(0, len(ys), 40):
        print(f"  y {ys[i]:+.2f} exact {X[i]:.4f} gather {D[i]:.4f} tracer {T[i]:.4f}")


if __name__ == "__main__":
    main()
