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


def _quads(quads, oids, names):
    """MeshInput of quads (Q, 4, 3) with one object id each."""
    from hr_addon.core.geometry import MeshInput

    q = np.asarray(quads, float)
    n = len(q)
    return MeshInput(
        verts=q.reshape(-1, 3),
        loop_start=np.arange(n) * 4,
        loop_total=np.full(n, 4),
        loop_verts=np.arange(4 * n),
        reflectance=np.full((n, 3), 0.5),
        emission=np.zeros((n, 3)),
        object_id=np.asarray(oids),
        object_names=names,
    )


def test_duplicated_faces_are_named_back_to_back_faces_are_not():
    """A second copy of a wall on top of it made the other walls 15% brighter, silently (issue 18)."""
    from hr_addon.core.geometry import coincident_patches, prepare_patches

    wall = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    floor = wall[:, [0, 2, 1]] + [0, 0, 0.0]
    shifted = wall[[1, 2, 3, 0]]  # the same face, its corners listed from another start
    back = wall[::-1]  # back to back: the other side of a thin wall
    p = prepare_patches(
        _quads([wall, floor, shifted, back], [0, 1, 2, 3], ["Wall", "Floor", "Wall.001", "Back"])
    )
    assert coincident_patches(p).tolist() == [2]
    assert any("lie exactly on another polygon" in w and "'Wall.001'" in w for w in p.warnings), p.warnings
    p = prepare_patches(_quads([wall, floor, back], [0, 1, 2], ["Wall", "Floor", "Back"]))
    assert len(coincident_patches(p)) == 0 and not p.warnings
