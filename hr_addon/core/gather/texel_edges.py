"""Texels whose direct light from a Blender light or an emitter changes inside them (a shadow's or a
spot cone's edge across the texel, an emitter's penumbra, a book's top between its neighbours): their
direct light is the mean over sub x sub points of the texel's area, as a renderer's bake averages it,
instead of the value at the centre (issues 19 and 20, docs/lights.md, docs/gather.md). A centre
decides a whole texel lit or dark where a sharp edge runs along texel rows."""

import copy
import time

import numpy as np

from ..parallel import batch_map, ranges
from .bakepoints import has_area, texel_points
from .points import onto_patch
from .sampling import Emitter, hash_uniform, position_keys

SUB = 8  # points per side of an edge texel (few texels: 64 points keep one texel's quantisation at 1/64)
# an edge texel: the light at its four corners and centre spans more than EDGE_TOL of their
# maximum (a smooth fall-off changes a texel by a few per cent, nearly linearly: its centre is
# its mean)
EDGE_TOL = 0.1
CORNERS = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
# texels whose corners one batch tests at most: a Blender light's corner costs one shadow ray, so
# batches by rays alone took 131,072 texels (524,288 points, about 1 kB of temporaries each in
# onto_patch and the light's read: +0.5 GB at a texture bake's frame, two_rooms, docs/scale.md
# session 32 "texmem"); each point's value is its own, so the batches do not change the values
CORNER_BATCH = 1 << 14


def emitter_rays(rays):
    """Shadow rays per corner and area point of an emitter's edge texel: a quarter of the texel's
    (at least 4, as a Blender light's own): 64 points x 4 rays are still 16x the centre's 16."""
    return max(rays // 4, 4)


def texel_area(points, axes, tris, rows):
    """The texel areas FinalGather.texel_area holds: (rows (k,) sample of each texel gathered at its
    centre, centres (k, 3), axes (k, 2, 3), tris (k, 3, 3) or None), texels without a triangle
    (degenerate) left out."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    axes = np.asarray(axes, np.float64).reshape(-1, 2, 3)
    if tris is not None:
        t = np.asarray(tris, np.float64).reshape(-1, 3, 3)
        keep = has_area(t)
        return rows[keep], points[keep], axes[keep], t[keep]
    return rows, points, axes, None


def edge_direct(g, light, centre, rays, stream, sub=SUB, tol=EDGE_TOL, shafts=None):
    """(n,) unit direct light of `light` at the samples of FinalGather g: `centre` (its values at the
    samples) with each edge texel of g.texel_area replaced by the mean over sub x sub jittered
    points of its area (bakepoints.texel_points: where Cycles' bake samples it).
    light: a core.lights.Light (not AREA or SKY) through core.lights.unit_incident, `rays` shadow
    rays per point; edge texels: their four corners (one hard shadow ray each) and centre differ
    by more than tol of their maximum.
    Or a sampling.Emitter (static emitters, light shapes, area lights) through g's direct_batch
    (shafts: its ClearShafts, or None; its own ray streams: `stream` unused), emitter_rays(rays)
    shadow rays per point; edge texels: the centre differs from the mean of the four corners by
    more than tol of their maximum. An emitter's soft penumbrae and near fall-off are ramps whose
    centre is their mean: the max - min rule flagged 15% of the Cornell sample's texels, 6x the
    cost for nothing; a shadow edge or a book's top between its neighbours bends the light inside
    the texel, which the bilinear test sees (docs/gather.md).
    Texels elsewhere keep their values bitwise. g.stats["edge_texels"]: (tested, edge texels, extra
    shadow rays: an Emitter's culled points take fewer) and ["edge_texels_cpu"] (process s),
    summed over calls."""
    from .. import lights as lt

    t0 = time.process_time()
    rows, cen, axes, tris = g.texel_area
    live = ~g.dark[rows]
    if g.gain is not None:  # in a slot: the slot's transfer carries the light (FinalGather._slots)
        live &= (g.gain[rows] == 1).all(1)
    j = np.flatnonzero(live)
    out = np.asarray(centre, np.float64).copy()
    if not len(j):
        return out
    pt, s = g.system.patches, g.system
    emitter = isinstance(light, Emitter)
    r_pt = emitter_rays(rays) if emitter else rays  # per area point
    r_c = r_pt if emitter else 1  # per corner

    def unit(x, patch, r):
        # as FinalGather's samples: a bake point on a slightly warped polygon's triangle lies off
        # its plane (1e-5 on the Cornell box's left wall), and its shadow rays would hit the wall
        x, nrm = onto_patch(pt, patch, x, g.margin), pt.normal[patch]
        keys = position_keys(x, g.unit)
        if emitter:
            p = copy.copy(g)  # the gather at these points (the arrays direct_batch reads)
            p.points, p.normals, p.keys, p.dark, p.shadow_rays = x, nrm, keys, np.zeros(len(x), bool), r
            # the clear-shaft cull pays from CULL_MIN_RAYS rays on (DirectLight.shafts)
            sh = shafts if r >= g.CULL_MIN_RAYS else None
            return p.direct_batch(light, 0, len(x), sh).astype(np.float64)
        return lt.unit_incident(
            light,
            x,
            nrm,
            s.backend,
            g.eps,
            rays=r,
            seed=g.seed,
            keys=keys,
            stream=stream,
            far=g.tmax,
        )

    # a point's work in rays (batch sizes): an emitter's form factor and sampling too
    c_cost, a_cost = (g.direct_cost(light, r_c), g.direct_cost(light, r_pt)) if emitter else (r_c, r_pt)
    edge = np.zeros(len(rows), bool)

    def corners(a, b):
        i = j[a:b]
        r = rows[i]
        tr = None if tris is None else tris[i]
        # the corners of the sampled part: those outside the centre's triangle on its edge
        cp = texel_points(cen[i], axes[i], tr, np.broadcast_to(CORNERS, (len(i), 4, 2)), clamp=True)
        v = np.concatenate([unit(cp, np.repeat(g.patch[r], 4), r_c).reshape(-1, 4), out[r, None]], 1)
        hi = v.max(1)
        dev = np.abs(v[:, 4] - v[:, :4].mean(1)) if emitter else hi - v.min(1)
        edge[i] = dev > tol * hi

    batch_map(corners, ranges(len(j), min(g.batch_rays // (4 * c_cost), CORNER_BATCH)), g.threads)
    e = np.flatnonzero(edge)
    k2 = sub * sub
    gx, gy = np.meshgrid(np.arange(sub), np.arange(sub), indexing="ij")
    grid = np.stack([gx.ravel(), gy.ravel()], 1)

    def area(a, b):
        i = e[a:b]
        r = rows[i]
        f = (grid[None] + hash_uniform(g.seed, g.keys[r], 2500, 2 * k2).reshape(-1, k2, 2)) / sub
        sp = texel_points(cen[i], axes[i], None if tris is None else tris[i], f)
        out[r] = unit(sp, np.repeat(g.patch[r], k2), r_pt).reshape(-1, k2).mean(1)

    batch_map(area, ranges(len(e), g.batch_rays // (k2 * a_cost)), g.threads)
    g.stats["edge_texels_cpu"] = g.stats.get("edge_texels_cpu", 0.0) + time.process_time() - t0
    was = g.stats.get("edge_texels", (0, 0, 0))  # summed over the lights and their geometries
    now = (len(j), len(e), 4 * r_c * len(j) + len(e) * k2 * r_pt)
    g.stats["edge_texels"] = tuple(int(a + b) for a, b in zip(was, now))
    return out
