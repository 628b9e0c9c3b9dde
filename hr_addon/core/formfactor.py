"""Form factors between convex planar polygons (numpy only).

Polygons follow docs/ARCHITECTURE.md: `corners (N, 4, 3)`, `nv (N,)` in {3, 4}, triangles padded by
repeating corner 2, counter-clockwise seen from the (only) emitting/receiving front side.

- `point_to_polygon`: exact unoccluded differential-area-to-polygon form factor (Lambert's contour
  integral) with the polygon clipped to the receiver's horizon.
- `patch_to_patch`: average of the above over a deterministic stratified set of points on p.
- `estimate`: cheap conservative disc approximation used as the refinement oracle.
"""

import functools
import math

import numpy as np

_TWO_PI = 2.0 * math.pi
# Relative tolerance (in units of the polygon's size) for "point lies on the polygon's plane".
_PLANE_EPS = 1e-12
# Fallback receiver cosine in `estimate` when p's centre is behind q but p may reach in front of it.
COS_FLOOR = 0.05
# rows per block of point_to_polygon: its temporaries ((rows, 4) per coordinate) stay in the L2
# cache; every row is its own, so the block size does not change a value (150k rows of the 100k
# room's exposed-part form factors: 2.5x faster than all rows at once). 8192 rather than 4096
# (session 33): a block's numpy calls hold the GIL for their set-up, the same per block, so less
# per row (the 20k build's point_to_polygon: GIL-held 0.21 -> 0.11 s, CPU 0.69 -> 0.64 s, one
# run each; docs/threads.md)
POINT_BLOCK = 8192


def _cross(a, b):
    # np.cross is slow on small trailing axes (it moves axes around); explicit components are faster.
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _dot(a, b):
    return np.einsum("...k,...k->...", a, b)


def norm3(v):
    """np.linalg.norm(v, axis=-1) of 3-vectors, bit for bit (its add.reduce over an axis of 3
    adds the squares in order), without the reduction's per-row overhead: 4x faster."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt((x * x + y * y) + z * z)


def row_range(x):
    """(min, max) over a short last axis (a polygon's corners, an end's samples) by its columns:
    .min(-1) / .max(-1) loop per row, about 10x slower. The same values (up to a zero's sign:
    for comparisons and ranges)."""
    cols = np.moveaxis(x, -1, 0)
    return functools.reduce(np.minimum, cols), functools.reduce(np.maximum, cols)


def unoccluded_share(front, occ, kw):
    """(N,) a link's visibility as its transfer reads it: the unoccluded share of its facing
    segments' kernel kw (N, S) (cos cos / r^2: a segment nearer or more head-on carries more; an
    unweighted count read the furnished 2k room's weak far links 2.4% darker than a dense
    kernel-weighted visibility). front, occ (N, S): which segments face both ways, which are
    blocked. The plain fraction where the kernel underflows (far links, farlinks; patch links,
    refine)."""
    k = np.where(front, kw, 0.0)
    K = k.sum(1)
    plain = (front & ~occ).sum(1) / np.maximum(front.sum(1), 1)
    return np.where(K > 0, np.where(occ, 0.0, k).sum(1) / np.where(K > 0, K, 1.0), plain)


def _padded(corners, nv):
    """float64 corners, with triangles (nv == 3) re-padded so corner 3 == corner 2."""
    c = np.asarray(corners, dtype=np.float64)
    if nv is not None and np.any(np.asarray(nv) == 3):
        c = c.copy()
        tri = np.broadcast_to(np.asarray(nv) == 3, c.shape[:-2])
        c[tri, 3] = c[tri, 2]
    return c


def polygon_normal_area(corners, nv=None):
    """Unit normals (N, 3) and areas (N,) of planar convex <=4-gons.

    Half the cross product of the diagonals is the exact area vector of any planar quad, and for a padded
    triangle (c3 == c2) it reduces to (c1 - c0) x (c2 - c0) / 2. Degenerate polygons get a zero normal and
    zero area instead of NaN.
    """
    c = _padded(corners, nv)
    av = 0.5 * _cross(c[..., 2, :] - c[..., 0, :], c[..., 3, :] - c[..., 1, :])
    area = norm3(av)
    normal = av / np.where(area > 0.0, area, 1.0)[..., None]
    return normal, area


def _clip_to_halfspace(verts, point, normal):
    """Clip cyclic polygons `verts (N, V, 3)` to the half-space dot(x - point, normal) >= 0.

    One Sutherland-Hodgman pass, vectorised: edge i emits (its start if inside, the crossing point if it
    crosses), i.e. 2V slots. Empty slots are filled with the previous valid vertex (cyclically), so the
    output is again a closed polygon whose extra vertices are repeats and whose extra edges have zero
    length (they contribute nothing to contour integrals). Returns (N, 2V, 3) and a mask of rows with any
    vertex left.
    """
    n, v = verts.shape[:2]
    d = _dot(verts - point[:, None, :], normal[:, None, :])  # signed heights above the horizon
    inside = d >= 0.0
    nxt = np.roll(verts, -1, axis=1)
    d_next = np.roll(d, -1, axis=1)
    crosses = inside != np.roll(inside, -1, axis=1)
    # Signs differ on crossing edges, so the denominator is non-zero there; elsewhere t is unused.
    t = np.where(crosses, d / np.where(crosses, d - d_next, 1.0), 0.0)
    hit = verts + t[..., None] * (nxt - verts)
    slots = np.stack([verts, hit], axis=2).reshape(n, 2 * v, 3)
    valid = np.stack([inside, crosses], axis=2).reshape(n, 2 * v)
    # Forward fill: index of the last valid slot at or before j; leading gaps wrap to the row's last valid.
    idx = np.where(valid, np.arange(2 * v), -1)
    idx = np.maximum.accumulate(idx, axis=1)
    last = idx[:, -1:]
    idx = np.where(idx < 0, last, idx)
    any_valid = last[:, 0] >= 0
    idx = np.maximum(idx, 0)  # rows with nothing left: masked out
    # one gather of whole rows (take_along_axis indexes each of the 3 coordinates: 2.4x slower)
    rows = (idx + 2 * v * np.arange(n)[:, None]).ravel()
    return slots.reshape(-1, 3)[rows].reshape(n, 2 * v, 3), any_valid


def point_to_polygon(points, normals, corners, nv=None, plane=None):
    """Exact unoccluded form factor from differential areas (points, unit normals) to polygons. -> (N,)

    F = -1/(2 pi) sum_i gamma_i n.(R_i x R_i+1)/|R_i x R_i+1| over the polygon's contour, after clipping
    the polygon to the receiver's upper half-space (the contour integral assumes the whole polygon is
    above the horizon). The minus sign: vertices are counter-clockwise about the polygon's normal, which
    points towards a point that can see its front. Points on or behind the polygon's plane get 0.
    plane: the polygons' (normals, areas) from polygon_normal_area(corners, nv), broadcast as the
    corners (a caller evaluating each polygon at many points computes them once per polygon).
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    c = np.asarray(corners, dtype=np.float64)
    shape = np.broadcast_shapes(p.shape[:-1], n.shape[:-1], c.shape[:-2])  # leading dims broadcast
    if nv is not None:
        nv = np.broadcast_to(np.broadcast_to(nv, c.shape[:-2]), shape).reshape(-1)
    p = np.broadcast_to(p, shape + (3,)).reshape(-1, 3)
    n = np.broadcast_to(n, shape + (3,)).reshape(-1, 3)
    c = np.broadcast_to(c, shape + (4, 3)).reshape(-1, 4, 3)

    if plane is None:
        qn, qa = polygon_normal_area(c, nv)
    else:
        qn = np.broadcast_to(plane[0], shape + (3,)).reshape(-1, 3)
        qa = np.broadcast_to(plane[1], shape).reshape(-1)
    # by blocks of rows whose temporaries stay in the cache (every row is its own: the same
    # values), the triangles re-padded block by block
    f = np.empty(len(p))
    for s in range(0, len(p), POINT_BLOCK):
        b = slice(s, s + POINT_BLOCK)
        cb = c[b] if nv is None else _padded(c[b], nv[b])
        f[b] = _point_to_polygon(p[b], n[b], cb, qn[b], qa[b])
    return f.reshape(shape)


def _point_to_polygon(p, n, c, qn, qa):
    """point_to_polygon of rows p (N, 3), n (N, 3), c (N, 4, 3) (padded) and their polygons'
    planes qn (N, 3), qa (N,). Component major: a row of N per coordinate (and corner) (numpy is
    slow on a last axis of 3); the dot products' sums in einsum's order (dot3): the same bits."""
    P, Nn = p.T, n.T
    height = dot3(P - c[:, 0].T, qn.T)
    front = height > _PLANE_EPS * np.sqrt(qa)  # one-sided emitter
    R = np.subtract(c.transpose(2, 1, 0), P[:, None], order="C")  # (3, 4, N): corners - point
    h = dot3(R, Nn[:, None])  # (4, N): the corners' heights above the horizon
    a0, a1, a2, a3 = h >= 0.0
    every, some = (a0 & a1) & (a2 & a3), (a0 | a1) | (a2 | a3)
    f = np.zeros(len(p))
    # Most polygons lie wholly above the receiver's horizon: no clipping needed for those. (Rows
    # by take: contiguous, where fancy indexing of the last axis gave strided operands, 1.4x the
    # contour's time; the same values.)
    whole = (front & every).nonzero()[0]  # (flatnonzero of a row: without its Python wrappers)
    f[whole] = _contour_cm(np.take(R, whole, 2), np.take(Nn, whole, 1))
    part = (front & some & ~every).nonzero()[0]
    if len(part):
        C = np.take(c.transpose(2, 1, 0), part, 2)  # (3, 4, M) the corners
        # the heights as _clip_to_halfspace's einsum has them (from +0: never a negative zero)
        verts, any_valid = _clip_cm(C, np.take(h, part, 1) + 0.0)
        Rp = np.subtract(verts, np.take(P, part, 1)[:, None], order="C")
        f[part] = np.where(any_valid, _contour_cm(Rp, np.take(Nn, part, 1)), 0.0)
    return np.clip(f, 0.0, 1.0)


@functools.cache
def _next(v):
    """The indices of np.roll(x, -1) along an axis of v: [1, ..., v - 1, 0]. A take with them is
    the same copy as roll's; np.roll spends ~10 us of Python per call with the GIL held, a few
    times per point_to_polygon block (issue 23, docs/threads.md, session 36)."""
    r = np.r_[1:v, 0]
    r.flags.writeable = False
    return r


def _clip_cm(C, d):
    """_clip_to_halfspace of component-major polygons C (3, V, M) with their corners' signed
    heights d (V, M) (the same values as its own): (3, 2V, M) and the rows with a vertex left.
    The same operations element by element, on contiguous rows per coordinate and vertex (the
    row form's (M, V, 3) stacks, rolls and gathers loop per row of 3): the same bits."""
    v, m = d.shape
    inside = d >= 0.0
    nx = _next(v)  # (np.roll(x, -1) by one take: the same values, without roll's Python)
    nxt = np.take(C, nx, 1)
    d_next = np.take(d, nx, 0)
    crosses = inside != np.take(inside, nx, 0)
    t = np.where(crosses, d / np.where(crosses, d - d_next, 1.0), 0.0)
    hit = C + t * (nxt - C)
    slots = np.empty((3, 2 * v, m))
    slots[:, 0::2], slots[:, 1::2] = C, hit
    valid = np.empty((2 * v, m), bool)
    valid[0::2], valid[1::2] = inside, crosses
    # forward fill: the last valid slot at or before j; leading gaps wrap to the row's last valid
    idx = np.where(valid, np.arange(2 * v)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    last = idx[-1]
    idx = np.where(idx < 0, last, idx)
    idx = np.maximum(idx, 0)  # rows with nothing left: masked out
    return np.take(slots.reshape(3, -1), idx * m + np.arange(m), 1), last >= 0


def clipped_rings(x, n, rings):
    """Unoccluded form factor from points x (N, 3), normals n to a planar polygon with holes (rings:
    outer CCW about the emitting normal, holes CW) cut by the points' horizons: each ring clipped
    to the point's upper half-space (Sutherland-Hodgman; a hole's clipped ring takes its clipped
    part away), then Lambert's contour integral. The same as the sum over the polygon's convex
    pieces, for a handful of edges."""
    f = np.zeros(len(x))
    for r in rings:
        verts, ok = _clip_to_halfspace(np.broadcast_to(r, (len(x),) + r.shape), x, n)
        f += np.where(ok, _contour(verts - x[:, None], n), 0.0)
    return np.clip(f, 0.0, 1.0)


def _contour(r, n):
    """Lambert's contour integral over polygons given as vertex offsets r (N, V, 3) from the point."""
    return _contour_cm(np.ascontiguousarray(r.transpose(2, 1, 0)), np.ascontiguousarray(n.T))


def dot3(a, b):
    """Dot products of component-major vectors a, b (3, ...) (broadcast): einsum's sum over an
    axis of 3, in its order ((x + z) + y: its SIMD pairs lanes 0, 2 and then adds lane 1), so
    the same bits as _dot / einsum("...k,...k") of the rows (up to a zero's sign: see _contour_cm)."""
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


def _contour_cm(R, n):
    """_contour of component-major offsets R (3, V, N) and normals n (3, N): a contiguous row of N
    per coordinate and vertex (numpy is slow on a last axis of 3: np.cross, the einsums and the
    sum over the vertices loop per row; and on operands of mixed memory order). The same
    operations in the same order as the row form had them (einsum's dot products as dot3, plus
    0.0 where einsum's result would be a zero of the other sign; the sum over V vertices as
    numpy's sum: in order for V < 8, pairwise for V = 8, from +0): the same bits, negative zeros
    included."""
    V = R.shape[1]
    Rn = np.take(R, _next(V), 1)  # np.roll(R, -1, axis=1)
    x, y, z = R
    xn, yn, zn = Rn
    c0 = y * zn - z * yn
    c1 = z * xn - x * zn
    c2 = x * yn - y * xn
    cr_len = np.sqrt((c0 * c0 + c2 * c2) + c1 * c1)  # (squares: no negative zero)
    # gamma via atan2 is accurate for both tiny and near-pi angles (arccos of a dot product is not);
    # its x argument's zero sign does not matter where it is used (cr_len > 0)
    gamma = np.arctan2(cr_len, (x * xn + z * zn) + y * yn)
    # Repeated vertices / zero-length edges give R_i x R_i+1 = 0: their term is exactly 0.
    ok = cr_len > 0.0
    nd = (c0 * n[0] + c2 * n[2]) + c1 * n[1]
    nd += 0.0  # einsum's sum starts from +0: never a negative zero
    t = np.where(ok, gamma * nd / np.where(ok, cr_len, 1.0), 0.0)
    if V < 8:
        s = t[0].copy()
        for j in range(1, V):
            s += t[j]
    elif V == 8:
        s = ((t[0] + t[1]) + (t[2] + t[3])) + ((t[4] + t[5]) + (t[6] + t[7]))
    else:
        return -t.sum(axis=0) / _TWO_PI  # (not the same order: no caller)
    s += 0.0  # (numpy's sum starts from +0 as well)
    return -s / _TWO_PI


def _unit_cell_params(k):
    """Parameters of the k*k sample points of the unit square (u, v) and unit triangle (a, b)."""
    g = (np.arange(k) + 0.5) / k
    uu, vv = np.meshgrid(g, g, indexing="ij")
    quad = np.stack([uu.ravel(), vv.ravel()], axis=-1)
    # Barycentric subdivision of the triangle into k*k congruent sub-triangles: k(k+1)/2 "upward" ones
    # (centroid at (i + 1/3, j + 1/3)/k) and k(k-1)/2 "downward" ones (centroid at (i + 2/3, j + 2/3)/k).
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (i + j) <= k - 1
    down = (i + j) <= k - 2
    tri = (
        np.concatenate(
            [np.stack([i[up] + 1 / 3, j[up] + 1 / 3], -1), np.stack([i[down] + 2 / 3, j[down] + 2 / 3], -1)]
        )
        / k
    )
    return quad, tri


def sample_points(corners, nv, k):
    """(N, k*k, 3) stratified points: centroids of a k x k subdivision of each polygon.

    Quads use the bilinear map of a k x k grid (equal-area cells for parallelograms); triangles use the
    k*k congruent sub-triangles of the uniform barycentric subdivision (always equal area).
    """
    c = np.asarray(corners, dtype=np.float64)
    quad, tri = _unit_cell_params(int(k))
    is_tri = np.broadcast_to(np.asarray(nv) == 3, c.shape[:1])
    out = np.empty((len(c), len(quad), 3))
    # each kind's points only on its own polygons (np.where of both over all: the same values)
    for sel, pick in ((~is_tri, True), (is_tri, False)):
        rows = np.flatnonzero(sel)
        if not len(rows):
            continue
        cs = c[rows] if len(rows) < len(c) else c
        c0, c1, c2, c3 = (cs[:, i, None, :] for i in range(4))
        if pick:
            u, v = quad[:, 0][None, :, None], quad[:, 1][None, :, None]
            pts = (1 - u) * (1 - v) * c0 + u * (1 - v) * c1 + u * v * c2 + (1 - u) * v * c3
        else:
            a, b = tri[:, 0][None, :, None], tri[:, 1][None, :, None]
            pts = c0 + a * (c1 - c0) + b * (c2 - c0)
        if len(rows) < len(c):
            out[rows] = pts
        else:
            out = pts
    return out


def patch_to_patch(corners_p, nv_p, corners_q, nv_q, n_samples=4):
    """Unoccluded F[p->q] (N,): mean of point_to_polygon over `n_samples` (= k*k) points on p."""
    k = math.isqrt(int(n_samples))
    if k * k != n_samples or k < 1:
        raise ValueError(f"n_samples must be a perfect square, got {n_samples}")
    cq = _padded(corners_q, nv_q)
    pts = sample_points(corners_p, nv_p, k)  # (N, S, 3)
    normals, _ = polygon_normal_area(corners_p, nv_p)
    return point_to_polygon(pts, normals[:, None, :], cq[:, None]).mean(axis=1)  # broadcast over S


def _unit(v):
    length = norm3(v)[..., None]
    return v / np.where(length > 0.0, length, 1.0)


def estimate(centers_p, normals_p, areas_p, corners_q, centers_q, normals_q, areas_q, corners_p=None):
    """Cheap refinement oracle F_est[p->q] = A_q cos_p cos_q / (pi r^2 + A_q), clipped to [0, 1].

    Conservative for patches partly behind each other:
    - cos_p is the largest cosine at p's centre towards any of q's corners or its centre (>= 0), so a q
      whose centre is below p's horizon but which reaches above it is not dropped.
    - cos_q uses the centre-to-centre direction (>= 0). If that is 0 while p may still reach in front of
      q, cos_q falls back to the largest cosine at q's centre towards p's corners when `corners_p` is given,
      else to COS_FLOOR when p's centre is less than sqrt(A_p) behind q's plane (a size-based guess).
    The +A_q in the denominator keeps the value finite (and <= 1) as r -> 0.
    Component major (rows per coordinate; numpy is slow on a last axis of 3); the norms and dot
    products in norm3's and einsum's orders, the largest cosine by columns: the same values (a
    zero's sign aside: the refinement only compares them).
    """
    cm = lambda x: np.ascontiguousarray(np.moveaxis(np.asarray(x, dtype=np.float64), -1, 0))  # (3, ...)
    cp, np_, cq, nq = cm(centers_p), cm(normals_p), cm(centers_q), cm(normals_q)
    aq = np.asarray(areas_q, dtype=np.float64)
    targets = np.concatenate([np.moveaxis(cm(corners_q), -1, 1), cq[:, None]], axis=1)  # (3, 5, ...)
    cos_t = dot3(_unit_cm(targets - cp[:, None]), np_[:, None])  # (5, ...)
    cos_p = np.clip(functools.reduce(np.maximum, cos_t), 0.0, None)

    d = cp - cq
    r2 = dot3(d, d)
    cos_q = np.clip(dot3(_unit_cm(d), nq), 0.0, None)
    if corners_p is not None:
        to_corners = _unit_cm(np.moveaxis(cm(corners_p), -1, 1) - cq[:, None])
        fallback = np.clip(functools.reduce(np.maximum, dot3(to_corners, nq[:, None])), 0.0, None)
    else:
        fallback = np.where(dot3(d, nq) > -np.sqrt(np.asarray(areas_p, dtype=np.float64)), COS_FLOOR, 0.0)
    cos_q = np.where(cos_q > 0.0, cos_q, fallback)
    return np.clip(aq * cos_p * cos_q / (math.pi * r2 + aq), 0.0, 1.0)


def _unit_cm(v):
    """_unit of vectors as rows per coordinate v (3, ...): the same values."""
    length = np.sqrt((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2])
    return v / np.where(length > 0.0, length, 1.0)


def _gauss_tables(k):
    """Basis weights of the k x k Gauss points over the 4 corners: quads (bilinear map), its u
    and v derivatives, triangles (collapsed map a + u (b - a) + u v (c - b)), and the weights."""
    x, w = np.polynomial.legendre.leggauss(k)
    x, w = (x + 1) / 2, w / 2
    u, v = (g.ravel() for g in np.meshgrid(x, x, indexing="ij"))
    quad = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], 1)
    du = np.stack([-(1 - v), 1 - v, v, -v], 1)
    dv = np.stack([-(1 - u), -u, u, 1 - u], 1)
    tri = np.stack([1 - u, u * (1 - v), u * v, np.zeros_like(u)], 1)
    return quad, du, dv, tri, np.outer(w, w).ravel(), u


_GAUSS = {}


def quadrature(corners, nv, k):
    """Gauss-Legendre k x k points and area weights (summing to 1) over convex quads and triangles.

    Quads: the bilinear map of the unit square, weighted by its Jacobian. Triangles: the collapsed
    (Duffy) map p = a + u (b - a) + u v (c - b), Jacobian proportional to u. Both integrate smooth
    kernels far better than the equal-weight centroid rule of sample_points (error O(h^2k) not O(h^2)).
    """
    c = _padded(corners, nv)
    tri = np.asarray(nv) == 3
    if k not in _GAUSS:
        _GAUSS[k] = _gauss_tables(k)
    quad_b, du_b, dv_b, tri_b, wu, u = _GAUSS[k]
    pts = np.empty((len(c), k * k, 3))
    wts = np.empty((len(c), k * k))
    q = ~tri
    if q.any():
        cq = c[q]
        pts[q] = np.einsum("sk,nkj->nsj", quad_b, cq)
        jac = _cross(np.einsum("sk,nkj->nsj", du_b, cq), np.einsum("sk,nkj->nsj", dv_b, cq))
        wts[q] = wu * np.sqrt(np.einsum("nsj,nsj->ns", jac, jac))
    if tri.any():
        pts[tri] = np.einsum("sk,nkj->nsj", tri_b, c[tri])
        wts[tri] = wu * u
    return pts, wts / wts.sum(1, keepdims=True)
