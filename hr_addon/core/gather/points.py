"""Where the gather's samples and hits lie: HR leaves by side tests (locate_below), samples kept
inside their patch."""

import numpy as np

from ..geometry import insideness


def _triple(e, w, n):
    """det[e, w, n] = (e x w) . n, rows (m, 3)."""
    return (
        (e[:, 1] * w[:, 2] - e[:, 2] * w[:, 1]) * n[:, 0]
        + (e[:, 2] * w[:, 0] - e[:, 0] * w[:, 2]) * n[:, 1]
        + (e[:, 0] * w[:, 1] - e[:, 1] * w[:, 0]) * n[:, 2]
    )


def split_lines(h, n_hr):
    """The lines that split each of the first n_hr nodes into its children, computed once for
    every locate_below of a gather (each level of each batch would redo them): per node up to
    three lines, origin m, direction e, and the side s of the corner the line cuts off (quads:
    lines 0 and 1 with corner a; triangles: corners a, b, c). The same expressions as the
    per-level code had, so a point goes to the same child, bit for bit. Component major, as
    locate_below reads them: (m (3 lines, 3 axes, n_hr), e (3, 3, n_hr), s (3, n_hr), the nodes'
    normals (3 axes, n_hr)), each row contiguous."""
    c, n = h.corners[:n_hr], h.normal[:n_hr]
    a, b, cc, d = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
    ab, bc, cd, da, ca = (a + b) / 2, (b + cc) / 2, (cc + d) / 2, (d + a) / 2, (cc + a) / 2
    quad = (h.nv[:n_hr] == 4)[:, None]
    # quads: ab -> cd separates u < 1/2 (a's side) from u > 1/2; da -> bc: v. Triangles: the
    # corner triangles' inner edges ab -> ca (a), ab -> bc (b), ca -> bc (c)
    m = np.stack([ab, np.where(quad, da, ab), ca], 1)
    e = np.stack([np.where(quad, cd, ca), bc, bc], 1) - m
    corner = np.stack([a, np.where(quad, a, b), cc], 1)
    s = np.sign(np.stack([_triple(e[:, k], corner[:, k] - m[:, k], n) for k in range(3)], 1))
    return (*(np.ascontiguousarray(np.moveaxis(x, 0, -1)) for x in (m, e, s)), np.ascontiguousarray(n.T))


def locate_below(h, patch, points, n_hr, lines=None):
    """The HR leaf holding each point (M,) <- patch (M,), points (M, 3): the leaf of the first
    n_hr nodes (nodes whose children were added later, by light events, count as leaves).

    Children of a quad are the bilinear images of the parameter square's quarters, split by the
    straight lines from edge midpoint to edge midpoint; children of a triangle are its corner
    triangles and the middle one. So one level costs two (quads) or three (triangles) side tests
    against those lines (split_lines; pass them when locating many batches) instead of
    output.locate's test against every child's edges; ties on a line go to either side, as
    locate's. The points still descending are kept apart, by coordinate: each level gathers only
    theirs (_triple's products in its order, so the same leaf bit for bit)."""
    m, e, s, nrm = split_lines(h, n_hr) if lines is None else lines
    out = np.asarray(patch, np.int64).copy()
    pts = np.asarray(points, float)
    idx, node = None, out  # the points still descending (None: all) and their nodes
    p = [pts[:, k].copy() for k in range(3)]
    while True:
        c0 = h.child0[node]
        inner = (c0 >= 0) & (c0 < n_hr)
        if not inner.all() or not len(inner):
            done = np.flatnonzero(~inner)
            out[done if idx is None else idx[done]] = node[done]
            go = np.flatnonzero(inner)
            if not len(go):
                return out
            idx = go if idx is None else idx[go]
            node, c0, p = node[go], c0[go], [x[go] for x in p]

        def side(k, rows):  # > 0: the point on the corner's side of line k (0 on the line)
            j = node if rows is None else node[rows]
            ex, ey, ez = (x.take(j) for x in e[k])
            wx, wy, wz = ((x if rows is None else x[rows]) - mk.take(j) for x, mk in zip(p, m[k]))
            nx, ny, nz = (x.take(j) for x in nrm)
            det = (ey * wz - ez * wy) * nx + (ez * wx - ex * wz) * ny + (ex * wy - ey * wx) * nz
            return det * s[k].take(j)

        quad = h.nv[node] == 4
        if quad.all():
            right, top = side(0, None) < 0, side(1, None) < 0
            k = np.where(top, np.where(right, 2, 3), np.where(right, 1, 0))
        else:
            k = np.zeros(len(node), np.int64)
            q = np.flatnonzero(quad)
            if len(q):
                right, top = side(0, q) < 0, side(1, q) < 0
                k[q] = np.where(top, np.where(right, 2, 3), np.where(right, 1, 0))
            t = np.flatnonzero(~quad)
            in_a, in_b, in_c = side(0, t) > 0, side(1, t) > 0, side(2, t) > 0
            k[t] = np.where(in_a, 0, np.where(in_b, 1, np.where(in_c, 2, 3)))
        node = c0 + k


def onto_patch(pt, patch, p, margin):
    """Points (M, 3) onto the planes of their patches, then into them (_into_patch): points on a
    renderer's triangulation of a slightly warped polygon lie off the patch (behind it by more
    than eps, every ray would hit its back), texels of a lightmap's dilation ring beyond its edge."""
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    pn = pt.normal[patch]
    p = p - np.einsum("ij,ij->i", p - pt.corners[patch, 0], pn)[:, None] * pn
    return _into_patch(pt, patch, p, margin)


def _into_patch(pt, patch, p, margin):
    """Points (M, 3) in their patches' planes moved to at least `margin` inside their patch: points
    beyond its outline (a lightmap's dilation ring) to the nearest point of it, then those closer
    than margin to it (texels and vertices on an edge where two surfaces meet: rays from there
    would start on the other surface and pass through it) towards the patch's centre."""
    c = pt.corners[patch]
    d = insideness(c[:, None], pt.normal[patch][:, None], p)[:, 0]
    size = np.sqrt(pt.area[patch])
    p = p.copy()
    out = np.flatnonzero(d < 0)
    if len(out):
        q, cc = p[out], c[out]
        a, b = cc, np.roll(cc, -1, axis=1)
        ab = b - a
        t = np.einsum("mkj,mkj->mk", q[:, None] - a, ab) / np.maximum(
            np.einsum("mkj,mkj->mk", ab, ab), 1e-300
        )
        near = a + np.clip(t, 0, 1)[..., None] * ab
        k = np.argmin(np.linalg.norm(near - q[:, None], axis=-1), axis=1)
        p[out] = near[np.arange(len(out)), k]
        d[out] = 0.0
    close = np.flatnonzero(d < margin)
    if len(close):
        nv = pt.nv[patch[close]]
        cc = c[close]
        centre = np.where((nv == 4)[:, None], cc.mean(1), cc[:, :3].mean(1))
        to = centre - p[close]
        # the inradius-like distance of the centre bounds how far moving towards it can go
        dc = insideness(cc[:, None], pt.normal[patch[close]][:, None], centre)[:, 0]
        f = np.clip((margin - d[close]) / np.maximum(dc - d[close], 1e-300), 0, 0.5)
        f = np.where(margin < 0.25 * size[close], f, np.minimum(f, 1e-3))
        p[close] += f[:, None] * to
    return p
