"""A light shape's emitting region when it reaches past the surfaces it lies on, and the grid of
clear shafts a dragged shape reuses (Live's edits, issue 19)."""

import numpy as np
import pytest

from hr_testing import scenes
from hr_testing import shapes as S
from hr_addon.core.events import DynamicRadiosity, LightShape
from hr_addon.core.events.direct import shape_form_factors, slab_pieces
from hr_addon.core.events.validation import to2d
from hr_addon.core.planes import ClearShafts
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams


@pytest.fixture(scope="module")
def system():
    # the back wall as a 4 x 4 grid of patches, slightly skewed as in the Cornell data
    return RadiositySystem(scenes.cornell_box(subdiv=4), RefineParams.preset("draft"))


@pytest.mark.parametrize(
    "centre, size, angle", [((0.5, 0.3), 0.16, 0.0), ((0.52, 0.2), 0.2, 0.3), ((0.3, 0.5), 0.2, 0.5)]
)
def test_merged_pieces_are_the_same_region(system, centre, size, angle):
    """A shape reaching past the wall's edge: its part on the wall cut along the outline of the
    covered patches' union (merge=True) is the region cut along every patch's edges: the same
    area (to 1e-12 relative) and form factors at points in front, also where their horizon cuts
    the shape (to 1e-12 of the largest), in fewer pieces."""
    dyn = DynamicRadiosity(system.copy(), method="FE")
    rect = S.on_plane(S.rect(size, 0.75 * size, centre=centre, angle=angle), S.CORNELL_BACK_WALL)
    dyn.add("a", LightShape(rect, np.full(3, 2.0), "a"))
    rec = dyn.shapes["a"]
    assert 0.3 < rec.covered < 1 - 1e-6 and len(rec.roots) > 1
    pt = system.patches
    nf = pt.normal[rec.roots[0]]
    cells = to2d(rec, pt.corners[rec.roots])
    every = slab_pieces(rec, nf, cells)
    merged = slab_pieces(rec, nf, cells, merge=True)
    assert len(merged[0]) < len(every[0])
    assert abs(merged[2].sum() - every[2].sum()) <= 1e-12 * every[2].sum()
    assert abs(merged[2].sum() - rec.covered * rec.area) <= 1e-9 * rec.area
    rng = np.random.default_rng(1)
    x = np.array([0.05, 0.05, 0.05]) + rng.random((400, 3)) * [0.45, 0.45, 0.45]
    n = rng.normal(size=(400, 3)) + [0, 2.0, 0]  # most face the wall, some see it cut by their horizon
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    Fa = shape_form_factors(x, n, None, every[0], every[1], 1e-6)
    Fb = shape_form_factors(x, n, None, merged[0], merged[1], 1e-6)
    assert Fa.max() > 0.01
    np.testing.assert_allclose(Fb, Fa, rtol=0, atol=1e-12 * Fa.max())


def test_a_dragged_shape_reuses_its_grid(system, monkeypatch):
    """Moves of a shape within its plane (Live's drags) test their shafts against the grid built
    for the first position: one ClearShafts for the plane, however many moves."""
    from hr_addon.core.gather import LoopGather
    from hr_addon.core.gather.direct import DirectLight

    built = []
    real = ClearShafts.__init__

    def counting(self, tris, plane, point, normal, margin, *threads):
        built.append(normal.copy())
        real(self, tris, plane, point, normal, margin, *threads)

    monkeypatch.setattr(ClearShafts, "__init__", counting)
    monkeypatch.setattr(DirectLight, "CULL_MIN_RAYS", 1)  # the gather's cull at 4 / 8 shadow rays too
    dyn = DynamicRadiosity(system.copy(), method="FE")
    g = LoopGather(dyn, rays=16, shadow_rays=4, levels=2)
    wall = S.CORNELL_BACK_WALL[1:]
    for cx in (0.2, 0.23, 0.26, 0.3):
        rect = S.on_plane(S.rect(0.1, 0.08, centre=(cx, 0.3)), S.CORNELL_BACK_WALL)
        dyn.apply({"a": LightShape(rect, np.full(3, 2.0), "a")})
        assert g.loop_radiance(dyn).max() > 0
    n = np.cross(*wall)
    on_wall = [b for b in built if abs(abs(b @ n) - 1) < 1e-9]
    assert len(on_wall) == 1


@pytest.mark.parametrize(
    "outline",
    [
        S.window(0.2, 0.16, 0.02, centre=(0.4, 0.4), angle=0.3, shear=0.3),  # holes
        S.star(0.1, 0.04, 5, centre=(0.45, 0.4), angle=0.2),  # not convex
        S.ellipse(0.12, 0.05, centre=(0.4, 0.45), angle=0.5),  # 48 vertices
    ],
)
def test_form_factors_over_the_rings_are_the_pieces_sum(system, outline):
    """shape_form_factors over a shape's rings (the contour integral where the shape lies wholly
    above a point's horizon, the rings clipped to it elsewhere) equals the sum over its convex
    pieces (point_to_polygon's), to 1e-12 of the largest."""
    from hr_addon.core.geometry import newell

    dyn = DynamicRadiosity(system.copy(), method="FE")
    dyn.add("a", LightShape(S.on_plane(outline, S.CORNELL_BACK_WALL), np.full(3, 2.0), "a"))
    rec = dyn.shapes["a"]
    nf = system.patches.normal[rec.roots[0]]
    rings = [r if (newell(r) @ nf > 0) == (i == 0) else r[::-1] for i, r in enumerate(rec.rings)]
    corners, nv = slab_pieces(rec, nf)[:2]
    rng = np.random.default_rng(2)
    x = np.array([0.05, 0.05, 0.05]) + rng.random((600, 3)) * [0.9, 0.8, 0.9]
    n = rng.normal(size=(600, 3)) + [0, 1.0, 0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    F = shape_form_factors(x, n, rings, None, None, 1e-6)
    ref = shape_form_factors(x, n, None, corners, nv, 1e-6)
    whole = ((np.concatenate(rings)[None] - x[:, None]) * n[:, None]).sum(-1).min(1) > 1e-6
    assert 0.2 < whole.mean() < 0.95 and (F[~whole] > 0).sum() > 20  # both paths taken
    np.testing.assert_allclose(F, ref, rtol=0, atol=1e-12 * ref.max())


def _pieces_one_by_one(rec, nf, cells=None, merge=False):
    """slab_pieces as it was before session 22: each kept piece turned and padded on its own."""
    from hr_addon.core import formfactor as ff
    from hr_addon.core.events.direct import _union_edges
    from hr_addon.core.events.planar import _in_convex, _in_rings, slab_decomposition
    from hr_addon.core.geometry import newell

    edges = [np.stack([x, np.roll(x, -1, 0)], 1) for x in rec.rings2d]
    if cells is not None and merge:
        e, lo, hi = _union_edges(cells), np.min(edges[0], (0, 1)), np.max(edges[0], (0, 1))
        edges.append(e[((e.max(1) >= lo) & (e.min(1) <= hi)).all(1)])
    elif cells is not None:
        edges.append(np.stack([cells, np.roll(cells, -1, 1)], 2).reshape(-1, 2, 2))
    edges = np.concatenate(edges)
    scale = float(np.abs(edges).max()) or 1.0
    traps = slab_decomposition(edges, 1e-9 * scale)
    mids = np.array([m for _, m in traps]).reshape(-1, 2)
    keep = _in_rings(mids, rec.rings2d)
    if cells is not None:
        keep &= _in_convex(mids, cells, 1e-9 * scale if merge else None).any(1)
    out, nvs = [], []
    for t in np.flatnonzero(keep):
        q = traps[t][0]
        p3 = rec.c + q[:, :1] * rec.u + q[:, 1:2] * rec.v
        if newell(p3) @ nf < 0:
            p3 = p3[::-1]
        nvs.append(len(p3))
        out.append(np.concatenate([p3, p3[-1:]]) if len(p3) == 3 else p3)
    c, nv = np.array(out).reshape(-1, 4, 3), np.array(nvs, int)
    return c, nv, ff.polygon_normal_area(c, nv)[1]


@pytest.mark.parametrize(
    "outline",
    [
        S.window(0.2, 0.16, 0.02, centre=(0.4, 0.4), angle=0.3, shear=0.3),  # holes
        S.star(0.1, 0.04, 5, centre=(0.45, 0.4), angle=0.2),  # not convex: triangles
        S.ellipse(0.12, 0.05, centre=(0.4, 0.45), angle=0.5),
        S.rect(0.2, 0.15, centre=(0.52, 0.2), angle=0.3),  # past the wall's edge
    ],
)
def test_pieces_as_arrays_are_the_pieces_one_by_one(system, outline):
    """slab_pieces turns and pads its pieces as arrays (session 22): the same corners, counts and
    areas bit for bit as each piece on its own, with and without the covered patches' cells."""
    dyn = DynamicRadiosity(system.copy(), method="FE")
    dyn.add("a", LightShape(S.on_plane(outline, S.CORNELL_BACK_WALL), np.full(3, 2.0), "a"))
    rec = dyn.shapes["a"]
    pt = system.patches
    nf = pt.normal[rec.roots[0]]
    cells = to2d(rec, pt.corners[rec.roots])
    for args in ((), (cells,), (cells, True)):
        got, ref = slab_pieces(rec, nf, *args), _pieces_one_by_one(rec, nf, *args)
        assert len(ref[0]) > 2 and (ref[1] == 3).any()  # (triangles padded too)
        for a, b in zip(got, ref):
            assert a.dtype == b.dtype and np.array_equal(a, b)
