"""Ray backends: known answers, cross-backend agreement, robustness (hr_addon/core/visibility.py).

Agreement rule (all backends vs the float64 numpy reference): on general rays, including rays starting or
ending exactly on surfaces, backends may disagree only on rays passing within EDGE_TOL (1e-7, scene size 1)
of a triangle edge, and on at most 1e-3 of the rays. Rays built to pass exactly through an edge are a tie
at float64 precision: there only the "near an edge" part of the rule is checked.
"""

import importlib
import sys

import numpy as np
import pytest

from hr_addon.core import visibility as vis
from hr_testing.scenes import box_triangles


def _importable(name):
    try:
        importlib.import_module(name)
        return True
    except ImportError:
        return False


def _require(name):
    """Skip unless the backend's module imports. bpy is imported only here, on demand (outside Blender it is
    what makes `mathutils` importable), so collecting this file does not load Blender."""
    if name == "embree" and not _importable("embreex.rtcore_scene"):
        pytest.skip("embreex not importable")
    if name == "mathutils" and not _importable("mathutils.bvhtree"):
        if not (_importable("bpy") and _importable("mathutils.bvhtree")):
            pytest.skip("mathutils not importable (neither inside Blender nor with the bpy module)")


@pytest.fixture(params=["numpy", "embree", "mathutils"])
def name(request):
    _require(request.param)
    return request.param


@pytest.fixture(params=["embree", "mathutils"])
def float32_name(request):
    _require(request.param)
    return request.param


EDGE_TOL = 1e-7
MAX_DISAGREE = 1e-3


# ---------------------------------------------------------------------------------------------- scenes


def cornell():
    """Closed unit box with two blocks standing on its floor (36 triangles)."""
    return np.array(
        box_triangles([0, 0, 0], [1, 1, 1])
        + box_triangles([0.2, 0.1, 0], [0.5, 0.4, 0.3])
        + box_triangles([0.6, 0.5, 0], [0.9, 0.8, 0.6])
    )


def random_triangles(rng, n, size=0.25):
    c = rng.uniform(0.1, 0.9, (n, 1, 3))
    return c + rng.uniform(-size / 2, size / 2, (n, 3, 3))


def scene(seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate([cornell(), random_triangles(rng, 150)])


def degenerate_triangles():
    p, q = np.array([0.3, 0.3, 0.3]), np.array([0.7, 0.6, 0.5])
    return np.array(
        [
            [p, p, p],
            [p, q, q],
            [p, q, 0.5 * (p + q)],  # point, repeated vertex, collinear
            [p, q, p + 2 * (q - p)],
            [p, q, [np.nan, 0, 0]],
            [p, q, [np.inf, 0, 0]],
        ]
    )


def surface_points(tri, k, rng):
    """Points exactly on (random) triangles, area-weighted."""
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    i = rng.choice(len(tri), k, p=area / area.sum())
    r1, r2 = rng.random((2, k, 1))
    s = np.sqrt(r1)
    return (1 - s) * tri[i, 0] + s * (1 - r2) * tri[i, 1] + s * r2 * tri[i, 2]


def coplanar(tri, a, b, tol=1e-9):
    """Segments lying in the plane of some triangle (an in-plane segment's answer is a tie: excluded)."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    da = np.abs(np.einsum("tk,rtk->rt", n, a[:, None] - tri[None, :, 0]))
    db = np.abs(np.einsum("tk,rtk->rt", n, b[:, None] - tri[None, :, 0]))
    return ((da < tol) & (db < tol)).any(axis=1)


def edge_distance(tri, a, b):
    """Distance from each segment a->b to the nearest triangle edge (closest points of two segments)."""
    p, q = tri.reshape(-1, 3), np.roll(tri, -1, axis=1).reshape(-1, 3)  # edge p -> q
    out = np.empty(len(a))
    for r in range(len(a)):
        d1, d2, w = b[r] - a[r], q - p, a[r] - p
        aa, ee = d1 @ d1, np.einsum("ij,ij->i", d2, d2)
        bb, cc, ff = d2 @ d1, w @ d1, np.einsum("ij,ij->i", d2, w)
        den = aa * ee - bb * bb
        with np.errstate(all="ignore"):
            s = np.where(den > 1e-300, np.clip((bb * ff - cc * ee) / den, 0, 1), 0.0)
            t = np.clip((bb * s + ff) / ee, 0, 1)
            s = np.clip((bb * t - cc) / aa, 0, 1)
        out[r] = np.linalg.norm(a[r] + s[:, None] * d1 - p - t[:, None] * d2, axis=1).min()
    return out


def ray_sets(tri, rng, n=6000):
    """Random segments of several kinds; returns {kind: (a, b)}."""
    inner = lambda k: rng.uniform(0.01, 0.99, (k, 3))  # noqa: E731
    sa, sb = surface_points(tri, n, rng), surface_points(tri, n, rng)
    keep = ~coplanar(tri, sa, sb)
    # through a point of an edge, continuing past it
    t = rng.integers(len(tri), size=n)
    k = rng.integers(3, size=n)
    e = tri[t, k] + rng.random((n, 1)) * (tri[t, (k + 1) % 3] - tri[t, k])
    ea = inner(n)
    # passing 1e-8..1e-6 from such a point: float32 tracers may disagree within ~1 ulp (6e-8) of an edge
    r = rng.normal(size=(n, 3))
    near = e + r / np.linalg.norm(r, axis=1, keepdims=True) * 10 ** rng.uniform(-8, -6, (n, 1))
    na = inner(n)
    return {
        "volume": (inner(n), inner(n)),
        "surface-surface": (sa[keep], sb[keep]),
        "surface-volume": (sa, inner(n)),
        "volume-surface": (inner(n), sb),
        "edge": (ea, ea + rng.uniform(1.0, 2.0, (n, 1)) * (e - ea)),
        "near-edge": (na, na + rng.uniform(1.0, 2.0, (n, 1)) * (near - na)),
    }


# ---------------------------------------------------------------------------------------------- tests


def test_known_answers(name):
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    be = vis.make_backend(tri, name)
    assert be.name == name
    a = np.array([[0.2, 0.2, -1], [0.2, 0.2, -1], [0.2, 0.2, 1], [0.2, 0.2, 0.5], [2, 2, -1], [0.2, 0.2, 1]])
    b = np.array(
        [[0.2, 0.2, 1], [0.2, 0.2, -1e-3], [0.2, 0.2, 3], [0.2, 0.2, -0.5], [2, 2, 1], [0.2, 0.2, 0]]
    )
    # through; stops short; starts beyond; through (from the back side: two-sided); misses; ends on it
    assert be.occluded(a, b).tolist() == [True, False, False, True, False, False]
    # endpoints exactly on the triangle never hit it, in either direction
    on = np.array([[0.3, 0.3, 0.0], [0.1, 0.6, 0.0]])
    assert not be.occluded(on, on[::-1] + [[0, 0, 1], [0, 0, -1]]).any()
    assert not be.occluded(on[:1], on[1:]).any()  # in the plane z = 0 (exact in float32 too)


def test_shapes_zero_length_and_empty(name):
    tri = scene()
    be = vis.make_backend(tri, name)
    rng = np.random.default_rng(1)
    p = surface_points(tri, 50, rng)
    q = rng.random((50, 3))
    assert not be.occluded(p, p).any() and not be.occluded(q, q).any()  # zero length: never occluded
    assert be.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    grid = rng.random((4, 5, 3))
    assert be.occluded(grid, q[0]).shape == (4, 5)  # broadcasting
    assert not vis.make_backend(np.zeros((0, 3, 3)), name).occluded(q, q[::-1]).any()


def test_degenerate_triangles_are_ignored(name):
    tri = scene()
    rng = np.random.default_rng(2)
    a, b = rng.random((3000, 3)), rng.random((3000, 3))
    ref = vis.make_backend(tri, name).occluded(a, b)
    mixed = np.concatenate([degenerate_triangles(), tri, degenerate_triangles()])
    be = vis.make_backend(mixed, name)
    assert len(be.triangles) == len(tri)
    # rays straight through the degenerate ones' point and line
    p, q = degenerate_triangles()[1, :2]
    d = np.array([p, 0.5 * (p + q), q])
    a2 = np.concatenate([a, d - 0.1, d + [0, 0, 0.1]])
    b2 = np.concatenate([b, d + 0.1, d - [0, 0, 0.1]])
    got = be.occluded(a2, b2)
    assert got.dtype == bool and np.array_equal(got[: len(a)], ref)
    assert np.array_equal(got[len(a) :], vis.make_backend(tri, name).occluded(a2[len(a) :], b2[len(a) :]))
    only = vis.make_backend(degenerate_triangles(), name)
    assert len(only.triangles) == 0 and not only.occluded(a2, b2).any()


def test_numpy_grid_matches_brute_force():
    """The grid is only an accelerator: same kernel, so answers must be identical, also for tiny chunks."""
    tri = scene(3)
    rng = np.random.default_rng(3)
    brute = vis.NumpyBackend(tri, grid=False)
    grid = vis.NumpyBackend(tri, grid=True)
    assert grid.grid and not brute.grid
    for kind, (a, b) in ray_sets(tri, rng, 3000).items():
        assert np.array_equal(grid.occluded(a, b), brute.occluded(a, b)), kind
    small = vis.NumpyBackend(tri, grid=True)
    small.CHUNK_RAYS, small.CHUNK_PAIRS, small.CHUNK_ELEMS = 100, 64, 50
    a, b = ray_sets(tri, rng, 2000)["surface-volume"]
    assert np.array_equal(small.occluded(a, b), brute.occluded(a, b))


def test_backends_agree(float32_name):
    name = float32_name
    tri = scene()
    rng = np.random.default_rng(4)
    ref_be, be = vis.make_backend(tri, "numpy"), vis.make_backend(tri, name)
    sets = ray_sets(tri, rng, 2000 if name == "mathutils" else 6000)
    total = bad_total = 0
    for kind, (a, b) in sets.items():
        ref, got = ref_be.occluded(a, b), be.occluded(a, b)
        bad = np.flatnonzero(ref != got)
        if len(bad):  # every disagreement must be an edge graze
            dist = edge_distance(be.triangles, a[bad], b[bad])
            assert dist.max() < EDGE_TOL, (kind, bad[dist >= EDGE_TOL][:5], dist.max())
        if "edge" not in kind:
            total, bad_total = total + len(a), bad_total + len(bad)
    assert bad_total <= MAX_DISAGREE * total, (bad_total, total)


def test_closed_box_blocks_everything_from_outside(name):
    """Every segment from inside the closed box to outside crosses a wall: occluded, never NaN-missed."""
    be = vis.make_backend(cornell(), name)
    rng = np.random.default_rng(5)
    inside = rng.uniform(0.01, 0.99, (3000, 3))
    u = rng.normal(size=(3000, 3))
    outside = 0.5 + u / np.abs(u).max(axis=1, keepdims=True) * rng.uniform(
        0.51, 5, (3000, 1)
    )  # |.|_inf > 0.5
    assert be.occluded(inside, outside).all()
    # and points on the inner faces of the walls see each other unless a block is in the way
    assert be.occluded([[0.35, 0.25, 1.0]], [[0.35, 0.25, 0.0]]).all()  # ceiling -> floor through block 1
    assert not be.occluded([[0.05, 0.95, 1.0]], [[0.05, 0.95, 0.0]]).any()  # ceiling -> floor, clear


def test_visibility_fraction():
    be = vis.make_backend(cornell(), "numpy")
    a = np.array([[0.35, 0.25, 0.99], [0.05, 0.95, 0.99], [0.35, 0.25, 0.31]])[:, None]  # (N, 1, 3)
    # below block 1, clear corner, above block 1, inside block 2
    b = np.array([[0.35, 0.25, 0.01], [0.05, 0.95, 0.01], [0.35, 0.25, 0.5], [0.75, 0.65, 0.01]])[None]
    np.testing.assert_allclose(vis.visibility_fraction(be, a, b), [0.5, 0.5, 0.25])
    with pytest.raises(ValueError):
        vis.visibility_fraction(be, a[:, 0], b[0])


def test_available_and_auto(monkeypatch):
    names = vis.available_backends()
    assert names[0] == ("embree" if _importable("embreex.rtcore_scene") else "numpy") and "numpy" in names
    assert ("mathutils" in names) == _importable("mathutils.bvhtree")
    tri = cornell()
    assert vis.make_backend(tri).name == ("embree" if _importable("embreex.rtcore_scene") else "numpy")
    for mod in ("embreex", "embreex.rtcore_scene", "embreex.mesh_construction"):
        monkeypatch.setitem(sys.modules, mod, None)  # `import embreex...` now raises ImportError
    assert "embree" not in vis.available_backends()
    assert vis.make_backend(tri, "auto").name == "numpy"
    with pytest.raises(ValueError):
        vis.make_backend(tri, "optix")


def test_first_hit_of_every_backend_matches_the_float64_reference(name):
    """first_hit (the final gather's rays): the nearest triangle and its t agree with the numpy
    backend's brute force, and a hit exists exactly where occluded() says the segment is blocked."""
    from hr_testing import scenes
    from hr_addon.core.geometry import prepare_patches

    tri = prepare_patches(scenes.cornell_box(subdiv=2)).triangles
    rng = np.random.default_rng(3)
    o = rng.uniform(0.05, 0.5, (2000, 3))
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ref_p, ref_t = vis.NumpyBackend(tri, grid=False).first_hit(o, d, 3.0)
    be = vis.make_backend(tri, name)
    p, t = be.first_hit(o, d, 3.0)
    assert np.array_equal(p >= 0, be.occluded(o, o + 3.0 * d))
    assert np.mean(p == ref_p) > 1 - MAX_DISAGREE
    hit = (p >= 0) & (ref_p >= 0)
    assert np.allclose(t[hit], ref_t[hit], rtol=1e-9)


def test_first_hit_with_sure_keeps_float32_t_away_from_the_ends(name):
    """first_hit(sure=...) (the final gather's rays): the same rays hit, mostly the same
    triangles, and the t of hits away from both ends is the tracer's float32 (no float64 re-test:
    near float32 precision, not bitwise); hits within `sure` of an end are float64's exactly."""
    from hr_testing import scenes
    from hr_addon.core.geometry import prepare_patches

    tri = prepare_patches(scenes.cornell_box(subdiv=2)).triangles
    rng = np.random.default_rng(5)
    o = rng.uniform(0.05, 0.5, (3000, 3))
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    be = vis.make_backend(tri, name)
    p, t = be.first_hit(o, d, 3.0)
    ps, ts = be.first_hit(o, d, 3.0, sure=0.1)
    assert np.array_equal(p >= 0, ps >= 0)
    assert np.mean(p == ps) > 1 - MAX_DISAGREE
    hit = (p >= 0) & (p == ps)
    near = hit & ((t < 0.3 * 0.99) | (t > 3.0 * 0.91))  # within sure = 0.1 of an end, with margin
    far = hit & (t > 0.3 * 1.01) & (t < 3.0 * 0.89)
    assert near.sum() > 100 and far.sum() > 100
    assert np.array_equal(ts[near], t[near])
    assert np.allclose(ts[far], t[far], rtol=1e-5)
    # the float32 backends take the tracer's t there (numpy's is float64 anyway)
    assert np.array_equal(ts[far], t[far]) == (name == "numpy")


def test_first_hit_per_origin_equals_the_origins_repeated(name):
    """first_hit(per=): rays sharing an origin (a sample's hemisphere rays), each origin given
    once, give bit for bit the hits and t of the origins repeated per ray: every backend, with and
    without `sure`, over threads' chunks (_map_per), with non-finite origins and rays among them,
    and through first_hit_within's second segment (the misses traced on)."""
    from hr_testing import scenes
    from hr_addon.core.geometry import prepare_patches

    tri = prepare_patches(scenes.cornell_box(subdiv=2)).triangles
    rng = np.random.default_rng(7)
    o = rng.uniform(0.05, 0.5, (300, 3))
    per = rng.integers(1, 12, len(o))
    d = rng.normal(size=(int(per.sum()), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for be in (vis.make_backend(tri, name), vis.make_backend(tri, name, threads=2)):
        be.PARALLEL_CHUNK = 256
        for sure in (None, 0.1):
            ref = be.first_hit(np.repeat(o, per, 0), d, 3.0, sure)
            got = be.first_hit(o, d, 3.0, sure, per=per)
            assert all(np.array_equal(x, y) for x, y in zip(ref, got))
            assert 0 < (ref[0] >= 0).sum() < len(d)
        ref = vis.first_hit_within(be, np.repeat(o, per, 0), d, 0.2, 3.0, 1e-4)
        got = vis.first_hit_within(be, o, d, 0.2, 3.0, 1e-4, per=per)
        assert all(np.array_equal(x, y) for x, y in zip(ref, got))
        bad_o, bad_d = o.copy(), d.copy()
        bad_o[3] = np.nan
        bad_d[5] = np.inf
        bad_d[9] = 0.0
        ref = be.first_hit(np.repeat(bad_o, per, 0), bad_d, 3.0)
        got = be.first_hit(bad_o, bad_d, 3.0, per=per)
        assert all(np.array_equal(x, y) for x, y in zip(ref, got))
    assert (got[0][[5, 9]] == -1).all()


def test_first_hit_paths_give_the_same_hits_as_the_plain_ones(name):
    """first_hit's shortcuts (session 38): as many rays per origin (the origins added by
    broadcasting), one tmax for all (a scalar) and every triangle kept (no index map) give bit for
    bit the hits and t of the general paths: per origin as the origins repeated, a scalar tmax as
    an array of it, and a scene with a degenerate triangle in front (its indices mapped back)."""
    from hr_testing import scenes
    from hr_addon.core.geometry import prepare_patches

    tri = prepare_patches(scenes.cornell_box(subdiv=2)).triangles
    rng = np.random.default_rng(9)
    o = rng.uniform(0.05, 0.5, (200, 3))
    d = rng.normal(size=(200 * 8, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    be = vis.make_backend(tri, name)
    flat = np.concatenate([tri[:1, [0, 0, 1]], tri])  # triangle 0 of zero area: dropped, kept ones + 1
    be0 = vis.make_backend(flat, name)
    assert be._identity and not be0._identity
    for sure in (None, 1e-4):
        ref = be.first_hit(np.repeat(o, 8, 0), d, np.full(len(d), 3.0), sure)
        assert 0 < (ref[0] >= 0).sum() < len(d)
        for got in (be.first_hit(o, d, 3.0, sure, per=8), be.first_hit(np.repeat(o, 8, 0), d, 3.0, sure)):
            assert all(np.array_equal(x, y) for x, y in zip(ref, got))
        p0, t0 = be0.first_hit(o, d, 3.0, sure, per=8)
        assert np.array_equal(np.where(p0 >= 0, p0 - 1, -1), ref[0]) and np.array_equal(t0, ref[1])


def test_component_major_occlusion_equals_occluded(name):
    """occluded_cm (the direct light's shadow rays, component-major) gives occluded()'s values
    exactly, zero-length and non-finite segments included."""
    tri = scene()
    be = vis.make_backend(tri, name)
    rng = np.random.default_rng(11)
    for kind, (a, b) in ray_sets(tri, rng, 2000 if name == "mathutils" else 5000).items():
        a, b = np.array(a, float), np.array(b, float)
        b[:3] = a[:3]  # zero length
        a[3, 1] = np.nan
        ref = be.occluded(a, b)
        got = be.occluded_cm(np.ascontiguousarray(a.T), np.ascontiguousarray((b - a).T))
        assert ref.any() and not ref.all(), kind
        assert np.array_equal(got, ref), kind


def test_component_major_occlusion_with_shared_origins(name):
    """occluded_cm(a, d, per) with each origin shared by `per` consecutive segments (the direct
    light's shadow rays: a point's origin once) gives occluded()'s values on the repeated
    origins exactly: every segment live, then with a non-finite origin and zero-length and
    too-short (F32_SHORT) segments among them."""
    tri = scene()
    be = vis.make_backend(tri, name)
    rng = np.random.default_rng(12)
    per = 8
    a = surface_points(tri, 400 if name == "mathutils" else 1000, rng)
    b = rng.uniform(0.01, 0.99, (len(a) * per, 3))
    full = np.repeat(a, per, axis=0)
    ref = be.occluded(full, b)
    got = be.occluded_cm(np.ascontiguousarray(a.T), np.ascontiguousarray((b - full).T), per)
    assert ref.any() and not ref.all()
    assert np.array_equal(got, ref)
    a[5, 1] = np.nan
    b[3 * per] = a[3]  # zero length
    b[7 * per + 2] = a[7] + 1e-7  # shorter than F32_SHORT of its magnitude
    full = np.repeat(a, per, axis=0)
    ref = be.occluded(full, b)
    got = be.occluded_cm(np.ascontiguousarray(a.T), np.ascontiguousarray((b - full).T), per)
    assert not ref[5 * per : 6 * per].any() and not ref[3 * per]
    assert np.array_equal(got, ref)


def test_any_hit_query_answers_as_the_nearest_hit():
    """EmbreeBackend's occlusion query (embreex "OCCLUDED": 0 for a hit, -1 for none) finds a hit
    on exactly the float32 rays where the nearest-hit query finds one, and occluded() through it
    (the middle of a segment by the any-hit query) answers as through the nearest hit alone:
    hits within SURE of an end, genuine or a rounding self-hit of an endpoint on a surface, are
    still decided in float64."""
    _require("embree")
    tri = scene()
    be = vis.make_backend(tri, "embree")
    nearest = vis.make_backend(tri, "embree")
    nearest.any_hit = False  # main's path: one nearest-hit query per segment
    assert be.any_hit
    rng = np.random.default_rng(12)
    o = rng.uniform(-0.6, 0.6, (20000, 3)).astype(np.float32)
    d = rng.normal(size=(20000, 3)).astype(np.float32)
    tfar = rng.uniform(0, 1, 20000).astype(np.float32)
    hit = be._any_hit(o, d, tfar)
    assert hit.any() and not hit.all()
    assert np.array_equal(hit, be._nearest(o, d, tfar.copy())[0] >= 0)
    total = bad_total = 0
    for kind, (a, b) in ray_sets(tri, rng, 5000).items():
        ref, got = nearest.occluded(a, b), be.occluded(a, b)
        bad = np.flatnonzero(ref != got)
        if len(bad):  # a different float32 ray (its origin at SURE): only edge grazes may differ
            assert edge_distance(be.triangles, a[bad], b[bad]).max() < EDGE_TOL, kind
        if "edge" not in kind:  # (rays through an edge are ties, as in test_backends_agree)
            total, bad_total = total + len(a), bad_total + len(bad)
    assert bad_total <= MAX_DISAGREE * total, (bad_total, total)
    # a plate within SURE of either end blocks; segments starting or ending on it do not
    plate = np.array([[[-5.0, -5.0, 0.0], [10.0, -5.0, 0.0], [-5.0, 10.0, 0.0]]])
    both = vis.make_backend(np.concatenate([plate, box_triangles([2, 2, 2], [3, 3, 3])]), "embree")
    x = np.column_stack([rng.uniform(0.1, 0.9, (500, 2)), np.zeros(500)])
    up = np.array([0.0, 0.0, 0.3])
    for a, b, blocked in (
        (x - 0.002 * up, x + up, True),  # the plate at t = 0.002 / 1.002
        (x + up, x - 0.002 * up, True),  # ... at 1 - that
        (x, x + up, False),  # from a point on the plate
        (x + up, x, False),  # to it
    ):
        assert (both.occluded(a, b) == blocked).all()
        assert np.array_equal(both.occluded(a, b), vis.make_backend(both.triangles, "numpy").occluded(a, b))


def test_retrace_by_boxes_equals_the_numpy_grid(float32_name):
    """_retrace (a float32 backend's refuted or short segments): by bounding boxes while few, then
    on the numpy grid, whose answers the boxes give exactly (same float64 kernel, every triangle
    that can meet the segment among the candidates)."""
    tri = scene(7)
    be = vis.make_backend(tri, float32_name)
    ref = vis.NumpyBackend(tri, grid=True)
    rng = np.random.default_rng(7)
    sets = ray_sets(tri, rng, 1500)
    be.BOXED_MAX = sum(len(a) for a, _ in sets.values()) * len(be.triangles)
    for kind, (a, b) in sets.items():
        a, b = np.asarray(a, float), np.asarray(b, float)
        got = be._retrace(a, b - a)
        assert be._exact is None, kind  # the boxes answered
        assert got.any() and not got.all(), kind
        assert np.array_equal(got, ref.occluded(a, b)), kind
    a, b = sets["volume"]
    assert np.array_equal(be._retrace(a, b - a), ref.occluded(a, b))
    assert be._exact is not None and be._exact.grid  # past BOXED_MAX: the grid
