"""Shared geometry helpers (hr_addon/core/geometry.py): Newell normals and connected components."""

import numpy as np

from hr_addon.core.geometry import components, loop_tables, newell, polygon_newell


def _union_find(n, pairs):
    """Plain union-find, the textbook loop: component of each item as its smallest member."""
    parent = list(range(n))

    def find(x):
        while parent[x] != x:
            x = parent[x]
        return x

    for a, b in pairs:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.array([find(x) for x in range(n)])


def test_components_match_union_find():
    rng = np.random.default_rng(1)
    for n, m in ((1, 0), (10, 3), (500, 200), (2000, 1990)):
        i, j = rng.integers(0, n, m), rng.integers(0, n, m)
        np.testing.assert_array_equal(components(n, i, j), _union_find(n, zip(i, j)))
    # a chain of 20,000 items in scrambled order is one component
    perm = rng.permutation(20_000)
    assert (components(20_000, perm[:-1], perm[1:]) == 0).all()


def test_newell_is_twice_the_area_along_the_normal():
    # a regular hexagon of circumradius r has area 3 sqrt(3) / 2 r^2
    r, t = 0.7, np.arange(6) * np.pi / 3
    hexagon = np.column_stack([r * np.cos(t), r * np.sin(t), np.zeros(6)])
    rot = np.linalg.qr(np.random.default_rng(2).normal(size=(3, 3)))[0]
    rot *= np.sign(np.linalg.det(rot))
    p = hexagon @ rot.T + [100.0, -50.0, 3.0]  # anywhere, any orientation
    n = newell(p)
    np.testing.assert_allclose(np.linalg.norm(n), 3 * np.sqrt(3) * r * r, rtol=1e-12)
    np.testing.assert_allclose(n / np.linalg.norm(n), rot[:, 2], atol=1e-12)
    # the ragged (Blender-layout) form agrees with the padded one; a clockwise ring flips it
    verts = np.concatenate([p, p[::-1][:3]])
    ls, lt = np.array([0, 6]), np.array([6, 3])
    got = polygon_newell(verts, ls, lt, np.arange(9))
    np.testing.assert_allclose(got[0], n, rtol=1e-12)
    np.testing.assert_allclose(got[1], -newell(p[[3, 4, 5]]), atol=1e-12)
    assert got[1] @ n < 0
    lp, nxt = loop_tables(ls, lt)
    np.testing.assert_array_equal(lp, [0] * 6 + [1] * 3)
    np.testing.assert_array_equal(nxt, [1, 2, 3, 4, 5, 0, 7, 8, 6])
