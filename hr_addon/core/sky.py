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


def sky_incident(light, x, n, backend, eps, rays, seed, keys, stream, far):
    """Unit direct light (irradiance / pi) of the sky `light` at points x (N, 3) with unit normals n:
    the mean over `rays` cosine-weighted directions of the table's radiance where the ray escapes
    the scene (a segment of length `far` that hits nothing). -> (N,) float64."""
    from .gather.sampling import cosine_directions

    N = len(x)
    if N == 0:
        return np.zeros(0)
    R = max(int(rays), 1)
    d = cosine_directions(n, keys, R, seed, stream=5000 + stream)  # (N, R, 3)
    o = np.broadcast_to((x + eps * n)[:, None], d.shape)
    free = ~backend.occluded(o.reshape(-1, 3), (o + far * d).reshape(-1, 3)).reshape(N, R)
    L = 1.0 if light.sky is None else lookup(light.sky, d)
    return (free * L).mean(1)
