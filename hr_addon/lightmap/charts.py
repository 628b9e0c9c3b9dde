"""Lightmap UVs (no bpy): planar charts of a mesh, each projected onto its plane, packed into a
square at one texel density.

Meshes come in Blender's layout (vertex coordinates, loop_start, loop_total, loop_verts). Charts
are edge-connected polygons in one plane (or nearly: a slightly twisted wall), so a chart unfolds
without overlaps; a curved surface gives one chart per polygon. Charts are turned to their
smallest bounding rectangle and shelf-packed with MARGIN texels around each, so that bilinear
filtering and the dilation (raster.py) never mix two charts.
"""

import numpy as np

from ..core.geometry import components, loop_tables, polygon_newell
from ..core.planes import frames
from . import TextureError

MARGIN = 2  # texels of padding on each side of a packed island (islands are 2 x MARGIN apart)
NEAR_ANGLE = 2.0  # degrees between neighbouring polygons of a nearly planar chart
CHART_ANGLE = 10.0  # degrees between any polygon of such a chart and its mean plane
CHART_FLAT = 0.005  # its thickness off the mean plane, fraction of its size


def find_charts(co, loop_start, loop_total, loop_verts):
    """Chart id per polygon and chart normals (C, 3).

    Polygons sharing an edge (of two faces) join when they lie in one plane, or when their normals
    differ by less than NEAR_ANGLE and the resulting chart stays nearly flat (within CHART_ANGLE of
    its mean plane and CHART_FLAT of its size off it: e.g. a slightly twisted wall). Flat charts project
    onto their plane without overlaps; curved surfaces give one chart per polygon."""
    P = len(loop_start)
    lp, nxt = loop_tables(loop_start, loop_total)
    p = co[loop_verts]
    n = polygon_newell(co, loop_start, loop_total, loop_verts)
    ln = np.linalg.norm(n, axis=1)
    nu = n / np.maximum(ln, 1e-300)[:, None]
    cen = np.stack([np.bincount(lp, p[:, k], P) for k in range(3)], 1) / np.maximum(loop_total, 1)[:, None]
    scale = float(np.linalg.norm(co.max(0) - co.min(0))) if len(co) else 1.0
    tol = 1e-5 * max(scale, 1e-30)
    dev = np.zeros(P)
    np.maximum.at(dev, lp, np.abs(np.einsum("ij,ij->i", p - cen[lp], nu[lp])))
    planar = (dev <= tol) & (ln > 0)
    off = np.einsum("ij,ij->i", nu, cen)
    a, b = loop_verts, loop_verts[nxt]
    key = np.minimum(a, b) * (len(co) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.r_[True, ks[1:] != ks[:-1]]
    run = np.diff(np.r_[np.flatnonzero(first), len(ks)])
    two = np.flatnonzero(first)[run == 2]
    pi, pj = lp[order[two]], lp[order[two + 1]]
    dot = np.einsum("ij,ij->i", nu[pi], nu[pj])
    base = (pi != pj) & (ln[pi] > 0) & (ln[pj] > 0)
    strict = base & planar[pi] & planar[pj] & (dot >= 1 - 1e-8) & (np.abs(off[pi] - off[pj]) <= tol)
    near = base & (dot >= np.cos(np.radians(NEAR_ANGLE)))
    lab_s = components(P, pi[strict], pj[strict])
    lab = components(P, pi[near], pj[near])
    # Keep a near-planar chart only if it is flat as a whole.
    uniq, ch = np.unique(lab, return_inverse=True)
    ch = ch.ravel()
    C = len(uniq)
    cn = np.stack([np.bincount(ch, n[:, k], C) for k in range(3)], 1)
    cn /= np.maximum(np.linalg.norm(cn, axis=1), 1e-300)[:, None]
    w = 0.5 * ln
    cc = (
        np.stack([np.bincount(ch, w * cen[:, k], C) for k in range(3)], 1)
        / np.maximum(np.bincount(ch, w, C), 1e-300)[:, None]
    )
    lch = ch[lp]
    thick = np.zeros(C)
    np.maximum.at(thick, lch, np.abs(np.einsum("ij,ij->i", p - cc[lch], cn[lch])))
    lo = np.full((C, 3), np.inf)
    hi = -lo
    np.minimum.at(lo, lch, p)
    np.maximum.at(hi, lch, p)
    size = np.linalg.norm(hi - lo, axis=1)
    cos_min = np.ones(C)
    np.minimum.at(cos_min, ch, np.einsum("ij,ij->i", nu, cn[ch]))
    flat = (thick <= CHART_FLAT * size) & (cos_min >= np.cos(np.radians(CHART_ANGLE)))
    final = np.where(flat[ch], lab, lab_s + P)
    uniq, chart = np.unique(final, return_inverse=True)
    chart = chart.ravel()
    cn = np.stack([np.bincount(chart, n[:, k], len(uniq)) for k in range(3)], 1)
    cl = np.linalg.norm(cn, axis=1)
    cn = np.where(cl[:, None] > 0, cn / np.maximum(cl, 1e-300)[:, None], [0.0, 0.0, 1.0])
    return chart, cn


def _shelf_pack(fw, fh, res):
    """Next-fit shelf packing of integer rectangles (sorted by height, tallest first) into res x res.
    Returns (x, y) or None."""
    C = np.cumsum(fw)
    x = np.empty(len(fw), np.int64)
    y = np.empty(len(fw), np.int64)
    i, top = 0, 0
    while i < len(fw):
        if fw[i] > res or top + fh[i] > res:
            return None
        base = C[i - 1] if i else 0
        j = int(np.searchsorted(C, base + res, "right"))
        x[i:j] = C[i:j] - fw[i:j] - base
        y[i:j] = top
        top += fh[i]
        i = j
    return x, y


def _chart_rects(co, loop_start, loop_total, loop_verts):
    """Planar charts laid flat: chart per loop (L,), the loops' chart coordinates x, y (L,) from the
    chart's lower corner lo (C, 2), and the charts' widths W and heights H (C,), W >= H."""
    co = np.asarray(co, np.float64)
    loop_start, loop_total = np.asarray(loop_start, np.int64), np.asarray(loop_total, np.int64)
    loop_verts = np.asarray(loop_verts, np.int64)
    lp, nxt = loop_tables(loop_start, loop_total)
    chart, cn = find_charts(co, loop_start, loop_total, loop_verts)
    C = len(cn)
    u, v = frames(cn)
    lc = chart[lp]
    p = co[loop_verts]
    x, y = np.einsum("ij,ij->i", p, u[lc]), np.einsum("ij,ij->i", p, v[lc])
    # Candidate orientations: the 4 edge directions (mod 90 degrees) carrying most edge length.
    ex, ey = x[nxt] - x, y[nxt] - y
    elen = np.hypot(ex, ey)
    qa = np.round(np.mod(np.arctan2(ey, ex), np.pi / 2) * 1000).astype(np.int64) % 1571
    pair, inv = np.unique(lc * 2000 + qa, return_inverse=True)
    w = np.bincount(inv.ravel(), elen, len(pair))
    pc, pq = pair // 2000, pair % 2000
    o = np.lexsort((-w, pc))
    pc, pq = pc[o], pq[o]
    rank = np.arange(len(pc)) - np.searchsorted(pc, pc, "left")
    keep = rank < 4
    cc, ang = pc[keep], pq[keep] / 1000.0
    # Bounding box of every (chart, angle) candidate.
    lorder = np.argsort(lc, kind="stable")
    cnt = np.bincount(lc, minlength=C)
    cstart = np.r_[0, np.cumsum(cnt)[:-1]]
    reps = cnt[cc]
    seg = np.r_[0, np.cumsum(reps)[:-1]]
    idx = lorder[np.repeat(cstart[cc], reps) + np.arange(reps.sum()) - np.repeat(seg, reps)]
    ca, sa = np.repeat(np.cos(ang), reps), np.repeat(np.sin(ang), reps)
    rx, ry = x[idx] * ca + y[idx] * sa, -x[idx] * sa + y[idx] * ca
    area = (np.maximum.reduceat(rx, seg) - np.minimum.reduceat(rx, seg)) * (
        np.maximum.reduceat(ry, seg) - np.minimum.reduceat(ry, seg)
    )
    o = np.lexsort((area, cc))
    best = np.full(C, 0.0)
    firsts = o[np.r_[True, cc[o][1:] != cc[o][:-1]]]
    best[cc[firsts]] = ang[firsts]
    ca, sa = np.cos(best[lc]), np.sin(best[lc])
    x, y = x * ca + y * sa, -x * sa + y * ca

    def extent(x, y):
        lo = np.stack([np.full(C, np.inf), np.full(C, np.inf)], 1)
        hi = -lo
        np.minimum.at(lo, lc, np.stack([x, y], 1))
        np.maximum.at(hi, lc, np.stack([x, y], 1))
        return lo, hi - lo

    lo, size = extent(x, y)
    tall = size[:, 1] > size[:, 0]  # turn by 90 degrees so that width >= height
    t = tall[lc]
    x, y = np.where(t, y, x), np.where(t, -x, y)
    lo, size = extent(x, y)
    return lc, x, y, lo, size[:, 0], size[:, 1]


def _fits(W, H, s, m, res):
    """Shelf positions of the charts (W, H sorted tallest first) at scale s (texels per unit) with m
    texels around each in a res x res square, or None."""
    fw = np.maximum(np.ceil(W * s - 1e-9), 1).astype(np.int64) + 2 * m
    fh = np.maximum(np.ceil(H * s - 1e-9), 1).astype(np.int64) + 2 * m
    return _shelf_pack(fw, fh, res)


def lightmap_size(co, loop_start, loop_total, loop_verts, density, lo=8, hi=128, step=4, margin=MARGIN):
    """The smallest lightmap size (a multiple of `step`, lo to hi) whose packing gives the mesh's
    charts at least `density` texels per unit with `margin` texels around each (hi when even hi
    does not: those charts get fewer). co in world units (the object's scale applied)."""
    _, _, _, _, W, H = _chart_rects(co, loop_start, loop_total, loop_verts)
    order = np.lexsort((-W, -H))
    W, H = W[order] * density, H[order] * density
    side = np.maximum(np.ceil(W - 1e-9), 1) + 2 * margin
    need = max(float(np.sqrt(np.sum(side * (np.maximum(np.ceil(H - 1e-9), 1) + 2 * margin)))), side.max())
    res = max(int(lo), int(np.ceil(need / step)) * step)  # the charts' own area: no smaller size fits
    while res < hi and _fits(W, H, 1.0, margin, res) is None:
        res += step
    return min(res, int(hi))


def surface_area(co, loop_start, loop_total, loop_verts):
    """The mesh's surface area: the sum of its polygons' areas (co in world units)."""
    n = polygon_newell(np.asarray(co, np.float64), loop_start, loop_total, loop_verts)
    return float(np.linalg.norm(n, axis=1).sum() / 2)


def pack_lightmap(co, loop_start, loop_total, loop_verts, res, margin=MARGIN):
    """(L, 2) lightmap UVs in [0, 1]: planar charts (edge-connected coplanar polygons, other polygons
    alone) projected isometrically onto their plane, turned to their smallest bounding rectangle and
    shelf-packed at one common texel density with `margin` texels around every chart."""
    lc, x, y, lo, W, H = _chart_rects(co, loop_start, loop_total, loop_verts)
    C = len(W)
    order = np.lexsort((-W, -H))
    Wo, Ho = W[order], H[order]

    def attempt(s, m):
        return _fits(Wo, Ho, s, m, res)

    for m in (margin, 1, 0):
        if attempt(0.0, m) is not None:
            break
    else:
        raise TextureError(f"{C} UV islands do not fit in a {res}x{res} lightmap")
    total = float(np.sum(W * H))
    hi_s = min((res - 2 * m) / max(float(W.max()), 1e-300), res / np.sqrt(max(total, 1e-300)))
    lo_s = 0.0
    if attempt(hi_s, m) is not None:
        lo_s = hi_s
    else:
        for _ in range(40):
            mid = 0.5 * (lo_s + hi_s)
            if attempt(mid, m) is not None:
                lo_s = mid
            else:
                hi_s = mid
            if hi_s - lo_s <= 1e-4 * hi_s:
                break
    s = lo_s
    px, py = attempt(s, m)
    ox, oy = np.empty(C), np.empty(C)
    ox[order], oy[order] = px + m, py + m
    uv = np.stack([ox[lc] + (x - lo[lc, 0]) * s, oy[lc] + (y - lo[lc, 1]) * s], 1) / res
    return np.clip(uv, 0.0, 1.0)
