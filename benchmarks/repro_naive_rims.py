"""Check (core only, no bpy, ~15 s): NAIVE must not darken the wall between and around light shapes.

Found by benchmarks/cycles_compare.py (docs/accuracy.md): on the Cornell sample at medium quality,
NAIVE's green wall was 5.5% darker than Cycles (AUTO: 1.3%), because the strips of wall between the
window panes (2 cm mullions) came out nearly black: events._NaiveState laid each shape over its wall
as a patch (offset 1e-4 x diagonal) and kept the wall polygon underneath, whose leaves straddling a
pane outline averaged hidden and visible parts. Fixed in c8dfb47 (NAIVE splits the host walls along
the shape outlines). Exit status 1 if the mullion is darker than 0.8 x AUTO's again (Cycles: the
mullion is as bright as AUTO's, 0.106 against 0.105).
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from benchmarks import scenes  # noqa: E402
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
            v = mesh.verts[
                mesh.loop_verts[mesh.loop_start[poly] : mesh.loop_start[poly] + mesh.loop_total[poly]]
            ]
            if (
                v[:, 1].min() - 1e-9 <= p[1] <= v[:, 1].max() + 1e-9
                and v[:, 2].min() - 1e-9 <= p[2] <= v[:, 2].max() + 1e-9
            ):
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
        print(
            f"{method:5s} reflected radiance in the mullion {res[method][0].mean():.4f}, "
            f"7 cm outside the window {res[method][1].mean():.4f}"
        )
    ratio = res["NAIVE"][0].mean() / res["AUTO"][0].mean()
    print(
        f"NAIVE / AUTO in the mullion: {ratio:.2f} (Cycles, 1024 spp, sample scene frame 6: 0.106 in the mullion, "
        "0.101 outside)"
    )
    if ratio < 0.8:
        print("FAIL: NAIVE leaves the wall between light shapes dark")
        sys.exit(1)
    print("OK")


if __name__ == "__main__":
    main()
