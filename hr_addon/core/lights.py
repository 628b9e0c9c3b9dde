"""Blender's own lights as light sources (issue 20), numpy only: point, spot, sun and area lights in
Cycles' units, their exact direct light at surface points (shadow rays), and their first bounce
on the hierarchy's nodes (the seed's "irregular light source", handled by DynamicRadiosity).

Units, each fitted against a Cycles render of a diffuse plane under the light
(scripts/measure_light_units.py, docs/lights.md):
- point and spot, power P watts: radiant intensity I = P / (4 pi) W/sr (measured 0.99984 x).
  With a radius r Cycles emits radiance I / (pi r^2) from a disc of radius r facing the point with
  soft falloff (Blender's default): E = I cos / (d^2 + r^2) (measured at r = 0.5, d = 2: 0.9408 x
  I / d^2; the formula gives 0.9412), or from a sphere without it: E = I cos / d^2; either cut by
  the point's horizon where it crosses it (sized_point_unit; within 0.2% of Cycles on a plane at
  r / d 0.1-9 and grazing angles, scripts/measure_sized_point.py, session 38).
- spot: the point light's intensity times smoothstep((cos a - cos(size / 2)) /
  ((1 - cos(size / 2)) blend)), a the angle off the spot's axis (size 60 deg, blend 0.5: within
  0.007 of the rendered profile once the pixels' footprint is averaged). Inside the cone it is not
  brighter than a point light of the same power.
- sun, strength S W/m^2: irradiance S cos on a surface (measured 1.0000 x, at 0 and 60 degrees).
- area, power P watts over an area A (world size): emitted radiance L = P / (pi A) (measured
  0.9996 x for a 1 x 1 square and 0.9997 x for a 1 x 0.5 rectangle), one-sided along the light's -Z.
- sky (the World, core/sky.py): radiance colour x strength x its table (mean 1) from every
  direction a ray escapes the scene in.

Everything here is per unit strength ("unit" direct light): the light's colour x power (or x
strength for the sun) is a scale applied afterwards, so a strength or colour edit never recomputes
rays. Direct light is returned in the gather's "incident" unit: irradiance / pi (what a white
Lambertian surface would reflect as radiance).
"""

from dataclasses import dataclass, field
import hashlib

import numpy as np

from . import formfactor as ff

KINDS = ("POINT", "SPOT", "SUN", "AREA", "SKY")
POINT_INTENSITY = 1.0 / (4.0 * np.pi)  # W/sr per watt (measured: 0.99984 / (4 pi))
SUN_IRRADIANCE = 1.0  # W/m^2 per unit strength (measured: 1.0000)
AREA_RADIANCE = 1.0 / np.pi  # W/(sr m^2) per watt per m^2 (measured: 0.9996 / pi)
DISK_SEGMENTS = 32


def smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


@dataclass
class Light:
    """One Blender light in world space.

    kind: POINT, SPOT, SUN or AREA. color (3,) linear RGB; strength: watts (point, spot, area) or
    W/m^2 (sun). position (3,): the light's origin. direction (3,) unit: where it shines (the
    object's -Z). radius: point/spot sphere radius (m); soft_falloff: Cycles' "Soft Falloff".
    spot_size (rad, full cone angle), spot_blend. angle (rad): the sun's angular diameter.
    outline (M, 3): an area light's polygon, counter-clockwise about `direction` (its emitting
    side); see area_outline(). sky (H, W): a SKY's latitude-longitude table of relative radiance
    (core/sky.py; None: uniform), its colour x strength the mean radiance."""

    kind: str
    color: np.ndarray
    strength: float
    position: np.ndarray = None
    direction: np.ndarray = None
    radius: float = 0.0
    soft_falloff: bool = True
    spot_size: float = np.pi
    spot_blend: float = 0.0
    angle: float = 0.0
    outline: np.ndarray = None
    sky: np.ndarray = None
    name: str = ""
    notes: list = field(default_factory=list)

    def __post_init__(self):
        self.kind = self.kind.upper()
        if self.kind not in KINDS:
            raise ValueError(f"light '{self.name}': unknown kind {self.kind!r} ({', '.join(KINDS)})")
        self.color = np.broadcast_to(np.asarray(self.color, np.float64), (3,)).copy()
        d = np.asarray(self.direction if self.direction is not None else (0, 0, -1), np.float64)
        self.direction = d / max(float(np.linalg.norm(d)), 1e-300)
        self.position = np.asarray(self.position if self.position is not None else (0, 0, 0), np.float64)
        if self.kind == "AREA":
            if self.outline is None or len(self.outline) < 3:
                raise ValueError(f"light '{self.name}': an area light needs an outline")
            self.outline = np.asarray(self.outline, np.float64)
        if self.sky is not None:
            self.sky = np.ascontiguousarray(self.sky, np.float64)

    @property
    def scale(self):
        """(3,) colour x strength: multiplies the unit direct light and the unit response."""
        return self.color * float(self.strength)

    @property
    def geom_key(self):
        """Everything but colour and strength: equal keys give equal unit light."""
        if self.kind == "SKY":  # at infinity: no position, no direction
            if self.sky is None:
                return (self.kind, None)
            return (self.kind, self.sky.shape, hashlib.sha1(self.sky.tobytes()).hexdigest())
        parts = [self.kind, self.position.tobytes(), self.direction.tobytes()]
        if self.kind in ("POINT", "SPOT"):
            parts += [float(self.radius), bool(self.soft_falloff)]
        if self.kind == "SPOT":
            parts += [float(self.spot_size), float(self.spot_blend)]
        if self.kind == "SUN":
            parts += [float(self.angle)]
        if self.kind == "AREA":
            parts += [self.outline.tobytes()]
        return tuple(parts)

    @property
    def area(self):
        """World area of an area light's polygon."""
        return float(np.linalg.norm(_newell(self.outline))) if self.kind == "AREA" else 0.0

    def pieces(self):
        """An area light's polygon as convex pieces (T, 4, 3) (a fan about its centre for many
        corners), nv (T,), areas (T,), CCW about its direction."""
        c = self.outline
        if len(c) <= 4:
            p = np.concatenate([c, c[-1:]]) if len(c) == 3 else c
            nv = np.array([len(c)])
            pieces = p[None]
        else:
            m = c.mean(0)
            pieces = np.stack([np.broadcast_to(m, c.shape), c, np.roll(c, -1, 0), np.roll(c, -1, 0)], 1)
            nv = np.full(len(c), 3)
        _, a = ff.polygon_normal_area(pieces, nv)
        return pieces, nv, a


def _newell(p):
    p = np.asarray(p, np.float64)
    q = np.roll(p, -1, 0)
    return 0.5 * np.array(
        [
            np.sum((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])),
            np.sum((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])),
            np.sum((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])),
        ]
    )


def area_outline(shape, size, size_y, matrix, segments=DISK_SEGMENTS):
    """World outline (M, 3) of a Blender area light: shape SQUARE / RECTANGLE (size x size_y) /
    DISK / ELLIPSE (diameters), in the light's local XY plane, mapped by the 4 x 4 world matrix;
    counter-clockwise about the emitting direction (local -Z)."""
    shape = shape.upper()
    sx = float(size)
    sy = float(size if shape in ("SQUARE", "DISK") else size_y)
    if shape in ("SQUARE", "RECTANGLE"):
        loc = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], np.float64) * [sx / 2, sy / 2]
    else:
        # clockwise seen from +Z = counter-clockwise about -Z; the polygon keeps the ellipse's area
        t = -2 * np.pi * np.arange(segments) / segments
        k = np.sqrt(2 * np.pi / (segments * np.sin(2 * np.pi / segments)))
        loc = np.column_stack([np.cos(t) * sx / 2, np.sin(t) * sy / 2]) * k
    M = np.asarray(matrix, np.float64)
    p = np.column_stack([loc, np.zeros(len(loc)), np.ones(len(loc))]) @ M.T
    return p[:, :3]


def _disk_points(c, axis, r, u):
    """Points (n, k, 3) on disks of radius r about centres c (3,), perpendicular to axis (n, 3)."""
    from .gather.sampling import _frame

    t, b = _frame(axis)
    rr = r * np.sqrt(u[..., 0])
    ph = 2 * np.pi * u[..., 1]
    return c + (rr * np.cos(ph))[..., None] * t[:, None] + (rr * np.sin(ph))[..., None] * b[:, None]


def _cone_dirs(axis, cz, u1):
    """Unit directions (n, k, 3) at cosine cz (n, k) from unit axes (n, 3), azimuth 2 pi u1 (n, k)
    (a sun's cone, a sphere light's outline)."""
    from .gather.sampling import _frame

    t, b = _frame(axis)
    sz = np.sqrt(np.maximum(1 - cz * cz, 0))
    ph = 2 * np.pi * u1
    dirs = (sz * np.cos(ph))[..., None] * t[:, None] + (sz * np.sin(ph))[..., None] * b[:, None]
    return dirs + cz[..., None] * axis[:, None]


def spot_factor(light, ca):
    """Cycles' spot cone at cos ca (N,) off the spot's axis: smoothstep((ca - cos(size / 2)) /
    ((1 - cos(size / 2)) blend)), a step without blend."""
    ch = np.cos(light.spot_size / 2)
    if light.spot_blend > 0:
        return smoothstep((ca - ch) / ((1 - ch) * light.spot_blend))
    return ca > ch


def disc_factor(t, cos):
    """Form factor from surface points to a uniform disc facing them (its axis through the point),
    of radius t x its distance, the point's normal at cos (N,) to the axis: clipped by the point's
    horizon where the disc crosses it (|cot| < t). Lambert's contour integral: the arc above the
    horizon, phi in (-pc, pc) about the normal's side, and the chord the horizon cuts it along
    (subtending b). Unclipped: t^2 cos / (1 + t^2)."""
    t = np.asarray(t, np.float64)
    cos = np.clip(cos, -1.0, 1.0)
    sin = np.sqrt(1.0 - cos * cos)
    t2 = t * t
    out = np.where(cos >= t * sin, t2 * np.maximum(cos, 0) / (1 + t2), 0.0)
    cut = np.flatnonzero(np.abs(cos) < t * sin)
    if len(cut):
        tc, c, s = np.broadcast_to(t, cos.shape)[cut], cos[cut], sin[cut]
        pc = np.arccos(np.clip(-c / (tc * s), -1.0, 1.0))
        sp = np.sin(pc)
        b = 2 * np.arcsin(np.minimum(tc * sp / np.sqrt(1 + tc * tc), 1.0))
        out[cut] = (pc * tc * tc * c - tc * s * sp) / (np.pi * (1 + tc * tc)) + b / (2 * np.pi)
    return out


def sized_point_unit(light, d, cos):
    """Unit incident light (irradiance / pi per watt) of a point or spot light of radius r > 0, no
    spot cone, no shadow, at points at distance d (N,) from its centre, normals at cos to the
    direction to it: Cycles' emitter of radiance I / (pi r^2) (scene/light.cpp: eval_fac
    1 / (4 pi r^2 pi) per watt, both modes). Soft falloff (Blender's default; Cycles' is_sphere
    false): a disc of radius r facing the point (kernel/light/point.h), I cos / (d^2 + r^2) above
    the horizon. Without: a sphere, the cone of its outline a disc with t = r / sqrt(d^2 - r^2)
    (I cos / d^2 above the horizon); inside it the whole hemisphere, I / (pi r^2)."""
    r = float(light.radius)
    d = np.maximum(d, 1e-300)
    if light.soft_falloff:
        F = disc_factor(np.minimum(r / d, 1e150), cos)
    else:
        out = d <= r
        F = disc_factor(np.minimum(r / np.sqrt(np.maximum(d * d - r * r, 1e-300)), 1e150), cos)
        F[out] = 1.0
    return F * (POINT_INTENSITY / (np.pi * r * r))


def _sized_incident(light, x, n, o, backend, rays, seed, keys, stream):
    """unit_incident of a point or spot light of radius > 0: the closed form (sized_point_unit)
    times a kernel-weighted visible share from `rays` shadow rays per point, each to a point of the
    emitter Cycles samples: area-uniform on the facing disc (soft falloff), uniform in the cone
    of directions to the sphere (else; cosine-weighted over the hemisphere inside it); a spot's
    cone taken per ray's direction as Cycles does (not inside the sphere). One ray (rays <= 1): to
    the centre, the cone at the centre's direction."""
    from .gather.sampling import rotated_hammersley

    d = light.position - x
    dist = np.sqrt(np.maximum(np.einsum("ij,ij->i", d, d), 1e-300))
    w = d / dist[:, None]
    cos = np.einsum("ij,ij->i", w, n)
    val = sized_point_unit(light, dist, cos)
    spot = light.kind == "SPOT"
    inside = (dist <= light.radius) & (not light.soft_falloff)
    if spot:
        ca = -(w @ light.direction)
        if rays <= 1:
            val *= np.where(inside, 1.0, spot_factor(light, ca))
        else:  # cull the points no ray can reach: the cone widened by the emitter's angular radius
            rim = np.arcsin(np.minimum(light.radius / dist, 1.0))
            reach = np.cos(np.minimum(np.arccos(np.clip(ca, -1, 1)) - rim, np.pi)) > np.cos(
                light.spot_size / 2
            )
            val *= reach | inside
    lit = np.flatnonzero(val > 0)
    if not len(lit):
        return val
    if rays <= 1:
        val[lit] *= ~backend.occluded(o[lit], np.broadcast_to(light.position, (len(lit), 3)))
        return val
    u = rotated_hammersley(rays, seed, keys[lit], 2000 + stream)
    wl, nl, xl = w[lit], n[lit], x[lit]
    if light.soft_falloff:
        y = _disk_points(light.position, wl, light.radius, u)
        v = y - xl[:, None]
        t2 = np.maximum(np.einsum("lsk,lsk->ls", v, v), 1e-300)
        # cos at the point x cos at the disc / distance^2 (area-uniform points)
        kern = np.maximum(np.einsum("lsk,lk->ls", v, nl), 0) * np.einsum("lsk,lk->ls", v, wl) / (t2 * t2)
        dirs = v / np.sqrt(t2)[..., None]
    else:
        # directions uniform in the cone of the sphere's outline (or cosine-weighted over the
        # hemisphere inside it), to the sphere's near (far, inside) surface
        dl, r = dist[lit], float(light.radius)
        ins = dl <= r
        cmax = np.sqrt(np.maximum(1 - (r / dl) ** 2, 0.0))
        axis = np.where(ins[:, None], nl, wl)
        cz = np.where(
            ins[:, None], np.sqrt(np.maximum(1 - u[..., 0], 0)), 1 - u[..., 0] * (1 - cmax[:, None])
        )
        dirs = _cone_dirs(axis, cz, u[..., 1])
        cw = np.einsum("lsk,lk->ls", dirs, wl) * dl[:, None]  # d cos to the centre
        root = np.sqrt(np.maximum(r * r - dl[:, None] ** 2 + cw * cw, 0))
        tlen = np.where(ins[:, None], cw + root, cw - root)
        y = xl[:, None] + tlen[..., None] * dirs
        kern = np.where(ins[:, None], 1.0, np.maximum(np.einsum("lsk,lk->ls", dirs, nl), 0))
    share = kern * ~backend.occluded(np.broadcast_to(o[lit, None], y.shape), y)
    if spot:
        cone = spot_factor(light, -(dirs @ light.direction))
        share = share * (np.where(inside[lit, None], 1.0, cone) if not light.soft_falloff else cone)
    ks = kern.sum(1)
    val[lit] *= np.where(ks > 0, share.sum(1) / np.where(ks > 0, ks, 1), 0.0)
    return val


def unit_incident(light, x, n, backend, eps, rays=8, seed=0, keys=None, stream=0, far=None, portal="auto"):
    """Unit direct light of `light` (per watt, or per W/m^2 for the sun) at surface points x (N, 3)
    with unit normals n, as irradiance / pi (the gather's "incident" unit), shadow rays through
    `backend` (visibility.RayBackend). rays: shadow rays per point for lights with a size (radius,
    sun angle, area; a point or spot with a radius: _sized_incident); a point light of radius 0
    casts one. keys: per-point random keys
    (gather.position_keys), default the point index. far: a sun's shadow ray length, beyond the
    scene but not far beyond it (ray backends' minimum hit distance is relative to the segment;
    default 1e4 x eps). portal: the sky's sky.EscapeMap ("auto": from these points' rays). -> (N,)
    float64."""
    from .gather.sampling import rotated_hammersley

    x = np.asarray(x, np.float64).reshape(-1, 3)
    n = np.asarray(n, np.float64).reshape(-1, 3)
    N = len(x)
    out = np.zeros(N)
    if N == 0:
        return out
    keys = np.arange(N, dtype=np.uint64) if keys is None else keys
    if light.kind == "SKY":
        from .sky import RAY_FACTOR, sky_incident

        far = float(far or 1e4 * eps)
        return sky_incident(light, x, n, backend, eps, rays * RAY_FACTOR, seed, keys, stream, far, portal)
    o = x + eps * n
    if light.kind in ("POINT", "SPOT") and light.radius > 0:
        return _sized_incident(light, x, n, o, backend, rays, seed, keys, stream)
    if light.kind in ("POINT", "SPOT"):
        d = light.position - x
        r2 = np.einsum("ij,ij->i", d, d)
        dist = np.sqrt(np.maximum(r2, 1e-300))
        w = d / dist[:, None]
        cos = np.einsum("ij,ij->i", w, n)
        val = np.maximum(cos, 0) * POINT_INTENSITY / np.maximum(r2, 1e-300) / np.pi
        if light.kind == "SPOT":
            val *= spot_factor(light, -(w @ light.direction))
        lit = np.flatnonzero(val > 0)
        if len(lit):
            val[lit] *= ~backend.occluded(o[lit], np.broadcast_to(light.position, (len(lit), 3)))
        return val
    if light.kind == "SUN":
        to_sun = -light.direction
        cos = n @ to_sun
        val = np.maximum(cos, 0) * SUN_IRRADIANCE / np.pi
        lit = np.flatnonzero(val > 0)
        if len(lit):
            far = float(far or 1e4 * eps)
            if light.angle > 0 and rays > 1:
                # directions uniform in the sun's cone (half angle angle / 2)
                u = rotated_hammersley(rays, seed, keys[lit], 3000 + stream)
                dirs = _cone_dirs(to_sun[None], 1 - u[..., 0] * (1 - np.cos(light.angle / 2)), u[..., 1])
                vis = ~backend.occluded(np.broadcast_to(o[lit, None], dirs.shape), o[lit, None] + far * dirs)
                val[lit] *= vis.mean(1)
            else:
                val[lit] *= ~backend.occluded(o[lit], o[lit] + far * to_sun)
        return val
    # AREA: exact form factor of the polygon (horizon clipped) x a kernel-weighted visibility ratio
    pieces, nv, area = light.pieces()
    nf = light.direction
    A = float(area.sum())
    front = (x - light.outline[0]) @ nf > eps
    i = np.flatnonzero(front)
    if len(i) == 0 or A <= 0:
        return out
    T = len(pieces)
    F = (
        ff.point_to_polygon(
            np.repeat(x[i], T, 0), np.repeat(n[i], T, 0), np.tile(pieces, (len(i), 1, 1)), np.tile(nv, len(i))
        )
        .reshape(-1, T)
        .sum(1)
    )
    lit = np.flatnonzero(F > 0)
    if len(lit) and rays > 0:
        from .gather.sampling import Emitter

        em = Emitter(pieces, nv, area, np.repeat(nf[None], T, 0))
        u = rotated_hammersley(rays, seed, keys[i[lit]], 4000 + stream)
        y, ny = em.sample(u)  # area-uniform
        d = y - x[i[lit], None]
        r2 = np.maximum(np.einsum("lsk,lsk->ls", d, d), 1e-300)
        kern = np.maximum(np.einsum("lsk,lk->ls", d, n[i[lit]]), 0) * np.maximum(-(d @ nf), 0) / r2**2
        vis = ~backend.occluded(np.broadcast_to(o[i[lit], None], y.shape), y + eps * nf)
        ks = kern.sum(1)
        F[lit] *= np.where(ks > 0, (kern * vis).sum(1) / np.where(ks > 0, ks, 1), 1.0)
    out[i] = F * AREA_RADIANCE / A
    return out


def area_emitter(light, stream=0):
    """gather.Emitter of an area light (its polygon; the contour fast path over its outline)."""
    from .gather.sampling import Emitter

    pieces, nv, area = light.pieces()
    nf = light.direction
    return Emitter(
        pieces,
        nv,
        area,
        np.repeat(nf[None], len(pieces), 0),
        [light.outline],
        nf,
        light.outline[0].copy(),
        stream=stream,
    )


def node_incident(h, nodes, light, backend, eps, rays=4, seed=0, unit=1.0, far=None, uneven=0.2, fine=6):
    """(len(nodes),) unit direct light (irradiance / pi) averaged over each node's 2 x 2 Gauss
    points, on its uncovered part (contacts: Hierarchy.dark). Nodes where those values differ by
    more than `uneven` x their largest (a spot's edge, a shadow boundary crossing the node), or
    where the light reaches some of them and its corners (just inside) but not others, are
    integrated again with fine x fine points: 2 x 2 points under a smoothstep edge or a shadow
    are off by tens of percent on a coarse node, and that node's light is bounce light for the
    whole room. The corners catch an edge that passes between the Gauss points and the node's
    side (a sun's patch through a hole: a strip along a leaf's side read dark, or a leaf read
    wholly lit, by its 4 points). A node near a point or spot light (its half-diagonal more than
    NEAR x its centre's distance from the light) takes NEAR_Q x that ratio points a side (fine to
    4 fine): 1 / d^2 curves across it, and 2 x 2 points symmetric about the light's foot read the
    same value, their mean low (a square under a light at its half-diagonal: -4.4%; the loft's
    lamp shade, 8 x 28 cm faces 16-22 cm from its bulb: -7%, its whole first bounce; session 36)."""
    from .gather.sampling import position_keys

    nodes = np.asarray(nodes, np.int64)
    if len(nodes) == 0:
        return np.zeros(0)
    v, vmin, vmax = _node_mean(h, nodes, light, backend, eps, rays, seed, unit, far, 2)
    edge = np.zeros(len(nodes), bool)
    q = np.full(len(nodes), 2, np.int64)  # each node's points a side
    if light.kind != "SKY":  # a sky point whose few rays all stay in is noise, not an edge
        c = h.corners[nodes]
        cen = ff.quadrature(c, h.nv[nodes], 1)[0][:, 0]
        inside = (c + CORNER_IN * (cen[:, None] - c)).reshape(-1, 3)  # triangles: corner 2 twice
        nrm = np.repeat(h.normal[nodes], 4, 0)
        keys = position_keys(inside, unit)
        vc = unit_incident(light, inside, nrm, backend, eps, rays, seed, keys, far=far).reshape(-1, 4)
        edge = ((vmax > 0) | (vc.max(1) > 0)) & ((vmin <= 0) | (vc.min(1) <= 0))
        if light.kind in ("POINT", "SPOT") and fine > 2:
            half = np.linalg.norm(c - cen[:, None], axis=2).max(1)
            ratio = half / np.maximum(np.linalg.norm(np.asarray(light.position) - cen, axis=1), 1e-300)
            near = (vmax > 0) & (ratio > NEAR)
            q[near] = np.clip(np.ceil(NEAR_Q * ratio[near]), fine, 4 * fine)
    redo = (vmax > 0) & (vmax - vmin > uneven * vmax) & ~edge
    if fine > 2:
        # where the light stops inside the node (a shadow, a cone, a hole's image) 2 fine points a
        # side: a step is integrated to about a half-row (0.125 m leaves under a hole's image: each
        # within 4.3% of a lit leaf's light)
        q[redo] = np.maximum(q[redo], fine)
        q[edge] = np.maximum(q[edge], 2 * fine)
        for k in np.unique(q[q > 2]).tolist():
            sel = np.flatnonzero(q == k)
            v[sel] = _node_mean(h, nodes[sel], light, backend, eps, rays, seed, unit, far, k)[0]
    return v


# node_incident near a point or spot light: NEAR_Q x (half-diagonal / distance) Gauss points a side
# where that ratio exceeds NEAR (a square centred under the light, 2 x 2 points: -0.4% at 0.5, -4.4% at
# 1; with NEAR_Q x the ratio points a side within 0.2% up to 3, 0.5% at 5)
NEAR = 0.5
NEAR_Q = 3.0


CORNER_IN = 0.02  # node_incident's corner tests: this share of the way to the node's centre (a corner
# on a wall's edge would read the neighbouring wall's shadow)


def _node_mean(h, nodes, light, backend, eps, rays, seed, unit, far, q):
    from .gather.sampling import position_keys

    x, gw = ff.quadrature(h.corners[nodes], h.nv[nodes], q)
    k = x.shape[1]
    pts = x.reshape(-1, 3)
    nrm = np.repeat(h.normal[nodes], k, 0)
    v = unit_incident(light, pts, nrm, backend, eps, rays, seed, position_keys(pts, unit), far=far)
    v = v.reshape(-1, k)
    ex = h.exposure[nodes]
    part = np.flatnonzero((ex > 0) & (ex < 1))
    w = gw.copy()
    if len(part) and h.contacts is not None:
        lit = ~h.dark(np.repeat(nodes[part], k), x[part].reshape(-1, 3)).reshape(-1, k)
        w[part] *= lit
    ws = w.sum(1)
    mean = np.where(ws > 0, (v * w).sum(1) / np.where(ws > 0, ws, 1), 0.0)
    return mean, v.min(1), v.max(1)


BRIGHT_LEAVES = 256  # bright_leaves: at most this many leaves are integrated explicitly
BRIGHT_SHARE = 0.95  # ... and only when so few hold this share of a light's first bounce
FAR_SIZES = 5.0  # leaf_bounce: a polygon this many times its size away is a point (its centroid)


def bright_leaves(power, most=None, share=BRIGHT_SHARE):
    """Indices of the leaves whose first-bounce `power` (m,) > 0 a final gather should integrate
    explicitly (leaf_bounce) rather than find with its hemisphere rays: every lit leaf (the
    brightest `most`) when at most `most` leaves hold `share` of the power, else none. A sun
    through a 0.17 m hole lights ~130 of Cornell's 5,800 HR leaves: the texels' 128 rays find that
    patch a few times each, and a surface's mean of its bounce scattered by +-2.5% from one gather
    seed to the next (docs/lights.md). A bounce spread over the room is found well by the rays."""
    most = BRIGHT_LEAVES if most is None else most
    power = np.asarray(power, np.float64)
    lit = np.flatnonzero(power > 0)
    if len(lit) == 0:
        return lit
    o = lit[np.argsort(-power[lit], kind="stable")]
    if np.searchsorted(np.cumsum(power[o]), share * power[o].sum()) >= most:
        return np.zeros(0, np.int64)
    return np.sort(o[:most])


def leaf_bounce(x, n, keys, corners, nv, radiance, backend, eps, rays=32, seed=0, stream=0, chunk=2048):
    """(N, 3) incident light (irradiance / pi) at points x (N, 3), unit normals n, from polygons
    (corners (m, 4, 3), nv (m,), CCW about their emitting side) of uniform radiance (m, 3): the
    exact unoccluded form factor of each (horizon clipped) x the visible share from `rays` shadow
    rays per point, each to an area-uniform point of a polygon picked by form factor x radiance
    (so a point next to the polygons is as well estimated as a far one), the visible share
    kernel-weighted and pooled over the point's rays. keys (N,): the points'
    random keys (gather.position_keys): the same values in any batching."""

    from .gather.sampling import hash_uniform, rotated_hammersley

    x = np.asarray(x, np.float64).reshape(-1, 3)
    n = np.asarray(n, np.float64).reshape(-1, 3)
    radiance = np.asarray(radiance, np.float64).reshape(-1, 3)
    out = np.zeros((len(x), 3))
    m = len(corners)
    if m == 0 or len(x) == 0:
        return out
    lum = radiance.mean(1)
    c = np.asarray(corners, np.float64).copy()
    tri = np.asarray(nv) == 3
    c[tri, 3] = c[tri, 2]
    nrm, _ = ff.polygon_normal_area(c, nv)
    a0 = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    a1 = 0.5 * np.linalg.norm(np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 0]), axis=1)
    area = a0 + a1
    split = a0 / np.maximum(area, 1e-300)  # share of triangle (0, 1, 2)
    cen = (a0[:, None] * (c[:, 0] + c[:, 1] + c[:, 2]) + a1[:, None] * (c[:, 0] + c[:, 2] + c[:, 3])) / (
        3 * np.maximum(area, 1e-300)[:, None]
    )
    for s0 in range(0, len(x), chunk):
        xs, ns = x[s0 : s0 + chunk], n[s0 : s0 + chunk]
        # only pairs where each faces the other (point_to_polygon would give them 0): a spot's
        # footprint on a wall is behind most of the room's samples
        ok = (np.einsum("lk,mk->lm", xs, nrm) > np.einsum("mk,mk->m", c[:, 0], nrm)[None] + eps) & (
            np.einsum("mvk,lk->lmv", c, ns).max(2) > np.einsum("lk,lk->l", xs, ns)[:, None]
        )
        # far pairs (beyond FAR_SIZES x the polygon's size) by the point-to-point kernel at its
        # centroid, the rest by the exact contour integral (most of the cost)
        dc = cen[None] - xs[:, None]
        d2 = np.einsum("lmk,lmk->lm", dc, dc)
        far = ok & (d2 > FAR_SIZES**2 * area[None])
        # divided only where far: near pairs can sit at d2 = 0 (0 / 0)
        F = np.divide(
            np.maximum(np.einsum("lmk,lk->lm", dc, ns), 0)
            * np.maximum(-np.einsum("lmk,mk->lm", dc, nrm), 0)
            * area[None],
            np.pi * d2**2,
            out=np.zeros_like(d2),
            where=far,
        )
        a, b = np.nonzero(ok & ~far)
        F[a, b] = ff.point_to_polygon(xs[a], ns[a], c[b])
        w = F * lum[None]
        W = w.sum(1)
        i = np.flatnonzero(W > 0)
        if len(i) == 0:
            continue
        cdf = np.cumsum(w[i], 1) / W[i, None]
        u = rotated_hammersley(rays, seed, keys[s0 + i], 5000 + stream)  # (l, rays, 2): leaf, tri
        # the point in the triangle: a 2-D set of its own, matched to the rays in a random order (both
        # sets' first coordinates run with the ray's index: unmatched, a picked polygon's points
        # would crowd towards one corner)
        v = rotated_hammersley(rays, seed, keys[s0 + i], 6000 + stream)
        with np.errstate(over="ignore"):
            ray_keys = keys[s0 + i, None] * np.uint64(rays) + np.arange(rays, dtype=np.uint64)
        order = np.argsort(hash_uniform(seed, ray_keys.ravel(), 7000 + stream, 1).reshape(len(i), rays), 1)
        v = np.take_along_axis(v, order[..., None], 1)
        j = np.minimum((cdf[:, None, :] <= u[..., :1]).sum(-1), m - 1)  # (l, rays)
        lo = np.where(j > 0, np.take_along_axis(cdf, np.maximum(j - 1, 0), 1), 0.0)
        hi = np.take_along_axis(cdf, j, 1)
        t = (u[..., 0] - lo) / np.maximum(hi - lo, 1e-300)  # uniform again within the picked leaf
        second = t >= split[j]
        p0 = c[j, 0]
        p1 = np.where(second[..., None], c[j, 2], c[j, 1])
        p2 = np.where(second[..., None], c[j, 3], c[j, 2])
        r = np.sqrt(v[..., 0])
        y = p0 + (r * (1 - v[..., 1]))[..., None] * (p1 - p0) + (r * v[..., 1])[..., None] * (p2 - p0)
        o = xs[i] + eps * ns[i]
        vis = ~backend.occluded(np.broadcast_to(o[:, None], y.shape), y + eps * nrm[j])
        # the visible share, kernel-weighted as the form factor is: each ray's kernel over its
        # polygon's mean kernel (pi F / A), pooled over the point's rays per channel (a share per
        # polygon from its few rays, the rest taking the pooled one, read a back wall 10% bright
        # through 32 rays on 130 leaves: the unsampled leaves are not the sampled ones' average)
        dv = y - o[:, None]
        r2 = np.maximum(np.einsum("lrk,lrk->lr", dv, dv), 1e-300)
        kern = np.maximum(np.einsum("lrk,lk->lr", dv, ns[i]), 0) * np.maximum(
            -np.einsum("lrk,lrk->lr", dv, nrm[j]), 0
        )
        Fi = F[i]
        q = kern / r2**2 * area[j] / (np.pi * np.maximum(np.take_along_axis(Fi, j, 1), 1e-300))
        # per ray radiance / luminance: rays went to polygons in proportion to F x luminance, so
        # the ratio's expectation is sum F L V / sum F L per channel (consistent; exact unoccluded)
        qc = q[..., None] * (radiance / np.where(lum > 0, lum, 1.0)[:, None])[j]  # (l, rays, 3)
        qs = qc.sum(1)
        share = np.einsum("lr,lrc->lc", vis, qc) / np.where(qs > 0, qs, 1.0)
        out[s0 + i] = (Fi @ radiance) * share
    return out


def indirect_incident(gather, dyn):
    """(n_out, 3) incident light (irradiance / pi) at a FinalGather's outputs without the direct
    light of the Blender lights and the World: what EEVEE does not render itself (it renders those
    lights' direct light and shadows; emissive meshes and light shapes light nothing in EEVEE, so
    their direct light stays). The lights' bounce light stays. The gather's cached unit direct
    light of each light (the same rays) is taken out of its incident light, per sample, then
    averaged over each output's samples as the incident light is (a texel's sub-samples)."""
    inc = gather.evaluate(dyn, "incident")
    lit = np.zeros((gather.n, 3))
    for rec in dyn.lights.values():
        lit += gather._light(rec)[:, None].astype(np.float64) * rec.scale[None]
    lit[gather.dark] = 0.0
    inc -= gather.outputs(gather.scaled(lit))
    inc[gather.out_dark] = 0.0
    return np.maximum(inc, 0.0)  # the same float32 parts subtracted: rounding only below 0
