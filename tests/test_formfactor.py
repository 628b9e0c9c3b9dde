"""Form factors against the closed forms of tests/closed_forms.py."""

import math

import numpy as np
import pytest

import closed_forms as cf
from hr_addon.core.formfactor import (
    estimate,
    patch_to_patch,
    point_to_polygon,
    polygon_normal_area,
    sample_points,
)

UP = np.array([0.0, 0.0, 1.0])


def quad(*pts):
    return np.array([pts], dtype=np.float64)


def rect_xy(x0, x1, y0, y1, z, facing_up=True):
    """Axis-aligned rectangle in the plane z, normal +z (or -z)."""
    c = [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
    return quad(*(c if facing_up else c[::-1]))


def fan(center, radius, n, facing_up=True):
    """Regular n-gon as n padded triangles (corners (n, 4, 3), nv (n,))."""
    a = np.linspace(0.0, 2 * math.pi, n + 1)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros_like(a)], -1) + center
    c = np.broadcast_to(np.asarray(center, float), (n, 3))
    p, q = (ring[:-1], ring[1:]) if facing_up else (ring[1:], ring[:-1])
    return np.stack([c, p, q, q], axis=1), np.full(n, 3)


# ---------------------------------------------------------------------------------------------------
def test_normal_area_quad_and_padded_triangle():
    c = np.array(
        [
            [[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]],
            [[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 0]],  # padded triangle in x=0, normal -x
            [[1, 1, 1], [1, 1, 1], [1, 1, 1], [1, 1, 1]],
        ],
        float,
    )
    n, a = polygon_normal_area(c, np.array([4, 3, 4]))
    np.testing.assert_allclose(a, [6.0, 0.5, 0.0])
    np.testing.assert_allclose(n, [[0, 0, 1], [-1, 0, 0], [0, 0, 0]], atol=1e-15)


def test_closed_forms_match_the_catalog_and_each_other():
    """The oracles themselves: values tabulated in Howell's catalog, and the unit cube's floor
    seeing exactly its ceiling and four walls."""
    assert cf.point_to_rect_corner(1, 1, 1) == pytest.approx(0.1385, abs=1e-4)
    assert cf.opposed_rects(1, 1, 1) == pytest.approx(0.1998, abs=1e-4)
    assert cf.opposed_rects(2, 1, 1) == pytest.approx(0.2859, abs=1e-4)
    assert cf.perpendicular_rects(1, 1, 1) == pytest.approx(0.2000, abs=1e-4)
    assert cf.opposed_rects(1, 1, 1) + 4 * cf.perpendicular_rects(1, 1, 1) == pytest.approx(1.0, abs=1e-12)
    centre = cf.point_to_parallel_rect(0.5, 0.5, 0, 1, 0, 1, 1)
    assert centre == pytest.approx(4 * cf.point_to_rect_corner(0.5, 0.5, 1))


def test_reference_points():
    sq = rect_xy(0, 1, 0, 1, 1.0, facing_up=False)  # faces the origin
    for p in ([0, 0], [0.5, 0.5], [0.2, 0.7], [1.6, -0.3]):
        assert point_to_polygon([[*p, 0]], UP[None], sq)[0] == pytest.approx(
            cf.point_to_parallel_rect(*p, 0, 1, 0, 1, 1.0), abs=1e-12
        )
    assert point_to_polygon([[0, 0, 0]], UP[None], rect_xy(0, 2, 0, 3, 1.5, False))[0] == pytest.approx(
        cf.point_to_rect_corner(2, 3, 1.5), abs=1e-12
    )


def test_one_sided_and_padding():
    sq = rect_xy(0, 1, 0, 1, 1.0, facing_up=True)  # back faces the origin
    assert point_to_polygon([[0.5, 0.5, 0]], UP[None], sq)[0] == 0.0
    # in the polygon's plane (also outside it): 0, no NaN
    sq = rect_xy(0, 1, 0, 1, 0.0, facing_up=False)
    f = point_to_polygon([[0.5, 0.5, 0], [3, 0.5, 0], [0, 0, 0]], [[0, 0, 1], [-1, 0, 0], [0, 0, -1]], sq)
    np.testing.assert_array_equal(f, 0.0)
    # a quad equals the sum of its two padded triangles, and the wrong 4th corner is ignored for nv == 3
    sq = rect_xy(-0.3, 1.2, -0.4, 0.8, 1.0, facing_up=False)[0]
    tris = np.array([[sq[0], sq[1], sq[2], [9, 9, 9]], [sq[0], sq[2], sq[3], sq[3]]])
    pts = np.array([[0.1, 0.2, 0.0]])
    f_tris = point_to_polygon(pts, UP, tris, np.array([3, 3])).sum()
    assert f_tris == pytest.approx(point_to_polygon(pts, UP, sq[None])[0], abs=1e-14)


def test_coaxial_disc():
    """Differential area on the axis of a disc of radius R at height h: F = R^2 / (R^2 + h^2)."""
    corners, nv = fan([0, 0, 1.0], 1.5, 4096, facing_up=False)
    f = point_to_polygon(np.zeros(3), UP, corners, nv).sum()
    assert f == pytest.approx(cf.point_to_coaxial_disc(1.5, 1.0), rel=1e-5)  # inscribed 4096-gon: ~4e-7 off


@pytest.mark.parametrize("theta_deg", [30, 60, 90, 120, 150])
def test_horizon_clipping_half_plane(theta_deg):
    """Element at height 1 under an (almost) infinite plane, its normal tilted by theta from the
    direction to the plane: F = (1 + cos theta) / 2; for theta > 0 part of the plane is below the horizon."""
    t = math.radians(theta_deg)
    big = 1e6
    plane = rect_xy(-big, big, -big, big, 1.0, facing_up=False)
    f = point_to_polygon(np.zeros(3), [math.sin(t), 0, math.cos(t)], plane)
    assert f[0] == pytest.approx(cf.tilted_under_plane(math.cos(t)), abs=1e-5)


def test_clipped_equals_upper_part():
    """A polygon straddling the horizon gives the same F as its upper part computed separately."""
    n = np.array([1.0, 0.0, 0.0])  # horizon: plane x = 0
    whole = rect_xy(-0.7, 0.9, -0.5, 0.6, 1.0, facing_up=False)
    upper = rect_xy(0.0, 0.9, -0.5, 0.6, 1.0, facing_up=False)
    lower = rect_xy(-0.7, 0.0, -0.5, 0.6, 1.0, facing_up=False)
    fw, fu, fl = (point_to_polygon(np.zeros(3), n, q)[0] for q in (whole, upper, lower))
    assert fw == pytest.approx(fu, abs=1e-14) and fl == 0.0 and fu > 0.05
    # Tilted normal, triangle cut through two edges: clipped F must stay additive, i.e. equal the sum
    # over a fine subdivision (pieces wholly above, wholly below, and a few straddling ones).
    n = np.array([0.3, 0.5, 0.2])
    n /= np.linalg.norm(n)
    a, b, c = np.array([[0, 0, 2], [1.5, -1, 1], [-1, -1, 1]], float)  # faces the origin; b above, c below
    k = 64
    u, v = np.meshgrid(np.arange(k + 1) / k, np.arange(k + 1) / k, indexing="ij")
    g = a + u[..., None] * (b - a) + v[..., None] * (c - a)
    subs = [[g[i, j], g[i + 1, j], g[i, j + 1], g[i, j + 1]] for i in range(k) for j in range(k - i)]
    subs += [
        [g[i + 1, j], g[i + 1, j + 1], g[i, j + 1], g[i, j + 1]] for i in range(k) for j in range(k - i - 1)
    ]
    subs = np.array(subs)
    f_parts = point_to_polygon(np.zeros(3), n, subs, np.full(len(subs), 3))
    assert (f_parts == 0).sum() > 100 and (f_parts > 0).sum() > 100
    f_whole = point_to_polygon(np.zeros(3), n, np.array([[a, b, c, c]]), [3])[0]
    assert f_whole == pytest.approx(f_parts.sum(), abs=1e-12)


def test_range_and_no_nan():
    rng = np.random.default_rng(1)
    m = 20000
    corners = rng.normal(size=(m, 1, 3)) + rng.normal(size=(m, 4, 3)) * 0.3
    corners[:, 3] = corners[:, 2]  # random triangles
    normals = rng.normal(size=(m, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    pts = np.zeros((m, 3))
    pts[: m // 10] = corners[: m // 10, 0]  # point on a vertex
    f = point_to_polygon(pts, normals, corners, np.full(m, 3))
    assert np.all(np.isfinite(f)) and f.min() >= 0.0 and f.max() <= 1.0
    assert np.all(f[: m // 10] == 0.0)
    assert (f > 0).mean() > 0.2


# ---------------------------------------------------------------------------------------------------
def test_sample_points():
    quads = np.array([[[0, 0, 0], [2, 0, 0], [3, 1, 0], [1, 1, 0]]], float)  # parallelogram
    tri = np.array([[[0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 3, 0]]], float)
    for k in (1, 2, 3, 5):
        pq = sample_points(quads, [4], k)[0]
        pt = sample_points(tri, [3], k)[0]
        assert pq.shape == pt.shape == (k * k, 3)
        np.testing.assert_allclose(pq.mean(0), quads[0].mean(0), atol=1e-14)  # equal-area cells
        np.testing.assert_allclose(pt.mean(0), tri[0, :3].mean(0), atol=1e-14)
        assert len(np.unique(np.round(pt, 12), axis=0)) == k * k
        assert np.all(pt[:, 0] + pt[:, 1] < 3) and np.all(pt[:, :2] > 0)  # strictly inside
    # k = 2 triangle: three corner sub-triangles plus the central (inverted) one
    np.testing.assert_allclose(
        np.sort(sample_points(tri, [3], 2)[0][:, :2], axis=0),
        [[0.5, 0.5], [0.5, 0.5], [1.0, 1.0], [2.0, 2.0]],
        atol=1e-14,
    )


def _unit_squares():
    floor = rect_xy(0, 1, 0, 1, 0.0, facing_up=True)
    ceiling = rect_xy(0, 1, 0, 1, 1.0, facing_up=False)
    wall = quad((0, 0, 0), (0, 0, 1), (1, 0, 1), (1, 0, 0))  # plane y = 0, normal +y
    return floor, ceiling, wall


@pytest.mark.parametrize(
    "n_samples, tol_opp, tol_perp",
    [(16, 0.01, 0.005), (36, 0.005, 0.002), (9, 0.02, 0.005), (4, 0.05, 0.011)],
)
def test_patch_to_patch_unit_squares(n_samples, tol_opp, tol_perp):
    floor, ceiling, wall = _unit_squares()
    four = np.array([4])
    opposite, perpendicular = cf.opposed_rects(1, 1, 1), cf.perpendicular_rects(1, 1, 1)
    assert patch_to_patch(floor, four, ceiling, four, n_samples)[0] == pytest.approx(opposite, rel=tol_opp)
    assert patch_to_patch(floor, four, wall, four, n_samples)[0] == pytest.approx(perpendicular, rel=tol_perp)


def test_cube_closure_and_2x1():
    floor, ceiling, wall = _unit_squares()
    walls = [
        wall,
        quad((1, 0, 0), (1, 0, 1), (1, 1, 1), (1, 1, 0)),  # x = 1, normal -x
        quad((1, 1, 0), (1, 1, 1), (0, 1, 1), (0, 1, 0)),  # y = 1, normal -y
        quad((0, 1, 0), (0, 1, 1), (0, 0, 1), (0, 0, 0)),
    ]  # x = 0, normal +x
    q = np.concatenate([ceiling] + walls)
    f = patch_to_patch(np.repeat(floor, 5, 0), np.full(5, 4), q, np.full(5, 4), 256)
    assert f.sum() == pytest.approx(1.0, abs=2e-4)
    assert patch_to_patch(rect_xy(0, 2, 0, 1, 0, True), [4], rect_xy(0, 2, 0, 1, 1, False), [4], 64)[
        0
    ] == pytest.approx(cf.opposed_rects(2, 1, 1), rel=5e-3)


def test_reciprocity_unequal_rectangles_and_triangles():
    p = quad((0, 0, 0), (2, 0, 0), (2, 1, 0), (0, 1, 0))
    q = quad((0.5, 1.5, 0.3), (0.5, 1.5, 1.0), (1.5, 2.0, 1.4), (1.5, 2.0, 0.7))  # tilted parallelogram
    t = np.array([[[0.2, 0.3, 1.0], [0.0, 2.0, 1.5], [1.0, 0.5, 1.2], [1.0, 0.5, 1.2]]])  # tilted triangle
    four, three = np.array([4]), np.array([3])
    for (a, na), (b, nb) in [((p, four), (q, four)), ((p, four), (t, three))]:
        if polygon_normal_area(b, nb)[0][0] @ (a[0].mean(0) - b[0].mean(0)) < 0:
            b = b[:, [0, 2, 1, 3]] if nb[0] == 3 else b[:, ::-1]  # make b face a
        aa, ab = polygon_normal_area(a, na)[1][0], polygon_normal_area(b, nb)[1][0]
        fab = patch_to_patch(a, na, b, nb, 256)[0]
        fba = patch_to_patch(b, nb, a, na, 256)[0]
        assert fab > 0.01
        assert aa * fab == pytest.approx(ab * fba, rel=2e-3)


def test_patch_to_patch_batch_matches_single():
    floor, ceiling, wall = _unit_squares()
    tri = np.array([[[0, 0, 1], [0, 1, 1], [1, 0, 1], [1, 0, 1]]], float)  # faces down
    p = np.concatenate([floor, floor, floor])
    q = np.concatenate([ceiling, wall, tri])
    nvq = np.array([4, 4, 3])
    batch = patch_to_patch(p, np.full(3, 4), q, nvq, 16)
    single = [patch_to_patch(floor, [4], q[i : i + 1], nvq[i : i + 1], 16)[0] for i in range(3)]
    np.testing.assert_allclose(batch, single, rtol=1e-14)
    with pytest.raises(ValueError):
        patch_to_patch(floor, [4], ceiling, [4], 8)


# ---------------------------------------------------------------------------------------------------
def _props(c, nv):
    n, a = polygon_normal_area(c, nv)
    return sample_points(c, nv, 1)[:, 0], n, a


def test_estimate_far_field_and_bounds():
    """Far apart, the disc estimate approaches the exact value; it never exceeds 1 and never is negative."""
    p = rect_xy(0, 0.1, 0, 0.1, 0.0, True)
    q = rect_xy(0, 0.1, 0, 0.1, 5.0, False)
    cp, np_, ap = _props(p, [4])
    cq, nq, aq = _props(q, [4])
    est = estimate(cp, np_, ap, q, cq, nq, aq)[0]
    exact = patch_to_patch(p, [4], q, [4], 16)[0]
    assert est == pytest.approx(exact, rel=0.01)
    # coincident / touching patches: finite and <= 1
    est = estimate(cp, np_, ap, rect_xy(0, 0.1, 0, 0.1, 0.0, False), cp, -np_, ap)
    assert np.all((0 <= est) & (est <= 1))


def test_estimate_conservative_cases():
    floor = rect_xy(0, 1, 0, 1, 0.0, True)
    cp, np_, ap = _props(floor, [4])
    # q entirely behind p: 0
    below = rect_xy(0, 1, 0, 1, -1.0, True)
    cq, nq, aq = _props(below, [4])
    assert estimate(cp, np_, ap, below, cq, nq, aq)[0] == 0.0
    # q's centre below p's horizon but a corner above: cos_p from the corner keeps it > 0
    tilted = quad((1.2, 0, 0.4), (1.2, 1, 0.4), (2.0, 1, -0.8), (2.0, 0, -0.8))  # faces -x (towards p)
    cq, nq, aq = _props(tilted, [4])
    assert nq[0, 0] < 0 and cq[0, 2] < 0
    assert estimate(cp, np_, ap, tilted, cq, nq, aq)[0] > 0.0
    assert patch_to_patch(floor, [4], tilted, [4], 64)[0] > 0.0  # and it is real
    # p's centre behind q's plane but p reaching in front of it: cos_q falls back
    p2 = quad((0, 0, 0.3), (1, 0, 0.3), (1, 0, -0.5), (0, 0, -0.5))  # plane y = 0, normal +y
    q2 = quad((-1, 1, 0), (2, 1, 0), (2, 3, 0), (-1, 3, 0))  # z = 0 facing up
    cp2, np2, ap2 = _props(p2, [4])
    cq2, nq2, aq2 = _props(q2, [4])
    assert (cp2 - cq2)[0] @ nq2[0] < 0
    exact = patch_to_patch(p2, [4], q2, [4], 64)[0]
    with_corners = estimate(cp2, np2, ap2, q2, cq2, nq2, aq2, corners_p=p2)[0]
    without = estimate(cp2, np2, ap2, q2, cq2, nq2, aq2)[0]
    assert exact > 0 and with_corners > 0 and without > 0
    # and the fallback does not fire when p lies wholly behind q
    p3 = p2 - [0, 0, 2.0]
    cp3, np3, ap3 = _props(p3, [4])
    assert estimate(cp3, np3, ap3, q2, cq2, nq2, aq2, corners_p=p3)[0] == 0.0


# -- the component-major forms (session 22, bld25) against the row forms they replaced -------------
def _row_contour(r, n):
    """The row form of formfactor._contour before session 22: np.cross, einsums and a sum over
    the vertices of (N, V, 3) offsets."""
    r_next = np.roll(r, -1, axis=1)
    cr = np.cross(r, r_next)
    cr_len = np.sqrt(np.einsum("nvk,nvk->nv", cr, cr))
    gamma = np.arctan2(cr_len, np.einsum("nvk,nvk->nv", r, r_next))
    ok = cr_len > 0.0
    term = np.where(ok, gamma * np.einsum("nvk,nk->nv", cr, n) / np.where(ok, cr_len, 1.0), 0.0)
    return -term.sum(axis=1) / (2 * math.pi)


def _row_point_to_polygon(p, n, c):
    """point_to_polygon's row form before session 22 (padded corners, all rows at once)."""
    from hr_addon.core.formfactor import _PLANE_EPS, _clip_to_halfspace

    qn, qa = polygon_normal_area(c)
    front = np.einsum("...k,...k->...", p - c[:, 0], qn) > _PLANE_EPS * np.sqrt(qa)
    r = c - p[:, None, :]
    above = np.einsum("...k,...k->...", r, n[:, None, :]) >= 0.0
    every, some = above.all(1), above.any(1)
    f = np.zeros(len(p))
    whole = np.flatnonzero(front & every)
    f[whole] = _row_contour(r[whole], n[whole])
    part = np.flatnonzero(front & some & ~every)
    verts, any_valid = _clip_to_halfspace(c[part], p[part], n[part])
    f[part] = np.where(any_valid, _row_contour(verts - p[part, None, :], n[part]), 0.0)
    return np.clip(f, 0.0, 1.0)


def test_point_to_polygon_by_blocks_is_the_row_form_bit_for_bit():
    """point_to_polygon component major and by blocks (POINT_BLOCK rows): the row form's values
    bit for bit, negative zeros included, over points in front of, beside, behind and on the
    polygons (clipped and whole), padded triangles and repeated corners, more rows than a block."""
    from hr_addon.core import formfactor as ff

    rng = np.random.default_rng(22)
    m = 3 * ff.POINT_BLOCK + 17
    c = rng.standard_normal((m, 4, 3))
    c[:, 3] = c[:, 0] + c[:, 2] - c[:, 1]  # planar parallelograms
    nv = rng.choice([3, 4], m)
    c[nv == 3, 3] = c[nv == 3, 2]
    c[::11, 1] = c[::11, 0]  # a repeated corner: a zero-length edge
    p = rng.standard_normal((m, 3)) * rng.choice([0.01, 1.0, 10.0], (m, 1))
    n = rng.standard_normal((m, 3))
    n /= np.linalg.norm(n, axis=1)[:, None]
    p[::7] = c[::7, 0]  # points on the polygons' planes
    want = _row_point_to_polygon(p, n, c)
    got = point_to_polygon(p, n, c, nv)
    assert got.tobytes() == want.tobytes()
    assert (want > 0).mean() > 0.2 and (want == 0).mean() > 0.1  # not a trivial case
    # the precomputed planes and broadcast leading dimensions take the same path
    qn, qa = polygon_normal_area(c, nv)
    assert point_to_polygon(p, n, c, nv, (qn, qa)).tobytes() == want.tobytes()
    two = point_to_polygon(p[:10, None], n[:10, None], c[None, :5], nv[None, :5])
    for i in range(10):
        assert (
            two[i].tobytes()
            == _row_point_to_polygon(
                np.repeat(p[i : i + 1], 5, 0), np.repeat(n[i : i + 1], 5, 0), c[:5]
            ).tobytes()
        )


def test_sample_points_and_estimate_are_the_row_forms():
    """sample_points (each kind's points on its own polygons) and estimate (component major):
    the values of the forms they replaced (np.where over both kinds; einsum and .max over rows)."""
    from hr_addon.core.formfactor import _unit_cell_params

    rng = np.random.default_rng(23)
    m = 2000
    c = rng.standard_normal((m, 4, 3))
    nv = rng.choice([3, 4], m)
    for k in (1, 2, 6):
        quad_, tri = _unit_cell_params(k)
        u, v = quad_[:, 0][None, :, None], quad_[:, 1][None, :, None]
        c0, c1, c2, c3 = (c[:, i, None, :] for i in range(4))
        pq = (1 - u) * (1 - v) * c0 + u * (1 - v) * c1 + u * v * c2 + (1 - u) * v * c3
        a, b = tri[:, 0][None, :, None], tri[:, 1][None, :, None]
        pt = c0 + a * (c1 - c0) + b * (c2 - c0)
        assert sample_points(c, nv, k).tobytes() == np.where((nv == 3)[:, None, None], pt, pq).tobytes()
    cp, cq = rng.standard_normal((m, 3)), c.mean(1)
    n_p, n_q = rng.standard_normal((2, m, 3)) / math.sqrt(3)
    ap, aq = rng.random(m), rng.random(m)

    def unit(v):
        length = np.sqrt((v[..., 0] ** 2 + v[..., 1] ** 2) + v[..., 2] ** 2)[..., None]
        return v / np.where(length > 0, length, 1.0)

    dot = lambda a, b: np.einsum("...k,...k->...", a, b)
    targets = np.concatenate([c, cq[:, None]], 1)
    cos_p = np.clip(dot(unit(targets - cp[:, None]), n_p[:, None]).max(-1), 0, None)
    d = cp - cq
    cos_q = np.clip(dot(unit(d), n_q), 0, None)
    for corners_p in (None, rng.standard_normal((m, 4, 3))):
        if corners_p is None:
            fb = np.where(dot(d, n_q) > -np.sqrt(ap), 0.05, 0.0)
        else:
            fb = np.clip(dot(unit(corners_p - cq[:, None]), n_q[:, None]).max(-1), 0, None)
        want = np.clip(aq * cos_p * np.where(cos_q > 0, cos_q, fb) / (math.pi * dot(d, d) + aq), 0, 1)
        got = estimate(cp, n_p, ap, c, cq, n_q, aq, corners_p=corners_p)
        np.testing.assert_array_equal(got, want)
        assert (want > 0).any() and (want == 0).any()
