"""LoopGather on a finer output mesh than the transport's (layouts.OutputLayout, Vertex Spacing of
session 22): the hierarchy on the user's mesh, the corner samples on the corners of its linear
subdivision. No bpy; nothing here asserts on time."""

import numpy as np
import pytest
from tests import closed_forms as cf

from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import LoopGather, OutputLayout
from hr_addon.core.gather import layouts
from hr_addon.core.gather.layouts import INSET, OUTPUT_INSET
from hr_addon.core.geometry import MeshInput
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.blender.settings import gather_params

RHO, STRENGTH = 0.5, 5.0
# tests/test_blender_vertex_spacing.py's scene: a 4 x 2.5 m wall facing +y, one quad; a 0.4 m
# square lamp 0.3 m in front of its west end, facing it
WALL = [(0, 0, 0), (0, 0, 2.5), (4, 0, 2.5), (4, 0, 0)]
LAMP = [(0.2, 0.3, 1.05), (0.6, 0.3, 1.05), (0.6, 0.3, 1.45), (0.2, 0.3, 1.45)]
# a floor before the wall (facing up), a pentagon (an extra vertex on its front edge): three
# triangles in the transport, 4 x 4 quads in the output, some across two of the triangles
FLOOR = [(0, 0, 0), (4, 0, 0), (4, 2, 0), (1.3, 2, 0), (0, 2, 0)]


def _grid(corners, n):
    """Vertices and quads of the bilinear n x n split of a quad (corners in its winding)."""
    c = np.asarray(corners, float)
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    u, v = u.ravel()[:, None], v.ravel()[:, None]
    verts = (1 - u) * (1 - v) * c[0] + u * (1 - v) * c[1] + u * v * c[2] + (1 - u) * v * c[3]
    k = lambda i, j: i * (n + 1) + j  # noqa: E731
    quads = [[k(i, j), k(i + 1, j), k(i + 1, j + 1), k(i, j + 1)] for i in range(n) for j in range(n)]
    return verts, quads


def _meshes(n, floor=True):
    """(transport mesh, output mesh, output polygon -> transport polygon): the wall and the floor
    split n x n in the output, the lamp as it is."""
    rho = [(RHO,) * 3, (0.0,) * 3] + ([(RHO,) * 3] if floor else [])
    em = [(0.0,) * 3, (STRENGTH,) * 3] + ([(0.0,) * 3] if floor else [])
    polys = [list(range(4)), list(range(4, 8))] + ([list(range(8, 13))] if floor else [])
    verts = WALL + LAMP + (FLOOR if floor else [])
    names = ["Wall", "Lamp", "Floor"][: len(polys)]
    coarse = MeshInput.from_polygons(verts, polys, rho, em, np.arange(len(polys)), names)
    fv, fq, frho, fem, foid, fpoly = [], [], [], [], [], []
    parts = [(WALL, n), (LAMP, 1)] + ([([FLOOR[0], FLOOR[1], FLOOR[2], FLOOR[4]], n)] if floor else [])
    for i, (c, k) in enumerate(parts):
        v, q = _grid(c, k)
        fq += [[len(fv) + j for j in p] for p in q]
        fv += [tuple(x) for x in v]
        frho += [rho[i]] * len(q)
        fem += [em[i]] * len(q)
        foid += [i] * len(q)
        fpoly += [i] * len(q)
    fine = MeshInput.from_polygons(fv, fq, np.array(frho), np.array(fem), np.array(foid), names)
    return coarse, fine, np.array(fpoly)


def _gather(mesh, output=None, poly=None, **kw):
    s = RadiositySystem(mesh, RefineParams.for_gather("draft"))
    dyn = DynamicRadiosity(s, method="FE")
    out = None if output is None else OutputLayout(s, output, poly)
    g = LoopGather(dyn, output=out, **dict(gather_params("draft"), **kw))
    return g, g.loop_radiance(dyn).astype(np.float64), dyn


@pytest.mark.parametrize("n", [4, 16])
def test_the_wall_s_finer_corners_read_the_analytic_light(n):
    """The one-quad wall (one patch in the transport), its output split n x n: every finer corner
    reads the lamp's direct light rho L F as the vertex layout reads a corner (the mean over the
    corners at its vertex of the value OUTPUT_INSET of the way from each to its face's centre:
    the finer corners' inset), within 1e-5 (the
    direct light is exact; the float32 output's rounding). The layout is the finer mesh's."""
    coarse, fine, poly = _meshes(n, floor=False)
    g, v, _ = _gather(coarse, fine, poly)
    assert v.shape == (len(fine.loop_verts), 3)
    w = np.flatnonzero(np.repeat(fine.object_id, fine.loop_total) == 0)  # the wall's loops
    lv, co = fine.loop_verts[w], fine.verts
    P = len(fine.loop_start)
    lp = np.repeat(np.arange(P), fine.loop_total)[w]
    centre = np.stack([np.bincount(lp, co[lv, c], P) / 4 for c in range(3)], 1)
    b = (
        RHO
        * STRENGTH
        * cf.point_to_polygon_contour(
            co[lv] + OUTPUT_INSET * (centre[lp] - co[lv]), np.array([0, 1.0, 0]), np.array(LAMP)
        )
    )
    ref = (np.bincount(lv, b, len(co)) / np.maximum(np.bincount(lv, minlength=len(co)), 1))[lv]
    assert ref.max() / ref.mean() > 3  # a gradient across the wall
    np.testing.assert_allclose(v[w], np.repeat(ref[:, None], 3, 1), rtol=1e-5)
    assert len(g.system.patches.nv) == 2  # the transport: the user's two quads


def test_the_output_on_the_finer_corners_is_today_s_within_the_gather_s_noise():
    """With a floor (the wall's light now also reflected off it; the floor a pentagon: three
    triangles in the transport, some finer quads over two of them, each sample located on the
    triangle under it): the gather on the user's mesh gives at the finer corners what the gather
    on the finer mesh (today's Vertex Spacing) gives: per object mean within 3% (measured: wall
    +0.01%, floor +1.7%: the indirect light through another hierarchy) and the median corner
    within 3%."""
    coarse, fine, poly = _meshes(4)
    g, v, dyn = _gather(coarse, fine, poly)
    g0, v0, _ = _gather(fine, inset=OUTPUT_INSET)  # (the finer corners' inset: the same samples)
    assert len(g.system.patches.nv) == 5 and len(g0.system.patches.nv) == 33
    assert v.shape == v0.shape
    tri = g.patch[g.system.patches.poly[g.patch] == 2]  # the floor's samples' transport triangles
    assert len(np.unique(tri)) == 3
    lo = np.repeat(fine.object_id, fine.loop_total)
    for o in (0, 2):
        a, b = v[lo == o, 0], v0[lo == o, 0]
        print(fine.object_names[o], a.mean() / b.mean() - 1, np.median(np.abs(a / b - 1)))
        assert abs(a.mean() / b.mean() - 1) < 0.03
        assert np.median(np.abs(a / b - 1)) < 0.03
    # the same samples (points, rays, direct light) but where one lies near the edge of the patch
    # it is gathered on (the gather moves it the margin inside, towards the patch's centre): a
    # finer face's today, a transport triangle's now (measured: 8 of 132, by at most 0.9 mm)
    d = np.linalg.norm(g.points[: g.n_loop] - g0.points[: g0.n_loop], axis=1)
    assert (d < 1e-9).mean() > 0.9 and d.max() < 5e-3


def test_without_an_output_layout_the_gather_is_unchanged():
    """OutputLayout(s, s.mesh, identity) on the system's own mesh: the same values as no layout (the
    layout's patches are the system's, each point's transport patch its own), at the same inset
    (by default an output layout's is OUTPUT_INSET: test below)."""
    coarse, _, _ = _meshes(4)
    g, v, dyn = _gather(coarse)
    g1, v1, _ = _gather(coarse, coarse, np.arange(len(coarse.loop_start)), inset=INSET)
    np.testing.assert_allclose(v1, v, rtol=1e-6, atol=1e-9)


def test_the_inset_is_0_5_on_the_user_s_corners_and_output_inset_on_the_finer_ones():
    """layouts.default_inset (session 24, vx27): without an output layout (Vertex Spacing 0, or a
    spacing that subdivides nothing) the corner samples lie half way to their face's centre, the
    samples and values of an explicit inset 0.5 bit for bit (the bake at spacing 0 as before); on an
    output layout's finer corners OUTPUT_INSET of the way (nearer the corners: a light falling off
    across a small face reads nearer its mean), those of an explicit OUTPUT_INSET bit for bit."""
    assert INSET == 0.5 and 0 < OUTPUT_INSET < INSET
    coarse, fine, poly = _meshes(4, floor=False)
    g, v, _ = _gather(coarse)
    g5, v5, _ = _gather(coarse, inset=0.5)
    np.testing.assert_array_equal(g.points, g5.points)
    np.testing.assert_array_equal(v, v5)
    h, w, _ = _gather(coarse, fine, poly)
    h1, w1, _ = _gather(coarse, fine, poly, inset=OUTPUT_INSET)
    np.testing.assert_array_equal(h.points, h1.points)
    np.testing.assert_array_equal(w, w1)
    h5 = _gather(coarse, fine, poly, inset=0.5)[0]
    # the wall's corner samples: OUTPUT_INSET of the way from their corner to their face's centre
    wl = np.flatnonzero(np.repeat(fine.object_id, fine.loop_total) == 0)
    P = len(fine.loop_start)
    lp = np.repeat(np.arange(P), fine.loop_total)
    co = fine.verts[fine.loop_verts]
    centre = np.stack([np.bincount(lp, co[:, c], P) / fine.loop_total for c in range(3)], 1)[lp]
    for gg, f in ((h, OUTPUT_INSET), (h5, 0.5)):
        at = gg.points[gg.loop_index[wl]]
        want = co[wl] + f * (centre[wl] - co[wl])
        assert np.median(np.linalg.norm(at - want, axis=1)) < 1e-9


def _flat_cylinder(flat, seg=16):
    """A flat-shaded closed cylinder (r 0.1 m, 0.3 m high, `seg` sides: 22.5 degrees apart at 16,
    within the smooth angle's 30) and a 0.3 m square lamp 0.6 m from its axis facing it (rho 0)."""
    from hr_testing.furnished import cylinder

    v, faces = cylinder([0.0, 0.0, 0.0], 0.1, 0.3, seg)
    polys = [list(map(int, f)) for part in faces for f in part]
    lamp = np.array([(0.6, -0.15, 0.0), (0.6, -0.15, 0.3), (0.6, 0.15, 0.3), (0.6, 0.15, 0.0)])
    verts = np.r_[np.asarray(v, float), lamp]
    polys.append(list(range(len(v), len(v) + 4)))
    P = len(polys)
    rho = np.full((P, 3), RHO)
    rho[-1] = 0.0
    em = np.zeros((P, 3))
    em[-1] = STRENGTH
    mesh = MeshInput.from_polygons(verts, polys, rho, em, [0] * (P - 1) + [1], ["Cup", "Lamp"])
    mesh.flat = np.ones(P, bool) if flat else None
    return mesh, lamp


@pytest.mark.parametrize("output", [False, True])
def test_a_flat_shaded_face_s_corners_keep_its_own_light(output, monkeypatch):
    """Issue 19 (session 33, branch vtxroom): a flat-shaded mesh (MeshInput.flat, Blender's
    sharp_face) shows each face's own light in a render, so its corners average only with faces in
    their plane (layouts.FLAT_ANGLE), not with every face within the smooth angle. A 16-sided
    cylinder (faces 22.5 degrees apart) before a square lamp, convex and alone (no indirect light,
    no shadow): over every side face that sees the whole lamp, the mean of the interpolated corner
    values is the face's mean of the analytic light rho L F (Lambert's contour integral at 16 x 16
    points) within 1.5% (measured: +1.1% at the user's corners' inset 0.5, -1.2% at an output
    layout's 0.36: the inset's own residual on a light falling off across the face; welded as
    before, the face facing the lamp -4.3 / -6.2%, averaged with its less lit neighbours).
    Smooth-shaded (flat None) the corners still weld: a vertex between two side faces reads one
    value. On the system's own mesh and on an output
    layout over it."""
    from hr_addon.core.output import corner_weights

    monkeypatch.setattr(layouts, "ELONGATED", 0.0)  # (these faces' corners alone, no extra samples)
    res = {}
    for flat in (True, False):
        mesh, lamp = _flat_cylinder(flat)
        ident = np.arange(len(mesh.loop_start))
        g, v, _ = _gather(mesh, mesh if output else None, ident if output else None)
        v = v.mean(1)
        lp = g._layout_patches()
        pc = g.average[4]
        uu = (np.arange(16) + 0.5) / 16
        U, W = (x.ravel()[:, None] for x in np.meshgrid(uu, uu, indexing="ij"))
        errs = {}
        for k in np.flatnonzero((lp.nv == 4) & (np.abs(lp.normal[:, 2]) < 0.5) & (lp.object_id == 0)):
            q, n = lp.corners[k], lp.normal[k]
            if ((lamp - q[0]) @ n).min() <= 0:  # (part of the lamp behind the face's plane)
                continue
            p = (1 - U) * (1 - W) * q[0] + U * (1 - W) * q[1] + U * W * q[2] + (1 - U) * W * q[3]
            m = len(p)
            w = corner_weights(np.repeat(q[None], m, 0), np.full(m, 4), np.repeat(n[None], m, 0), p)
            ours = (w @ v[pc[k]]).mean()
            exact = (RHO * STRENGTH * cf.point_to_polygon_contour(p, n, lamp[::-1])).mean()
            errs[k] = ours / exact - 1
        res[flat] = errs
        if not flat:  # welded: the loops at one vertex of two side faces read one value
            lv = np.asarray(mesh.loop_verts)
            side = np.repeat(np.arange(len(mesh.loop_start)), mesh.loop_total) < 16
            vals = [np.ptp(v[(lv == x) & side]) for x in range(16)]
            assert max(vals) < 1e-6 * v.max()
    print({f: {k: round(e, 4) for k, e in r.items()} for f, r in res.items()})
    assert len(res[True]) >= 5
    assert max(abs(e) for e in res[True].values()) < 0.015
    assert min(res[False].values()) < -0.03  # (why: the welded faces' lit side reads dark)


def _strip_scene():
    """A 24 x 1.6 cm strip standing at x = 0 facing +x (a bottle's side), a 0.2 m square lamp
    0.5 m before it and above it facing it, and a panel 10 cm before the strip up to 20 cm high
    facing the lamp, whose shadow covers the strip's lower half (its edge 10-15 cm up)."""
    strip = [(0, -0.008, 0), (0, 0.008, 0), (0, 0.008, 0.24), (0, -0.008, 0.24)]
    lamp = [(0.5, -0.1, 0.4), (0.5, -0.1, 0.6), (0.5, 0.1, 0.6), (0.5, 0.1, 0.4)]
    plate = [(0.1, -0.2, -0.05), (0.1, 0.2, -0.05), (0.1, 0.2, 0.2), (0.1, -0.2, 0.2)]  # facing +x
    verts = strip + lamp + plate
    rho = [(RHO,) * 3, (0.0,) * 3, (RHO,) * 3]
    em = [(0.0,) * 3, (STRENGTH,) * 3, (0.0,) * 3]
    mesh = MeshInput.from_polygons(verts, [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]], rho, em, [0, 1, 2])
    return mesh, np.array(strip)


def test_an_elongated_face_the_spacing_leaves_whole_keeps_its_light_s_mean(monkeypatch):
    """Issue 19 (session 33, branch vtxroom): on an output layout a face ELONGATED x longer than
    wide and longer than ELONGATED_MIN (a bottle's 24 cm side, which 0.25 m leaves whole) gets
    corner_fit's extra samples along it and its corners shifted to keep their mean. A plate's
    shadow across its lower half: the mean of the interpolated corners over the strip against the
    dense gather's (16 x 64 points) about half as far off as with its corner samples alone
    (ELONGATED 0), measured +6.2% against +11.9%: the 8 extra samples along the strip (1 x 8) are
    a quadrature of the shadow's 5 cm edge, one of them in it."""
    from hr_addon.core.gather import FinalGather
    from hr_addon.core.output import corner_weights

    mesh, strip = _strip_scene()
    ident = np.arange(len(mesh.loop_start))
    uu, vv = (np.arange(16) + 0.5) / 16, (np.arange(64) + 0.5) / 64
    U, W = (x.ravel()[:, None] for x in np.meshgrid(uu, vv, indexing="ij"))
    p = (1 - U) * (1 - W) * strip[0] + U * (1 - W) * strip[1] + U * W * strip[2] + (1 - U) * W * strip[3]
    res = {}
    for on in (4.0, 0.0):
        monkeypatch.setattr(layouts, "ELONGATED", on)
        g, v, dyn = _gather(mesh, mesh, ident)
        v = v.mean(1)
        lp = g._layout_patches()
        k = int(np.flatnonzero(lp.object_id == 0)[0])
        m = len(p)
        w = corner_weights(
            np.repeat(lp.corners[k][None], m, 0), np.full(m, 4), np.repeat(lp.normal[k][None], m, 0), p
        )
        ours = (w @ v[g.average[4][k]]).mean()
        dense = FinalGather(
            dyn, p, np.repeat(lp.normal[k][None], m, 0), np.full(m, k), **gather_params("draft")
        )
        exact = dense.evaluate(dyn, "radiance").mean()
        res[on] = ours / exact - 1
    print(res)
    assert abs(res[4.0]) < 0.6 * abs(res[0.0]) and abs(res[4.0]) < 0.08


@pytest.mark.parametrize("top", [0.5, 0.75])
def test_a_thin_face_cut_along_shows_the_light_of_its_part_a_camera_sees(top):
    """Issue 19 (session 34, branch tworooms): the strip of _strip_scene (a bottle's side, the
    plate's shadow across its lower half) seen only above `top` of its height, as a camera sees a
    bottle behind the table's items. Whole (its corners at the ends, the elongated face's extra
    samples keeping its mean), the interpolant runs from the shadow's corners to the lit ones and
    the part seen reads dark against the dense gather there (16 x 64 points over the part):
    measured -18.6% (the upper half) and -20.6% (the upper quarter); cut 4 x 4 (own_values' FINER 2
    on a thin face in part: Subdivide Mesh's grid) its corners follow the shadow's edge 6 cm apart:
    -7.2% and -1.7%."""
    from hr_addon.core.gather import FinalGather
    from hr_addon.core.output import corner_weights

    mesh, strip = _strip_scene()
    uu, vv = (np.arange(16) + 0.5) / 16, top + (1 - top) * (np.arange(64) + 0.5) / 64
    U, W = (x.ravel()[:, None] for x in np.meshgrid(uu, vv, indexing="ij"))
    p = (1 - U) * (1 - W) * strip[0] + U * (1 - W) * strip[1] + U * W * strip[2] + (1 - U) * W * strip[3]
    res = {}
    for k in (1, 4):
        v, q = _grid(strip, k)
        verts = [tuple(x) for x in v] + [tuple(x) for x in mesh.verts[4:]]
        polys = [list(f) for f in q] + [[len(v) + j for j in range(4)], [len(v) + 4 + j for j in range(4)]]
        poly = np.r_[np.zeros(len(q), np.int64), 1, 2]
        fine = MeshInput.from_polygons(verts, polys, mesh.reflectance[poly], mesh.emission[poly], poly)
        g, val, dyn = _gather(mesh, fine, poly)
        val = val.mean(1)
        lp = g._layout_patches()
        # each point's output face: the grid cell holding it
        cell = np.minimum((U[:, 0] * k).astype(int), k - 1) * k + np.minimum((W[:, 0] * k).astype(int), k - 1)
        rows = np.flatnonzero(lp.object_id == 0)
        K = rows[cell] if k > 1 else np.full(len(p), rows[0])
        w = corner_weights(lp.corners[K], lp.nv[K], lp.normal[K], p)
        ours = np.einsum("mc,mc->m", w, val[g.average[4][K]]).mean()
        dense = FinalGather(dyn, p, lp.normal[K], np.zeros(len(p), np.int64), **gather_params("draft"))
        res[k] = ours / dense.evaluate(dyn, "radiance").mean() - 1
    print(res)
    assert res[1] < -0.1 and abs(res[4]) < 0.5 * abs(res[1])
