"""Where Cycles' bake samples a texel: its points over the texel's area (the middle half, the
part of it inside the centre's triangle), shared by the texel gather's sub-samples (layouts.py)
and the direct light of texels a light's edge crosses (texel_edges.py)."""

import numpy as np

# Blender hands Cycles half the barycentric change per pixel as the bake's differentials
# (render/intern/bake.cc, bake_differentials: A = 0.5f / A), so its samples span the middle half
# of the texel in each direction
BAKE_SPAN = 0.5


def has_area(t):
    """(n,) whether triangles t (n, 3, 3) are not degenerate (a texel without one reads its centre)."""
    a = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return a > 1e-12 * np.maximum(np.abs(t).max((1, 2)), 1e-300) ** 2


def bake_points(tris, centres, axes, f, clamp=False):
    """Where Cycles' bake evaluates a texel at sub-pixel offsets f (n, ..., 2) in [0, 1]^2, 0.5 the
    centre (kernel/integrator/init_from_bake.h, Blender 5.0): the centre's barycentrics in its
    triangle tris (n, 3, 3) moved by BAKE_SPAN x the barycentric steps of the texel's sides axes
    (n, 2, 3); Cycles draws an offset that leaves the triangle again (up to 10 tries, then the
    centre), so its samples are uniform over the middle half of the texel inside the centre's
    triangle: a texel straddling the triangle's edge reads its own triangle, never the neighbour.
    Cycles 3.x folded such offsets back by mirror repeat instead (denser near the edge); a
    Position bake of Blender 5.0.1 matches the redraw (benchmarks/bake_footprint.py,
    docs/lights.md). Here the offsets inside keep their place and each one outside takes the
    place of an inside one, spread evenly over them in f's order: with stratified f the points
    stay stratified over that part (a few dozen random redraws would add their noise to a texel
    that a thin lit strip crosses), none inside: the centre. clamp: each offset outside moved
    towards the centre onto the triangle's edge instead (the sampled part's outline, for tests of
    whether the light changes across it). Returns (n, ..., 3)."""
    t = np.asarray(tris, np.float64)
    E = np.stack([t[:, 0] - t[:, 2], t[:, 1] - t[:, 2]], 2)  # (n, 3, 2): d P / d (u, v)
    G = np.einsum("nki,nkj->nij", E, E)
    rhs = np.concatenate(
        [(centres - t[:, 2])[:, :, None], BAKE_SPAN * np.swapaxes(axes, 1, 2)], 2
    )  # (n, 3, 3)
    B = np.linalg.solve(G, np.einsum("nki,nkj->nij", E, rhs))  # (n, 2, 3): uv of centre, d/dx, d/dy
    f = np.asarray(f, np.float64)
    n, shape = len(t), f.shape[1:-1]
    fx, fy = f[..., 0].reshape(n, -1) - 0.5, f[..., 1].reshape(n, -1) - 0.5
    u = B[:, 0, :1] + B[:, 0, 1:2] * fx + B[:, 0, 2:3] * fy
    v = B[:, 1, :1] + B[:, 1, 1:2] * fx + B[:, 1, 2:3] * fy
    ok = (u > 0) & (v > 0) & (u + v < 1)
    k = u.shape[1]
    if clamp and not ok.all():
        # the largest step from the centre (u0, v0) along each offset that stays inside
        u0, v0 = B[:, 0, :1], B[:, 1, :1]
        du, dv = u - u0, v - v0
        with np.errstate(divide="ignore", invalid="ignore"):
            lim = [np.where(du < 0, u0 / -du, 1), np.where(dv < 0, v0 / -dv, 1)]
            lim.append(np.where(du + dv > 0, (1 - u0 - v0) / (du + dv), 1))
        s = np.clip(np.minimum.reduce(lim), 0, 1) * (1 - 1e-9)
        u, v = np.where(ok, u, u0 + s * du), np.where(ok, v, v0 + s * dv)
    elif not ok.all():
        n_in = ok.sum(1, keepdims=True)
        order = np.argsort(~ok, axis=1, kind="stable")  # each row's inside offsets first, in f's order
        rank = np.cumsum(~ok, axis=1) - 1  # an outside offset's place among the row's outside ones
        src = np.minimum(((rank + 0.5) * n_in / np.maximum(k - n_in, 1)).astype(np.int64), n_in - 1)
        take = np.take_along_axis(order, np.maximum(src, 0), 1)
        u = np.where(ok, u, np.take_along_axis(u, take, 1))
        v = np.where(ok, v, np.take_along_axis(v, take, 1))
        none = n_in[:, 0] == 0
        u[none], v[none] = B[none, 0, :1], B[none, 1, :1]
    P = u[..., None] * t[:, None, 0] + v[..., None] * t[:, None, 1] + (1 - u - v)[..., None] * t[:, None, 2]
    return P.reshape((n,) + shape + (3,))


def texel_points(centres, axes, tris, f, rows=slice(None), clamp=False):
    """Points at offsets f (n, k, 2) in [0, 1]^2 over texels with centres (n, 3) and sides axes
    (n, 2, 3): placed as Cycles' bake places them (bake_points) in tris[rows] (the centres'
    triangles), or over the texel's parallelogram where tris is None. -> (n, k, 3)."""
    if tris is None:
        return (
            centres[:, None] + (f[..., :1] - 0.5) * axes[:, None, 0] + (f[..., 1:] - 0.5) * axes[:, None, 1]
        )
    return bake_points(np.asarray(tris, np.float64).reshape(-1, 3, 3)[rows], centres, axes, f, clamp)
