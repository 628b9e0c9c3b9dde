"""2D clipping and overlap areas: exact area conservation over tilings, agreement with the reference
single-polygon clipper and with a raster estimate."""

import math

import numpy as np
import pytest

from hr_addon.core.clip import classify, clip_convex, overlap_areas, polygon_area_2d


def star(n_points, r_out, r_in, center=(0.0, 0.0), phase=0.0):
    a = phase + np.arange(2 * n_points) * math.pi / n_points
    r = np.where(np.arange(2 * n_points) % 2 == 0, r_out, r_in)
    return np.stack([center[0] + r * np.cos(a), center[1] + r * np.sin(a)], -1)


def rect(cx, cy, w, h, angle=0.0):
    c, s = math.cos(angle), math.sin(angle)
    local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
    return local @ np.array([[c, s], [-s, c]]) + [cx, cy]


L_SHAPE = np.array([[0.1, 0.1], [1.7, 0.1], [1.7, 0.6], [0.6, 0.6], [0.6, 1.8], [0.1, 1.8]]) - 0.6


def quad_grid(lo, hi, n, jitter=0.0, seed=0):
    """n x n convex quads tiling [lo, hi]^2 (interior vertices jittered), with alternating orientation."""
    g = np.linspace(lo, hi, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x, y], -1)
    h = (hi - lo) / n
    v[1:-1, 1:-1] += np.random.default_rng(seed).uniform(-jitter, jitter, v[1:-1, 1:-1].shape) * h
    nodes = np.stack([v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]], 2).reshape(-1, 4, 2)
    nodes[::2] = nodes[::2, ::-1]  # clockwise: must be normalised
    return nodes, np.full(len(nodes), 4)


def tri_grid(lo, hi, n):
    """2 n^2 padded triangles tiling [lo, hi]^2, mixed orientation."""
    q, _ = quad_grid(lo, hi, n)
    t1 = q[:, [0, 1, 2, 2]]
    t2 = q[:, [0, 2, 3, 3]]
    t2[::3] = t2[::3][:, [2, 1, 0, 0]]  # some clockwise
    t2[::3, 3] = t2[::3, 2]
    tris = np.concatenate([t1, t2])
    return tris, np.full(len(tris), 3)


SHAPES = {
    "rotated_rect": [rect(0.1, -0.2, 1.3, 0.7, 0.4)],
    "l_shape": [L_SHAPE],
    "l_shape_cw": [L_SHAPE[::-1]],
    "star": [star(7, 1.1, 0.35, phase=0.1)],
    "star64": [star(32, 1.2, 0.5)],
    "star_with_hole": [star(5, 1.2, 0.5), star(5, 0.3, 0.15, phase=0.3)[::-1]],
    "star_with_same_orientation_hole": [star(5, 1.2, 0.5), rect(0.05, 0.02, 0.3, 0.2, 0.3)],
    "sliver": [np.array([[-1.1, -0.3], [1.2, 0.9], [1.2, 0.9 + 2.6e-4]])],  # aspect ~1e-4
    "tiny": [rect(0.137, 0.1, 1.3e-4 * 0.15, 0.77e-4 * 0.15, 0.3)],  # ~1e-8 node area
    "tiny_on_corner": [rect(0.1, 0.1, 2e-5, 1e-5, 0.2)],  # on a grid vertex
    "covering": [rect(0.0, 0.0, 5.0, 5.0, 0.1)],
}


def shape_area(rings):
    return abs(polygon_area_2d(rings[0])) - sum(abs(polygon_area_2d(r)) for r in rings[1:])


@pytest.mark.parametrize("grid", ["quads", "jittered", "triangles"])
@pytest.mark.parametrize("name", [k for k in SHAPES if k != "covering"])
def test_tiling_conserves_area(name, grid):
    rings = SHAPES[name]
    nodes, nv = {
        "quads": lambda: quad_grid(-1.5, 1.5, 15),
        "jittered": lambda: quad_grid(-1.5, 1.5, 15, jitter=0.3),
        "triangles": lambda: tri_grid(-1.5, 1.5, 15),
    }[grid]()
    ov = overlap_areas(rings, nodes, nv)
    assert ov.min() >= 0
    assert ov.sum() == pytest.approx(shape_area(rings), rel=1e-9)
    assert (ov > 0).sum() >= 1


@pytest.mark.parametrize("grid", ["quads", "triangles"])
def test_covering_shape(grid):
    nodes, nv = quad_grid(-1.5, 1.5, 10) if grid == "quads" else tri_grid(-1.5, 1.5, 10)
    frac, inside, outside = classify(SHAPES["covering"], nodes, nv)
    np.testing.assert_allclose(frac, 1.0, rtol=0, atol=1e-12)
    assert inside.all() and not outside.any()


def test_matches_reference_clipper():
    nodes, nv = tri_grid(-1.5, 1.5, 6)
    qn, _ = quad_grid(-1.5, 1.5, 6, jitter=0.3)
    nodes = np.concatenate([nodes, qn])
    for name in ("l_shape", "star", "star_with_hole", "sliver"):
        rings = SHAPES[name]
        ov = overlap_areas(rings, nodes, np.r_[nv, np.full(len(qn), 4)])
        ref = [
            abs(polygon_area_2d(clip_convex(rings[0], nd)))
            - sum(abs(polygon_area_2d(clip_convex(h, nd))) for h in rings[1:])
            for nd in nodes
        ]
        np.testing.assert_allclose(ov, ref, rtol=1e-12, atol=1e-15)


def test_clip_convex_basics():
    sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    # concave subject: U shape whose two arms poke through the top edge; clipped result has a bridge
    u = np.array(
        [[0.2, 0.2], [0.8, 0.2], [0.8, 1.5], [0.6, 1.5], [0.6, 0.5], [0.4, 0.5], [0.4, 1.5], [0.2, 1.5]]
    )
    out = clip_convex(u, sq[::-1])  # clip given clockwise
    assert polygon_area_2d(out) == pytest.approx(0.6 * 0.3 + 2 * 0.2 * 0.5)
    assert len(clip_convex(sq + 5, sq)) == 0
    assert polygon_area_2d(clip_convex(sq * 0.5 + 0.25, sq)) == pytest.approx(0.25)


def test_outside_and_classify():
    nodes, nv = quad_grid(-1.5, 1.5, 10)
    far = [rect(10, 10, 1, 1)]
    np.testing.assert_array_equal(overlap_areas(far, nodes, nv), 0.0)
    # bounding box overlaps the corner node, shape itself does not
    near = [np.array([[1.45, 1.65], [1.65, 1.45], [1.7, 1.7]])]
    np.testing.assert_array_equal(overlap_areas(near, nodes, nv), 0.0)
    frac, inside, outside = classify([rect(0, 0, 1.2, 1.2)], nodes, nv)  # exactly the central 4 x 4
    assert inside.sum() == 16 and outside.sum() == 84
    # tiny overlaps are neither inside nor outside with the default tolerance
    frac, inside, outside = classify(SHAPES["tiny"], nodes, nv)
    assert frac.max() == pytest.approx(shape_area(SHAPES["tiny"]) / 0.09, rel=1e-9)
    assert frac.max() > 1e-9 and not inside.any()


def raster_overlap(rings, nodes, res=1200):
    """Brute force: fraction of raster cell centres in shape and node (even-odd shape test)."""
    lo, hi = nodes.reshape(-1, 2).min(0), nodes.reshape(-1, 2).max(0)
    gx = lo[0] + (np.arange(res) + 0.5) * (hi[0] - lo[0]) / res
    gy = lo[1] + (np.arange(res) + 0.5) * (hi[1] - lo[1]) / res
    x, y = np.meshgrid(gx, gy, indexing="ij")
    in_shape = np.zeros(x.shape, bool)
    for r in rings:
        for (x0, y0), (x1, y1) in zip(r, np.roll(r, -1, 0)):
            crosses = (y0 > y) != (y1 > y)
            xc = x0 + (y - y0) * (x1 - x0) / np.where(y1 != y0, y1 - y0, 1.0)
            in_shape ^= crosses & (x < xc)
    cell = (hi - lo).prod() / res**2
    out = []
    for nd in nodes:
        if polygon_area_2d(nd) < 0:
            nd = nd[::-1]
        inside = in_shape.copy()
        for a, b in zip(nd, np.roll(nd, -1, 0)):
            e = b - a
            inside &= e[0] * (y - a[1]) - e[1] * (x - a[0]) >= 0
        out.append(inside.sum() * cell)
    return np.array(out)


@pytest.mark.parametrize("name", ["star_with_hole", "l_shape"])
def test_matches_raster(name):
    nodes, nv = quad_grid(-1.5, 1.5, 4, jitter=0.3, seed=3)
    tris, nvt = tri_grid(-1.5, 1.5, 2)
    nodes, nv = np.concatenate([nodes, tris]), np.r_[nv, nvt]
    ov = overlap_areas(SHAPES[name], nodes, nv)
    ref = raster_overlap(SHAPES[name], nodes)
    # raster error ~ boundary length x cell size; generous absolute tolerance
    np.testing.assert_allclose(ov, ref, atol=3e-3)
    assert ov.max() > 0.1


def test_far_from_origin():
    """Conservation holds for tiny and large shapes far from the origin (local origins in shoelace sums)."""
    offset = np.array([3.0e4, -1.7e4])
    nodes, nv = tri_grid(-1.5, 1.5, 15)
    for name in ("tiny", "tiny_on_corner", "star_with_hole"):
        rings = [r + offset for r in SHAPES[name]]
        ov = overlap_areas(rings, nodes + offset, nv)
        assert ov.sum() == pytest.approx(shape_area(rings), rel=1e-9)
