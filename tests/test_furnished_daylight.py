"""hr_testing.furnished.daylight_room, the furnished room lit by daylight (issue 20's furnished
target, benchmarks/furnished_lights.py): the furnished room without its ceiling panel and with a
window opening through the south wall; everything else as furnished_room builds it."""

import numpy as np
import pytest

from hr_addon.core.geometry import newell
from hr_testing.furnished import SOUTH_WINDOW, SUN, daylight_room, furnished_room


def _objects(mesh):
    """{name: (polygon corner coordinates, reflectance)} per object."""
    out = {}
    for k, name in enumerate(mesh.object_names):
        polys = np.flatnonzero(mesh.object_id == k)
        corners = [
            mesh.verts[mesh.loop_verts[mesh.loop_start[i] : mesh.loop_start[i] + mesh.loop_total[i]]]
            for i in polys
        ]
        out[name] = (corners, mesh.reflectance[polys])
    return out


def test_daylight_room_is_the_furnished_room_with_a_window_and_no_panel():
    plain, _ = furnished_room("2k")
    day, info = daylight_room("2k")
    a, b = _objects(plain), _objects(day)
    assert set(a) - set(b) == {"ceiling_light"} and set(b) <= set(a)
    for name in b:
        if name != "wall_south":
            assert len(a[name][0]) == len(b[name][0]) and all(
                np.array_equal(p, q) for p, q in zip(a[name][0], b[name][0])
            ), name
    # the opening: the wall's cells whose centre lies in SOUTH_WINDOW, a rectangle on the grid lines
    lo, hi = info["window"]
    assert lo[1] == hi[1] == 0.0  # in the wall's plane
    cell = a["wall_south"][0][0]
    step = np.ptp(cell, 0)  # one grid cell (x and z extents)
    assert np.allclose(np.round((hi - lo)[[0, 2]] / step[[0, 2]]), (hi - lo)[[0, 2]] / step[[0, 2]])
    area = lambda polys: sum(np.linalg.norm(newell(p)) / 2 for p in polys)  # noqa: E731
    assert np.isclose(area(a["wall_south"][0]) - area(b["wall_south"][0]), (hi[0] - lo[0]) * (hi[2] - lo[2]))
    centres = np.array([p.mean(0) for p in b["wall_south"][0]])
    assert not np.all((centres > SOUTH_WINDOW[0]) & (centres < SOUTH_WINDOW[1]), 1).any()
    assert not np.all((centres > lo) & (centres < hi), 1).any()
    # the sun comes in through the opening and down onto the floor, from outside the south wall
    assert SUN["direction"][1] > 0 and SUN["direction"][2] < 0


@pytest.mark.bpy
def test_daylight_scene_lights_and_a_cycles_portal_is_no_light():
    """The Blender scene has the sun and the sky as the bake reads them; a Cycles portal in the
    window (an area light that only guides Cycles' sampling of the World) is not read as a light:
    it emits nothing in Cycles."""
    from hr_addon.blender.lights_in import collect_lights
    from hr_addon.core.lights import Light
    from hr_testing.cycles_lights import daylight_scene

    for portal in (False, True):
        daylight_scene("2k", portal=portal)
        import bpy

        assert ("Window portal" in bpy.data.objects) == portal
        vl = bpy.context.view_layer
        lights = collect_lights(vl, vl.depsgraph, Light)
        assert sorted(L.kind for L in lights.values()) == ["SKY", "SUN"]
        sun = next(L for L in lights.values() if L.kind == "SUN")
        assert np.allclose(sun.direction, SUN["direction"], atol=1e-6)
        assert np.allclose(sun.scale, np.multiply(SUN["color"], SUN["strength"]), rtol=1e-6)
