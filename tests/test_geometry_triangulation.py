"""core.geometry: a given triangulation (MeshInput.tri_loops, e.g. Blender's loop_triangles) is
used for the polygons that must be split; planar convex quads stay quads; bad input is refused."""

import numpy as np
import pytest

from hr_addon.core.geometry import InputError, MeshInput, prepare_patches

TWISTED = [(0, 0, 0), (2, 0, 0), (2, 1, 0.5), (0, 1, 0)]
FLAT = [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]


def _tris(p, poly):
    sel = (p.poly == poly) & (p.nv == 3)
    return sorted(tuple(int(x) for x in np.roll(v[:3], -int(np.argmin(v[:3])))) for v in p.vert_index[sel])


def _mesh(tri_loops=None):
    m = MeshInput.from_polygons(np.array(TWISTED + FLAT, float), [[0, 1, 2, 3], [4, 5, 6, 7]], 0.5)
    m.tri_loops = tri_loops
    return m


def test_given_triangulation_is_used_for_split_polygons():
    own = prepare_patches(_mesh())
    assert _tris(own, 0) == [(0, 1, 3), (1, 2, 3)]  # the core's rule: the shorter diagonal
    given = prepare_patches(_mesh(np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])))
    assert _tris(given, 0) == [(0, 1, 2), (0, 2, 3)]
    assert list(given.nv[given.poly == 1]) == [4]  # a planar convex quad stays one patch
    assert np.isclose(given.area[given.poly == 0].sum(), own.area[own.poly == 0].sum(), rtol=0.05)


def test_polygons_the_triangulation_does_not_cover_are_split_here():
    p = prepare_patches(_mesh(np.array([[4, 5, 6], [4, 6, 7]])))
    assert _tris(p, 0) == [(0, 1, 3), (1, 2, 3)]


def test_concat_offsets_the_triangulation():
    a = _mesh(np.array([[0, 1, 2], [0, 2, 3]]))
    b = _mesh(np.array([[0, 1, 2], [0, 2, 3]]))
    c = a.concat(b)
    assert c.tri_loops.tolist() == [[0, 1, 2], [0, 2, 3], [8, 9, 10], [8, 10, 11]]
    p = prepare_patches(c)
    assert _tris(p, 2) == [(8, 9, 10), (8, 10, 11)]
    assert a.concat(_mesh()).tri_loops.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert _mesh().concat(_mesh()).tri_loops is None


def test_bad_triangulation_is_refused():
    with pytest.raises(InputError, match="mixes the loops of several polygons"):
        prepare_patches(_mesh(np.array([[0, 1, 5], [0, 2, 3]])))
    with pytest.raises(InputError, match="do not exist"):
        prepare_patches(_mesh(np.array([[0, 1, 99]])))
