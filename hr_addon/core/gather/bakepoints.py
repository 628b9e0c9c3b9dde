"""Where Cycles' bake samples a texel: its points over the texel's area (the middle half, folded
into the centre's triangle), shared by the texel gather's sub-samples (layouts.py) and the
direct light of texels a light's edge crosses (texel_edges.py)."""

import numpy as np

# Blender hands Cycles half the barycentric change per pixel as the bake's differentials
# (render/intern/bake.cc, bake_differentials: A = 0.5f / A), so its samples span the middle half
# of the texel in each direction
BAKE_SPAN = 0.5


def has_area(t):
    """(n,) whether triangles t (n, 3, 3) are not degenerate (a texel without one reads its centre)."""
    a = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return a > 1e-12 * np.maximum(np.abs(t).max((1, 2)), 1e-300) ** 2


def bake_mirror(x, m):
    """Cycles' bake_clamp_mirror_repeat: x folded into [0, m] by mirror repeat."""
    m = np.maximum(m, 1e-12)
    x = x / m
    f = np.floor(x)
    x = x - f
    return np.where(f.astype(np.int64) % 2 == 1, 1 - x, x) * m


def bake_points(tris, centres, axes, f):
    """Where Cycles' bake evaluates a texel at sub-pixel offsets f (..., 2) in [0, 1]^2, 0.5 the
    centre (kernel/integrator/init_from_bake.h): the centre's barycentrics (u, v) in its triangle
    tris (n, 3, 3) in the mesh's loop-triangle order (P = u v0 + v v1 + (1 - u - v) v2, Cycles'
    triangle_point_normal) moved by BAKE_SPAN x the barycentric steps of the texel's sides axes
    (n, 2, 3), u folded into [0, 1] and then v into [0, 1 - u] by mirror repeat: the samples
    never leave the centre's triangle, a texel straddling its edge reads its own triangle folded
    back. Returns (n, ..., 3) points."""
    t = np.asarray(tris, np.float64)
    E = np.stack([t[:, 0] - t[:, 2], t[:, 1] - t[:, 2]], 2)  # (n, 3, 2): d P / d (u, v)
    G = np.einsum("nki,nkj->nij", E, E)
    rhs = np.concatenate(
        [(centres - t[:, 2])[:, :, None], BAKE_SPAN * np.swapaxes(axes, 1, 2)], 2
    )  # (n, 3, 3)
    B = np.linalg.solve(G, np.einsum("nki,nkj->nij", E, rhs))  # (n, 2, 3): uv of centre, d/dx, d/dy
    B = B.reshape(B.shape + (1,) * (f.ndim - 2))  # broadcast over f's sample axes
    fx, fy = f[..., 0] - 0.5, f[..., 1] - 0.5
    u = bake_mirror(B[:, 0, 0] + B[:, 0, 1] * fx + B[:, 0, 2] * fy, 1.0)
    v = bake_mirror(B[:, 1, 0] + B[:, 1, 1] * fx + B[:, 1, 2] * fy, 1.0 - u)
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
