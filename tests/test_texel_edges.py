"""Texels a Blender light's edge crosses (a sun's shadow edge, a spot's cone) read the mean of the
direct light over their area (core.gather.texel_edges), against area means the tests compute
themselves; texels away from edges keep their centre's value bitwise.

No bpy. Nothing here asserts on time; tolerances are justified where they are set."""

import math

import numpy as np

from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import texel_gather
from hr_addon.core.gather.texel_edges import SUB
from hr_addon.core.lights import Light
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_testing.scenes import SceneBuilder
from tests import closed_forms as cf

T = 0.1  # texel side (m)
EDGE = 0.33  # the blocker's edge, inside the texel [0.3, 0.4]


def _scene(blocker=True):
    """A 4 m grey floor, and 1 m above it a black blocker over x < EDGE (reflects nothing: the
    floor's light is direct only)."""
    sb = SceneBuilder()
    sb.add_quad("floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], (0.5,) * 3)
    if blocker:
        sb.add_quad("blocker", [(-1.5, -1.5, 1), (-1.5, 1.5, 1), (EDGE, 1.5, 1), (EDGE, -1.5, 1)], (0.0,) * 3)
    return RadiositySystem(sb.build(), RefineParams())


def _texels(x, y):
    cen = np.array([[a, b, 0.0] for a in x for b in y])
    axes = np.tile(np.array([[T, 0, 0], [0, T, 0]])[None], (len(cen), 1, 1))
    return cen, axes


def _both(s, light, cen, axes, **kw):
    """(area, centre): incident light of texels gathered with their areas and at centres only."""
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply({}, {"l": light})
    patch = np.zeros(len(cen), np.int64)  # the floor
    g = texel_gather(dyn, patch, cen, axes=axes, rays=8, shadow_rays=16, **kw)
    c = texel_gather(dyn, patch, cen, rays=8, shadow_rays=16, **kw)
    return g, g.evaluate(dyn, "incident")[:, 0], c.evaluate(dyn, "incident")[:, 0]


def test_sun_shadow_edge_texels_read_their_lit_share():
    """A sun straight down, the blocker's shadow edge at x = 0.33 across texels [0.3, 0.4]: their
    exact mean is 0.7 of the lit value, their centre (0.35) reads all of it. Each texel averages
    SUB x SUB points jittered in their strata (8 x 8): only the column of strata across the edge
    ([0.325, 0.3375]: 0.4 of it lit) can be off, by at most 0.6 of its share 1/8 (0.075 of the lit
    value): held to 0.1 of it, where the centre is off by 0.3."""
    s = _scene()
    sun = Light("SUN", (1, 1, 1), 3.0, direction=(0, 0, -1), angle=0.0)
    cen, axes = _texels(np.arange(0.05, 0.8, T), [-0.35, 0.05, 0.45])
    g, area, centre = _both(s, sun, cen, axes)
    lit = cf.sun_irradiance(3.0, 1.0) / np.pi
    frac = np.clip((cen[:, 0] + T / 2 - EDGE) / T, 0, 1)  # the texel's part beyond the edge
    edge = (frac > 0) & (frac < 1)
    assert edge.sum() == 3 and np.allclose(frac[edge], 0.7)
    assert np.all(np.abs(centre[edge] - frac[edge] * lit) > 0.29 * lit)  # the centre: lit
    assert np.all(np.abs(area[edge] - frac[edge] * lit) <= 0.1 * lit)
    # the rest: wholly lit or dark, their centres' values bitwise (the same samples, no bounce)
    assert np.array_equal(area[~edge], centre[~edge])
    assert np.allclose(centre[~edge], frac[~edge] * lit, rtol=1e-7, atol=0)  # the float32 cache
    tested, n_edge, rays = g.stats["edge_texels"]
    assert tested == len(cen) and n_edge == 3 and rays == 4 * len(cen) + 3 * SUB**2 * 4  # 4 rays a point
    # the same values on 2 threads
    g2, area2, _ = _both(s, sun, cen, axes, threads=2)
    assert np.array_equal(area, area2)


def test_spot_cone_edge_texels_read_their_area_mean():
    """A hard-edged spot 2 m above the floor lighting a disc of radius 0.5 m; 10 cm texels on a
    grid across it. Reference: the texel's mean of the closed-form spot light (cos / r^2 inside the
    cone) on a 64 x 64 midpoint grid. The jittered SUB x SUB points (8 x 8) are unbiased, but a
    texel the edge crosses is off by up to the share of the strata it cuts (a near-straight edge:
    at most 2 SUB - 1 of SUB^2, each off by at most 1/SUB^2 of the texel's peak): each held to
    that, and the root mean square error over the edge texels to half the centres' (which read 0
    or all of it)."""
    s = _scene(blocker=False)
    P, h, R = 100.0, 2.0, 0.5
    size = 2 * math.atan(R / h)
    spot = Light(
        "SPOT", (1, 1, 1), P, position=(0, 0, h), direction=(0, 0, -1), spot_size=size, spot_blend=0.0
    )
    x = np.arange(-0.7, 0.71, T) + 0.013
    cen, axes = _texels(x, x + 0.021)
    g, area, centre = _both(s, spot, cen, axes)

    def exact(p):
        r = np.linalg.norm(p - spot.position, axis=1)
        c = h / r
        return np.array(
            [cf.point_light_irradiance(P, ri, ci) * cf.spot_factor(ci, size, 0.0) for ri, ci in zip(r, c)]
        )

    u = (np.arange(64) + 0.5) / 64 - 0.5
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2) * T
    ref = np.array([exact(np.column_stack([p[:2] + grid, np.zeros(len(grid))])).mean() for p in cen]) / np.pi
    edge = np.abs(np.linalg.norm(cen[:, :2], axis=1) - R) < T  # the texels the cone's edge can cross
    cut = np.array([0 < (np.linalg.norm(p[:2] + grid, axis=1) < R).mean() < 1 for p in cen])
    assert cut.sum() >= 20 and not (cut & ~edge).any()
    peak = exact(np.array([[0.0, 0, 0]]))[0] / np.pi
    assert np.all(np.abs(area[cut] - ref[cut]) <= (2 * SUB - 1) / SUB**2 * peak)
    err_a = np.sqrt(np.mean((area[cut] - ref[cut]) ** 2))
    err_c = np.sqrt(np.mean((centre[cut] - ref[cut]) ** 2))
    assert err_a < 0.5 * err_c
    # texels the edge does not cross (a 10% change of cos / r^2 inside one is no edge): bitwise
    far = ~edge
    assert far.sum() > 50 and np.array_equal(area[far], centre[far])


# -- emitters and light shapes (issue 19: the books' tops between their neighbours) ---------------
ZE, W, B = 2.0, 0.04, 0.1625  # the emitter strip's height and width, the blocker's edge (x < B, z = 1)
RAD = 50.0  # the strip's radiance


def _strip_scene(shape):
    """A 4 m grey floor; 2 m above it, facing down, a W x 2 m strip emitting RAD (a static emitter,
    or with shape=True a light shape on a black ceiling); 1 m above the floor a black blocker over
    x < B. The blocker's shadow edge is a penumbra over x in [2B - W/2, 2B + W/2] = [0.305, 0.345]
    (a ray from the floor at x to the strip at e crosses z = 1 at (x + e) / 2): across the texels
    [0.3, 0.4], whose centre (0.35) is lit wholly. Nothing else reflects: the floor's light is
    direct only."""
    from hr_addon.core.events import LightShape

    sb = SceneBuilder()
    sb.add_quad("floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], (0.5,) * 3)
    sb.add_quad("blocker", [(-1.5, -1.5, 1), (-1.5, 1.5, 1), (B, 1.5, 1), (B, -1.5, 1)], (0.0,) * 3)
    strip = [(-W / 2, -1, ZE), (-W / 2, 1, ZE), (W / 2, 1, ZE), (W / 2, -1, ZE)]  # facing down
    if shape:
        sb.add_quad("ceiling", [(-2, -2, ZE), (-2, 2, ZE), (2, 2, ZE), (2, -2, ZE)], (0.0,) * 3)
    else:
        sb.add_quad("strip", strip, (0.0,) * 3, (RAD,) * 3)
    s = RadiositySystem(sb.build(), RefineParams())
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply({"w": LightShape([np.array(strip, float)], np.full(3, RAD), "w")} if shape else {})
    return dyn


def _strip_exact(p):
    """Exact direct light (incident radiance, / pi of irradiance: RAD x F) at floor points p (m, 3):
    the strip's part beyond the blocker's shadow, x > 2B - p.x, seen from p (closed form)."""
    out = np.zeros(len(p))
    for i, (x, y, _) in enumerate(p):
        x0 = max(-W / 2, 2 * B - x)
        if x0 < W / 2:
            out[i] = RAD * cf.point_to_parallel_rect(x, y, x0, W / 2, -1.0, 1.0, ZE)
    return out


def _check_strip(shape):
    dyn = _strip_scene(shape)
    cen, axes = _texels(np.arange(0.05, 0.8, T), [-0.35, 0.05, 0.45])
    patch = np.zeros(len(cen), np.int64)  # the floor
    g = texel_gather(dyn, patch, cen, axes=axes, rays=8, shadow_rays=16)
    g.edge_shapes = True  # (light shapes' edge texels are off by default: their cost per event)
    c = texel_gather(dyn, patch, cen, rays=8, shadow_rays=16)
    area, centre = g.direct_and_emission(dyn)[0][:, 0], c.direct_and_emission(dyn)[0][:, 0]
    u = (np.arange(64) + 0.5) / 64 - 0.5
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2) * T
    ref = np.array([_strip_exact(np.column_stack([q[:2] + grid, np.zeros(len(grid))])).mean() for q in cen])
    lit = _strip_exact(np.array([[0.35, 0.05, 0.0]]))[0]
    edge = np.abs(cen[:, 0] - 0.35) < 1e-9
    # their exact mean: 0.005 dark, the ramp's 0.04 half lit, 0.055 lit: a quarter dark
    assert edge.sum() == 3 and np.all(ref[edge] < 0.76 * lit)
    # the centres see the whole strip (16 shadow rays, all clear): high by a quarter
    assert np.all(centre[edge] - ref[edge] > 0.2 * centre[edge])
    # the area: 8 x 8 jittered points (the penumbra a smooth ramp over 3 of the 8 strata columns:
    # the jitter's error a fraction of a per cent), each with emitter_rays(16) = 4 shadow rays (a
    # penumbra point's visible share to about 1/8; ~25 such points per texel, independently
    # rotated: ~2.5% of it, on the penumbra's share 0.4 of the texel): held to 3% of the lit value,
    # an eighth of the centre's error
    assert np.all(np.abs(area[edge] - ref[edge]) <= 0.03 * lit)
    # the rest (dark, or lit with a smooth fall-off of a few per cent): the centres' values bitwise
    assert np.array_equal(area[~edge], centre[~edge])
    assert np.all(centre[cen[:, 0] < 0.3] == 0) and np.allclose(centre[~edge], ref[~edge], rtol=0.05, atol=0)
    tested, n_edge, _ = g.stats["edge_texels"]
    assert tested == len(cen) and n_edge == 3


def test_static_emitter_shadow_edge_texels_read_their_area_mean():
    _check_strip(shape=False)


def test_light_shape_shadow_edge_texels_read_their_area_mean():
    _check_strip(shape=True)


def test_light_shape_edge_texels_off_by_default_keep_the_centres():
    dyn = _strip_scene(True)
    cen, axes = _texels(np.arange(0.05, 0.8, T), [-0.35, 0.05, 0.45])
    patch = np.zeros(len(cen), np.int64)
    g = texel_gather(dyn, patch, cen, axes=axes, rays=8, shadow_rays=16)
    c = texel_gather(dyn, patch, cen, rays=8, shadow_rays=16)
    area, centre = g.direct_and_emission(dyn)[0], c.direct_and_emission(dyn)[0]
    assert np.array_equal(area, centre) and centre.max() > 0
