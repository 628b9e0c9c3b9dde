"""Surfaces facing the wrong way (hr_addon/core/orientation.py): a reversed wall or a ceiling panel
facing the ceiling are turned around before the build, as Cycles (two-sided) shows them."""

import dataclasses

import numpy as np
import pytest

from hr_testing import scenes
from hr_addon.core.orientation import find_reversed, turn_around
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

PARAMS = dataclasses.replace(RefineParams.preset("draft"), orient=True)
# A polygon turned around lists its corners in another order, so its quadtree numbers its children
# otherwise: the same nodes and links, but draft's push corrections (vcorr 1e-3) sample the children
# in that order (measured: 1.2e-4 apart; 8e-6 without push corrections)
RTOL = 1e-3
WALLS = ("floor", "ceiling", "x0", "x1", "y0", "y1")


def _room(reversed_walls=(), panel_up=False, panel_drop=0.01, triangles=()):
    """A closed 1 m room (inward faces, 2 x 2 quads per wall; walls named in `triangles` as
    triangles) lit by a 0.3 m ceiling panel `panel_drop` below the ceiling, facing down (or up)."""
    sb = scenes.SceneBuilder()
    c = np.full(3, 0.5)
    box = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    faces = {
        "floor": (0, 2, 6, 4),
        "ceiling": (1, 5, 7, 3),
        "x0": (0, 1, 3, 2),
        "x1": (4, 6, 7, 5),
        "y0": (0, 4, 5, 1),
        "y1": (2, 3, 7, 6),
    }
    for name, f in faces.items():
        quad = scenes._orient(box[list(f)], c)
        v, polys = scenes.grid(quad, 2)
        if name in triangles:
            polys = [t for p in polys for t in ([p[0], p[1], p[2]], [p[0], p[2], p[3]])]
        if name in reversed_walls:
            polys = [p[::-1] for p in polys]
        sb.add(name, v, polys, (0.5, 0.5, 0.5))
    z = 1.0 - panel_drop
    panel = [(0.35, 0.35, z), (0.35, 0.65, z), (0.65, 0.65, z), (0.65, 0.35, z)]  # faces down
    sb.add("panel", panel, [[0, 3, 2, 1] if panel_up else [0, 1, 2, 3]], (0.5, 0.5, 0.5), (10.0, 10.0, 10.0))
    return sb.build()


def _per_object_light(system):
    """Leaving power per area (3,) of each object: the area-weighted mean radiance of its leaves."""
    system.solve()
    pt, h = system.patches, system.h
    lf = h.leaves()
    obj = pt.object_id[h.patch[lf]]
    out = {}
    for k, name in enumerate(pt.object_names):
        m = obj == k
        out[name] = (system.B[:, lf[m]] * h.area[lf[m]]).sum(1) / h.area[lf[m]].sum()
    return out


@pytest.fixture(scope="module")
def correct():
    s = RadiositySystem(_room(), PARAMS)
    assert not any("turned around" in w for w in s.build.warnings), s.build.warnings
    return _per_object_light(s)


def test_reversed_wall_bakes_like_the_correct_room(correct):
    bad = RadiositySystem(_room(reversed_walls=("x0",)), PARAMS)
    msg = " ".join(bad.build.warnings)
    assert "4 polygon(s) faced away from everything" in msg and "4 in 'x0'" in msg, msg
    got = _per_object_light(bad)
    for name in WALLS + ("panel",):
        np.testing.assert_allclose(got[name], correct[name], rtol=RTOL, err_msg=name)


def test_reversed_wall_without_the_check_is_black_and_darkens_the_rest(correct):
    """What the check fixes (issue 18): the wall bakes to 0 and the others lose light."""
    got = _per_object_light(RadiositySystem(_room(reversed_walls=("x0",)), RefineParams.preset("draft")))
    assert np.all(got["x0"] == 0)
    assert got["x1"].mean() < 0.95 * correct["x1"].mean()


def test_reversed_triangulated_wall_is_turned_around():
    """Triangles keep the padded convention (corner 3 repeats corner 2) when turned around."""
    correct = _per_object_light(RadiositySystem(_room(triangles=("y1",)), PARAMS))
    bad = RadiositySystem(_room(reversed_walls=("y1",), triangles=("y1",)), PARAMS)
    assert "8 in 'y1'" in " ".join(bad.build.warnings), bad.build.warnings
    pt = bad.patches
    tri = pt.nv == 3
    assert tri.any() and np.array_equal(pt.corners[tri, 3], pt.corners[tri, 2])
    assert np.all(pt.vert_index[tri, 3] == -1)
    vi = pt.vert_index[:, :3]
    np.testing.assert_allclose(pt.corners[:, :3], bad.mesh.verts[vi])
    got = _per_object_light(bad)
    for name in WALLS:
        np.testing.assert_allclose(got[name], correct[name], rtol=RTOL, err_msg=name)


def test_ceiling_panel_facing_the_ceiling_is_turned_around(correct):
    bad = RadiositySystem(_room(panel_up=True), PARAMS)
    msg = " ".join(bad.build.warnings)
    assert "1 emitting polygon(s) faced a surface right in front of them" in msg and "'panel'" in msg, msg
    got = _per_object_light(bad)
    for name in WALLS:
        np.testing.assert_allclose(got[name], correct[name], rtol=RTOL, err_msg=name)
    off = _per_object_light(RadiositySystem(_room(panel_up=True), RefineParams.preset("draft")))
    assert off["floor"].mean() < 0.5 * correct["floor"].mean()  # the issue: a quarter of the light


def test_reversed_panel_a_millimetre_under_the_ceiling(correct):
    """A reversed panel 1 mm under the ceiling made the whole scene 0."""
    ref = _per_object_light(RadiositySystem(_room(panel_drop=0.001), PARAMS))
    bad = RadiositySystem(_room(panel_up=True, panel_drop=0.001), PARAMS)
    assert "'panel'" in " ".join(bad.build.warnings), bad.build.warnings
    got = _per_object_light(bad)
    assert ref["floor"].mean() > 0
    for name in WALLS:
        np.testing.assert_allclose(got[name], ref[name], rtol=RTOL, err_msg=name)


def test_correct_scenes_are_left_alone():
    for mesh in (_room(), scenes.cornell_box(), scenes.closed_box(subdiv=2)):
        s = RadiositySystem(mesh, dataclasses.replace(RefineParams.preset("draft"), orient=False))
        flip, reasons = find_reversed(s.patches, s.backend)
        assert reasons == {} and not flip.any()


def test_turn_around_twice_is_the_identity():
    s = RadiositySystem(_room(triangles=("x0",)), RefineParams.preset("draft"))
    pt = s.patches
    before = (pt.corners.copy(), pt.vert_index.copy(), pt.normal.copy())
    flip = np.ones(len(pt.nv), bool)
    turn_around(pt, flip)
    assert np.allclose(pt.normal, -before[2])
    turn_around(pt, flip)
    for a, b in zip((pt.corners, pt.vert_index, pt.normal), before):
        np.testing.assert_array_equal(a, b)


def test_without_embree_the_float64_search_finds_the_same(monkeypatch):
    from hr_addon.core import visibility

    s = RadiositySystem(
        _room(reversed_walls=("x0",), panel_up=True), RefineParams.preset("draft"), backend="numpy"
    )
    monkeypatch.setattr(visibility, "_importable", lambda name: False)
    flip, reasons = find_reversed(s.patches, s.backend)
    assert sorted(set(reasons.values())) == ["back", "emitter"]
    names = {
        s.patches.object_names[s.patches.object_id[np.flatnonzero(s.patches.poly == p)[0]]] for p in reasons
    }
    assert names == {"x0", "panel"}


def test_a_box_standing_on_the_floor_is_left_alone():
    """A face lying on another one facing it (a box's bottom on the floor, its top open under a lid
    facing down) is covered, not reversed."""
    sb = scenes.SceneBuilder()
    mesh = _room()
    # an open box (no top) on the floor, with a plate above it facing down into it
    b = np.array([[x, y, z] for x in (0.2, 0.4) for y in (0.2, 0.4) for z in (0.0, 0.2)], float)
    c = np.array([0.3, 0.3, 0.1])
    faces = [(0, 2, 6, 4), (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6)]  # bottom and sides
    quads = [scenes._orient(b[list(f)], 2 * b[list(f)].mean(0) - c) for f in faces]  # outward
    for i, q in enumerate(quads):
        sb.add(f"box{i}", q, [[0, 1, 2, 3]], (0.5, 0.5, 0.5))
    sb.add(
        "lid",
        [(0.2, 0.2, 0.3), (0.2, 0.4, 0.3), (0.4, 0.4, 0.3), (0.4, 0.2, 0.3)],
        [[0, 1, 2, 3]],
        (0.5, 0.5, 0.5),
    )
    mesh = mesh.concat(sb.build())
    s = RadiositySystem(mesh, RefineParams.preset("draft"))
    assert s.patches.normal[s.patches.object_names.index("lid") == s.patches.object_id][0, 2] < 0
    flip, reasons = find_reversed(s.patches, s.backend)
    assert reasons == {}, reasons


def test_a_room_with_every_wall_reversed_is_not_recognised():
    """The documented limit: each wall sees only the others' backs, so nothing is turned around."""
    s = RadiositySystem(_room(reversed_walls=WALLS), RefineParams.preset("draft"))
    assert find_reversed(s.patches, s.backend)[1] == {}


def test_vertex_values_of_a_turned_wall_land_on_its_own_vertices():
    """Output follows vert_index: the reversed room's values per vertex are the correct room's."""
    good = RadiositySystem(_room(), PARAMS)
    bad = RadiositySystem(_room(reversed_walls=("x0",)), PARAMS)
    a, b = good.loop_radiance("POINT"), bad.loop_radiance("POINT")
    assert a.shape == b.shape and a.max() > 0
    np.testing.assert_allclose(b, a, rtol=RTOL, atol=RTOL * a.max())


@pytest.mark.parametrize("method", ["NAIVE", "AUTO"])
def test_light_shape_on_a_turned_wall(method):
    """A window on the reversed wall: NAIVE rebuilds a system from the input polygons (turned again
    by its own check), AUTO covers the turned patches; both equal the correct room's light."""
    from hr_testing import shapes as S
    from hr_addon.core.events import DynamicRadiosity, LightShape

    frame = (np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]))  # x = 0, faces +x
    window = LightShape(S.on_plane(S.rect(0.3, 0.2, (0.5, 0.5)), frame), np.array([4.0, 4.0, 4.0]), "window")
    out = []
    for walls in ((), ("x0",)):
        dyn = DynamicRadiosity(RadiositySystem(_room(reversed_walls=walls), PARAMS), method=method)
        rep = dyn.apply({"w": window})
        assert not any("no surface" in m or "off the" in m for m in rep.messages), rep.messages
        out.append(dyn.loop_radiance("POINT"))
    assert out[0].max() > 0
    np.testing.assert_allclose(out[1], out[0], rtol=RTOL, atol=RTOL * out[0].max())
