"""Agreement with Cycles on the Cornell box sample (see docs/accuracy.md, benchmarks/cycles_compare.py).

A coarse version of the benchmark: ~32 x 32 texels per wall (texel = 1/56 of the scene diagonal),
Cycles at 32 samples, our solution at the default quality (medium) and method
(AUTO), frames 1 (ceiling light only) and 13 (ceiling light + window + back-wall patch, reached
through frame 6 as the bake does). Reflected radiance at the same texels on both sides.

Tolerances, from measurement with margin (5 Cycles seeds at these settings, see docs/accuracy.md):
- every surface of >= 400 texels: |mean ours - mean Cycles| / mean Cycles <= MRE_TOL (measured
  worst surface 1.5-2.7%: our medium solution is 1-2% darker than Cycles, +-0.5% Cycles noise;
  surfaces below 400 texels, i.e. the light, are left out: too noisy at 32 spp);
- all texels: signed bias of the mean within +-BIAS_TOL (measured -0.9 to -1.6%), texel RMSE
  <= RMSE_TOL x mean radiance (measured 0.154-0.174, mostly Cycles noise at 32 spp: a gross check
  that catches misplaced light, e.g. a shape emitting on the wrong side or a shifted shadow).
A position bake checks that our texel -> surface point map is the one Cycles bakes.
"""

import os

import numpy as np
import pytest

from test_blender_helpers import load_bpy, open_sample

pytestmark = [pytest.mark.bpy, pytest.mark.cycles, pytest.mark.shared_scene, pytest.mark.slow]


SPP = 32
TEXEL_REL = 1 / 56
MIN_TEXELS = 400
MRE_TOL = 0.04
BIAS_TOL = 0.03
RMSE_TOL = 0.22


@pytest.fixture(scope="module")
def comparison(tmp_path_factory):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    bpy = load_bpy()
    from hr_testing import cycles_ref as C
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    open_sample("cornell", tmp_path_factory.mktemp("cycles"))
    rs = C.prepare(bpy.context.scene, texel_rel=TEXEL_REL)
    system = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("medium"))
    dyn = DynamicRadiosity(system, method="AUTO")
    ours = C.Ours(rs, system, dyn)
    out = {}
    for f in (1, 6, 13):
        shapes = C.shape_proxies(rs, f)
        dyn.apply(shapes)
        if f == 6:
            continue
        res = ours.evaluate(shapes, smooth=False)
        ref, seconds, mask = C.bake(rs, SPP, seed=f)
        out[f] = (rs, res, ref, mask, shapes)
    return out


def test_texel_map_matches_cycles_position_bake(comparison):
    """Cycles' Position bake at every texel = the mean of our sub-texel points (within 0.25 texel)."""
    bpy = load_bpy()
    from hr_testing import cycles_ref as C

    rs = comparison[1][0]
    spp = 16
    C.configure_cycles(rs.scene, spp)
    for name in rs.objects:
        C.clear_image(rs.images[name])
    bpy.ops.object.bake(type="POSITION", margin=0, use_clear=False, target="IMAGE_TEXTURES")
    for name in rs.objects:
        at, img = rs.atlases[name], rs.images[name]
        px = np.empty(at.width * at.height * 4, np.float32)
        img.pixels.foreach_get(px)
        p = px.reshape(at.height, at.width, 4)[at.ty, at.tx, :3].astype(float)
        mine = at.texel_mean(at.s_point)
        # Blender 5.0 leaves the Position pass summed over the samples: accept either convention
        scale = float(np.sum(p * mine) / np.sum(mine * mine))
        assert abs(scale - 1) < 0.02 or abs(scale - spp) < 0.02 * spp, scale
        p /= 1.0 if abs(scale - 1) < 0.02 else spp
        d = np.linalg.norm(p - mine, axis=1) / at.texel
        assert np.percentile(d, 99) < 0.25 and d.max() < 0.5, (name, d.max())


@pytest.mark.parametrize("frame", [1, 13])
def test_reflected_radiance_agrees_with_cycles(comparison, frame):
    from hr_testing import cycles_ref as C

    rs, res, ref, mask, shapes = comparison[frame]
    assert len(shapes) == (0 if frame == 1 else 5)
    assert all(m.all() for m in mask.values()), "Cycles left texels of the UV islands unbaked"
    worst = {}
    for n in rs.objects:
        m = C.metrics(res[n]["leaf_refl"], ref[n])
        assert m is not None and np.isfinite(m["rmse"])
        if m["texels"] >= MIN_TEXELS:
            worst[n] = m["mre"]
    assert len(worst) >= 6
    bad = {n: round(e, 4) for n, e in worst.items() if e > MRE_TOL}
    assert not bad, f"surface mean differs from Cycles by more than {MRE_TOL:.0%}: {bad}"
    o = np.concatenate([res[n]["leaf_refl"] for n in rs.objects])
    r = np.concatenate([ref[n] for n in rs.objects])
    allm = C.metrics(o, r)
    assert abs(allm["bias"]) <= BIAS_TOL, allm
    assert allm["rel_rmse"] <= RMSE_TOL, allm


def test_light_shapes_add_light_like_cycles(comparison):
    """Frame 13 minus frame 1: the light of the window and the back patch alone (both sides)."""
    from hr_testing import cycles_ref as C

    rs, r1, c1, _, _ = comparison[1]
    _, r13, c13, _, _ = comparison[13]
    o = np.concatenate([r13[n]["leaf_refl"] - r1[n]["leaf_refl"] for n in rs.objects])
    c = np.concatenate([c13[n] - c1[n] for n in rs.objects])
    m = C.metrics(o, c)
    assert abs(m["bias"]) <= BIAS_TOL, m


def test_texel_samples_lie_where_cycles_bakes_them(tmp_path):
    """Each texel's mean sample in a Cycles Position bake (256 spp, the Cornell back wall: an 8 x 8
    grid of quads, so a third of its texels reach a triangle's edge with their sampled part) is
    the mean of the points core.gather.bakepoints places there (uniform over the middle half of
    the texel inside the centre's triangle; Cycles' first sample is the centre itself). Measured
    (benchmarks/bake_footprint.py): 0.0014 texel apart per axis at 1024 spp, Blender's own offset
    of the bake's pixels (0.001, 0.002 texel) included; the mirror fold of Cycles 3.x was 0.011
    apart (99th percentile 0.061), up to 0.1 texel at the triangles' edges. Here, Blender's
    offset taken out: 99th percentile 0.010, worst 0.017 texel (seed 3; the samples redrawn at a
    triangle's edge are random, 256 of them per texel); asserted 0.02 and 0.04."""
    bpy = load_bpy()
    from hr_addon.core.gather.bakepoints import texel_points
    from hr_testing import cycles_ref as C

    open_sample("cornell", tmp_path)
    rs = C.prepare(bpy.context.scene, texel_rel=TEXEL_REL)
    spp = 256
    C.configure_cycles(rs.scene, spp, seed=3)
    ob = bpy.data.objects["back"]
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob
    at, img = rs.atlases["back"], rs.images["back"]
    C.clear_image(img)
    bpy.ops.object.bake(type="POSITION", margin=0, use_clear=False, target="IMAGE_TEXTURES")
    px = np.empty(at.width * at.height * 4, np.float32)
    img.pixels.foreach_get(px)
    cen = np.flatnonzero(at.s_centre)
    p = px.reshape(at.height, at.width, 4)[at.ty, at.tx, :3].astype(float)[at.s_texel[cen]]
    g = (np.stack(np.meshgrid(np.arange(32), np.arange(32), indexing="ij"), -1).reshape(-1, 2) + 0.5) / 32
    axes = at.s_axes[cen]
    ours = texel_points(at.s_point[cen], axes, at.s_tri[cen], np.broadcast_to(g, (len(cen),) + g.shape))
    ours = (at.s_point[cen] + (spp - 1) * ours.mean(1)) / spp
    p /= 1.0 if abs(np.sum(p * ours) / np.sum(ours * ours) - 1) < 0.02 else spp  # 5.0: summed
    d = p - ours
    off = np.stack([(d * axes[:, i]).sum(1) / (axes[:, i] ** 2).sum(1) for i in (0, 1)], 1)
    e = np.hypot(*(off - np.median(off, 0)).T)  # Blender's pixel offset taken out
    print(f"median offset {np.median(off, 0).round(4)}, p99 {np.percentile(e, 99):.4f}, max {e.max():.4f}")
    assert len(cen) > 900
    assert np.percentile(e, 99) < 0.02 and e.max() < 0.04
