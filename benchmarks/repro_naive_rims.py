"""Reproduction (core only, no bpy, ~15 s): NAIVE darkens the wall between and around light shapes.

Found by benchmarks/cycles_compare.py (docs/accuracy.md, "NAIVE is not a reference"): on the Cornell
sample at medium quality, NAIVE's green wall is 5.5% darker than Cycles (AUTO: 1.3%), because the
strips of wall between the window panes (2 cm mullions) and a rim around them come out nearly black.

events._NaiveState lays each shape over its wall as a new patch, offset 1e-4 x diagonal, and keeps
the wall polygon underneath. The wall's quadtree leaves that straddle a pane outline are partly
hidden behind the light patch, so their visibility (and gathered light) is an average of hidden and
visible parts, and the medium preset does not subdivide them along the outline: a 2 cm strip between
two panes sits entirely in such leaves. In Cycles (and with AR/FE/AUTO) the strip is as bright as
the wall around the window.

Exit status 1 while the defect is present. Suggested fix: in _NaiveState, also split the host
patches along the shape outlines (the slab decomposition already produces the trapezoids of the
plane; pass the uncovered ones as input polygons replacing the host polygon), so that no leaf of
the host surface straddles a light patch; or remove the hidden part of the host surface.
"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from hr_addon.core import scenes  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

# The sample's window (scripts/make_samples.py): 2 x 2 panes of 9 cm, 2 cm bars, on the green wall
# x = 0 (normal +x), centre (y, z) = (0.28, 0.30), emission 8 x (1, 0.95, 0.85).
CY, CZ, P, BAR = 0.28, 0.30, 0.09, 0.02
EM = 8.0 * np.array([1.0, 0.95, 0.85])


def panes():
    out = {}
    for i, dy in enumerate((-(BAR / 2 + P), BAR / 2)):
        for j, dz in enumerate((-(BAR / 2 + P), BAR / 2)):
            y0, z0 = CY + dy, CZ + dz
            ring = np.array([(0, y0, z0), (0, y0 + P, z0), (0, y0 + P, z0 + P), (0, y0, z0 + P)], float)
            out[f"pane{i}{j}"] = LightShape([ring], EM, f"pane{i}{j}")
    return out


def wall_points():
    """Points in the middle of the vertical mullion, and 6-8 cm outside the window (same heights)."""
    z = np.linspace(CZ - P, CZ + P, 9)
    mullion = np.column_stack([np.zeros_like(z), np.full_like(z, CY), z])
    outside = np.column_stack([np.zeros_like(z), np.full_like(z, CY + BAR / 2 + P + 0.07), z])
    return mullion, outside


def reflected(dyn, pts):
    from cycles_ref import _patch_of
    pt = dyn.system.patches
    mesh = dyn.system.mesh
    green = mesh.object_names.index("right_green")
    polys = np.flatnonzero(mesh.object_id == green)
    # the input polygon holding each point (the green wall is a grid of planar quads)
    cand = []
    for p in pts:
        for poly in polys:
            v = mesh.verts[mesh.loop_verts[mesh.loop_start[poly]:mesh.loop_start[poly] + mesh.loop_total[poly]]]
            if v[:, 1].min() - 1e-9 <= p[1] <= v[:, 1].max() + 1e-9 and v[:, 2].min() - 1e-9 <= p[2] <= v[:, 2].max() + 1e-9:
                cand.append(poly)
                break
    patch, _ = _patch_of(pt, np.array(cand), pts)
    B, E = dyn.evaluate(pts, patch)
    return (B - E).mean(1)


def main():
    mesh = scenes.cornell_box(subdiv=8)
    params = RefineParams.preset("medium")
    mullion, outside = wall_points()
    res = {}
    for method in ("AUTO", "NAIVE"):
        dyn = DynamicRadiosity(RadiositySystem(mesh, params), method=method)
        dyn.apply(panes())
        res[method] = (reflected(dyn, mullion), reflected(dyn, outside))
        print(f"{method:5s} reflected radiance in the mullion {res[method][0].mean():.4f}, "
              f"7 cm outside the window {res[method][1].mean():.4f}")
    ratio = res["NAIVE"][0].mean() / res["AUTO"][0].mean()
    print(f"NAIVE / AUTO in the mullion: {ratio:.2f} (Cycles, 1024 spp, sample scene frame 6: 0.106 in the mullion, "
          "0.101 outside)")
    if ratio < 0.8:
        print("FAIL: NAIVE leaves the wall between light shapes dark")
        sys.exit(1)
    print("OK")


if __name__ == "__main__":
    main()
