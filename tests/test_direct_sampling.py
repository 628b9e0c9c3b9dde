"""The direct light's shadow rays by area (DirectLight.area_sampling) against oracles the test
computes: a floor under a rectangular emitter, half shadowed by a thin strip."""

import numpy as np
import pytest

from hr_addon.core import formfactor as ff
from hr_addon.core.events.direct import shape_form_factors
from hr_addon.core.gather.direct import DirectLight
from hr_addon.core.gather.sampling import Emitter, position_keys
from hr_addon.core.visibility import make_backend

H, STRIP = 1.0, 0.1  # emitter height; the strip's half width, at H / 2


class _Gather(DirectLight):
    """The arrays direct_batch reads, for samples x on the floor (z = 0, facing up)."""

    def __init__(self, x, rays, area, backend):
        self.points, self.normals = x, np.tile([0.0, 0, 1], (len(x), 1))
        self.dark, self.eps, self.seed, self.shadow_rays = np.zeros(len(x), bool), 1e-6, 3, rays
        self.keys = position_keys(x, 1e-4)
        self.area_sampling, self.AREA_NEAR = area, 0.0  # area: every sample by area
        self.system = type("S", (), {"backend": backend})()


def _quad(x0, x1, y0, y1, z, down=True):
    q = np.array([[x0, y0, z], [x0, y1, z], [x1, y1, z], [x1, y0, z]], float)
    return q if down else q[::-1]


def _scene():
    rect = _quad(-0.5, 0.5, -0.5, 0.5, H)  # CCW seen from below: emits down
    n = np.array([0.0, 0, -1])
    em = Emitter(rect[None], np.array([4]), np.array([1.0]), n[None], [rect], n, rect[0], stream=7)
    s = _quad(-STRIP, STRIP, -3, 3, H / 2)
    backend = make_backend(np.array([s[[0, 1, 2]], s[[0, 2, 3]]]), prefer="numpy")
    return em, backend


def _visible_form_factor(x):
    """Closed form: from (x, 0, 0) the strip hides the emitter's band |x_e + x| < 2 STRIP (its
    shadow on the plane z = H); the rest is at most two rectangles, their exact form factors."""
    out = np.zeros(len(x))
    up = np.array([[0.0, 0, 1]])
    for i, xp in enumerate(x):
        lo, hi = -2 * STRIP - xp, 2 * STRIP - xp
        for a, b in ((-0.5, min(lo, 0.5)), (max(hi, -0.5), 0.5)):
            if b > a:
                q = _quad(a, b, -0.5, 0.5, H)
                out[i] += ff.point_to_polygon(np.array([[xp, 0, 0]]), up, q[None])[0]
    return out


@pytest.mark.parametrize("area", [False, True])
def test_shadowed_ratio_and_fully_lit_samples(area):
    em, backend = _scene()
    xs = np.r_[np.linspace(-0.6, 0.6, 13), -0.9, 0.8, 1.2]
    x = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    exact = _visible_form_factor(xs)
    F = shape_form_factors(x, np.tile([0.0, 0, 1], (len(x), 1)), em.rings, em.corners, em.nv, 1e-6)
    # fully lit (|x| > 0.7: every segment passes beside the strip): the closed-form F to rounding
    lit = np.abs(xs) > 0.7
    assert np.allclose(exact[lit], F[lit], rtol=1e-9)
    for rays in (16, 1024):
        v = _Gather(x, rays, area, backend).direct_batch(em, 0, len(x))
        assert np.array_equal(v[lit], F[lit].astype(np.float32))
    # penumbra: 1024 stratified rays against the closed form (measured over 61 points: within 0.7%
    # (solid angle) / 0.5% (area) of the largest F; 16 rays up to 19% / 13%)
    v = _Gather(x, 1024, area, backend).direct_batch(em, 0, len(x))
    assert np.all(exact[~lit] < F[~lit] * 0.97)  # these samples are shadowed in part
    assert np.abs(v - exact).max() < 0.01 * F.max()


def test_area_sampling_does_not_depend_on_threads_or_batches():
    """With the default near rule: samples near the emitter take Arvo's rays (their values equal
    the solid-angle path's bit for bit), the others area-uniform ones (equal to the all-area
    path's); any batching and 1 or 2 threads give the same values."""
    from hr_addon.core.parallel import batch_map

    em, backend = _scene()
    rng = np.random.default_rng(1)
    x = np.column_stack([rng.uniform(-1.6, 1.6, (400, 2)), np.zeros(400)])
    g = _Gather(x, 16, True, backend)
    g.AREA_NEAR = DirectLight.AREA_NEAR
    near = np.linalg.norm(x - [0, 0, H], axis=1) < DirectLight.AREA_NEAR * np.sqrt(0.5)
    assert 50 < near.sum() < 350
    whole = g.direct_batch(em, 0, len(x))
    arvo = _Gather(x, 16, False, backend).direct_batch(em, 0, len(x))
    area = _Gather(x, 16, True, backend).direct_batch(em, 0, len(x))
    assert np.array_equal(whole[near], arvo[near]) and np.array_equal(whole[~near], area[~near])
    assert not np.array_equal(arvo, area)
    for threads in (1, 2):
        parts = batch_map(lambda a, b: g.direct_batch(em, a, b), [(0, 150), (150, 151), (151, 400)], threads)
        assert np.array_equal(np.concatenate(parts), whole)


def test_form_factors_only_where_a_shadow_ray_gets_through(monkeypatch):
    """direct_batch traces the shadow rays first and takes the form factor only at samples some
    ray reaches: the umbra of a plate over part of the floor reads 0 without one, and samples no
    occluder shadows read their form factor exactly (as shape_form_factors gives it for all)."""
    from hr_addon.core.gather import direct

    em, _ = _scene()
    s, p = _quad(-STRIP, STRIP, -3, 3, H / 2), _quad(-3, -0.3, -3, 3, H / 4)
    backend = make_backend(np.array([s[[0, 1, 2]], s[[0, 2, 3]], p[[0, 1, 2]], p[[0, 2, 3]]]), prefer="numpy")
    xs = np.linspace(-1.2, 1.2, 49)
    x = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    up = np.tile([0.0, 0, 1], (len(x), 1))
    F = shape_form_factors(x, up, em.rings, em.corners, em.nv, 1e-6)
    taken = []

    def spy(xx, *args):
        taken.append(xx.copy())
        return shape_form_factors(xx, *args)

    monkeypatch.setattr(direct, "shape_form_factors", spy)
    v = _Gather(x, 16, True, backend).direct_batch(em, 0, len(x))
    # every segment from x < -0.567 to the emitter (x_e <= 0.5) crosses the plate (z = H / 4, x < -0.3)
    umbra = xs < -0.6
    assert umbra.sum() >= 10 and np.all(v[umbra] == 0) and np.all(F[umbra] > 0)
    got = np.concatenate(taken)
    assert len(got) == np.count_nonzero(v) and not np.isin(got[:, 0], xs[umbra]).any()
    lit = xs > 0.7  # beside the strip's shadow, far from the plate's
    assert lit.sum() >= 8 and np.array_equal(v[lit], F[lit].astype(np.float32))
