"""Slot texels next to a mouth: ours against a path tracer, light split by kind (issue 19,
docs/gather.md "The mouth's own light"). Two boxes 2 mm apart on a floor, a lamp panel above at a
slant, a grey room: points on box a's side in the slot at depths d gap widths below the top.

    .venv/bin/python benchmarks/slot_mouth_light.py [paths=20000] [kw=dict(...)]
"""

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "tests"))

from test_gather_texels import _path_traced, _slot_under_a_lamp  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

opt = dict(paths=20000, kw="dict()", lamp=0.3)
opt.update(a.split("=", 1) for a in sys.argv[1:])
W = 0.002


def scene(lx):
    return _slot_under_a_lamp(lx, W)


m = scene(float(opt["lamp"]))
s = RadiositySystem(m, RefineParams.preset("draft"))
pt = s.patches
names = np.array(pt.object_names)[pt.object_id]
side = np.flatnonzero((names == "a") & (pt.normal[:, 0] > 0.5))[0]
fside = np.flatnonzero((names == "b") & (pt.normal[:, 0] < -0.5))[0]
dep = np.array([0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 15.0])
P = np.column_stack([np.full(len(dep), -W / 2), np.zeros(len(dep)), 0.2 - W * dep])
F = P + [W, 0, 0]  # the facing points on b's side
nx = np.array([1.0, 0, 0])
k = int(opt["paths"])
rng = np.random.default_rng(1)


def trace(pts, n, **kw):
    return _path_traced(m, np.repeat(pts, k, 0), n, rng, **kw).reshape(len(pts), k).mean(1)


def inner(name, q):  # the facing side inside the slot
    return (name == "b") & (q[:, 2] < 0.2) & (q[:, 0] < W)


full, direct = trace(P, nx), trace(P, nx, bounces=1)
seen = trace(P, nx, drop_first=inner)  # paths whose first hit is not b's side in the slot
fdirect, ffull = trace(F, -nx, bounces=1), trace(F, -nx)
kw = dict(rays=128, shadow_rays=16, levels=2, iterations=4)
kw.update(eval(opt["kw"]))
t0 = time.process_time()
g = FinalGather(s, P, np.repeat(nx[None], len(P), 0), np.full(len(P), side), **kw)
cpu = time.process_time() - t0
inc = g.evaluate(s, "incident")[:, 0]
D = g.direct_and_emission(s)[0][:, 0]
gain = np.ones(len(P)) if g.gain is None else g.gain[:, 0]
print(f"lamp x {opt['lamp']}, {k} paths a point, gather {kw} ({cpu:.1f} s CPU)")
print("depth/h  paths: full direct via-mouth | facing: direct full | ours: total gain D/gain D | ours/paths")
for i, d in enumerate(dep):
    print(
        f"{d:5.1f}  {full[i]:8.4f} {direct[i]:7.4f} {seen[i]:8.4f} | {fdirect[i]:7.4f} {ffull[i]:7.4f} |"
        f" {inc[i]:8.4f} {gain[i]:5.2f} {D[i]:7.4f} {gain[i] * D[i]:7.4f} | {inc[i] / full[i]:5.3f}"
    )
