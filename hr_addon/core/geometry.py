"""Input validation and conversion of arbitrary polygons into convex planar patches.

Patches are the roots of the radiosity quadtrees. Triangles and planar convex quads are kept;
non-planar or concave quads and n-gons are triangulated: as MeshInput.tri_loops says when it is
given (Blender's loop_triangles, what Cycles and EEVEE render), else here (quads along the inner or
shorter diagonal, n-gons by ear clipping).
"""
from dataclasses import dataclass, field

import numpy as np


class InputError(ValueError):
    """Bad scene input; the message names the polygon and object at fault."""


@dataclass
class MeshInput:
    """Polygons in world space, laid out like Blender's mesh arrays (all objects concatenated)."""
    verts: np.ndarray          # (V, 3)
    loop_start: np.ndarray     # (P,) first loop of each polygon
    loop_total: np.ndarray     # (P,) vertex count of each polygon
    loop_verts: np.ndarray     # (L,) vertex index of each loop
    reflectance: np.ndarray    # (P, 3) in [0, 1)
    emission: np.ndarray       # (P, 3) emitted radiance, >= 0
    object_id: np.ndarray      # (P,) index into object_names
    object_names: list = field(default_factory=list)
    # Optional triangulation, (T, 3) loop indices (into loop_verts), each triangle wound like its
    # polygon, e.g. Blender's mesh.loop_triangles. The polygons that must be split use it (those it
    # covers); the others are split here.
    tri_loops: np.ndarray = None

    @staticmethod
    def from_polygons(verts, polys, reflectance, emission=None, object_id=None, object_names=None):
        """Convenience constructor from a list of vertex-index lists."""
        sizes = np.array([len(p) for p in polys], dtype=np.int64)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if len(polys) else np.zeros(0, np.int64)
        loops = np.array([i for p in polys for i in p], dtype=np.int64)
        n = len(polys)
        rho = np.broadcast_to(np.asarray(reflectance, float), (n, 3)).copy()
        em = np.zeros((n, 3)) if emission is None else np.broadcast_to(np.asarray(emission, float), (n, 3)).copy()
        oid = np.zeros(n, np.int64) if object_id is None else np.asarray(object_id, np.int64)
        names = object_names or [f"object{i}" for i in range(int(oid.max()) + 1 if n else 1)]
        return MeshInput(np.asarray(verts, float), starts, sizes, loops, rho, em, oid, names)

    def concat(self, other):
        off = len(self.verts)
        tris = [t for t in (self.tri_loops, None if other.tri_loops is None
                            else np.asarray(other.tri_loops, np.int64) + len(self.loop_verts)) if t is not None]
        return MeshInput(
            np.concatenate([self.verts, other.verts]),
            np.concatenate([self.loop_start, other.loop_start + len(self.loop_verts)]),
            np.concatenate([self.loop_total, other.loop_total]),
            np.concatenate([self.loop_verts, other.loop_verts + off]),
            np.concatenate([self.reflectance, other.reflectance]),
            np.concatenate([self.emission, other.emission]),
            np.concatenate([self.object_id, other.object_id + len(self.object_names)]),
            list(self.object_names) + list(other.object_names),
            np.concatenate([np.asarray(t, np.int64).reshape(-1, 3) for t in tris]) if tris else None)


@dataclass
class Patches:
    corners: np.ndarray      # (K, 4, 3) convex planar, CCW; triangles repeat corner 2
    nv: np.ndarray           # (K,) 3 or 4
    vert_index: np.ndarray   # (K, 4) input vertex index of each corner (-1 padding)
    poly: np.ndarray         # (K,) input polygon each patch came from
    object_id: np.ndarray    # (K,)
    reflectance: np.ndarray  # (3, K)
    emission: np.ndarray     # (3, K)
    normal: np.ndarray       # (K, 3)
    area: np.ndarray         # (K,)
    object_names: list
    dropped: int = 0         # degenerate polygons (or triangles) removed
    warnings: list = field(default_factory=list)

    @property
    def triangles(self):
        """Occluder triangle soup (T, 3, 3) for the visibility backends."""
        tri = self.corners[:, [0, 1, 2]]
        quads = self.nv == 4
        return np.concatenate([tri, self.corners[quads][:, [0, 2, 3]]])


def _newell(p):
    """Newell normal (unnormalised, length = 2 x area) of polygons p (..., n, 3)."""
    q = np.roll(p, -1, axis=-2)
    return np.stack([np.sum((p[..., 1] - q[..., 1]) * (p[..., 2] + q[..., 2]), -1),
                     np.sum((p[..., 2] - q[..., 2]) * (p[..., 0] + q[..., 0]), -1),
                     np.sum((p[..., 0] - q[..., 0]) * (p[..., 1] + q[..., 1]), -1)], -1)


def _ear_clip(pts, idx):
    """Triangulate one simple polygon (any concavity) given its 3D points; returns index triples."""
    n = _newell(pts)
    axis = int(np.argmax(np.abs(n)))
    uv = np.delete(pts, axis, axis=1)
    if n[axis] < 0:  # keep CCW orientation in the projected plane
        uv = uv[:, ::-1]
    rem = list(range(len(pts)))
    tris = []
    guard = 0
    while len(rem) > 3 and guard < 10 * len(pts) ** 2:
        guard += 1
        m = len(rem)
        for k in range(m):
            a, b, c = rem[k - 1], rem[k], rem[(k + 1) % m]
            ab, ac = uv[b] - uv[a], uv[c] - uv[a]
            if ab[0] * ac[1] - ab[1] * ac[0] <= 0:
                continue  # reflex or degenerate corner
            others = [j for j in rem if j not in (a, b, c)]
            if others:
                p = uv[others]
                def side(u, v):
                    return (v[0] - u[0]) * (p[:, 1] - u[1]) - (v[1] - u[1]) * (p[:, 0] - u[0])
                if np.any((side(uv[a], uv[b]) >= 0) & (side(uv[b], uv[c]) >= 0) & (side(uv[c], uv[a]) >= 0)):
                    continue
            tris.append((idx[a], idx[b], idx[c]))
            rem.pop(k)
            break
        else:  # self-intersecting or numerically degenerate: fall back to a fan
            break
    tris += [(idx[rem[0]], idx[rem[i]], idx[rem[i + 1]]) for i in range(1, len(rem) - 1)]
    return tris


def prepare_patches(mesh: MeshInput, planar_tol=1e-3, area_tol=1e-10) -> Patches:
    """Validate input and convert to convex planar patches.

    planar_tol: a quad whose fourth corner is off the plane of the first three by more than
    planar_tol x its diagonal is split in two triangles. area_tol: polygons with area below
    area_tol x (scene bounding diagonal)^2 are dropped and counted.
    """
    P = len(mesh.loop_start)
    names = list(mesh.object_names)

    def who(i):
        oid = int(mesh.object_id[i])
        return f"polygon {i} of object '{names[oid] if 0 <= oid < len(names) else oid}'"

    if P == 0:
        raise InputError("The scene has no polygons to compute radiosity on.")
    verts = np.asarray(mesh.verts, float)
    rho = np.asarray(mesh.reflectance, float)
    em = np.asarray(mesh.emission, float)
    for arr, what in ((rho, "reflectance"), (em, "emission")):
        bad = ~np.isfinite(arr).all(1)
        if bad.any():
            raise InputError(f"Non-finite {what} on {who(int(np.argmax(bad)))}.")
    bad = ((rho < 0) | (rho >= 1)).any(1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"Reflectance {tuple(np.round(rho[i], 4))} on {who(i)} is outside [0, 1): "
                         "a diffuse surface cannot reflect all the light it receives.")
    bad = (em < 0).any(1)
    if bad.any():
        raise InputError(f"Negative emission on {who(int(np.argmax(bad)))}.")
    loop_poly = np.repeat(np.arange(P), mesh.loop_total)
    bad_loops = ~np.isfinite(verts[mesh.loop_verts]).all(1)
    if bad_loops.any():
        raise InputError(f"NaN or infinite vertex coordinates on {who(int(loop_poly[np.argmax(bad_loops)]))}.")

    used = verts[mesh.loop_verts]
    diag = float(np.linalg.norm(used.max(0) - used.min(0))) or 1.0
    min_area = area_tol * diag * diag

    tri_list, quad_list = [], []  # (poly, v0, v1, v2[, v3])
    sizes = np.asarray(mesh.loop_total)
    starts = np.asarray(mesh.loop_start)
    lv = np.asarray(mesh.loop_verts)
    dropped_small = int(np.sum(sizes < 3))

    t = np.flatnonzero(sizes == 3)
    tri_list.append(np.column_stack([t, lv[starts[t][:, None] + np.arange(3)]]))

    q = np.flatnonzero(sizes == 4)
    qv = lv[starts[q][:, None] + np.arange(4)]
    qp = verts[qv]
    n = _newell(qp)
    nn = np.linalg.norm(n, axis=1, keepdims=True)
    nu = n / np.where(nn > 0, nn, 1)
    d_off = np.abs(np.einsum("ij,ij->i", qp[:, 3] - qp[:, 0], nu))
    d_off = np.maximum(d_off, np.abs(np.einsum("ij,ij->i", qp[:, 2] - qp[:, 0], nu)))
    diag_len = np.maximum(np.linalg.norm(qp[:, 2] - qp[:, 0], axis=1), np.linalg.norm(qp[:, 3] - qp[:, 1], axis=1))
    planar = d_off <= planar_tol * np.maximum(diag_len, 1e-300)
    e = np.roll(qp, -1, axis=1) - qp
    turn = np.einsum("ijk,ik->ij", np.cross(e, np.roll(e, -1, axis=1)), nu)
    convex = (turn > 0).all(1)
    keep = planar & convex
    quad_list.append(np.column_stack([q[keep], qv[keep]]))
    # Polygons that must be split and that the given triangulation covers use it.
    given = np.zeros(P, bool)
    if mesh.tri_loops is not None and len(mesh.tri_loops):
        tl = np.asarray(mesh.tri_loops, np.int64).reshape(-1, 3)
        if tl.min() < 0 or tl.max() >= len(lv):
            raise InputError("Triangulation (tri_loops) refers to loops that do not exist.")
        tpoly = loop_poly[tl]
        bad = (tpoly != tpoly[:, :1]).any(1)
        if bad.any():
            raise InputError(f"Triangulation (tri_loops) mixes the loops of several polygons at {who(int(tpoly[np.argmax(bad), 0]))}.")
        tpoly = tpoly[:, 0]
        need = np.zeros(P, bool)
        need[q[~keep]] = True
        need[sizes > 4] = True
        count = np.bincount(tpoly, minlength=P)
        given = need & (count == np.maximum(sizes - 2, 0))
        use = given[tpoly]
        tri_list.append(np.column_stack([tpoly[use], lv[tl[use]]]))
    # Split the others along the diagonal that stays inside (the one through a reflex corner)
    # or, for non-planar quads, the shorter one.
    own = ~keep & ~given[q]
    sq, sqv, sturn = q[own], qv[own], turn[own]
    reflex13 = (sturn[:, 0] <= 0) | (sturn[:, 2] <= 0)   # turn k is at corner k+1
    use02 = np.where(planar[own], ~reflex13,
                     np.linalg.norm(qp[own][:, 2] - qp[own][:, 0], axis=1)
                     <= np.linalg.norm(qp[own][:, 3] - qp[own][:, 1], axis=1))
    tri_list.append(np.column_stack([sq, np.where(use02[:, None], sqv[:, [0, 1, 2]], sqv[:, [0, 1, 3]])]))
    tri_list.append(np.column_stack([sq, np.where(use02[:, None], sqv[:, [0, 2, 3]], sqv[:, [1, 2, 3]])]))

    for i in np.flatnonzero((sizes > 4) & ~given):
        idx = lv[starts[i]:starts[i] + sizes[i]]
        tri_list.append(np.array([(i, *tr) for tr in _ear_clip(verts[idx], idx)], dtype=np.int64).reshape(-1, 4))

    tris = np.concatenate(tri_list).astype(np.int64)
    quads = np.concatenate(quad_list).astype(np.int64)
    poly = np.concatenate([tris[:, 0], quads[:, 0]])
    vidx = np.concatenate([np.column_stack([tris[:, 1:], tris[:, 3]]), quads[:, 1:]])
    nv = np.concatenate([np.full(len(tris), 3), np.full(len(quads), 4)])
    corners = verts[vidx]
    n = _newell(corners)  # a padded triangle's repeated corner adds a zero-length edge
    area = 0.5 * np.linalg.norm(n, axis=1)
    ok = area > min_area
    dropped = dropped_small + int(np.sum(sizes >= 3)) - len(np.unique(poly[ok]))
    order = np.argsort(poly[ok], kind="stable")
    sel = np.flatnonzero(ok)[order]
    vidx = vidx[sel].copy()
    vidx[nv[sel] == 3, 3] = -1
    # Quads kept as "planar" may still be off their plane by up to planar_tol x diagonal. Flatten
    # them onto their mean plane so the node geometry, its sample points and its occluder triangles
    # coincide; otherwise rays leaving a slightly twisted quad hit its own triangles.
    corners = corners[sel]
    nrm = n[sel] / np.maximum(np.linalg.norm(n[sel], axis=1, keepdims=True), 1e-300)
    q4 = nv[sel] == 4
    cen = corners[q4].mean(1, keepdims=True)
    corners[q4] -= np.einsum("nkj,nj->nk", corners[q4] - cen, nrm[q4])[..., None] * nrm[q4][:, None]
    result = Patches(
        corners=corners, nv=nv[sel], vert_index=vidx, poly=poly[sel],
        object_id=np.asarray(mesh.object_id)[poly[sel]], reflectance=rho[poly[sel]].T.copy(),
        emission=em[poly[sel]].T.copy(), normal=n[sel] / (2 * area[sel, None]), area=area[sel],
        object_names=names, dropped=dropped)
    if dropped:
        result.warnings.append(f"Dropped {dropped} degenerate polygon(s) (zero area or fewer than 3 vertices).")
    if len(sel) == 0:
        raise InputError("All polygons are degenerate (zero area); nothing to compute radiosity on.")
    return result
