"""The World as a light at infinity (issue 20), numpy only.

A diffuse solution needs of the World only the irradiance it gives a surface point through the
openings of the scene: E(x) = integral over the directions w above x of L(w) V(x, w) cos dw, with
V = 1 where a ray from x escapes the scene. With cosine-weighted directions that is
E / pi = mean over the rays of L(w) V(w): for a uniform sky of radiance L, L times the fraction of
the rays that escape (1 under an open sky: E = pi L).

The environment is a small latitude-longitude table of radiance (Blender's equirectangular
mapping: column u = 0.5 - atan2(y, x) / 2 pi, row v = 0.5 + asin(z) / pi, row 0 at the bottom),
reduced from an Environment Texture by solid-angle weighted block means: a diffuse surface
integrates over a hemisphere, so detail below a few degrees does not change its light. A table
whose colour is the same everywhere up to a scale is one light (a grey table x one colour); any
other is three, one per channel (three times the rays).

A sky is a core.lights.Light of kind SKY whose `sky` table is normalised to a solid-angle mean of 1
and whose colour x strength carries the mean radiance, so a keyframed World strength or colour is
a scale of the cached parts like any light's. Its direct light at the output samples and its
first bounce on the hierarchy's leaves go through core.lights.unit_incident like every other
light's (the final gather and events/lightsrc.py need nothing of their own)."""

import numpy as np

RAY_FACTOR = 16  # sky rays per point = RAY_FACTOR x a light's shadow rays: the whole hemisphere is
# the light, so the escape fraction behind an opening needs more rays than a lamp's penumbra: with
# the gather's 32 shadow rays, 128 sky rays per sample; at 128 x 4 rays the direct light of an open
# box's floor is 2.7% rms off the exact lid-emitter value per sample, at 512 rays 0.9% (tests/test_sky.py)
PORTAL_CELLS = 32  # escape map: cells per side of each face of the scene's box
PORTAL_SHARE = 0.5  # share of a point's sky rays aimed at the escape map (where there is one)
PORTAL_OPEN = 0.25  # no escape map where more of the cosine rays escape (an open sky: they find it)
PILOT_POINTS = 16384  # an escape map is built from the rays of at most this many of the points
PILOT_STREAM = 9000  # ... with rays of their own: a map made of the rays it weighs biases them
TABLE_ROWS, TABLE_COLS = 32, 64  # reduced table: 5.6 degrees per cell
GREY_TOL = 1e-3  # channels equal up to a scale within this: one light, not three


def directions_to_uv(d):
    """(u, v) in [0, 1) of unit directions d (..., 3), Blender's equirectangular mapping."""
    u = 0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(d[..., 2], -1.0, 1.0)) / np.pi
    return u % 1.0, v


def lookup(table, d):
    """Radiance of the table (H, W) (or (H, W, C)) in unit directions d (..., 3): the cell holding
    each direction (the table is already a mean over its cells)."""
    H, W = table.shape[:2]
    u, v = directions_to_uv(d)
    col = np.minimum((u * W).astype(np.int64), W - 1)
    row = np.clip((v * H).astype(np.int64), 0, H - 1)
    return table[row, col]


def row_weights(H):
    """(H,) solid angle of a table row per cell, relative: rows of an equirectangular table span
    equal latitude steps, their cells' solid angle goes as sin(top) - sin(bottom)."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, H + 1)
    return np.diff(np.sin(lat))


def sphere_mean(table):
    """Solid-angle mean over the sphere of a table (H, W[, C])."""
    w = row_weights(table.shape[0])
    per_row = table.mean(1)
    return np.tensordot(w, per_row, axes=(0, 0)) / w.sum()


def reduce_table(pixels, rows=TABLE_ROWS, cols=TABLE_COLS):
    """An equirectangular image (H, W, C) (row 0 at the bottom) -> (rows, cols, C) solid-angle
    weighted block means (an image smaller than the table is kept as it is)."""
    px = np.asarray(pixels, np.float64)
    if px.ndim == 2:
        px = px[..., None]
    H, W = px.shape[:2]
    rows, cols = min(rows, H), min(cols, W)
    re = np.linspace(0, H, rows + 1).astype(np.int64)
    ce = np.linspace(0, W, cols + 1).astype(np.int64)
    w = row_weights(H)[:, None, None]
    num = np.add.reduceat(np.add.reduceat(px * w, re[:-1], 0), ce[:-1], 1)
    den = np.add.reduceat(np.broadcast_to(w, (H, 1, 1)), re[:-1], 0) * np.diff(ce)[None, :, None]
    return num / den


SUN_CONTRAST = 100.0  # a sun's pixels are this many times brighter than the sky's median
SUN_SHARE = 0.05  # ... and carry at least this share of the sky's light (else nothing is split off)
SUN_RADIUS = np.radians(5.0)  # ... within this of the brightest pixel (a sun, not a bright region)


def pixel_directions(H, W):
    """(H, W, 3) unit directions of an equirectangular image's pixel centres, (H,) solid angle of a
    pixel per row (row 0 at the bottom, Blender's mapping: directions_to_uv inverted)."""
    v = (np.arange(H) + 0.5) / H
    u = (np.arange(W) + 0.5) / W
    lat = (v - 0.5) * np.pi
    lon = (0.5 - u) * 2 * np.pi
    cl = np.cos(lat)[:, None]
    d = np.stack(np.broadcast_arrays(cl * np.cos(lon), cl * np.sin(lon), np.sin(lat)[:, None]), -1)
    return d, row_weights(H) * 2 * np.pi / W


def split_sun(pixels):
    """(pixels without the sun, sun or None) of an equirectangular image (H, W, 3), row 0 at the
    bottom. A sun is the pixels within SUN_RADIUS of the brightest one that are SUN_CONTRAST times
    the median's luminance, when they carry SUN_SHARE of the image's light and none that bright
    lies within twice that radius outside them (a bright region that wide is left in the table,
    a window or a lamp of an interior's HDR, not a sun): (unit direction toward
    it, irradiance (3,) at normal incidence, angular diameter of a disc of their solid angle). Its
    pixels are replaced by the median colour of the sky around it (within twice that radius), so
    the table keeps the sky and the sun gets exact shadow rays: drawn into a table cell of 5.6
    degrees it would be seen by one cosine-weighted sky ray in hundreds."""
    px = np.asarray(pixels, np.float64)
    H, W = px.shape[:2]
    y = px @ np.array([0.2126, 0.7152, 0.0722])
    d, omega = pixel_directions(H, W)
    med = float(np.median(y))
    top = np.unravel_index(np.argmax(y), y.shape)
    cos_top = d @ d[top]
    bright = y > SUN_CONTRAST * max(med, 1e-12)
    sun = bright & (cos_top > np.cos(SUN_RADIUS))
    ring = ~sun & (cos_top > np.cos(2 * SUN_RADIUS))
    flux = y * omega[:, None]
    if not sun.any() or flux[sun].sum() < SUN_SHARE * flux.sum() or (bright & ring).any():
        return px, None  # no sun, a faint one, or a bright region wider than a sun (a window)
    w = omega[:, None] * sun
    fill = np.median(px[ring], axis=0) if ring.any() else np.zeros(3)
    irr = np.tensordot(w, np.clip(px - fill, 0, None), axes=([0, 1], [0, 1]))  # the sky stays behind
    centre = np.tensordot(flux * sun, d, axes=([0, 1], [0, 1]))
    solid = float(w.sum())
    out = px.copy()
    out[sun] = fill
    angle = 2 * np.arccos(max(1 - solid / (2 * np.pi), -1.0))  # a cap of that solid angle
    return out, (centre / np.linalg.norm(centre), irr, float(angle))


def environment_parts(table_rgb):
    """[(colour (3,), normalised table (H, W))]: the sky lights of an RGB table (H, W, 3). One part
    when the channels are equal up to a scale (within GREY_TOL of the largest), else one per
    channel. Each table has solid-angle mean 1; colour is the channel means (x a unit vector)."""
    t = np.asarray(table_rgb, np.float64)
    mean = sphere_mean(t)  # (3,)
    if not mean.max() > 0:
        return []
    k = int(np.argmax(mean))
    grey = t[..., k] / mean[k]
    if np.all(np.abs(t - grey[..., None] * mean) <= GREY_TOL * t.max()):
        return [(mean, grey)]
    return [(np.eye(3)[c] * mean[c], t[..., c] / mean[c]) for c in range(3) if mean[c] > 0]


class EscapeMap:
    """Where the sky's light leaves the scene: a histogram of the exit points of escaping rays on
    the faces of the scene's box (6 x PORTAL_CELLS^2 cells), sampled as a source of directions.
    Seen from inside a room, a window is a small solid angle that cosine-weighted rays find a few
    times in a thousand; rays aimed at the cells the window's escapes cross find it with most of
    theirs. Only a proposal: sky_incident mixes it with the cosine rays (balance heuristic), so a
    direction the map misses is still sampled and the estimate stays unbiased."""

    def __init__(self, backend, cells=PORTAL_CELLS):
        tri = backend.triangles
        lo, hi = tri.min(axis=(0, 1)), tri.max(axis=(0, 1))
        pad = 1e-3 * max(float(np.max(hi - lo)), 1e-9)  # every surface point strictly inside
        self.lo, self.hi, G = lo - pad, hi + pad, int(cells)
        self.G, self.counts = G, np.zeros(6 * G * G)
        size = self.hi - self.lo
        # each cell's corner and edges (cell = face G^2 + i G + j, i along axis + 1, j along axis + 2)
        f, i, j = np.unravel_index(np.arange(6 * G * G), (6, G, G))
        ax = f // 2
        self.corner = np.where(f[:, None] % 2 == 1, self.hi, self.lo) * (np.arange(3) == ax[:, None])
        self.e1, self.e2 = np.zeros((2, 6 * G * G, 3))
        for k, (c, e) in enumerate(((i, self.e1), (j, self.e2))):
            a = (ax + k + 1) % 3
            e[np.arange(len(a)), a] = size[a] / G
            self.corner[np.arange(len(a)), a] = self.lo[a] + c * size[a] / G
        self.area = np.linalg.norm(np.cross(self.e1, self.e2), axis=1)

    def add(self, o, d):
        """Count escaping rays o + t d (unit d) where they leave the box. -> self"""
        cell, _, _ = self._exit(o, d)
        self.counts += np.bincount(cell, minlength=len(self.counts))
        self.P = self.counts / max(self.counts.sum(), 1.0)
        self.cdf = np.cumsum(self.P)
        self.density = self.P / self.area  # per unit area of the box's face
        return self

    def _exit(self, o, d):
        """(cell, distance, |d| along the face's normal) where rays o + t d (unit d) leave the box."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (self.hi - o) / d, np.where(d < 0, (self.lo - o) / d, np.inf))
        ax = np.argmin(t, -1)
        tt = t.min(-1)
        G = self.G
        ij = np.clip(((o + tt[..., None] * d - self.lo) / (self.hi - self.lo) * G).astype(np.int64), 0, G - 1)
        i = np.where(ax == 0, ij[..., 1], np.where(ax == 1, ij[..., 2], ij[..., 0]))
        j = np.where(ax == 0, ij[..., 2], np.where(ax == 1, ij[..., 0], ij[..., 1]))
        dax = np.where(ax == 0, d[..., 0], np.where(ax == 1, d[..., 1], d[..., 2]))
        return (2 * ax + (dax > 0)) * G * G + i * G + j, tt, np.abs(dax)

    def pdf(self, o, d):
        """Solid-angle density of directions d (unit) from points o under sample()."""
        cell, t, dax = self._exit(o, d)
        return self.density[cell] * t * t / np.maximum(dax, 1e-12)

    def sample(self, o, u, v):
        """Unit directions (N, R, 3) from points o (N, 3) to points uniform in cells picked by their
        share; u (N, R, 2) and v (N, R, 2) uniforms."""
        k = np.minimum(np.searchsorted(self.cdf, u[..., 0] * self.cdf[-1], side="right"), len(self.cdf) - 1)
        d = self.corner[k] + v[..., :1] * self.e1[k] + v[..., 1:] * self.e2[k] - o[:, None]
        return d / np.maximum(np.linalg.norm(d, axis=-1), 1e-300)[..., None]


def escape_map(x, n, backend, eps, rays, seed, keys, stream, far, chunk=1 << 21):
    """The EscapeMap of cosine-weighted sky rays from points x (N, 3), normals n (at most
    PILOT_POINTS of them, evenly strided; rays of a stream of their own, independent of those
    sky_incident weighs with the map; `chunk` rays at a time), or None where none escapes (a
    closed scene) or more than PORTAL_OPEN of them do (under an open sky the cosine rays alone are
    exact)."""
    k = slice(None, None, -(-len(x) // PILOT_POINTS))
    x, n, keys = x[k], n[k], keys[k]
    m = EscapeMap(backend)
    step = max(chunk // max(int(rays), 1), 1)
    for a in range(0, len(x), step):
        b = slice(a, a + step)
        o, d, free = _cosine_rays(x[b], n[b], backend, eps, rays, seed, keys[b], PILOT_STREAM + stream, far)
        m.add(np.broadcast_to(o[:, None], d.shape)[free], d[free])
    return m if 0 < m.counts.sum() <= PORTAL_OPEN * len(x) * max(int(rays), 1) else None


def _cosine_rays(x, n, backend, eps, rays, seed, keys, stream, far):
    from .gather.sampling import cosine_directions

    d = cosine_directions(n, keys, max(int(rays), 1), seed, stream=5000 + stream)  # (N, R, 3)
    o = x + eps * n
    ob = np.broadcast_to(o[:, None], d.shape)
    free = ~backend.occluded(ob.reshape(-1, 3), (ob + far * d).reshape(-1, 3)).reshape(d.shape[:2])
    return o, d, free


def sky_incident(light, x, n, backend, eps, rays, seed, keys, stream, far, portal="auto"):
    """Unit direct light (irradiance / pi) of the sky `light` at points x (N, 3) with unit normals n:
    the integral of the table's radiance over the directions whose ray escapes the scene (a segment
    of length `far` that hits nothing), cos-weighted, from `rays` rays: cosine-weighted directions,
    and with an EscapeMap (portal: one built for a larger set of points, "auto": escape_map of
    these points, None: none) PORTAL_SHARE of them aimed at it instead, combined by the balance
    heuristic: each ray weighs L cos / pi / (R p_cos + R_p p_map). -> (N,) float64."""
    N = len(x)
    if N == 0:
        return np.zeros(0)
    R = max(int(rays), 1)
    if isinstance(portal, str):
        portal = escape_map(x, n, backend, eps, R, seed, keys, stream, far)
    Rp = 0 if portal is None or R < 2 else max(int(round(PORTAL_SHARE * R)), 1)
    if Rp == 0:
        portal = None
    R -= Rp
    o, d, free = _cosine_rays(x, n, backend, eps, R, seed, keys, stream, far)
    L = 1.0 if light.sky is None else lookup(light.sky, d)
    if portal is None:
        return (free * L).mean(1)
    from .gather.sampling import rotated_hammersley

    # the cosine rays: cos / pi / (R cos / pi + Rp p_map) = 1 / (R + Rp pi p_map / cos)
    cos = np.einsum("nrk,nk->nr", d, n)
    i, j = np.nonzero(free)
    wc = np.zeros(free.shape)
    wc[i, j] = 1.0 / (R + Rp * np.pi * portal.pdf(o[i], d[i, j]) / np.maximum(cos[i, j], 1e-12))
    out = (wc * L).sum(1)
    u, v = (rotated_hammersley(Rp, seed, keys, s + stream) for s in (7000, 8000))
    dp = portal.sample(o, u, v)
    cp = np.einsum("nrk,nk->nr", dp, n)
    ob = np.broadcast_to(o[:, None], dp.shape)
    up = cp > 0
    fp = np.zeros(up.shape, bool)
    fp[up] = ~backend.occluded(ob[up], ob[up] + far * dp[up])
    i, j = np.nonzero(fp)
    wp = np.zeros(fp.shape)
    c = cp[i, j] / np.pi
    wp[i, j] = c / (R * c + Rp * portal.pdf(o[i], dp[i, j]))
    Lp = 1.0 if light.sky is None else lookup(light.sky, dp)
    return out + (wp * Lp).sum(1)
