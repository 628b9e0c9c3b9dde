"""Where Cycles' bake samples a texel: its points over the texel's area (the middle half, the
part of it inside the centre's triangle), shared by the texel gather's sub-samples (layouts.py)
and the direct light of texels a light's edge crosses (texel_edges.py)."""

import numpy as np

from .sampling import hash_uniform

# Blender hands Cycles half the barycentric change per pixel as the bake's differentials
# (render/intern/bake.cc, bake_differentials: A = 0.5f / A), so its samples span the middle half
# of the texel in each direction
BAKE_SPAN = 0.5
# Cycles' bake_jitter_barycentric (kernel/integrator/init_from_bake.h, Blender 5.0): a jittered
# point outside the centre's triangle is drawn again, up to this many tries, then the centre
BAKE_TRIES = 10


def has_area(t):
    """(n,) whether triangles t (n, 3, 3) are not degenerate (a texel without one reads its centre)."""
    a = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return a > 1e-12 * np.maximum(np.abs(t).max((1, 2)), 1e-300) ** 2


def bake_points(tris, centres, axes, f):
    """Where Cycles' bake evaluates a texel at sub-pixel offsets f (n, ..., 2) in [0, 1]^2, 0.5 the
    centre (kernel/integrator/init_from_bake.h, Blender 5.0): the centre's barycentrics in its
    triangle tris (n, 3, 3) moved by BAKE_SPAN x the barycentric steps of the texel's sides axes
    (n, 2, 3); an offset that leaves the triangle is drawn again (BAKE_TRIES, then the centre). So
    the points are uniform over the middle half of the texel inside the centre's triangle: a
    texel straddling the triangle's edge reads its own triangle, never the neighbour. Offsets
    inside keep their place; the redrawn ones are uniforms keyed by the offset (deterministic).
    Cycles 3.x folded such offsets back by mirror repeat instead; a Position bake of Blender
    5.0.1 matches this (benchmarks/bake_footprint.py, docs/lights.md). Returns (n, ..., 3)."""
    t = np.asarray(tris, np.float64)
    E = np.stack([t[:, 0] - t[:, 2], t[:, 1] - t[:, 2]], 2)  # (n, 3, 2): d P / d (u, v)
    G = np.einsum("nki,nkj->nij", E, E)
    rhs = np.concatenate(
        [(centres - t[:, 2])[:, :, None], BAKE_SPAN * np.swapaxes(axes, 1, 2)], 2
    )  # (n, 3, 3)
    B = np.linalg.solve(G, np.einsum("nki,nkj->nij", E, rhs))  # (n, 2, 3): uv of centre, d/dx, d/dy
    f = np.array(f, np.float64)
    B = B.reshape(B.shape + (1,) * (f.ndim - 2))  # broadcast over f's sample axes

    def uv(g):
        fx, fy = g[..., 0] - 0.5, g[..., 1] - 0.5
        u = B[:, 0, 0] + B[:, 0, 1] * fx + B[:, 0, 2] * fy
        v = B[:, 1, 0] + B[:, 1, 1] * fx + B[:, 1, 2] * fy
        return u, v, (u > 0) & (v > 0) & (u + v < 1)

    u, v, ok = uv(f)
    for k in range(1, BAKE_TRIES):
        if ok.all():
            break
        bits = f[~ok].view(np.uint64)
        f[~ok] = hash_uniform(k, bits[:, 0] ^ (bits[:, 1] << np.uint64(1)), 2700, 2)
        u2, v2, ok2 = uv(f)
        new = ~ok & ok2
        u, v, ok = np.where(new, u2, u), np.where(new, v2, v), ok | new
    u, v = np.where(ok, u, B[:, 0, 0]), np.where(ok, v, B[:, 1, 0])
    t = t.reshape((len(t),) + (1,) * (f.ndim - 2) + (3, 3))
    return u[..., None] * t[..., 0, :] + v[..., None] * t[..., 1, :] + (1 - u - v)[..., None] * t[..., 2, :]


def texel_points(centres, axes, tris, f, rows=slice(None)):
    """Points at offsets f (n, k, 2) in [0, 1]^2 over texels with centres (n, 3) and sides axes
    (n, 2, 3): placed as Cycles' bake places them (bake_points) in tris[rows] (the centres'
    triangles), or over the texel's parallelogram where tris is None. -> (n, k, 3)."""
    if tris is None:
        return (
            centres[:, None] + (f[..., :1] - 0.5) * axes[:, None, 0] + (f[..., 1:] - 0.5) * axes[:, None, 1]
        )
    return bake_points(np.asarray(tris, np.float64).reshape(-1, 3, 3)[rows], centres, axes, f)
