"""The direct light's clear-shaft cull (gather/direct.ClearShafts): samples whose segments to an
emitter certainly meet no triangle get no shadow rays, and the output is the same as with every
sample's rays traced (issue 19, light events)."""

import numpy as np
import pytest

from hr_testing import scenes
from hr_testing import shapes as S
from hr_addon.core.events import DynamicRadiosity, LightShape
from hr_addon.core.events.direct import FirstBounce
from hr_addon.core.gather import LoopGather
from hr_addon.core.gather.direct import DirectLight
from hr_addon.core.planes import ClearShafts
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams


def _outputs(system, g, frames, method):
    """The gathered corner output after each frame of shapes, on a copy of the system with fresh
    caches."""
    dyn = DynamicRadiosity(system.copy(), method=method)
    lv = g
    while lv is not None:
        lv._D_static, lv._shape_cache = None, {}
        lv._responses.clear()
        lv = lv.second
    out = []
    for frame in frames:
        dyn.apply(frame)
        out.append(g.loop_radiance(dyn))
    return out


def _check(system, frames, method, monkeypatch):
    """Outputs with the cull and with every shaft called blocked (all rays traced): bitwise equal.
    Returns the samples the cull tested and found clear."""
    monkeypatch.setattr(DirectLight, "CULL_MIN_RAYS", 1)  # the cull at these few shadow rays too
    monkeypatch.setattr(FirstBounce, "CULL_MIN_POINTS", 1)  # and in AUTO's first bounce
    g = LoopGather(
        DynamicRadiosity(system.copy(), method=method), rays=32, shadow_rays=8, levels=2, iterations=2
    )
    counted = {"clear": 0, "all": 0}
    real = ClearShafts.clear

    def counting(self, o, elo, ehi):
        ok = real(self, o, elo, ehi)
        counted["clear"] += int(ok.sum())
        counted["all"] += len(ok)
        return ok

    monkeypatch.setattr(ClearShafts, "clear", counting)
    with_cull = _outputs(system, g, frames, method)
    monkeypatch.setattr(ClearShafts, "clear", lambda self, o, elo, ehi: np.zeros(len(o), bool))
    without = _outputs(system, g, frames, method)
    for a, b in zip(with_cull, without, strict=True):
        assert np.abs(a).max() > 0
        np.testing.assert_array_equal(a, b)
    return counted


@pytest.mark.parametrize("method", ["FE", "AUTO"])
def test_the_cull_leaves_the_cornell_output_unchanged(method, monkeypatch):
    """A shape on the back wall, then moved onto the green wall, then two shapes: the gathered
    output (the static emitter's and the shapes' direct light at both levels) equals the output
    with every sample's shadow rays traced, bitwise; and the cull did skip samples."""
    s = RadiositySystem(scenes.cornell_box(), RefineParams.preset("draft"))
    back = LightShape(
        S.on_plane(S.rect(0.16, 0.12, centre=(0.25, 0.3), angle=0.2), S.CORNELL_BACK_WALL),
        np.array([4.0, 3, 2]),
        "a",
    )
    green = LightShape(
        S.on_plane(S.rect(0.2, 0.1, centre=(0.3, 0.35)), S.CORNELL_GREEN_WALL), np.array([2.0, 3, 4]), "a"
    )
    floor = LightShape(S.on_plane(S.rect(0.1, 0.1, centre=(0.1, 0.1)), S.CORNELL_FLOOR), np.full(3, 3.0), "b")
    counted = _check(s, [{"a": back}, {"a": green}, {"a": green, "b": floor}], method, monkeypatch)
    assert 0 < counted["clear"] < counted["all"]


@pytest.mark.parametrize("method", ["FE", "AUTO"])
def test_the_cull_leaves_the_furnished_output_unchanged(method, monkeypatch):
    """The furnished 2k room (furniture, books, contacts; AUTO's first bounce takes the grid too,
    as at any size): a window in three places on its wall: bitwise equal with and without the
    cull, which skipped some of the lit samples."""
    from hr_testing.furnished import furnished_room

    mesh, info = furnished_room("2k")
    _, frame = info["light_wall"]
    s = RadiositySystem(mesh, RefineParams.for_gather("draft"))

    def window(cx, cy):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, cy), angle=0.2), frame)
        return {"w": LightShape(rect, np.full(3, 20.0), "window")}

    counted = _check(s, [window(0.7, 0.6), window(2.5, 1.2), window(4.0, 0.4)], method, monkeypatch)
    assert 0 < counted["clear"] < counted["all"]


def test_clear_shafts_is_conservative():
    """Random segments from points to a square emitter: wherever ClearShafts says clear, the
    segments to the emitter's corners and to random points on it are unoccluded by the rays."""
    from hr_addon.core.visibility import make_backend

    s = RadiositySystem(scenes.cornell_box(), RefineParams.preset("draft"))
    tri = s.patches.triangles
    point, normal = np.array([0.28, 0.2795, 0.548]), np.array([0.0, 0.0, -1.0])  # under the ceiling
    sh = ClearShafts(tri, s.refiner.occluders.plane, point + 1e-6 * normal, normal, 1e-9)
    rng = np.random.default_rng(0)
    lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
    o = lo + rng.random((4000, 3)) * (hi - lo) * [1, 1, 0.95]
    elo, ehi = point - [0.1, 0.1, 0], point + [0.1, 0.1, 0]
    ok = sh.clear(o, elo, ehi)
    assert 0 < ok.sum() < len(ok)
    b = make_backend(tri)
    for _ in range(8):
        e = elo + rng.random((ok.sum(), 3)) * (ehi - elo)
        assert not b.occluded(o[ok], e).any()


def test_clear_shafts_grid_is_the_same_on_threads(monkeypatch):
    """ClearShafts' triangles' boxes and grid cells by batches on 2 threads (planes.TRI_BATCH
    small enough to split the furnished 2k room's triangles): the same grid and big planes' boxes
    as on one thread."""
    from hr_addon.core import planes
    from hr_testing.furnished import furnished_room

    mesh, info = furnished_room("2k")
    o, u, v = (np.asarray(x, float) for x in info["light_wall"][1])
    s = RadiositySystem(mesh, RefineParams.for_gather("draft"))
    tri = s.patches.triangles
    monkeypatch.setattr(planes, "TRI_BATCH", 100)
    assert len(tri) > 10 * planes.TRI_BATCH
    point, normal = o + 0.7 * u + 0.6 * v, np.cross(u, v) / np.linalg.norm(np.cross(u, v))
    a, b = (ClearShafts(tri, s.refiner.occluders.plane, point, normal, 1e-9, threads) for threads in (1, 2))
    assert a.sat is not None and a.sat.max() > 0 and len(a.big_lo) > 0
    for k in ("sat", "big_lo", "big_hi", "o", "cell"):
        assert np.array_equal(getattr(a, k), getattr(b, k))


def test_first_bounce_and_gather_share_one_grid(monkeypatch):
    """An AUTO window on the furnished 2k room: its first bounce on nodes and the gather's direct
    light at both levels test their shafts against one ClearShafts grid, built once per emitter
    plane (a copy of the system shares it)."""
    from hr_testing.furnished import furnished_room

    mesh, info = furnished_room("2k")
    _, frame = info["light_wall"]
    s = RadiositySystem(mesh, RefineParams.for_gather("draft"))
    built = []
    real = ClearShafts.__init__

    def counting(self, *a, **k):
        built.append(a[2].copy())  # the emitter's point
        real(self, *a, **k)

    monkeypatch.setattr(ClearShafts, "__init__", counting)
    monkeypatch.setattr(DirectLight, "CULL_MIN_RAYS", 1)  # the gather's cull at 4 / 8 shadow rays too
    dyn = DynamicRadiosity(s.copy(), method="AUTO")
    g = LoopGather(dyn, rays=16, shadow_rays=4, levels=2)
    rect = S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame)
    dyn.add("w", LightShape(rect, np.full(3, 20.0), "window"))
    c = dyn.shapes["w"].c

    def grids():  # built for the window's plane (static emitters have their own)
        return sum(np.array_equal(p, c) for p in built)

    assert dyn.shapes["w"].direct_links > 0 and grids() == 1  # the first bounce built it
    assert g.loop_radiance(dyn).max() > 0 and grids() == 1  # both levels reused it


def test_few_shadow_rays_skip_the_cull():
    """Below CULL_MIN_RAYS shadow rays the test would cost more than the rays it saves: no grid."""
    s = RadiositySystem(scenes.cornell_box(), RefineParams.preset("draft"))
    dyn = DynamicRadiosity(s.copy(), method="FE")
    g = LoopGather(dyn, rays=16, shadow_rays=DirectLight.CULL_MIN_RAYS, levels=2)
    em = g.static_emitters()[0][0]
    assert g.shafts(em) is not None and g.second.shadow_rays < DirectLight.CULL_MIN_RAYS
    assert g.second.shafts(em) is None
