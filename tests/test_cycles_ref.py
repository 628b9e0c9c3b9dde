"""The Cycles comparison's own helpers (hr_testing/cycles_ref.py): error statistics, exact shape
emission, the point -> patch map and the texel atlas. The Cycles agreement tests rest on these, so
each is checked here against something computed another way; no Cycles render."""

import numpy as np
import pytest

from hr_addon.core.events import LightShape
from hr_addon.core.geometry import MeshInput, prepare_patches
from hr_testing import cycles_ref as C
from hr_testing import shapes as S


def test_metrics_of_a_uniform_ten_percent_error_leave_out_masked_and_unbaked_texels():
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 1.0, (50, 3))
    ours = 1.1 * ref
    ours[3] = np.nan  # a texel without a sample on our side
    mask = np.ones(50, bool)
    mask[7] = False  # a texel Cycles did not bake
    ours[7] = 100.0
    m = C.metrics(ours, ref, mask)
    ok = np.ones(50, bool)
    ok[[3, 7]] = False
    assert m["texels"] == 48
    assert m["mre"] == pytest.approx(0.1) and m["bias"] == pytest.approx(0.1)
    d = 0.1 * ref[ok]
    assert m["rmse"] == pytest.approx(np.sqrt(np.mean(d**2)))
    assert m["rel_rmse"] == pytest.approx(m["rmse"] / ref[ok].mean())
    assert m["p95"] == pytest.approx(np.percentile(d.mean(1), 95))
    assert C.metrics(0.9 * ref, ref)["bias"] == pytest.approx(-0.1)  # signed; mre is not
    assert C.metrics(ours, ref, np.zeros(50, bool)) is None


def test_noise_of_two_seeds_is_the_per_bake_standard_deviation():
    """Two bakes x + e1, x + e2 with independent errors of standard deviation s: RMS((a - b) / sqrt 2)
    estimates s; the surface-mean noise is |mean(a - b)| / sqrt 2 relative to the mean."""
    rng = np.random.default_rng(1)
    x = np.full((20000, 3), 0.5)
    a, b = x + rng.normal(0, 0.05, x.shape), x + rng.normal(0, 0.05, x.shape)
    rms, of_mean = C.noise(a, b)
    assert rms == pytest.approx(0.05, rel=0.02)
    want = np.mean(np.abs((a - b).mean(0)) / ((a + b).mean(0) / 2)) / np.sqrt(2)
    assert of_mean == pytest.approx(want)
    b[5] = np.nan  # unbaked texel: left out
    assert np.isfinite(C.noise(a, b)[0])


def test_shape_emission_is_the_window_outline_minus_its_mullions():
    """A window (outer frame minus a cross of mullions, shapes.window) on the Cornell green wall:
    emission at points inside the panes, none on the mullions, outside or off the wall's plane;
    overlapping shapes add."""
    w, h, bar = 0.4, 0.3, 0.04
    rings = S.on_plane(S.window(w, h, bar, centre=(0.25, 0.3)), S.CORNELL_GREEN_WALL)
    em = np.array([1.0, 2.0, 3.0])
    shapes = {"w": LightShape(rings, em, "w")}
    rng = np.random.default_rng(2)
    p2 = rng.uniform(-0.3, 0.3, (4000, 2))
    x, y = np.abs(p2[:, 0]), np.abs(p2[:, 1])
    a, b, c = (w - 2 * bar) / 2, (h - 2 * bar) / 2, bar / 2
    edges = np.array([w / 2, a, c]), np.array([h / 2, b, c])
    clear = (np.abs(x[:, None] - edges[0]).min(1) > 1e-6) & (np.abs(y[:, None] - edges[1]).min(1) > 1e-6)
    p2, x, y = p2[clear], x[clear], y[clear]
    lit = (x < w / 2) & (y < h / 2) & ~(((x < a) & (y < c)) | ((x < c) & (y < b)))
    pts = S.on_plane([p2 + (0.25, 0.3)], S.CORNELL_GREEN_WALL)[0]
    E = C.shape_emission(shapes, pts, diag=1.0)
    assert lit.any() and (~lit).any()
    np.testing.assert_array_equal(E[lit], np.broadcast_to(em, (lit.sum(), 3)))
    assert not E[~lit].any()
    off = pts + [0.01, 0, 0]  # 1 cm in front of the wall: beyond plane_tol x diag = 1 mm
    assert not C.shape_emission(shapes, off, diag=1.0).any()
    two = dict(shapes, v=LightShape(rings, em, "v"))
    np.testing.assert_array_equal(C.shape_emission(two, pts, diag=1.0), 2 * E)


def test_patch_of_finds_the_patch_holding_each_point_of_a_split_polygon():
    """An L-shaped hexagon and a concave 8-corner polygon are split into several patches: each
    point gets the patch (of its own polygon) whose outline holds it, by a containment test of the
    patch corners; a polygon with no patch reports missing."""
    L = [(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)]
    U = [(3, 0, 0), (6, 0, 0), (6, 2, 0), (5, 2, 0), (5, 1, 0), (4, 1, 0), (4, 2, 0), (3, 2, 0)]
    mesh = MeshInput.from_polygons(np.array(L + U, float), [list(range(6)), list(range(6, 14))], 0.5)
    pt = prepare_patches(mesh)
    assert np.bincount(pt.poly).min() > 1  # both are split
    rng = np.random.default_rng(3)
    q = rng.uniform(0, 2, (3000, 2))
    inL = ~((q[:, 0] > 1) & (q[:, 1] > 1))
    qu = rng.uniform(0, 2, (3000, 2)) * [1.5, 1] + [3, 0]
    inU = ~((qu[:, 0] > 4) & (qu[:, 0] < 5) & (qu[:, 1] > 1))
    pts = np.concatenate([q[inL], qu[inU]])
    pts = np.column_stack([pts, np.zeros(len(pts))])
    polys = np.r_[np.zeros(inL.sum(), int), np.ones(inU.sum(), int)]
    patch, missing = C._patch_of(pt, polys, pts)
    assert not missing.any()
    assert (pt.poly[patch] == polys).all()
    c, nv = pt.corners[patch], pt.nv[patch][:, None]
    idx = np.arange(c.shape[1])[None]
    e = np.take_along_axis(c, ((idx + 1) % nv)[:, :, None], 1) - c
    side = np.cross(e, pts[:, None] - c)[:, :, 2]
    assert (side[idx < nv] >= -1e-9).all()  # inside every edge of its (convex, CCW) patch
    _, gone = C._patch_of(pt, np.array([2]), pts[:1])
    assert gone.all()


@pytest.mark.bpy
def test_atlas_of_a_cube_has_one_texel_per_texel_area_and_samples_on_the_surface():
    """A 0.5 m cube (moved and scaled by its object transform) at 5 cm texels: six 10 x 10 charts
    that do not share a texel, 3 x 3 sub-samples per texel, every sample on the world-space cube,
    each texel's mean point within its texel; UVs in the active "HR_Ref" layer, inside [0, 1]."""
    from test_blender_helpers import load_bpy

    bpy = load_bpy()
    v = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    me = bpy.data.meshes.new("cube")
    me.from_pydata(v, [], f)
    ob = bpy.data.objects.new("cube", me)
    bpy.context.scene.collection.objects.link(ob)
    ob.location, ob.scale = (2.0, -1.0, 0.5), (0.5, 0.5, 0.5)
    bpy.context.view_layer.update()
    at = C.Atlas.build(ob, texel=0.05, k=3)
    assert at.n == 600 and len(at.s_texel) == 600 * 9 and at.s_centre.sum() == 600
    assert len(set(zip(at.tx, at.ty))) == 600 and at.area == pytest.approx(1.5)
    lo, hi = np.array([2.0, -1.0, 0.5]), np.array([2.5, -0.5, 1.0])
    p = at.s_point
    assert ((p >= lo - 1e-9) & (p <= hi + 1e-9)).all()
    on_face = np.minimum(np.abs(p - lo), np.abs(p - hi)).min(1)
    assert on_face.max() < 1e-9
    centre = at.texel_mean(p)
    assert np.abs(at.s_point - centre[at.s_texel]).max() <= at.texel / 2 + 1e-9
    layer = me.uv_layers.active
    assert layer.name == C.UV_NAME and layer.active_render
    uv = np.empty(len(me.loops) * 2, np.float32)
    layer.data.foreach_get("uv", uv)
    assert uv.min() >= 0 and uv.max() <= 1
    np.testing.assert_allclose(at.texel_mean(np.ones((len(p), 3))), 1.0)
    # the texels' sides on the surface (the final gather's texel area): two perpendicular texel
    # lengths in the face's plane, the steps between the sub-samples of a texel (k = 3)
    ax = at.s_axes
    np.testing.assert_allclose(np.linalg.norm(ax, axis=2), at.texel, rtol=1e-9)
    assert np.abs(np.einsum("sj,sj->s", ax[:, 0], ax[:, 1])).max() < 1e-12
    c = np.flatnonzero(at.s_centre)
    off = p - p[c][np.searchsorted(at.s_texel[c], at.s_texel)]
    coef = np.einsum("sj,skj->sk", off, ax[c][np.searchsorted(at.s_texel[c], at.s_texel)]) / at.texel**2
    np.testing.assert_allclose(np.sort(np.unique(np.round(coef * 3, 6))), [-1, 0, 1], atol=1e-6)


@pytest.mark.bpy
@pytest.mark.cycles
def test_tiny_cycles_bake_of_parallel_plates_matches_the_closed_form():
    """The whole reference pipeline (prepare: atlases, images, one-sided reference materials; bake;
    texel read-back) on the parallel-plates oracle: a grey 1 x 1 m receiver (reflectance 0.5) under
    a black emitter (radiance 1) 0.5 m above, facing it. The receiver's reflected radiance is
    0.5 x F(point -> emitter) exactly (nothing else lights it); the black emitter reflects nothing.
    At 16 samples a texel is noisy; the mean over the 400 texels is within 3% of the closed form
    averaged over the same sub-samples, and so is the centre's light relative to the rim's."""
    import os

    from test_blender_helpers import empty_scene
    from tests import closed_forms as cf

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    bpy, ms, scene = empty_scene()
    quad = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    ms.mesh_object("receiver", quad, [[0, 1, 2, 3]], ms.diffuse("grey", (0.5, 0.5, 0.5)))
    ms.mesh_object(
        "emitter", [(x, y, 0.5) for x, y, _ in quad], [[3, 2, 1, 0]], ms.emission("em", (1, 1, 1), 1)
    )
    rs = C.prepare(scene, texel=0.05)
    assert sorted(rs.objects) == ["emitter", "receiver"] and rs.atlases["receiver"].n == 400
    ref, _, mask = C.bake(rs, samples=16, seed=1)
    assert all(m.all() for m in mask.values())
    assert np.abs(ref["emitter"]).max() < 1e-6
    at = rs.atlases["receiver"]
    F = np.array([cf.point_to_parallel_rect(x, y, 0, 1, 0, 1, 0.5) for x, y, _ in at.s_point])
    want = at.texel_mean(0.5 * F[:, None].repeat(3, 1))
    got = ref["receiver"]
    assert got.mean() == pytest.approx(want.mean(), rel=0.03)
    centre = (np.abs(at.texel_mean(at.s_point)[:, :2] - 0.5) < 0.25).all(1)
    ratio, exact = got[centre].mean() / got[~centre].mean(), want[centre].mean() / want[~centre].mean()
    print(f"mean {got.mean() / want.mean() - 1:+.4f}, centre / rim {ratio:.4f} (exact {exact:.4f})")
    assert ratio == pytest.approx(exact, rel=0.03)


def test_objects_baked_together_share_their_texels_random_numbers_unless_seeded_per_object():
    """Cycles draws a texel's samples from its pixel (x, y) and the seed, and each object bakes into
    its own image: two identical plate pairs (a grey receiver under a black emitter, as above) 100 m
    apart bake nearly the same noise texel for texel when baked together (a mean over both is hardly
    better than over one); with seed_per_object their errors (against the closed form) are
    independent."""
    import os

    from test_blender_helpers import empty_scene
    from tests import closed_forms as cf

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    bpy, ms, scene = empty_scene()
    quad = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], float)
    grey = ms.diffuse("grey", (0.5, 0.5, 0.5))
    for k, dx in enumerate((0.0, 100.0)):
        ms.mesh_object(f"receiver{k}", quad + (dx, 0, 0), [[0, 1, 2, 3]], grey)
        ms.mesh_object(
            f"emitter{k}", quad + (dx, 0, 0.5), [[3, 2, 1, 0]], ms.emission(f"em{k}", (1, 1, 1), 1)
        )
    rs = C.prepare(scene, texel=0.05, only=["receiver0", "receiver1"])
    at = rs.atlases["receiver0"]
    F = np.array([cf.point_to_parallel_rect(x, y, 0, 1, 0, 1, 0.5) for x, y, _ in at.s_point])
    exact = at.texel_mean(0.5 * F[:, None].repeat(3, 1)).mean(1)
    for per_object in (False, True):
        ref, _, _ = C.bake(rs, samples=4, seed=1, seed_per_object=per_object)
        e0, e1 = (ref[f"receiver{k}"].mean(1) / exact - 1 for k in (0, 1))
        corr = np.corrcoef(e0, e1)[0, 1]
        print(f"per_object {per_object}: texel noise {e0.std():.3f}, {e1.std():.3f}; correlation {corr:.3f}")
        assert min(e0.std(), e1.std()) > 0.02  # noisy at 4 samples
        # shared: 0.86 measured (not 1: the light tree picks an emitter for each pair); independent:
        # 400 texels give |corr| about 0.05
        assert corr > 0.7 if not per_object else abs(corr) < 0.2


def _bakes(rng, truth, sigma, spp, seeds):
    """Per-object means of `seeds` Cycles-like bakes at `spp` samples: unbiased, each object's
    relative noise sigma / sqrt(spp), independent per object and channel (a seed per object)."""
    return [
        {
            n: t * (1 + s / np.sqrt(spp) * rng.standard_normal(t.shape))
            for (n, t), s in zip(truth.items(), sigma)
        }
        for _ in range(seeds)
    ]


def _median_error(x, ref, names):
    return C.object_summary({n: C.metrics(x[n], ref[n]) for n in names}, names)["median"]


def test_the_sample_count_at_an_error_is_found_through_a_noisy_reference():
    """The furnished room's equal-error count (benchmarks/cycles_compare.py equal_object_error):
    Cycles' per-object median error at one sample from the reference's two seeds, a 16-spp bake
    read against that 2 x 128-spp reference gives back 16 samples. 8000 objects of one texel (its
    value the object's mean) with relative noise spread 5-30%: the medians' own spread is ~2%, the
    sample count's (a squared ratio of two medians) ~5%."""
    rng = np.random.default_rng(7)
    names = [f"o{i}" for i in range(8000)]
    truth = dict(zip(names, rng.uniform(0.1, 1.0, (len(names), 1, 3))))
    sigma = rng.uniform(0.05, 0.3, len(names))
    a, b = _bakes(rng, truth, sigma, 128, 2)
    ref = {n: (a[n] + b[n]) / 2 for n in names}
    ref_noise = np.median([C.noise(a[n], b[n])[1] / np.sqrt(2) for n in names])
    scale = C.noise_scale(ref_noise, 256)
    (one,) = _bakes(rng, truth, sigma, 1, 1)
    assert scale == pytest.approx(_median_error(one, truth, names), rel=0.05)
    (x16,) = _bakes(rng, truth, sigma, 16, 1)
    err = _median_error(x16, ref, names)
    # read against the reference, the bake holds its noise too: 16 samples; that noise counted as
    # the bake's own error, 16 / (1 + 16 / 256) = 15.1
    assert C.spp_at_error(err, scale, 256) == pytest.approx(16, rel=0.12)
    assert C.spp_at_error(err, scale) == pytest.approx(16 / (1 + 16 / 256), rel=0.12)
    assert C.noise_scale(err, 16, 256) == pytest.approx(scale, rel=0.06)
    # an error within the reference's own noise matches no sample count
    assert C.spp_at_error(0.9 * ref_noise, scale, 256) == float("inf")


def test_lit_objects_leave_out_those_darker_than_a_twentieth_of_the_mean_and_unbaked_texels():
    ref = {
        "wall": np.full((10, 3), 1.0),
        "book": np.full((4, 3), 0.2),
        "dark": np.full((4, 3), 0.02),
        "unbaked": np.full((2, 3), np.nan),
    }
    ref["book"][0] = np.nan  # a texel the bake did not write
    # mean over the baked texels (10 x 1.0 + 3 x 0.2 + 4 x 0.02) / 17 = 0.628: the bar 0.031
    assert C.lit_objects(ref) == ["book", "wall"]


@pytest.mark.bpy
def test_a_light_shape_keyed_flat_gets_no_proxy_face_and_no_nan_vertex():
    """The loft's skylight (hr_testing/loft.py): a light shape whose blind is closed at frame 1 (scale
    0 along one side, no area) and open at frame 3. The reference's proxies left its polygon in at
    frame 1 with a NaN normal (_surface_front) and NaN vertices for Cycles to render; now it is off
    on that frame, as the bake reads it, and the proxy of frame 3 is the open shape."""
    from test_blender_helpers import empty_scene

    bpy, ms, scene = empty_scene()
    quad = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    ms.mesh_object("floor", quad, [[0, 1, 2, 3]], ms.diffuse("grey", (0.5, 0.5, 0.5)))
    sky = ms.mesh_object(
        "sky",
        [(0.25, 0.25, 0), (0.75, 0.25, 0), (0.75, 0.75, 0), (0.25, 0.75, 0)],
        [[0, 1, 2, 3]],
        ms.emission("em", (1, 1, 1), 5),
    )
    sky.hr.is_light_shape = True
    sky.scale = (1, 0, 1)
    sky.keyframe_insert("scale", frame=1)
    sky.scale = (1, 1, 1)
    sky.keyframe_insert("scale", frame=3)
    scene.frame_start, scene.frame_end = 1, 3
    rs = C.prepare(scene, only=())
    assert C.shape_proxies(rs, 1) == {}
    (proxy,) = rs.proxies
    co = np.array([v.co for v in proxy.data.vertices]).reshape(-1, 3)
    assert np.isfinite(co).all() and len(proxy.data.polygons) == 0
    shapes = C.shape_proxies(rs, 3)
    (proxy,) = rs.proxies
    co = np.array([v.co for v in proxy.data.vertices])
    assert len(shapes) == 1 and len(proxy.data.polygons) == 1 and np.isfinite(co).all()
