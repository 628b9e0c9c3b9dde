"""Texels of UV triangles (no bpy): which texel centres each triangle covers, a ring just outside
the islands, and the dilation steps that fill a few more texels around them.

Texel (x, y) of a res x res image has its centre at uv = ((x + 0.5) / res, (y + 0.5) / res);
row 0 is at v = 0, as Blender stores pixels. Texels inside a triangle get the surface point of
their centre; ring texels (within RING texels) the nearest point of the triangle, so that texels
that bilinear filtering reads at island edges hold the surface's value, not black. The image then
writes each ring texel from the inside texels next to it (ring_sources), not from its own point.
"""

import numpy as np

RING = 1.5  # texels outside an island evaluated at the nearest point of the island
DILATE = 2  # further texels filled with the mean of their filled neighbours


def rasterise(tri_uv, res, ring=RING, budget=400_000):
    """Texels of a res x res image covered by UV triangles tri_uv (T, 3, 2).

    Returns texel (N,) flat index y * res + x (row 0 at v = 0), tri (N,), bary (N, 3), inside (N,):
    texels whose centre lies in a triangle (barycentric coordinates of the centre) or within `ring`
    texels of one (coordinates of the nearest triangle point), each texel once."""
    Pt = np.asarray(tri_uv, np.float64) * res - 0.5  # texel (i, j) has its centre at (i, j)
    a, b, c = Pt[:, 0], Pt[:, 1], Pt[:, 2]
    v0, v1 = b - a, c - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    ok = np.abs(den) > 1e-12
    lo = np.clip(np.floor(Pt.min(1) - ring), 0, res - 1).astype(np.int64)
    hi = np.clip(np.ceil(Pt.max(1) + ring), 0, res - 1).astype(np.int64)
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    counts = np.where(ok, nx * ny, 0)
    out = []
    cum = np.cumsum(counts)
    t0 = 0
    while t0 < len(counts):
        base = cum[t0 - 1] if t0 else 0
        t1 = max(int(np.searchsorted(cum, base + budget, "right")), t0 + 1)
        ids = np.arange(t0, t1)
        cn = counts[ids]
        t0 = t1
        if cn.sum() == 0:
            continue
        t = np.repeat(ids, cn)
        k = np.arange(cn.sum()) - np.repeat(np.cumsum(cn) - cn, cn)
        x = lo[t, 0] + k % nx[t]
        y = lo[t, 1] + k // nx[t]
        q = np.stack([x, y], 1).astype(np.float64)
        w = q - a[t]
        l1 = (w[:, 0] * v1[t, 1] - v1[t, 0] * w[:, 1]) / den[t]
        l2 = (v0[t, 0] * w[:, 1] - w[:, 0] * v0[t, 1]) / den[t]
        bary = np.stack([1 - l1 - l2, l1, l2], 1)
        inside = (bary >= -1e-9).all(1)
        dist = np.zeros(len(t))
        out_i = np.flatnonzero(~inside)
        if len(out_i):
            tt, qq = t[out_i], q[out_i]
            best_d = np.full(len(out_i), np.inf)
            best_b = np.zeros((len(out_i), 3))
            for i, j in ((0, 1), (1, 2), (2, 0)):
                pa, pb = Pt[tt, i], Pt[tt, j]
                e = pb - pa
                s = np.einsum("ij,ij->i", qq - pa, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300)
                s = np.clip(s, 0, 1)
                d = np.linalg.norm(qq - pa - s[:, None] * e, axis=1)
                better = d < best_d
                best_d = np.where(better, d, best_d)
                nb = np.zeros((len(out_i), 3))
                nb[:, i], nb[:, j] = 1 - s, s
                best_b[better] = nb[better]
            dist[out_i] = best_d
            bary[out_i] = best_b
        keep = inside | (dist <= ring)
        out.append((y[keep] * res + x[keep], t[keep], bary[keep], dist[keep], inside[keep]))
    if not out:
        z = np.zeros(0, np.int64)
        return z, z, np.zeros((0, 3)), np.zeros(0, bool)
    texel, tri, bary, dist, inside = (np.concatenate(z) for z in zip(*out))
    o = np.lexsort((tri, dist, texel))
    firsts = o[np.r_[True, texel[o][1:] != texel[o][:-1]]]
    return texel[firsts], tri[firsts], bary[firsts], inside[firsts]


def ring_sources(texel, inside, edge, res):
    """Where each ring texel's value comes from: the inside texel i1 nearest to its island point
    `edge` (N, 2) (texel coordinates, centres at integers) and the next inside texel i2 beyond it.
    Returns ring, i1, i2 (indices into texel) and w: ring value = (1 + w) v1 - w v2, the inside
    values' line carried out to the ring texel (w = 0 where there is no i2; rings with no inside
    texel within 1.5 texels of their point are not listed and keep their own value).

    Why not the value at the island's point: along a contact that point is the contact line, the
    darkest value, and bilinear filtering mixes it into the band next to it (docs/accuracy.md,
    *Texels along contacts*); the line through the inside texels keeps seams and gradients."""
    texel, inside = np.asarray(texel, np.int64), np.asarray(inside, bool)
    dense = np.full(res * res, -1, np.int64)
    dense[texel[inside]] = np.flatnonzero(inside)
    ring = np.flatnonzero(~inside)
    p = np.asarray(edge, np.float64)[ring]
    best, best_d = np.full(len(ring), -1, np.int64), np.full(len(ring), np.inf)
    base = np.floor(p).astype(np.int64)
    for dy in (-1, 0, 1, 2):
        for dx in (-1, 0, 1, 2):
            x, y = base[:, 0] + dx, base[:, 1] + dy
            ok = (x >= 0) & (x < res) & (y >= 0) & (y < res)
            j = np.where(ok, dense[np.clip(y, 0, res - 1) * res + np.clip(x, 0, res - 1)], -1)
            d = np.hypot(x - p[:, 0], y - p[:, 1])
            better = (j >= 0) & (d < best_d) & (d <= 1.5)
            best, best_d = np.where(better, j, best), np.where(better, d, best_d)
    keep = best >= 0
    ring, i1 = ring[keep], best[keep]
    rx, ry = texel[ring] % res, texel[ring] // res
    x1, y1 = texel[i1] % res, texel[i1] // res
    sx, sy = np.sign(x1 - rx), np.sign(y1 - ry)  # one texel step on from i1, away from the ring
    x2, y2 = x1 + sx, y1 + sy
    ok = (x2 >= 0) & (x2 < res) & (y2 >= 0) & (y2 < res) & ((sx != 0) | (sy != 0))
    i2 = np.where(ok, dense[np.clip(y2, 0, res - 1) * res + np.clip(x2, 0, res - 1)], -1)
    w = np.where(i2 >= 0, np.hypot(x1 - rx, y1 - ry) / np.maximum(np.hypot(sx, sy), 1), 0.0)
    return ring, i1, np.where(i2 >= 0, i2, i1), w


def dilation_steps(covered, res, steps=DILATE):
    """[(dst, inv, src, weight)] per step: empty texels next to filled ones take the mean of their
    filled 8-neighbours (apply in order)."""
    filled = np.zeros(res * res, bool)
    filled[covered] = True
    filled = filled.reshape(res, res)
    out = []
    offs = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx]
    for _ in range(steps):
        pad = np.pad(filled, 1)
        cnt = sum(pad[1 + dy : 1 + dy + res, 1 + dx : 1 + dx + res].astype(np.int64) for dy, dx in offs)
        new = ~filled & (cnt > 0)
        ys, xs = np.nonzero(new)
        if not len(ys):
            break
        d, s = [], []
        for dy, dx in offs:
            yy, xx = ys + dy, xs + dx
            m = (yy >= 0) & (yy < res) & (xx >= 0) & (xx < res)
            m[m] = filled[yy[m], xx[m]]
            d.append(ys[m] * res + xs[m])
            s.append(yy[m] * res + xx[m])
        d, s = np.concatenate(d), np.concatenate(s)
        dst, inv = np.unique(d, return_inverse=True)
        wgt = 1.0 / np.bincount(inv.ravel())[inv.ravel()]
        out.append((dst, inv.ravel(), s, wgt))
        filled = filled | new
    return out
