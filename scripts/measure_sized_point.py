"""A sized point / spot light against Cycles on a plane (issue 20, docs/lights.md, session 38): a
diffuse plane at z = 0 under a light of radius r at height h, an orthographic camera looking
straight down (scripts/measure_light_units.py's scene), the rendered incident light E / pi per
watt (pixel / rho / P) against core.lights.unit_incident (nothing occludes: the closed form, a
spot's cone by its shadow rays) averaged over SUB x SUB points of each pixel. Pixels are binned
by r / d and the angle theta between the plane's normal and the direction to the light's centre.
h < r puts a soft-falloff disc across the plane's horizon (grazing theta) and a sphere through it.

Run: .venv/bin/python scripts/measure_sized_point.py [samples [label part]] [--code DIR] (DIR: another
checkout's hr_addon for a before / after pair, default this one). Prints one MEASURE JSON line per
light and bin."""

import json
import math
import os
import sys

import numpy as np

args = sys.argv[1:]
code = None
if "--code" in args:
    i = args.index("--code")
    code = args[i + 1]
    del args[i : i + 2]
sys.path.insert(0, code or os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(1, os.path.dirname(os.path.abspath(__file__)))
import measure_light_units as M  # noqa: E402
from hr_addon.core import lights as lt  # noqa: E402

M.RES = 96
SUB = 4
P = 100.0
# (label, kind, radius, h, soft falloff, spot size deg, spot blend, ortho width)
CASES = [
    ("disc h=2r", "POINT", 0.05, 0.10, True, 0, 0, 0.6),
    ("disc h=r/2", "POINT", 0.05, 0.025, True, 0, 0, 0.6),
    ("disc h=r/10", "POINT", 0.05, 0.005, True, 0, 0, 0.3),
    ("sphere h=2r", "POINT", 0.05, 0.10, False, 0, 0, 0.6),
    ("sphere h=r/2", "POINT", 0.05, 0.025, False, 0, 0, 0.6),
    ("spot disc h=2r", "SPOT", 0.05, 0.10, True, 60, 0.3, 0.3),
    ("spot sphere h=2r", "SPOT", 0.05, 0.10, False, 60, 0.3, 0.3),
    ("spot radius 0", "SPOT", 0.0, 0.10, True, 60, 0.3, 0.3),  # the cone's own profile, for the fringe
]


class _Clear:
    def occluded(self, a, b):
        return np.zeros(np.broadcast_shapes(np.shape(a), np.shape(b))[:-1], bool)


def ours(kind, r, h, soft, size, blend, ortho):
    res = M.RES
    px = ortho / res
    g = (np.arange(res * SUB) + 0.5) / (res * SUB) * ortho - ortho / 2
    X, Y = np.meshgrid(g, g, indexing="xy")  # row = y (bottom first), as M.render's pixels
    x = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    n = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    kw = dict(position=(0, 0, h), radius=r)
    if "soft_falloff" in lt.Light.__dataclass_fields__:
        kw["soft_falloff"] = soft
    if kind == "SPOT":
        kw.update(spot_size=math.radians(size), spot_blend=blend, direction=(0, 0, -1))
    L = lt.Light(kind, (1, 1, 1), 1.0, **kw)
    v = lt.unit_incident(L, x, n, _Clear(), 1e-7, rays=256, keys=np.arange(len(x), dtype=np.uint64))
    v = v.reshape(res, SUB, res, SUB).mean((1, 3))
    c = (np.arange(res) + 0.5) * px - ortho / 2
    cx, cy = np.meshgrid(c, c, indexing="xy")
    return v, np.hypot(cx, cy)


def main(samples, only=""):
    for label, kind, r, h, soft, size, blend, ortho in CASES:
        if only not in label:
            continue
        sc = M.scene(ortho=ortho, samples=samples)
        props = dict(energy=P, shadow_soft_size=r, use_soft_falloff=soft)
        if kind == "SPOT":
            props.update(spot_size=math.radians(size), spot_blend=blend)
        M.light(sc, kind, loc=(0, 0, h), **props)
        img = M.render(sc) / M.RHO / P  # E / pi per watt
        v, s = ours(kind, r, h, soft, size, blend, ortho)
        d = np.hypot(s, h)
        rd, th = r / d, np.degrees(np.arctan2(s, h))
        edges = (
            [0, 20, 45, 70, 80, 85, 88, 90] if kind == "POINT" else [0, 20, 25, 30, 35, 40, 45, 50, 55, 60]
        )
        for a, b in zip(edges[:-1], edges[1:]):
            m = (th >= a) & (th < b) & (v > 0)
            if m.sum() < 8:
                continue
            out = dict(
                light=label,
                theta=[a, b],
                r_over_d=[round(float(rd[m].min()), 3), round(float(rd[m].max()), 3)],
                pixels=int(m.sum()),
                cycles_over_ours=round(float(img[m].sum() / v[m].sum()), 4),
                # the pixels' scatter about the fitted ratio, as the ratio's standard error
                noise=round(
                    float(np.sqrt(((img[m] - img[m].sum() / v[m].sum() * v[m]) ** 2).sum()) / v[m].sum()), 4
                ),
            )
            print("MEASURE " + json.dumps(out), flush=True)


if __name__ == "__main__":
    main(int(args[0]) if args else 256, args[1] if len(args) > 1 else "")
