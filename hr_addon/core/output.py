"""Leaf radiance -> values at the input polygons' vertices.

Each patch corner takes the radiance of the leaf that holds it (the quadtree is descended towards
that corner). A vertex value is the area-weighted mean over every patch corner at the same position
of the same object whose patch normal lies within `smooth_angle` of the polygon's own normal, so
polygons that meet smoothly share one value (no cracks, also across T-junctions of the hierarchy,
which never reach the output) while creases (a wall meeting the floor) stay sharp.
"""

import numpy as np

from .geometry import MeshInput, insideness
from .hierarchy import Hierarchy

# Points per pass of radiance_at and locate_near: bounds their memory at any number of points
# (0.16 GB peak on the furnished 20k room at medium, docs/scale.md); the values do not depend on it.
CHUNK = 32768


def loop_welds(mesh: MeshInput):
    """(loop -> polygon, loop -> weld id): the same weld id for loops whose vertices share object
    and position (split-edge meshes)."""
    loop_poly = np.repeat(np.arange(len(mesh.loop_start)), mesh.loop_total)
    return loop_poly, weld_ids(np.asarray(mesh.object_id)[loop_poly], mesh.verts[mesh.loop_verts])


def weld_ids(object_id, pos):
    """The same id for points (N, 3) of the same object at the same position (to 1e-9 of the
    points' extent)."""
    scale = max(float(np.abs(pos).max()), 1e-30) * 1e-9
    key = np.column_stack([object_id, np.round(pos / scale).astype(np.int64)])
    return np.unique(key, axis=0, return_inverse=True)[1].ravel()


def equal_key_pairs(queries, keys):
    """(i, j): every pair of a query i and a key j with queries[i] == keys[j] (i ascending)."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    start = np.searchsorted(ks, queries, "left")
    count = np.searchsorted(ks, queries, "right") - start
    i = np.repeat(np.arange(len(queries)), count)
    offs = np.arange(len(i)) - np.repeat(np.cumsum(count) - count, count)
    return i, order[np.repeat(start, count) + offs]


def loop_radiance(h: Hierarchy, B, mesh: MeshInput, smooth_angle=30.0, domain="CORNER", plan=None):
    """Radiance (L, 3) per input loop (CORNER) or (V, 3) per input vertex (POINT), float32.
    plan: loop_plan() of the same arguments and hierarchy state, reused (it is nearly all the cost)."""
    leaf, li, w, den, n = plan or loop_plan(h, mesh, smooth_angle, domain)
    num = np.zeros((n, 3))
    for c in range(3):
        num[:, c] = np.bincount(li, weights=w * B[c, leaf], minlength=n)
    # corners whose every leaf is covered (contacts.py) show 0
    return in_domain(np.where(den[:, None] > 0, num / np.maximum(den, 1e-300)[:, None], 0.0), mesh, domain)


def in_domain(out, mesh: MeshInput, domain):
    """Per-loop values (L, 3) as float32 output: as they are (CORNER), or per vertex (POINT: a
    vertex takes its last loop's value)."""
    if domain == "POINT":
        res = np.zeros((len(mesh.verts), 3))
        res[mesh.loop_verts] = out
        out = res
    return out.astype(np.float32)


def loop_plan(h: Hierarchy, mesh: MeshInput, smooth_angle=30.0, domain="CORNER"):
    """What loop_radiance() weighs, independent of B: (leaf, output index, weight) per (loop,
    patch corner) pair, the weight sums and the number of welded loops."""
    pt = h.patches
    P = len(mesh.loop_start)
    loop_poly, weld = loop_welds(mesh)
    # vertex index -> weld id (any loop using the vertex tells it)
    v2w = np.full(len(mesh.verts), -1, np.int64)
    v2w[mesh.loop_verts] = weld

    # Table of patch corners: weld id, weight, normal.
    jj, kk = np.nonzero(pt.vert_index >= 0)
    leaf = np.empty(len(jj), np.int64)
    for k in range(4):
        m = kk == k
        leaf[m] = h.leaf_at_corner(jj[m], k)
    w_id = v2w[pt.vert_index[jj, kk]]
    wgt = h.area[leaf]
    nrm = pt.normal[jj]

    # Polygon normal (from its first patch); dropped polygons have none and take every neighbour.
    poly_normal = np.zeros((P, 3))
    first = np.unique(pt.poly, return_index=True)
    poly_normal[first[0]] = pt.normal[first[1]]

    li, ci = equal_key_pairs(weld, w_id)  # (loop, candidate corner) pairs, a few per loop
    if domain == "POINT":
        ok = np.ones(len(li), bool)
    else:
        pn = poly_normal[loop_poly[li]]
        ok = (np.einsum("ij,ij->i", pn, nrm[ci]) >= np.cos(np.radians(smooth_angle))) | ~pn.any(1)
    w = wgt[ci] * ok
    # B holds node means, covered parts included: weigh by exposed area below (contacts.py)
    den = np.bincount(li, weights=w * h.exposure[leaf[ci]], minlength=len(weld))
    return leaf[ci], li, w, den, len(weld)


def locate(h: Hierarchy, patch, points):
    """Leaf of `patch`'s quadtree containing each point (M,) <- (M,), (M, 3).

    Descends by picking, among the four children, the one the point is most inside of (largest
    minimum signed edge distance), which is robust for points on shared edges or slightly off."""
    node = np.asarray(patch, np.int64).copy()
    pts = np.asarray(points, float)
    while True:
        inner = np.flatnonzero(h.child0[node] >= 0)
        if len(inner) == 0:
            return node
        kids = h.child0[node[inner]][:, None] + np.arange(4)  # (m, 4)
        d = insideness(h.corners[kids], h.normal[kids], pts[inner])
        node[inner] = kids[np.arange(len(inner)), np.argmax(d, axis=1)]


def patch_neighbours(h: Hierarchy, smooth_angle=30.0):
    """(K, D) padded table (-1) of the patches sharing a corner position with each patch, in the
    same object, with normals within smooth_angle: where a smooth surface continues."""
    pt = h.patches
    if getattr(pt, "_neighbours", None) is not None:
        return pt._neighbours
    jj, kk = np.nonzero(pt.vert_index >= 0)
    g = weld_ids(pt.object_id[jj], pt.corners[jj, kk])
    i, j = equal_key_pairs(g, g)
    a, b = jj[i], jj[j]
    ok = (a != b) & (np.einsum("ij,ij->i", pt.normal[a], pt.normal[b]) >= np.cos(np.radians(smooth_angle)))
    pairs = np.unique(np.column_stack([a[ok], b[ok]]), axis=0)
    K = len(pt.nv)
    deg = np.bincount(pairs[:, 0], minlength=K) if len(pairs) else np.zeros(K, np.int64)
    table = np.full((K, max(int(deg.max()) if K else 0, 1)), -1, np.int64)
    if len(pairs):
        first = np.searchsorted(pairs[:, 0], np.arange(K))
        table[pairs[:, 0], np.arange(len(pairs)) - first[pairs[:, 0]]] = pairs[:, 1]
    pt._neighbours = table
    return table


def locate_near(h: Hierarchy, patch, points):
    """Like locate, but a point just outside its patch goes to the smooth neighbour holding it.

    Only a patch's actual neighbours are tested: the table's width D is the largest degree (a
    cylinder cap's fan), and a dense (M, 1 + D, 4, 3) test took ~17 kB per point on the furnished
    room (D = 23). Chunks bound the rest; each point's result is independent of the others."""
    patch = np.asarray(patch, np.int64)
    pts = np.asarray(points, float)
    table = patch_neighbours(h)
    out = np.empty(len(patch), np.int64)
    for a in range(0, len(patch), CHUNK):
        p, x = patch[a : a + CHUNK], pts[a : a + CHUNK]
        cand = np.column_stack([p, table[p]])  # (m, 1 + D)
        i, j = np.nonzero(cand >= 0)
        k = cand[i, j]
        d = np.full(cand.shape, -np.inf)
        d[i, j] = insideness(h.corners[k][:, None], h.normal[k][:, None], x[i])[:, 0]
        out[a : a + CHUNK] = locate(h, cand[np.arange(len(cand)), np.argmax(d, axis=1)], x)
    return out


def radiance_at(h: Hierarchy, B, patch, points, smooth=True, mask=True):
    """Radiance (M, 3) at surface points of the given patches (texel centres for texture baking).

    smooth=False returns the leaf values: the piecewise-constant HR solution. smooth=True
    interpolates linearly inside the leaf (quads as two triangles) between corner values, each the
    mean of the leaves touching that corner weighted by the inverse distance of their centres
    from it, found by probing just beside it, also
    in the neighbouring patches of a smooth surface (so input polygon edges leave no seam). The
    result is continuous across edges between leaves of equal size; at a T-vertex the jump is a
    fraction of the neighbouring leaves' difference. mask: points on covered parts of surfaces
    (contacts.py) read 0 (False: the interpolated field, for texels.radiance_per_leaf's probes).
    Runs over CHUNK points at a time (each point's value is independent of the others)."""
    patch = np.asarray(patch, np.int64)
    pts = np.asarray(points, float)
    if len(pts) > CHUNK:
        return np.concatenate(
            [
                radiance_at(h, B, patch[a : a + CHUNK], pts[a : a + CHUNK], smooth, mask)
                for a in range(0, len(pts), CHUNK)
            ]
        )
    leaf = locate(h, patch, pts)
    if not smooth:
        return h.values_at(B, leaf, pts) if mask else h.shown(B)[:, leaf].T.copy()
    c = h.corners[leaf]  # (M, 4, 3)
    size = np.sqrt(h.area[leaf])[:, None, None]
    unit = lambda v: v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)
    u, w = unit(np.roll(c, -1, axis=1) - c), unit(np.roll(c, 1, axis=1) - c)
    num = np.zeros((len(leaf), 4, 3))
    den = np.zeros((len(leaf), 4))
    for su, sw in ((1, 1), (-1, 1), (1, -1), (-1, -1)):
        probe = (c + 1e-3 * size * (su * u + sw * w)).reshape(-1, 3)
        pl = locate_near(h, np.repeat(patch, 4), probe).reshape(-1, 4)
        # A leaf's mean is the field near its centre: weigh it by the inverse of that centre's
        # distance from the corner (linear between the centres along a line). Area weights let a
        # large leaf, its centre far off, outweigh the small ones refinement made beside the
        # corner where the light changes fastest: +4.1% in the band beside a box (test_contacts).
        a = 1.0 / np.maximum(np.linalg.norm(h.centre[pl] - c, axis=-1), 1e-300)
        num += a[..., None] * B[:, pl].transpose(1, 2, 0)
        den += a * h.exposure[pl]  # node means over exposed area: the light on the uncovered part
    val = num / np.maximum(den, 1e-300)[..., None]
    out = np.einsum("mk,mkc->mc", corner_weights(c, h.nv[leaf], h.normal[leaf], pts), val)
    if mask:  # covered points stay dark: no light interpolated under a block
        out[h.dark(leaf, pts)] = 0.0
    return out


_TRIS = np.array([[0, 1, 2], [0, 2, 3]])


def corner_weights(c, nv, normal, pts):
    """(M, 4) weights of a leaf's corner values at points inside it: linear on the triangle
    (0, 1, 2) or, for quads, (0, 2, 3) that holds the point."""
    second = (nv == 4) & (np.einsum("mj,mj->m", np.cross(c[:, 2] - c[:, 0], pts - c[:, 0]), normal) > 0)
    idx = _TRIS[second.astype(np.int64)]
    t = np.take_along_axis(c, idx[..., None], axis=1)
    v0, v1, v2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0], pts - t[:, 0]
    d00, d01, d11 = (np.einsum("mj,mj->m", x, y) for x, y in ((v0, v0), (v0, v1), (v1, v1)))
    d20, d21 = np.einsum("mj,mj->m", v2, v0), np.einsum("mj,mj->m", v2, v1)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-300)
    b1 = np.clip((d11 * d20 - d01 * d21) / den, 0, 1)
    b2 = np.clip((d00 * d21 - d01 * d20) / den, 0, 1 - b1)
    w = np.zeros((len(pts), 4))
    np.put_along_axis(w, idx, np.stack([1 - b1 - b2, b1, b2], 1), axis=1)
    return w
