"""Clutter sunk into clutter and a pillar of thin strips against Cycles (issue 19, "Tests"): two of
the failure modes seen on an unseen furnished room (its clutter 40-45% dark at draft, a 64-segment
pillar 16-19% dark at every quality, before the final gather).

Scene (hr_testing/clutter.py): a closed 4 x 4 x 2.6 m room (1,462 triangles) lit by an emissive
ceiling panel; a table whose top carries a box and a cylinder sunk 2-3 cm into it and into each
other, and a lid sunk into both; a 64-segment pillar (strips 1.5 cm wide) 10 and 15 cm from the
walls of a corner. Cycles bakes the reflected radiance (DIFFUSE, direct + indirect x colour) of the
five objects' texels (2 cm, 15,508 texels), 64 spp, seeds 1 and 2, their mean the reference;
ours: the bake's path (hr_testing.cycles_lights.bake_ours: BakeConfig, FE, the final gather on),
at draft and medium,
- texture output: the texel gather at the texels, every texel (buried ones read 0 on both sides);
- vertex output (the default): the corner gather (LoopGather) interpolated over the loop triangles
  as a render shows it, over the fully visible texels (no sub-sample inside another solid:
  clutter.visible_texels): a buried part is never seen, and a corner value cannot be 0 under the
  table and lit above it.

Target: the issue's, every object's mean within 5%. Measured (2026-12-04, one run, CPU 33 s user +
4 s sys on this machine): texture worst -1.95% draft / -1.12% medium (the sunk cylinder); vertex
worst +3.45% / +3.18% (the pillar: two samples per 2.45 m strip), the sunk box +0.96% / +1.42%.
The reference's noise of an object mean (two seeds) at most 0.32% (the sunk cylinder's visible
texels), the others 0.23% or less. The sunk cylinder's vertex output missed (-6.8% / -6.2%, strict
xfail until branch vfit): a strip's two corner values, interpolated, could not hold the dark bands
along the table and under the lid and the light between. Since the corners' values are shifted so
each face keeps the mean of its gathered light, with samples over the faces cut by another solid
(gather/corner_fit.py): -1.0% / -0.8% (benchmarks/clutter_vs_cycles.py at 256 spp, one run,
2026-12-04). Before LoopGather moved buried corner samples to the visible part of their region
(gather/layouts._uncover), vertex output read the table top -17.2%, the sunk box -21.6% and the
lid -6.8% on their visible texels (benchmarks/clutter_vs_cycles.py, docs/accuracy.md)."""

import os

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy, pytest.mark.cycles, pytest.mark.shared_scene, pytest.mark.slow]

pytest.importorskip("bpy")

SPP = 64
TEXEL = 0.02
TOL = 0.05
NOISE_MAX = 0.015  # the reference's noise of an object mean must stay well below the tolerance


@pytest.fixture(scope="module")
def clutter():
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from hr_testing import clutter as CL, cycles_lights, cycles_ref as C
    from hr_testing.blend import mesh_scene

    mesh, info = CL.clutter_room()
    scene = mesh_scene(mesh)
    rs = C.prepare(scene, texel=TEXEL, only=CL.COMPARED)
    refs = []
    for seed in (1, 2):
        vals, _, mask = C.bake(rs, SPP, seed=seed)
        for n in rs.objects:
            vals[n][~mask[n]] = np.nan  # the pillar's foot on the floor: not baked
        refs.append(vals)
    ours = {q: cycles_lights.bake_ours(rs, q, method="FE", vertex=True)[0] for q in ("DRAFT", "MEDIUM")}
    visible = {n: CL.visible_texels(rs.atlases[n], n, info["solids"]) for n in rs.objects}
    return rs, info, refs, ours, visible


def test_the_clutter_is_sunk_and_the_pillar_stands_near_two_walls(clutter):
    from hr_testing import clutter as CL

    rs, info, refs, _, visible = clutter
    assert sorted(rs.objects) == sorted(info["compared"])
    assert info["pillar_gaps"] == pytest.approx((0.10, 0.15))
    assert info["strip_width"] < 0.015
    for n in ("sunk_box", "sunk_cylinder", "lid", "table_top"):
        at = rs.atlases[n]
        inside = np.bincount(at.s_texel, ~CL.buried(at.s_point, n, info["solids"]), at.n) == 0
        assert inside.any() and visible[n].any() and visible[n].mean() < 0.95, n  # partly buried
        ref = (refs[0][n] + refs[1][n]) / 2
        # texels wholly inside another object are dark in Cycles too
        assert np.nanmean(ref[inside]) < 0.01 * np.nanmean(ref[visible[n]]), n


def _errors(clutter, quality, output, objects):
    from hr_testing import cycles_lights, cycles_ref as C

    rs, _, refs, ours, visible = clutter
    key = "gather_refl" if output == "texture" else "gvertex_total"
    errors, noise = {}, {}
    for n in objects:
        mask = None if output == "texture" else visible[n]
        ref = (refs[0][n] + refs[1][n]) / 2
        m = C.metrics(ours[quality][n][key], ref, mask)
        errors[n] = round(m["bias"], 4)
        sel = slice(None) if mask is None else mask
        noise[n] = cycles_lights._noise_of_mean([refs[0][n][sel], refs[1][n][sel]])
    print(output, quality, errors, {n: round(v, 4) for n, v in noise.items()})
    assert max(noise.values()) < NOISE_MAX, noise
    return errors


@pytest.mark.parametrize("quality", ["DRAFT", "MEDIUM"])
@pytest.mark.parametrize("output", ["texture", "vertex"])
def test_every_object_mean_within_5_percent_of_cycles(clutter, quality, output):
    from hr_testing.clutter import COMPARED

    errors = _errors(clutter, quality, output, COMPARED)
    bad = {n: e for n, e in errors.items() if not abs(e) <= TOL}
    assert not bad, (output, quality, bad, errors)
