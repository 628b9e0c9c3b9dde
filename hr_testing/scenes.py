"""Scenes built from numbers, in Blender's frame (z up, metres): the Cornell box, a closed box,
spheres, parallel plates. For the tests, the benchmarks and scripts/make_samples.py
(`from hr_testing import scenes`, with the repository root on sys.path); not shipped in the
extension."""

import numpy as np

from hr_addon.core.geometry import MeshInput

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
CORNELL_LIGHT = (17.0, 12.0, 4.0)

# Cornell Program of Computer Graphics, "Cornell Box Data" (https://www.graphics.cornell.edu/online/box/data.html):
# mm, y up.
_CORNELL = {
    "floor": ([(552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)], WHITE),
    "ceiling": ([(556, 548.8, 0), (556, 548.8, 559.2), (0, 548.8, 559.2), (0, 548.8, 0)], WHITE),
    "back": ([(549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)], WHITE),
    "right_green": ([(0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)], GREEN),
    "left_red": ([(552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)], RED),
}
_LIGHT = [(343, 548.8, 227), (343, 548.8, 332), (213, 548.8, 332), (213, 548.8, 227)]
_SHORT_TOP = [(130, 165, 65), (82, 165, 225), (240, 165, 272), (290, 165, 114)]
_TALL_TOP = [(423, 330, 247), (265, 330, 296), (314, 330, 456), (472, 330, 406)]
ROOM_CENTRE_MM = np.array([278.0, 274.4, 279.6])


def _to_blender(p):
    p = np.asarray(p, float)
    return p[..., [0, 2, 1]] * 0.001


def _orient(quad, towards):
    """Reverse the corner order if the normal does not point towards `towards` (x - centre sign)."""
    q = np.asarray(quad, float)
    n = np.cross(q[1] - q[0], q[2] - q[0])
    return q[::-1] if np.dot(n, towards - q.mean(0)) < 0 else q


def grid(quad, n):
    """Split a planar quad into n x n bilinear sub-quads (vertices shared)."""
    a, b, c, d = np.asarray(quad, float)
    u = np.linspace(0, 1, n + 1)
    U, V = np.meshgrid(u, u, indexing="ij")
    P = (
        ((1 - U) * (1 - V))[..., None] * a
        + (U * (1 - V))[..., None] * b
        + (U * V)[..., None] * c
        + ((1 - U) * V)[..., None] * d
    )
    verts = P.reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    polys = [[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]] for i in range(n) for j in range(n)]
    return verts, polys


class SceneBuilder:
    """Accumulates named objects made of quads/polygons into one MeshInput."""

    def __init__(self):
        self.verts, self.polys, self.rho, self.em, self.oid, self.names = [], [], [], [], [], []
        self._nv = 0

    def add(self, name, verts, polys, rho, emission=(0, 0, 0)):
        oid = len(self.names)
        self.names.append(name)
        self.verts.append(np.asarray(verts, float))
        self.polys += [[i + self._nv for i in p] for p in polys]
        self._nv += len(verts)
        self.rho += [np.broadcast_to(np.asarray(rho, float), 3)] * len(polys)
        self.em += [np.broadcast_to(np.asarray(emission, float), 3)] * len(polys)
        self.oid += [oid] * len(polys)
        return self

    def add_quad(self, name, quad, rho, emission=(0, 0, 0), subdiv=1):
        v, p = grid(np.asarray(quad, float), subdiv)
        return self.add(name, v, p, rho, emission)

    def build(self) -> MeshInput:
        return MeshInput.from_polygons(
            np.concatenate(self.verts),
            self.polys,
            np.array(self.rho),
            np.array(self.em),
            np.array(self.oid),
            self.names,
        )


def cornell_box(subdiv=1, light=True, light_drop_mm=0.5, light_emission=CORNELL_LIGHT) -> MeshInput:
    """The Cornell box in metres, z up, normals into the room / out of the blocks."""
    sb = SceneBuilder()
    centre = _to_blender(ROOM_CENTRE_MM)
    for name, (quad, rho) in _CORNELL.items():
        sb.add_quad(name, _orient(_to_blender(quad), centre), rho, subdiv=subdiv)
    for name, top in (("short_block", _SHORT_TOP), ("tall_block", _TALL_TOP)):
        top = _to_blender(top)
        bottom = top.copy()
        bottom[:, 2] = 0.0
        bc = np.r_[top.mean(0)[:2], top[0, 2] / 2]
        away = lambda q: 2 * q.mean(0) - bc  # point outside the block, beyond the face
        faces = [top] + [
            np.array([bottom[i], bottom[(i + 1) % 4], top[(i + 1) % 4], top[i]]) for i in range(4)
        ]
        # one object per block, as in the sample .blend (contacts.py joins its faces by position)
        vs, ps = [], []
        for f in faces:
            v, p = grid(_orient(f, away(f)), max(1, subdiv // 2))
            ps += [[i + sum(len(x) for x in vs) for i in q] for q in p]
            vs.append(v)
        sb.add(name, np.concatenate(vs), ps, WHITE)
    if light:
        q = _to_blender(_LIGHT)
        q[:, 2] -= light_drop_mm * 0.001
        sb.add_quad("light", _orient(q, centre), (0.78, 0.78, 0.78), light_emission)
    return sb.build()


def box_triangles(lo, hi):
    """The 12 triangles (list of (3, 3) corner lists) of an axis-aligned box, normals outward: a
    triangle soup for the ray backends."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ex, ey, ez = np.diag(hi - lo)

    def quad(p, u, v):
        return [[p, p + u, p + u + v], [p, p + u + v, p + v]]

    return (
        quad(lo, ey, ex)
        + quad(lo + ez, ex, ey)
        + quad(lo, ex, ez)
        + quad(lo + ey, ez, ex)
        + quad(lo, ez, ey)
        + quad(lo + ex, ey, ez)
    )


def closed_box(size=1.0, rho=0.5, emission=(1, 1, 1), subdiv=1) -> MeshInput:
    """A closed cube with inward faces: the furnace test."""
    s = size
    c = np.array([s / 2] * 3)
    corners = np.array([[x, y, z] for x in (0, s) for y in (0, s) for z in (0, s)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    sb = SceneBuilder()
    for i, f in enumerate(faces):
        sb.add_quad(f"face{i}", _orient(corners[list(f)], c), rho, emission, subdiv)
    return sb.build()


def icosphere(subdiv=2, radius=1.0, inward=True):
    """Vertices and triangles of an icosphere (normals inward by default)."""
    t = (1 + 5**0.5) / 2
    v = [
        (-1, t, 0),
        (1, t, 0),
        (-1, -t, 0),
        (1, -t, 0),
        (0, -1, t),
        (0, 1, t),
        (0, -1, -t),
        (0, 1, -t),
        (t, 0, -1),
        (t, 0, 1),
        (-t, 0, -1),
        (-t, 0, 1),
    ]
    f = [
        (0, 11, 5),
        (0, 5, 1),
        (0, 1, 7),
        (0, 7, 10),
        (0, 10, 11),
        (1, 5, 9),
        (5, 11, 4),
        (11, 10, 2),
        (10, 7, 6),
        (7, 1, 8),
        (3, 9, 4),
        (3, 4, 2),
        (3, 2, 6),
        (3, 6, 8),
        (3, 8, 9),
        (4, 9, 5),
        (2, 4, 11),
        (6, 2, 10),
        (8, 6, 7),
        (9, 8, 1),
    ]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    cache = {}

    def mid(i, j):
        key = (min(i, j), max(i, j))
        if key not in cache:
            m = verts[i] + verts[j]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    for _ in range(subdiv):
        f = [
            g
            for a, b, c in f
            for g in (
                (a, mid(a, b), mid(c, a)),
                (b, mid(b, c), mid(a, b)),
                (c, mid(c, a), mid(b, c)),
                (mid(a, b), mid(b, c), mid(c, a)),
            )
        ]
    faces = [tuple(reversed(x)) for x in f] if inward else f
    return np.array(verts) * radius, [list(x) for x in faces]


def sphere(subdiv=2, rho=0.5, emission_fn=None) -> MeshInput:
    """Closed inward-facing icosphere; emission_fn(face centres (F,3)) -> (F,3) radiance."""
    v, f = icosphere(subdiv)
    cen = np.array([v[x].mean(0) for x in f])
    em = np.zeros((len(f), 3)) if emission_fn is None else np.asarray(emission_fn(cen), float)
    return MeshInput.from_polygons(v, f, rho, em)


def parallel_plates(size=1.0, distance=1.0, rho_receiver=0.5, emission=1.0, subdiv=1) -> MeshInput:
    """A black emitting square above a grey receiver square facing it (pointwise oracle)."""
    s = size
    sb = SceneBuilder()
    sb.add_quad("receiver", [(0, 0, 0), (s, 0, 0), (s, s, 0), (0, s, 0)], (rho_receiver,) * 3, subdiv=subdiv)
    sb.add_quad(
        "emitter",
        [(0, 0, distance), (0, s, distance), (s, s, distance), (s, 0, distance)],
        (0, 0, 0),
        (emission,) * 3,
        subdiv=1,
    )
    return sb.build()


def wall_lightmap(system, name="back"):
    """The lightmap triangles of the single-quad wall `name` of `system`'s mesh (the Cornell box's
    back wall), its UVs the quad's own corners scaled into [0.05, 0.95]: (object id, triangle UVs,
    corners, patches, skipped triangles) from lightmap.plan.triangle_uvs."""
    from hr_addon.lightmap.plan import triangle_uvs

    mesh, pt = system.mesh, system.patches
    oid = mesh.object_names.index(name)
    polys = np.flatnonzero(mesh.object_id == oid)
    p0 = int(polys[0])
    ls, lt = mesh.loop_start[polys] - mesh.loop_start[p0], mesh.loop_total[polys]
    lv_g = np.concatenate([mesh.loop_verts[s : s + n] for s, n in zip(mesh.loop_start[polys], lt)])
    v0 = int(lv_g.min())
    q = mesh.verts[lv_g]
    e1, e2 = q[1] - q[0], q[3] - q[0]  # the wall's two edge directions
    uv = np.column_stack([(q - q[0]) @ e1 / (e1 @ e1), (q - q[0]) @ e2 / (e2 @ e2)]) * 0.9 + 0.05
    return (oid,) + tuple(triangle_uvs(pt, oid, uv, ls, lt, lv_g - v0, p0, v0, len(mesh.verts) - v0))
