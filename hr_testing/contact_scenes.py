"""Scenes of objects touching each other (numpy only; tests and benchmarks, not shipped): a floor with
solids on it, a black box on a floor under an emitting sky with its shadow-ray reference, and a
closed furnace room with boxes standing on the floor, against a wall and on each other."""

import numpy as np

from hr_addon.core.geometry import prepare_patches
from hr_addon.core.visibility import make_backend

from .furnished import Builder, box, cylinder, grid_quad


def floor_with(*objects, n=8, size=2.0):
    b = Builder()
    v, q = grid_quad(np.array([-size / 2, -size / 2, 0]), [size, 0, 0], [0, size, 0], n, n)
    b.add("floor", v, [q], 0.5)
    for name, (v, f) in objects:
        b.add(name, v, f, 0.5)
    return b


def sky_scene(n=8):
    """A 2 x 2 m floor (reflectance 0.5, n x n quads) with a black 0.4 m cube standing on it, under
    a 4 x 4 m emitter 1 m up (radiance 1, black): the floor's light is direct only."""
    v, f = box([-0.2, -0.2, 0], [0.2, 0.2, 0.4])
    b = floor_with(n=n)
    b.add("box", v, f, 0.0)
    v, q = grid_quad(np.array([-2.0, -2, 1]), [0, 4, 0], [4, 0, 0], 4, 4)
    b.add("sky", v, [q], 0.0, (1.0, 1.0, 1.0))
    return b.build()


def sky_reference(mesh, pts, n=64):
    """Reflected radiance 0.5 x H / pi at floor points: the emitter in n x n cells, each seen
    through a shadow ray (independent of the hierarchy)."""
    be = make_backend(prepare_patches(mesh).triangles)
    s = (np.arange(n) + 0.5) / n * 4 - 2
    X, Y = np.meshgrid(s, s)
    em = np.column_stack([X.ravel(), Y.ravel(), np.ones(n * n)])
    out = np.zeros(len(pts))
    for i, p in enumerate(pts):
        d = em - p
        r2 = (d**2).sum(1)
        vis = ~be.occluded(np.repeat(p[None] + [0, 0, 1e-6], len(em), 0), em - [0, 0, 1e-6])
        out[i] = np.sum(d[:, 2] ** 2 / r2 / (np.pi * r2) * (4 / n) ** 2 * vis)
    return 0.5 * out


def sky_points(seed=1):
    """Floor points of sky_scene: 200 in the penumbra band 1-40 mm beside the box (random side,
    position along it and distance), and 50 under the box."""
    rng = np.random.default_rng(seed)
    side, t, off = rng.integers(0, 4, 200), rng.uniform(-0.19, 0.19, 200), rng.uniform(0.001, 0.04, 200)
    band = np.zeros((200, 3))
    for k, (ax, sg) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1)]):
        band[side == k, ax] = sg * (0.2 + off[side == k])
        band[side == k, 1 - ax] = t[side == k]
    under = np.column_stack([rng.uniform(-0.195, 0.195, (50, 2)), np.zeros(50)])
    return band, under


def contact_furnace(rho=0.5, emission=(1.0, 1.0, 1.0)):
    """A closed 3 x 3 x 2.5 m room with boxes standing on the floor, against a wall and on each
    other, and a leg standing on a box; reflectance and emission the same everywhere, so every
    exposed point has B = E / (1 - rho) = 2 whatever covers what. emission 0: a room for a Blender
    light, whose reflected power is rho / (1 - rho) of what its direct light gives (closed)."""
    W, D, H = 3.0, 3.0, 2.5
    b = Builder()
    for name, o, u, v in (
        ("floor", (0, 0, 0), (W, 0, 0), (0, D, 0)),
        ("ceiling", (0, 0, H), (0, D, 0), (W, 0, 0)),
        ("wall0", (0, 0, 0), (0, 0, H), (W, 0, 0)),
        ("wall1", (0, D, 0), (W, 0, 0), (0, 0, H)),
        ("wall2", (0, 0, 0), (0, D, 0), (0, 0, H)),
        ("wall3", (W, 0, 0), (0, 0, H), (0, D, 0)),
    ):
        gv, gq = grid_quad(np.array(o, float), u, v, 6, 6)
        b.add(name, gv, [gq], rho, emission)
    for name, (v, f) in (
        ("box", box([0.5, 0.5, 0], [1.1, 1.0, 0.5])),
        ("stacked", box([0.6, 0.6, 0.5], [0.9, 0.85, 0.8])),
        ("against_wall", box([2.0, 0.0, 0], [2.6, 0.4, 0.7])),
        ("post", box([1.8, 2.0, 0], [2.3, 2.4, 0.4])),
        ("leg", cylinder([2.0, 2.2, 0.4], 0.08, 0.9, 12)),
    ):
        b.add(name, v, f, rho, emission)
    return b.build()
