"""Leaf radiance -> values at the input polygons' vertices.

Each patch corner takes the radiance of the leaf that holds it (the quadtree is descended towards
that corner). A vertex value is the area-weighted mean over every patch corner at the same position
of the same object whose patch normal lies within `smooth_angle` of the polygon's own normal, so
polygons that meet smoothly share one value (no cracks, also across T-junctions of the hierarchy,
which never reach the output) while creases (a wall meeting the floor) stay sharp.
"""
import numpy as np

from .geometry import MeshInput
from .hierarchy import Hierarchy


def _weld_ids(mesh: MeshInput, loop_obj):
    """Same id for loops whose vertices share object and position (split-edge meshes)."""
    v = mesh.verts[mesh.loop_verts]
    scale = max(float(np.abs(v).max()), 1e-30) * 1e-9
    key = np.column_stack([loop_obj, np.round(v / scale).astype(np.int64)])
    return np.unique(key, axis=0, return_inverse=True)[1].ravel()


def loop_radiance(h: Hierarchy, B, mesh: MeshInput, smooth_angle=30.0, domain="CORNER"):
    """Radiance (L, 3) per input loop (CORNER) or (V, 3) per input vertex (POINT), float32."""
    pt = h.patches
    K = len(pt.nv)
    P = len(mesh.loop_start)
    loop_poly = np.repeat(np.arange(P), mesh.loop_total)
    loop_obj = np.asarray(mesh.object_id)[loop_poly]
    weld = _weld_ids(mesh, loop_obj)
    # vertex index -> weld id (any loop using the vertex tells it)
    v2w = np.full(len(mesh.verts), -1, np.int64)
    v2w[mesh.loop_verts] = weld

    # Table of patch corners: weld id, value, weight, normal.
    jj, kk = np.nonzero(pt.vert_index >= 0)
    leaf = np.empty(len(jj), np.int64)
    for k in range(4):
        m = kk == k
        leaf[m] = h.leaf_at_corner(jj[m], k)
    w_id = v2w[pt.vert_index[jj, kk]]
    val = B[:, leaf].T
    wgt = h.area[leaf]
    nrm = pt.normal[jj]

    # Polygon normal (from its first patch); dropped polygons have none and take every neighbour.
    poly_normal = np.zeros((P, 3))
    first = np.unique(pt.poly, return_index=True)
    poly_normal[first[0]] = pt.normal[first[1]]

    order = np.argsort(w_id, kind="stable")
    w_sorted = w_id[order]
    start = np.searchsorted(w_sorted, weld, "left")
    count = np.searchsorted(w_sorted, weld, "right") - start
    # Expand (loop, candidate corner) pairs, a few per loop.
    li = np.repeat(np.arange(len(weld)), count)
    offs = np.arange(len(li)) - np.repeat(np.cumsum(count) - count, count)
    ci = order[np.repeat(start, count) + offs]
    if domain == "POINT":
        ok = np.ones(len(li), bool)
    else:
        pn = poly_normal[loop_poly[li]]
        ok = (np.einsum("ij,ij->i", pn, nrm[ci]) >= np.cos(np.radians(smooth_angle))) | ~pn.any(1)
    w = wgt[ci] * ok
    num = np.zeros((len(weld), 3))
    for c in range(3):
        num[:, c] = np.bincount(li, weights=w * val[ci, c], minlength=len(weld))
    den = np.bincount(li, weights=w, minlength=len(weld))
    out = num / np.maximum(den, 1e-300)[:, None]
    if domain == "POINT":
        res = np.zeros((len(mesh.verts), 3))
        res[mesh.loop_verts] = out
        return res.astype(np.float32)
    return out.astype(np.float32)
