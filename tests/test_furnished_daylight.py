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


@pytest.mark.bpy
@pytest.mark.cycles
def test_a_cycles_portal_in_the_window_gives_the_same_sky_with_less_noise():
    """The daylight reference's portal (benchmarks/furnished_lights.py bakes with it): the 2k
    daylight room lit by its sky alone, baked by Cycles at 32 spp, seeds 1 and 2, three ways: the
    World without the portal, the World with it, and (the portal's World dark) the sky as an emitter
    of its radiance filling the window (cycles_lights.daylight_part: the same light exactly, found
    by Cycles' light sampling). Per room surface, the portal's mean is the emitter's within 4 sigma
    of their noise (the seeds' mean, from the texels' seed differences: a bake's texels are
    independent samples) and the plain World's within 4 sigma; its noise is at most half the plain
    World's. Measured (Blender 5.0.1, one run, 32 s CPU in all): the portal against the emitter
    -0.38% to +0.20% (0.7 sigma at most), against the plain World -2.5% to +1.3% (1.1 sigma); the
    noise of a surface mean 1.4-2.7% plain, 0.21-0.48% with the portal, 0.15-0.36% the emitter.
    daylight_scene gives the portal a small World map: with the AUTOMATIC one Cycles is slow."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import bpy

    from hr_testing import cycles_ref as C
    from hr_testing.cycles_lights import daylight_part, daylight_scene

    room = ("floor", "ceiling", "wall_south", "wall_north", "wall_west", "wall_east")

    def bake(rs):  # {surface: (mean of the two seeds, its noise)}
        a, b = (C.bake(rs, 32, seed)[0] for seed in (1, 2))
        out = {}
        for n in room:
            ok = np.isfinite(a[n]).all(1) & np.isfinite(b[n]).all(1)
            d = (a[n][ok] - b[n][ok]).mean(1)  # a texel's two seeds: twice one bake's variance
            out[n] = ((a[n][ok] + b[n][ok]).mean() / 2, np.std(d, ddof=1) / 2 / np.sqrt(ok.sum()))
        return out

    got = {}
    for portal in (False, True):
        _, info = daylight_scene("2k", portal=portal)
        bpy.data.objects["Sun"].data.energy = 0.0
        rs = C.prepare(bpy.context.scene, texel_rel=1 / 60)
        got[portal] = bake(rs)
    daylight_part("sky", info)
    got["emitter"] = bake(rs)
    for n in room:
        (m0, s0), (m1, s1), (me, se) = got[False][n], got[True][n], got["emitter"][n]
        print(
            f"{n}: portal / emitter {m1 / me - 1:+.2%} ({(m1 - me) / np.hypot(s1, se):+.1f} sigma), "
            f"portal / plain {m1 / m0 - 1:+.2%} ({(m1 - m0) / np.hypot(s0, s1):+.1f} sigma), "
            f"noise plain {s0 / m0:.2%}, portal {s1 / m1:.2%}, emitter {se / me:.2%}"
        )
        assert abs(m1 - me) < 4 * np.hypot(s1, se), n
        assert abs(m1 - m0) < 4 * np.hypot(s0, s1), n
        assert s1 < 0.5 * s0, n
