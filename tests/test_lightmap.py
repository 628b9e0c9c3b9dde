"""Lightmaps without Blender (hr_addon/lightmap, core/texels.py, io/images.py structure checks):
per-leaf evaluation, UV charts and packing, rasterisation, dilation, the image sequence of a plan."""

from types import SimpleNamespace

import numpy as np
import pytest

from hr_testing import scenes
from hr_addon.core.output import locate, radiance_at
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.core.texels import TexelLocator, radiance_per_leaf
from hr_addon.io.cache import CacheWriter
from hr_addon.io.images import encode_exr, encode_png16, image_file_problem
from hr_addon.lightmap import TextureError
from hr_addon.lightmap.charts import MARGIN, find_charts, lightmap_size, pack_lightmap
from hr_addon.lightmap.plan import TexturePlan
from hr_addon.lightmap.raster import dilation_steps, rasterise


def texels_in_polygon(uv_poly, res, margin=1e-6):
    """Texel centres strictly inside a convex UV polygon (fan), by brute force over its bounding
    box: x (n,), y (n,), bary (n, 3), tri (n,)."""
    out = []
    for t in range(1, len(uv_poly) - 1):
        a, b, c = uv_poly[0] * res - 0.5, uv_poly[t] * res - 0.5, uv_poly[t + 1] * res - 0.5
        lo = np.floor(np.minimum(np.minimum(a, b), c)).astype(int)
        hi = np.ceil(np.maximum(np.maximum(a, b), c)).astype(int)
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        q = np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
        m = np.array([b - a, c - a]).T
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        l12 = np.linalg.solve(m, (q - a).T).T
        bary = np.column_stack([1 - l12.sum(1), l12])
        ok = (bary > margin).all(1)
        out.append((q[ok, 0].astype(int), q[ok, 1].astype(int), bary[ok], np.full(ok.sum(), t)))
    if not out:
        return [np.zeros(0, int)] * 2 + [np.zeros((0, 3)), np.zeros(0, int)]
    return [np.concatenate(z) for z in zip(*out)]


@pytest.fixture(scope="module")
def cornell():
    s = RadiositySystem(scenes.cornell_box(), RefineParams.preset("draft"))
    s.solve()
    return s


def _surface_points(pt, n, seed=0):
    rng = np.random.default_rng(seed)
    k = rng.integers(0, len(pt.nv), n)
    c = pt.corners[k]
    r = rng.random((n, 2))
    r[r.sum(1) > 1] = 1 - r[r.sum(1) > 1]
    p = c[:, 0] + r[:, :1] * (c[:, 1] - c[:, 0]) + r[:, 1:] * (c[:, 2] - c[:, 0])
    p[::7] = c[::7, 0]  # corners and edges too
    p[1::7] = 0.5 * (c[1::7, 1] + c[1::7, 2])
    return k, p


def test_per_leaf_evaluation_equals_radiance_at(cornell):
    k, p = _surface_points(cornell.patches, 3000)
    h, B = cornell.h, cornell.B
    np.testing.assert_allclose(radiance_per_leaf(h, B, k, p), radiance_at(h, B, k, p), rtol=1e-9, atol=1e-12)
    # TexelLocator: leaves found from representatives (here: the first point of each patch) and,
    # on the next call, from the remembered nodes, are those of a descent from the patch.
    first = np.unique(k, return_index=True)
    loc = TexelLocator(k, p, first[1][np.searchsorted(first[0], k)])
    for _ in range(2):
        np.testing.assert_array_equal(loc.leaves(h), locate(h, k, p))
    np.testing.assert_allclose(
        radiance_per_leaf(h, B, k, p, locator=loc), radiance_at(h, B, k, p), rtol=1e-6, atol=1e-9
    )


def test_packed_sphere_islands_do_not_overlap():
    sph = scenes.sphere()
    res = 64
    uv = pack_lightmap(sph.verts, sph.loop_start, sph.loop_total, sph.loop_verts, res)
    assert uv.min() >= 0 and uv.max() <= 1
    chart, _ = find_charts(sph.verts, sph.loop_start, sph.loop_total, sph.loop_verts)
    assert len(np.unique(chart)) == len(sph.loop_start)  # curved: one chart per polygon
    hits = np.zeros(res * 4 * res * 4, int)
    for s, n in zip(sph.loop_start, sph.loop_total):
        x, y, _, _ = texels_in_polygon(uv[s : s + n], 4 * res)
        hits[y * 4 * res + x] += 1
    assert hits.max() == 1
    with pytest.raises(TextureError, match="do not fit"):
        pack_lightmap(sph.verts, sph.loop_start, sph.loop_total, sph.loop_verts, 8)


def test_flat_grid_is_one_chart_at_one_texel_density():
    n = 5  # a 2 m x 1 m wall of n x n quads, tilted
    u, v = np.meshgrid(np.linspace(0, 2, n + 1), np.linspace(0, 1, n + 1))
    rot = np.array([[1.0, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
    verts = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)]) @ rot.T
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    ls, lt = np.arange(len(quads)) * 4, np.full(len(quads), 4)
    chart, _ = find_charts(verts, ls, lt, quads.ravel())
    assert (chart == 0).all()
    uv = pack_lightmap(verts, ls, lt, quads.ravel(), 64)
    # one isometric projection: UV distances are world distances times one scale, the 2 m side
    # spanning the map but the 2-texel margins on each side
    lv = quads.ravel()
    a, b = np.triu_indices(len(lv), 1)
    w = np.linalg.norm(verts[lv[a]] - verts[lv[b]], axis=1)
    s = np.linalg.norm(uv[a] - uv[b], axis=1)[w > 0] / w[w > 0]
    assert np.ptp(s) < 1e-9 * s.mean()
    assert 2 * s.mean() == pytest.approx((64 - 4) / 64)


def _box(sx, sy, sz):
    co = np.array([[x, y, z] for x in (0, sx) for y in (0, sy) for z in (0, sz)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return co, np.arange(0, 24, 4), np.full(6, 4), np.array(faces).ravel()


@pytest.mark.parametrize("dims", [(0.02, 0.15, 0.22), (0.5, 0.4, 0.3), (3.0, 0.1, 2.5)])
def test_lightmap_size_gives_the_density_at_the_smallest_size(dims):
    """Sized by area: the smallest multiple of 4 (8 at least) whose packing gives the charts the
    texel density with their margins; one step smaller does not fit at that density."""
    box, density = _box(*dims), 50.0
    co, _, _, lv = box
    edge = np.linalg.norm(co[lv[1::4]] - co[lv[::4]], axis=1)  # each face's first edge

    def texels_per_metre(res):  # pack_lightmap's largest scale, found to 1e-4
        uv = pack_lightmap(*box, res)
        return (np.linalg.norm(uv[1::4] - uv[::4], axis=1) * res / edge).min()

    res = lightmap_size(*box, density, lo=8, hi=1024)
    assert res % 4 == 0 and 8 <= res < 1024
    assert texels_per_metre(res) >= density * (1 - 1e-4)
    if res > 8:
        assert texels_per_metre(res - 4) < density


def test_lightmap_size_follows_area_and_stays_in_bounds():
    book, wall = (
        lightmap_size(*_box(0.02, 0.15, 0.22), 50.0),
        lightmap_size(*_box(4.0, 0.1, 2.5), 50.0, hi=4096),
    )
    assert book == 32 and wall > 8 * book  # 2 cm x 15 cm x 22 cm at 2 cm texels: 11 x 8 texels a face
    assert lightmap_size(*_box(0.01, 0.01, 0.01), 50.0) == 16  # six 1 x 1 charts with their margins
    assert lightmap_size(*_box(4.0, 0.1, 2.5), 50.0, hi=128) == 128  # the Texture Size caps it
    tile = np.array([[0, 0, 0], [0.01, 0, 0], [0.01, 0.01, 0], [0, 0.01, 0]], float)
    assert lightmap_size(tile, [0], [4], [0, 1, 2, 3], 50.0) == 8  # one chart: the smallest size
    assert 1 + 2 * MARGIN <= 8


def test_rasterise_matches_brute_force_texel_centres():
    rng = np.random.default_rng(4)
    res = 32
    tri = rng.random((40, 3, 2)) * 0.3 + rng.random((40, 1, 2)) * 0.7
    texel, which, bary, inside = rasterise(tri, res, ring=0)
    assert len(np.unique(texel)) == len(texel)  # each texel once
    centre = np.stack([texel % res, texel // res], 1) + 0.5
    np.testing.assert_allclose(np.einsum("nk,nkj->nj", bary, tri[which] * res), centre, atol=1e-9)
    want = set()
    for t in tri:
        x, y, _, _ = texels_in_polygon(t, res)
        want |= set((y * res + x).tolist())
    got = set(texel[inside].tolist())
    assert want <= got and len(got - want) <= 0.02 * len(got)  # centres on an edge may go either way
    # ring texels: outside the triangles, at most RING texels from the nearest triangle point
    t2, w2, b2, in2 = rasterise(tri, res, ring=1.5)
    assert set(texel.tolist()) <= set(t2.tolist()) and (~in2).any()
    near = np.einsum("nk,nkj->nj", b2[~in2], tri[w2[~in2]] * res)
    c2 = np.stack([t2[~in2] % res, t2[~in2] // res], 1) + 0.5
    assert np.linalg.norm(near - c2, axis=1).max() <= 1.5 + 1e-9


def test_dilation_fills_neighbours_with_their_mean():
    res = 6
    covered = np.array([2 * res + 2, 2 * res + 3])
    img = np.zeros(res * res)
    img[covered] = [1.0, 3.0]
    for dst, inv, src, w in dilation_steps(covered, res, steps=1):
        img[dst] = np.bincount(inv, w * img[src], len(dst))
    img = img.reshape(res, res)
    assert img[2, 1] == 1.0 and img[2, 4] == 3.0 and img[1, 2] == 2.0 and img[3, 3] == 2.0
    assert img[0].sum() == 0 and img[:, 0].sum() == 0  # one step: one ring


@pytest.mark.parametrize("lo, hi", [((4, 5), (11, 9)), ((4.3, 5.6), (10.8, 9.2))])
def test_ring_carries_the_inside_values_line_out(lo, hi):
    """Ring texels hold the inside texels' values carried out along their line, not their own point's
    value: bilinear reads anywhere in an island of a linear quantity give it exactly, though every
    ring point's own value is dark (a contact line; docs/accuracy.md, *Texels along contacts*)."""
    from hr_addon.lightmap.albedo import sample_image

    res = 16
    (x0, y0), (x1, y1) = np.divide(lo, res), np.divide(hi, res)
    quad = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    tri_uv = quad[[[0, 1, 2], [0, 2, 3]]]
    corners = np.concatenate([tri_uv, np.zeros((2, 3, 1))], 2)
    plan = TexturePlan()
    plan.add_object("a", "a", res, tri_uv, corners, np.zeros(2, np.int64), "")
    o = plan.objects[0]
    xy = np.stack([o.texel % res, o.texel // res], 1) + 0.5
    f = lambda p: (1.0 + 0.3 * p[:, :1] - 0.2 * p[:, 1:]) * np.array([1.0, 0.5, 2.0])  # noqa: E731
    values = np.where(o.inside[:, None], f(xy), 0.0)
    assert (~o.inside).sum() > 2 * (hi[0] - lo[0] + hi[1] - lo[1])
    img = o.image(values)
    rng = np.random.default_rng(0)
    uv = np.concatenate([rng.random((400, 2)) * [x1 - x0, y1 - y0] + [x0, y0], quad])
    np.testing.assert_allclose(sample_image(img, uv, extension="EXTEND"), f(uv * res), rtol=1e-5)


def test_image_structure_check(tmp_path):
    img = np.ones((16, 16, 3), np.float32)
    files = {"a.exr": encode_exr(img), "b.exr": encode_exr(img, "NONE"), "c.png": encode_png16(img)}
    for name, data in files.items():
        f = tmp_path / name
        f.write_bytes(data)
        assert image_file_problem(f, 16) == ""
        assert image_file_problem(f, 32) == "is 16 x 16 texels, not 32 x 32"
        f.write_bytes(data[: len(data) - 20])
        assert image_file_problem(f, 16) in ("truncated", "truncated or not an image of a bake"), name
        f.write_bytes(b"hello world, not an image")
        assert image_file_problem(f, 16).startswith("not a")
    assert image_file_problem(tmp_path / "none.exr") == "missing"


def test_plan_texels_lie_on_their_patches_and_fill_the_sequence(tmp_path, cornell):
    """A plan of the Cornell box's back wall (one quad, UVs = its own corners): texel points lie in
    their patch's plane, radiance() is radiance_at there, and the file sequence has one complete
    file per frame number (gaps and the frame before the first filled by links)."""
    pt = cornell.patches
    oid, tri_uv, corners, tri_patch, skipped = scenes.wall_lightmap(cornell, "back")
    assert skipped == 0 and len(tri_uv) == 2 * (pt.object_id == oid).sum()
    plan = TexturePlan("exr")
    plan.add_object("back", "back", 16, tri_uv, corners, tri_patch, "uv")
    loc = plan.locator
    d = np.einsum("ij,ij->i", loc.points - pt.corners[loc.patch, 0], pt.normal[loc.patch])
    assert len(loc.points) > 150 and np.abs(d).max() < 1e-12
    want = radiance_at(cornell.h, cornell.B, loc.patch, loc.points)
    np.testing.assert_allclose(plan.radiance(cornell), want, rtol=1e-5, atol=1e-6)
    w = CacheWriter(
        tmp_path / "cache",
        plan.objects_info([SimpleNamespace(name="back", mesh_name="m")]),
        "TEXTURE",
        plan.signature("s"),
    )
    plan.bind(w.tmp)
    values = plan.radiance(cornell)
    for f in (2, 4):
        plan.write(f, values)
        w.write(f, {})
    plan.finish(w)
    w.commit()
    files = sorted(p.name for p in (tmp_path / "cache" / "textures").iterdir())
    assert files == [f"back_{f:06d}.exr" for f in (1, 2, 3, 4)]
    assert all(image_file_problem(tmp_path / "cache" / "textures" / n, 16) == "" for n in files)
    with pytest.raises(TextureError):
        TexturePlan("tiff")


def test_sample_image_like_an_image_texture():
    """lightmap.albedo.sample_image: pixel centres give the pixels, bilinear between them, REPEAT
    wraps, EXTEND clamps, Closest picks the nearest; texel_uv interpolates loop UVs."""
    from hr_addon.lightmap.albedo import albedo_factor, mix_colour, sample_image, texel_uv

    px = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)  # H 2, W 4
    centres = np.array([[(i + 0.5) / 4, (j + 0.5) / 2] for j in range(2) for i in range(4)])
    np.testing.assert_allclose(sample_image(px, centres), px.reshape(-1, 3))
    mid = np.array([[0.25, 0.25]])  # between pixels (0, 0) and (1, 0)
    np.testing.assert_allclose(sample_image(px, mid), [(px[0, 0] + px[0, 1]) / 2])
    edge = np.array([[0.0, 0.25]])  # between the last and the first column
    np.testing.assert_allclose(sample_image(px, edge), [(px[0, 3] + px[0, 0]) / 2])
    np.testing.assert_allclose(sample_image(px, edge, extension="EXTEND"), [px[0, 0]])
    np.testing.assert_allclose(sample_image(px, [[0.3, 0.3]], "Closest"), [px[0, 1]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    np.testing.assert_allclose(texel_uv(uv, [[0, 1, 2]], [[0.5, 0.25, 0.25]]), [[0.25, 0.25]])
    tex = np.array([[0.2, 0.4, 0.8]])
    np.testing.assert_allclose(mix_colour(tex, ("MULTIPLY", 1.0, (0.5, 0.5, 0.5), True)), [[0.1, 0.2, 0.4]])
    np.testing.assert_allclose(mix_colour(tex, ("MIX", 0.5, (0, 0, 0), False)), [[0.1, 0.2, 0.4]])
    np.testing.assert_allclose(albedo_factor(tex, [0.4, 0.4, 0.0]), [[0.5, 1.0, 1.0]])


def test_radiance_at_memory_is_bounded_and_chunks_change_nothing(monkeypatch):
    """The texture output's smooth interpolation (output.radiance_at, also radiance_per_leaf's
    probes) ran over all points at once and tested every probe against the neighbour table's full
    width, the largest degree (a cylinder cap's fan): 69 kB per point on the furnished 20k room
    at medium, tens of GB for a bake's texels (docs/scale.md). Its peak must not grow with the
    number of points, and the chunks must not change a value."""
    import tracemalloc

    from hr_addon.core import output
    from hr_testing.furnished import Builder, box, cylinder, grid_quad

    b = Builder()
    b.add("floor", *(lambda v, q: (v, [q]))(*grid_quad([-1.0, -1, 0], [2.0, 0, 0], [0, 2.0, 0], 4, 4)), 0.6)
    b.add("vase", *cylinder([0.0, 0, 0], 0.2, 0.5, 48), 0.5)  # 48-triangle fans: degree 47
    b.add("lamp", *box([-0.2, -0.2, 1.5], [0.2, 0.2, 1.6]), 0.0, (5.0, 5.0, 5.0))
    s = RadiositySystem(b.build(), RefineParams.preset("draft"))
    s.solve()
    h, B = s.h, s.B
    assert output.patch_neighbours(h).shape[1] >= 47
    k, p = _surface_points(s.patches, 4000, seed=3)
    whole = radiance_at(h, B, k, p)

    def peak(n):
        tracemalloc.start()
        out = radiance_at(h, B, k[:n], p[:n])
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return out, peak

    monkeypatch.setattr(output, "CHUNK", 250)
    small, p_small = peak(500)
    large, p_large = peak(4000)
    np.testing.assert_array_equal(large, whole)
    np.testing.assert_array_equal(small, whole[:500])
    assert p_large < 1.5 * p_small, (p_small, p_large)  # all at once: ~8x


def _box_plan(dims, density=50.0, hi=1024):
    """A TexturePlan of one box sized by area (charts.lightmap_size at `density`, packed): the
    plan, its surface area, its lightmap size."""
    from hr_addon.lightmap.charts import surface_area

    co, ls, lt, lv = _box(*dims)
    res = lightmap_size(co, ls, lt, lv, density, hi=hi)
    uv = pack_lightmap(co, ls, lt, lv, res)
    tri = (4 * np.arange(6)[:, None, None] + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    plan = TexturePlan("exr")
    plan.add_object("box", "box", res, uv[tri], co[lv[tri]], np.repeat(np.arange(6), 2), "uv")
    return plan, surface_area(co, ls, lt, lv), res


def test_surface_area_of_boxes():
    from hr_addon.lightmap.charts import surface_area

    assert surface_area(*_box(1, 1, 1)) == pytest.approx(6.0)
    assert surface_area(*_box(3.0, 0.1, 2.5)) == pytest.approx(2 * (0.3 + 7.5 + 0.25))


@pytest.mark.parametrize("dims", [(0.02, 0.15, 0.22), (0.5, 0.4, 0.3), (3.0, 0.1, 2.5), (6.0, 0.2, 2.8)])
def test_gathered_estimate_follows_the_texels_a_plan_gathers(dims):
    """plan.gathered_estimate (the surface at the density, times RING_SHARE, at most the image)
    against the texels a plan of a box sized by area gathers (TexturePlan.gathered: inside texels
    and the ring texels not written from them), a book to a wall: within 0.8x-1.3x of them."""
    from hr_addon.lightmap.plan import RING_SHARE, gathered_estimate

    plan, area, res = _box_plan(dims)
    est = gathered_estimate([area], [res], 50.0)[0]
    got = len(plan.gathered)
    print(dims, res, got, est, got / est)
    assert est == pytest.approx(min(RING_SHARE * area * 2500, res * res))
    assert 0.8 * got <= est <= 1.3 * got


def test_gathered_estimate_is_capped_by_the_image():
    from hr_addon.lightmap.plan import gathered_estimate

    est = gathered_estimate([1.0, 100.0, np.nan], [64, 128, 32], 50.0)
    assert est.tolist() == [min(1.25 * 2500, 64 * 64), 128 * 128, 32 * 32]
    assert gathered_estimate([1.0], [64], 0.0).tolist() == [64 * 64]  # density 0: every image


def test_bake_bytes_and_the_density_bound():
    """bake_bytes: fixed + per polygon + per gathered texel (the rays scale the gather's part);
    bounded_density keeps the estimated peak within the budget, lowering the density just as
    much as needed (texels as density^2 while no object is capped), and leaves it alone under it."""
    from hr_addon.lightmap import plan as P

    assert P.bake_bytes(0, 1000) == P.BAKE_FIXED_BYTES + 1000 * P.POLYGON_BYTES
    assert P.bake_bytes(10**6, 0, rays=256) - P.bake_bytes(0) == 2 * P.gather_bytes(10**6)
    areas = np.array([0.05] * 800 + [17.0] * 6)  # books and walls

    def fit(d):  # sizes the density asks, capped at 1024: none is here
        return np.minimum(np.ceil(np.sqrt(areas) * d * 1.3 / 4) * 4, 1024), areas

    asked = P.gathered_estimate(areas, fit(50.0)[0], 50.0).sum()
    need = P.bake_bytes(asked, 20_000)
    d, got, a, total = P.bounded_density(fit, 50.0, need + 1, 20_000)
    assert (d, a, total) == (50.0, asked, asked) and np.array_equal(got[0], fit(50.0)[0])
    budget = P.bake_bytes(asked / 4, 20_000)  # a quarter of the texels: about half the density
    d, got, a, total = P.bounded_density(fit, 50.0, budget, 20_000)
    assert a == asked and P.bake_bytes(total, 20_000) <= budget
    assert 0.95 * 25.0 < d < 25.0
    assert np.array_equal(got[0], fit(d)[0])
    d, _, _, total = P.bounded_density(fit, 50.0, P.bake_bytes(0, 20_000), 20_000, lowest=0.5)
    assert d == 0.5  # no room for any texel: the lowest density
    assert P.bounded_density(fit, 0.0, 1, 20_000)[0] == 0.0  # density 0 is not bound
