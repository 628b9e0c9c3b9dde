"""Hot secondary sources (issue 19, session 35, branch shade; core/gather/hot.py): a Blender
light's first bounce off a few leaves far brighter than the room (a lamp shade's inside) is taken
out of the final gather's hemisphere rays and integrated exactly (lights.leaf_bounce). No bpy."""

import numpy as np

from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import FinalGather, hot
from hr_addon.core.lights import Light, bright_leaves
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_testing.scenes import SceneBuilder


def plate_lamp(ceiling=False):
    """A 4 m grey floor (rho 0.5, 24 x 24 patches) and a 0.2 m white plate (rho 0.8) facing it
    1 m up, a 50 W point light 3 cm under the plate: the plate's underside holds 44% of the
    light's first bounce at 175x the room's mean radiance (a lamp shade's hot inside). ceiling:
    a grey ceiling 2 m up (8 x 8 patches) too, which sees the plate's unlit top and the floor."""
    sb = SceneBuilder()
    sb.add_quad("floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], (0.5,) * 3, subdiv=24)
    sb.add_quad("plate", [(-0.1, -0.1, 1), (-0.1, 0.1, 1), (0.1, 0.1, 1), (0.1, -0.1, 1)], (0.8,) * 3)
    if ceiling:
        sb.add_quad("ceiling", [(-2, -2, 2), (-2, 2, 2), (2, 2, 2), (2, -2, 2)], (0.5,) * 3, subdiv=8)
    s = RadiositySystem(sb.build(), RefineParams())
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply({}, {"lamp": Light("POINT", (1, 1, 1), 50.0, position=np.array([0.0, 0.0, 0.97]))})
    return s, dyn


def test_bounce_leaves_keeps_the_few_leaves_rule_and_adds_the_hot_ones():
    # a bounce few leaves hold: bright_leaves' answer, whatever is hot
    few = np.array([0.0, 5.0, 1.0, 0.0])
    assert np.array_equal(hot.bounce_leaves(few, np.ones(4), most=2), bright_leaves(few, 2))
    # spread over many leaves: none but those above HOT x the area-weighted mean, the brightest first
    rad = np.r_[np.ones(1000), 500.0, 200.0, 0.0]
    area = np.r_[np.ones(1000), 0.01, 0.01, 1.0]
    assert len(bright_leaves(rad * area, 256)) == 0
    assert np.array_equal(hot.bounce_leaves(rad, area), [1000, 1001])
    assert np.array_equal(hot.bounce_leaves(rad, area, most=1), [1000])
    assert len(hot.bounce_leaves(rad, area, hot=np.inf)) == 0
    assert len(hot.bounce_leaves(np.zeros(3), np.ones(3))) == 0


def test_a_hot_plate_over_a_point_light_is_integrated_exactly_with_the_rays_mean(monkeypatch):
    """The plate's first bounce is spread over too many leaves for bright_leaves (the floor holds
    the rest), but the plate is hot: the gather integrates it exactly. The 100 floor patches' centres
    0.3-1 m from the plate's axis (form factor to it 0.3-1.2%), 32 rays, 12 gather seeds: the
    same mean as the rays alone (measured 0.9848 against 0.9883 +- 0.016), each point's spread over
    the seeds 0.33% (median; at most 0.6%: the rays on the plate's light after its first bounce)
    against the rays' 54% (a hit or none)."""
    s, dyn = plate_lamp()
    h, pt = s.h, s.patches
    cen = pt.corners.mean(1)
    r = np.linalg.norm(cen[:, :2], axis=1)
    fl = np.flatnonzero((pt.object_id == 0) & (r > 0.3) & (r < 1.0))
    up = np.tile([0.0, 0.0, 1.0], (len(fl), 1))

    def incident(seed):
        g = FinalGather(dyn, cen[fl], up, fl, rays=32, levels=2, seed=seed)
        return g, g.evaluate(dyn, "incident")[:, 0]

    g, _ = incident(0)
    rec = next(iter(dyn.lights.values()))
    idx = g._bounce_cache[rec.geom_key][0]
    assert len(idx) and np.all(pt.object_id[h.patch[idx]] == pt.object_names.index("plate"))
    Y1 = rec.D[:, : g.n_hr].T  # the first bounce as the hierarchy holds it: too spread for bright_leaves
    assert len(bright_leaves(Y1.mean(1) * h.area[: g.n_hr] * h.exposure[: g.n_hr], 256)) == 0
    seeds = range(12)
    exact = np.array([incident(k)[1] for k in seeds])
    monkeypatch.setattr(hot, "HOT", np.inf)  # the rays alone
    rays = np.array([incident(k)[1] for k in seeds])
    spread_exact = exact.std(0) / exact.mean(0)
    spread_rays = rays.std(0) / rays.mean(0)
    assert np.median(spread_exact) < 0.01 and spread_exact.max() < 0.02, spread_exact
    assert np.median(spread_rays) > 0.3, spread_rays
    se = rays.mean(1).std() / np.sqrt(len(seeds))
    assert abs(exact.mean() - rays.mean()) < 3 * se, (exact.mean(), rays.mean(), se)


def test_the_second_levels_samples_take_the_hot_plate_exactly_too(monkeypatch):
    """The ceiling sees the plate's unlit top and the floor: its light from the plate comes through
    the floor's leaf values, the means of the second level's samples, whose 16 rays each found the
    plate or not. With the plate taken out of those rays too (hot.SECOND, FinalGather._hot_second)
    the ceiling's 64 patch centres (0.3 m and more off the axis), 32 rays, 12 seeds: each point's
    spread over the seeds 6.0% (median) against 15.5% without, the same mean (measured: 0.0991 +-
    0.0002 and 0.1002 +- 0.0009; 512 rays without hot leaves, 4 seeds: 0.0993 +- 0.0002)."""
    s, dyn = plate_lamp(ceiling=True)
    pt = s.patches
    cen = pt.corners.mean(1)
    r = np.linalg.norm(cen[:, :2], axis=1)
    ce = np.flatnonzero((pt.object_id == pt.object_names.index("ceiling")) & (r > 0.3))

    def incident(seed):
        g = FinalGather(dyn, cen[ce], pt.normal[ce], ce, rays=32, levels=2, seed=seed)
        return g.evaluate(dyn, "incident")[:, 0]

    seeds = range(12)
    both = np.array([incident(k) for k in seeds])
    monkeypatch.setattr(hot, "SECOND", False)  # the top level's samples only
    top = np.array([incident(k) for k in seeds])
    spread_both, spread_top = (np.median(v.std(0) / v.mean(0)) for v in (both, top))
    assert spread_both < 0.5 * spread_top, (spread_both, spread_top)
    se = np.hypot(both.mean(1).std(), top.mean(1).std()) / np.sqrt(len(seeds))
    assert abs(both.mean() - top.mean()) < 3 * se, (both.mean(), top.mean(), se)
