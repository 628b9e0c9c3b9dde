"""Cornell box lit by a Blender light in place of its emitter, against Cycles (issue 20):
reflected radiance per surface, our final gather (two levels + 4 iterations, medium solution)
against a Cycles DIFFUSE bake (direct + indirect x colour) of the same texels, 32 spp, two seeds
(benchmarks/cycles_lights.py, docs/lights.md).

Tolerance: the issue's target, every surface within 2%. Measured (this machine, Blender 5.0.1):
area light worst surface 0.37%, point light 0.41%, a uniform World sky through the open front
(WORLD) 0.58%; the reference's own noise of a surface mean (two seeds) at most 0.37% (area),
0.36% (point) and 0.49% (WORLD), so 2% is more than 3 sigma of the reference noise above the
worst error seen. WORLD is checked per channel too (its sky is blue-white).

SPOT (60 W aimed at the back wall: the other surfaces are lit by its bounce) needs a finer
reference: at 32 spp a surface mean's noise is up to 2% (per seed, 16 seeds measured; two
seeds' mean up to 1.4%), and seeds 1 and 2 read 0.6-2.1% above an 8 x 1024-spp reference on the
six bounce-lit surfaces (docs/lights.md). At 1024 spp, seeds 1 and 2: worst surface -1.15% (short
block; worst channel -1.21%), noise of the mean at most 0.20%; against 8 seeds x 1024 spp the
worst is -0.81% (noise 0.12%); -0.30% since the gather integrates a first bounce held by a few
leaves itself (docs/lights.md, branch holesun).

SUN_HOLE (20 W/m^2 through a 0.17 m hole in the ceiling; its bounce lights the room from a small
patch, which the gather integrates itself since branch holesun: before, its rays read the back
wall +2.28% against 8 x 1024 spp, +0.6 to +2.3% at other gather seeds): at 1024 spp, seeds 1 and
2, worst surface +0.83% (tall block; worst channel +0.95%), the reference's noise of a surface
mean at most 0.37%; against 8 seeds x 1024 spp the worst is +0.76% (noise 0.38%)."""

import math
import os

import pytest

pytestmark = [pytest.mark.bpy, pytest.mark.cycles, pytest.mark.slow]

pytest.importorskip("bpy")

TOL = 0.02


@pytest.mark.parametrize(
    "kind, spp", [("AREA", 32), ("POINT", 32), ("WORLD", 32), ("SPOT", 1024), ("SUN_HOLE", 1024)]
)
def test_cornell_lit_by_a_blender_light_agrees_with_cycles(kind, spp):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from hr_testing import cycles_lights

    out = cycles_lights.run(kind, spp=spp, seeds=(1, 2))
    surf = out["surfaces"]
    assert len(surf) == 7
    bad = {n: s["gather"] for n, s in surf.items() if not abs(s["gather"]) <= TOL}
    assert not bad, (kind, bad, surf)
    rgb = {n: s["gather_rgb"] for n, s in surf.items() if not max(map(abs, s["gather_rgb"])) <= TOL}
    assert not rgb, (kind, rgb)
    assert all(math.isfinite(s["ref_noise_of_mean"]) for s in surf.values())


def test_indirect_only_plus_cycles_direct_light_is_full_cycles():
    """Values "Indirect only (for EEVEE)" (core.lights.indirect_incident x rho) added to Cycles'
    DIRECT pass of the same bake is the full Cycles bake (direct + indirect): EEVEE renders the
    direct light, our bake the bounce. Measured (the area light): worst surface 0.36%, worst
    channel 0.51% (benchmarks/out/cycles_lights_indirect.log); target 2% as above."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from hr_testing import cycles_lights

    surf = cycles_lights.run("AREA", spp=32, seeds=(1, 2), indirect=True)["surfaces"]
    bad = {n: s["composite_rgb"] for n, s in surf.items() if not max(map(abs, s["composite_rgb"])) <= TOL}
    assert not bad, bad
