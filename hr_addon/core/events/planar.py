"""Planar polygon helpers of the light shapes (winding, point in polygon, slab decomposition) and
stratified surface samples."""

import numpy as np

from .. import formfactor as ff


def _winding(pts, ring):
    """Signed winding number of ring (M, 2) about points (N, 2)."""
    a, b = ring[None], np.roll(ring, -1, 0)[None]
    x, y = pts[:, :1], pts[:, 1:2]
    side = (b[..., 0] - a[..., 0]) * (y - a[..., 1]) - (b[..., 1] - a[..., 1]) * (x - a[..., 0])
    up = (a[..., 1] <= y) & (b[..., 1] > y) & (side > 0)
    down = (b[..., 1] <= y) & (a[..., 1] > y) & (side < 0)
    return up.sum(1) - down.sum(1)


def surface_samples(patches, per_area, min_k=2):
    """Stratified points on every input patch: k x k per patch with k ~ sqrt(area x per_area).
    Returns points (N, 3), patch ids (N,), area weights (N,)."""
    k = np.maximum(np.ceil(np.sqrt(patches.area * per_area)).astype(int), min_k)
    pts, ids, wts = [], [], []
    for kk in np.unique(k):
        m = np.flatnonzero(k == kk)
        p = ff.sample_points(patches.corners[m], patches.nv[m], kk)
        pts.append(p.reshape(-1, 3))
        ids.append(np.repeat(m, kk * kk))
        wts.append(np.repeat(patches.area[m] / (kk * kk), kk * kk))
    return np.concatenate(pts), np.concatenate(ids), np.concatenate(wts)


def _in_rings(pts, rings):
    """Even-odd point-in-polygon over all rings (outer + holes), pts (N, 2)."""
    inside = np.zeros(len(pts), bool)
    for r in rings:
        a, b = r, np.roll(r, -1, 0)
        ay, by = a[:, 1][None], b[:, 1][None]
        y = pts[:, 1:2]
        crosses = (ay > y) != (by > y)
        t = (y - ay) / np.where(by != ay, by - ay, 1)
        x = a[:, 0][None] + t * (b[:, 0] - a[:, 0])[None]
        inside ^= (crosses & (pts[:, :1] < x)).sum(1) % 2 == 1
    return inside


def _in_convex(pts, poly, tol=None):
    """pts (N, 2) inside convex polygons poly (T, M, 2) of either orientation (zero edges ignored): (N, T).
    tol: also points up to that distance outside."""
    e = np.roll(poly, -1, 1) - poly  # (T, M, 2)
    w = pts[:, None, None, :] - poly[None]  # (N, T, M, 2)
    cr = e[None, ..., 0] * w[..., 1] - e[None, ..., 1] * w[..., 0]
    zero = (np.abs(e).sum(-1) == 0)[None]
    if tol is not None:
        ln = np.sqrt((e * e).sum(-1))[None]
        cr = np.where(zero, 0, cr / np.where(zero, 1, ln))
        return (cr >= -tol).all(-1) | (cr <= tol).all(-1)
    return (np.where(zero, 0, cr) >= 0).all(-1) | (np.where(zero, 0, cr) <= 0).all(-1)


def slab_decomposition(edges, eps):
    """Trapezoids (and triangles) between consecutive non-crossing edges in horizontal slabs.

    edges (E, 2, 2). Slab boundaries are all endpoint heights and pairwise crossing heights, so inside a
    slab no edges cross. Returns a list of (polygon (3 or 4, 2) counter-clockwise, midpoint (2,))."""
    a, b = edges[:, 0].copy(), edges[:, 1].copy()
    keep = np.abs(a[:, 1] - b[:, 1]) > eps
    a, b = a[keep], b[keep]
    sw = a[:, 1] > b[:, 1]
    a[sw], b[sw] = b[sw].copy(), a[sw].copy()
    ys = [a[:, 1], b[:, 1]]
    i, j = np.triu_indices(len(a), 1)
    d1, d2 = b[i] - a[i], b[j] - a[j]
    den = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    ok = np.abs(den) > 1e-30
    r = a[j] - a[i]
    t = np.where(ok, (r[:, 0] * d2[:, 1] - r[:, 1] * d2[:, 0]) / np.where(ok, den, 1), -1)
    s = np.where(ok, (r[:, 0] * d1[:, 1] - r[:, 1] * d1[:, 0]) / np.where(ok, den, 1), -1)
    hit = ok & (t > 0) & (t < 1) & (s > 0) & (s < 1)
    ys.append((a[i] + t[:, None] * d1)[hit, 1])
    ys = np.sort(np.concatenate(ys))
    ys = ys[np.concatenate([[True], np.diff(ys) > eps])]
    out = []
    for y0, y1 in zip(ys[:-1], ys[1:]):
        ym = 0.5 * (y0 + y1)
        act = np.flatnonzero((a[:, 1] < ym) & (b[:, 1] > ym))
        if len(act) < 2:
            continue
        aa, bb = a[act], b[act]
        dx = (bb[:, 0] - aa[:, 0]) / (bb[:, 1] - aa[:, 1])
        x0 = aa[:, 0] + (y0 - aa[:, 1]) * dx
        x1 = aa[:, 0] + (y1 - aa[:, 1]) * dx
        xm = 0.5 * (x0 + x1)
        o = np.argsort(xm)
        x0, x1, xm = x0[o], x1[o], xm[o]
        for k in range(len(o) - 1):
            if xm[k + 1] - xm[k] <= eps:
                continue
            mid = np.array([0.5 * (xm[k] + xm[k + 1]), ym])
            bot, top = x0[k + 1] - x0[k] > eps, x1[k + 1] - x1[k] > eps
            if bot and top:
                poly = [(x0[k], y0), (x0[k + 1], y0), (x1[k + 1], y1), (x1[k], y1)]
            elif bot:
                poly = [(x0[k], y0), (x0[k + 1], y0), (0.5 * (x1[k] + x1[k + 1]), y1)]
            elif top:
                poly = [(0.5 * (x0[k] + x0[k + 1]), y0), (x1[k + 1], y1), (x1[k], y1)]
            else:
                continue
            out.append((np.array(poly), mid))
    return out
