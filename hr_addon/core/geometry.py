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

    verts: np.ndarray  # (V, 3)
    loop_start: np.ndarray  # (P,) first loop of each polygon
    loop_total: np.ndarray  # (P,) vertex count of each polygon
    loop_verts: np.ndarray  # (L,) vertex index of each loop
    reflectance: np.ndarray  # (P, 3) in [0, 1)
    emission: np.ndarray  # (P, 3) emitted radiance, >= 0
    object_id: np.ndarray  # (P,) index into object_names
    object_names: list = field(default_factory=list)
    # Optional triangulation, (T, 3) loop indices (into loop_verts), each triangle wound like its
    # polygon, e.g. Blender's mesh.loop_triangles. The polygons that must be split use it (those it
    # covers); the others are split here.
    tri_loops: np.ndarray = None
    # Optional (P,) per polygon the first polygon of the user's face it was subdivided from (Vertex
    # Spacing: the finer faces of one face share its orientation check's votes); None: its own.
    face_group: np.ndarray = None
    # Optional (P,) bool per polygon: shaded flat (Blender's sharp_face), its light its own (the
    # vertex output averages its corners only with polygons in its own plane); None: all smooth.
    flat: np.ndarray = None

    @staticmethod
    def from_polygons(verts, polys, reflectance, emission=None, object_id=None, object_names=None):
        """Convenience constructor from a list of vertex-index lists."""
        sizes = np.array([len(p) for p in polys], dtype=np.int64)
        starts = (
            np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
            if len(polys)
            else np.zeros(0, np.int64)
        )
        loops = np.array([i for p in polys for i in p], dtype=np.int64)
        n = len(polys)
        rho = np.broadcast_to(np.asarray(reflectance, float), (n, 3)).copy()
        em = (
            np.zeros((n, 3))
            if emission is None
            else np.broadcast_to(np.asarray(emission, float), (n, 3)).copy()
        )
        oid = np.zeros(n, np.int64) if object_id is None else np.asarray(object_id, np.int64)
        names = object_names or [f"object{i}" for i in range(int(oid.max()) + 1 if n else 1)]
        return MeshInput(np.asarray(verts, float), starts, sizes, loops, rho, em, oid, names)

    def concat(self, other):
        off = len(self.verts)
        tris = [
            t
            for t in (
                self.tri_loops,
                None
                if other.tri_loops is None
                else np.asarray(other.tri_loops, np.int64) + len(self.loop_verts),
            )
            if t is not None
        ]
        return MeshInput(
            np.concatenate([self.verts, other.verts]),
            np.concatenate([self.loop_start, other.loop_start + len(self.loop_verts)]),
            np.concatenate([self.loop_total, other.loop_total]),
            np.concatenate([self.loop_verts, other.loop_verts + off]),
            np.concatenate([self.reflectance, other.reflectance]),
            np.concatenate([self.emission, other.emission]),
            np.concatenate([self.object_id, other.object_id + len(self.object_names)]),
            list(self.object_names) + list(other.object_names),
            np.concatenate([np.asarray(t, np.int64).reshape(-1, 3) for t in tris]) if tris else None,
            None
            if self.face_group is None and other.face_group is None
            else np.concatenate([self.face_groups(), other.face_groups() + len(self.loop_start)]),
            None
            if self.flat is None and other.flat is None
            else np.concatenate([self.flats(), other.flats()]),
        )

    def flats(self):
        """flat, or no polygon flat."""
        return np.zeros(len(self.loop_start), bool) if self.flat is None else np.asarray(self.flat, bool)

    def face_groups(self):
        """face_group, or each polygon its own."""
        return np.arange(len(self.loop_start)) if self.face_group is None else np.asarray(self.face_group)


@dataclass
class Patches:
    corners: np.ndarray  # (K, 4, 3) convex planar, CCW; triangles repeat corner 2
    nv: np.ndarray  # (K,) 3 or 4
    vert_index: np.ndarray  # (K, 4) input vertex index of each corner (-1 padding)
    poly: np.ndarray  # (K,) input polygon each patch came from
    object_id: np.ndarray  # (K,)
    reflectance: np.ndarray  # (3, K)
    emission: np.ndarray  # (3, K)
    normal: np.ndarray  # (K, 3)
    area: np.ndarray  # (K,)
    object_names: list
    dropped: int = 0  # degenerate polygons (or triangles) removed
    warnings: list = field(default_factory=list)
    face: np.ndarray = None  # (K,) MeshInput.face_group of each patch's polygon (None: not given)

    @property
    def triangles(self):
        """Occluder triangle soup (T, 3, 3) for the visibility backends."""
        tri = self.corners[:, [0, 1, 2]]
        quads = self.nv == 4
        return np.concatenate([tri, self.corners[quads][:, [0, 2, 3]]])

    @property
    def triangle_patch(self):
        """(T,) patch of each triangle of `triangles` (the index first_hit() of a backend built
        from them reports)."""
        return np.concatenate([np.arange(len(self.nv)), np.flatnonzero(self.nv == 4)])


def insideness(c, nrm, pts):
    """Min signed distance of pts (M, 3) to the edges of polygons c (M, K, 4, 3), positive inside."""
    e = np.roll(c, -1, axis=2) - c
    length = np.linalg.norm(e, axis=-1)
    d = np.einsum("mkvj,mkj->mkv", np.cross(e, pts[:, None, None] - c), nrm) / np.maximum(length, 1e-300)
    return np.where(length > 0, d, np.inf).min(-1)  # padded triangle edge ignored


def newell(p):
    """Newell normal (unnormalised, length = 2 x area) of polygons p (..., n, 3): the exact normal
    of a planar polygon, a best-fit one of a slightly warped polygon, zero for a degenerate one."""
    q = np.roll(p, -1, axis=-2)
    return np.stack(
        [
            np.sum((p[..., 1] - q[..., 1]) * (p[..., 2] + q[..., 2]), -1),
            np.sum((p[..., 2] - q[..., 2]) * (p[..., 0] + q[..., 0]), -1),
            np.sum((p[..., 0] - q[..., 0]) * (p[..., 1] + q[..., 1]), -1),
        ],
        -1,
    )


def loop_tables(loop_start, loop_total):
    """Blender-style polygons: (loop -> polygon, loop -> next loop of the same polygon)."""
    loop_start, loop_total = np.asarray(loop_start, np.int64), np.asarray(loop_total, np.int64)
    lp = np.repeat(np.arange(len(loop_start)), loop_total)
    nxt = np.arange(len(lp)) + 1
    m = loop_total > 0
    nxt[(loop_start + loop_total - 1)[m]] = loop_start[m]
    return lp, nxt


def polygon_newell(verts, loop_start, loop_total, loop_verts):
    """newell() of every polygon of a Blender-style mesh, polygons of any size: (P, 3)."""
    lp, nxt = loop_tables(loop_start, loop_total)
    lv = np.asarray(loop_verts, np.int64)
    p, q = verts[lv], verts[lv[nxt]]
    t = np.stack(
        [
            (p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2]),
            (p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0]),
            (p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1]),
        ],
        1,
    )
    return np.stack([np.bincount(lp, t[:, k], len(loop_start)) for k in range(3)], 1)


def components(n, i, j):
    """Connected-component label of n items joined by the pairs (i[k], j[k]): each item's label is
    the smallest item of its component. Vectorised union-find: every tree's root hooks onto the
    smallest root it is joined to, then pointers are jumped until each item points at its root; a
    handful of passes even for long chains in scrambled order (hooking items instead of roots would
    need as many passes as the longest chain)."""
    lab = np.arange(n)
    i, j = np.asarray(i, np.int64), np.asarray(j, np.int64)
    while len(i):
        li, lj = lab[i], lab[j]
        if np.array_equal(li, lj):
            break
        m = np.minimum(li, lj)
        np.minimum.at(lab, li, m)  # labels only decrease: no cycles
        np.minimum.at(lab, lj, m)
        while True:
            jumped = lab[lab]
            if np.array_equal(jumped, lab):
                break
            lab = jumped
    return lab


def _per_object(mesh, polys):
    """'3 in 'Wall', 1 in 'Floor'' for input polygons `polys` (the objects with most first)."""
    names = list(mesh.object_names)
    oid = np.asarray(mesh.object_id)[np.asarray(polys, np.int64)]
    ids, cnt = np.unique(oid, return_counts=True)
    order = np.lexsort((ids, -cnt))
    parts = [f"{cnt[i]} in '{names[ids[i]] if 0 <= ids[i] < len(names) else ids[i]}'" for i in order[:5]]
    return ", ".join(parts) + (f" and {len(ids) - 5} more object(s)" if len(ids) > 5 else "")


def _off_plane(verts, starts, sizes, lv, polys):
    """Largest distance of each polygon's corners from its mean (Newell) plane, relative to its
    size (the longest distance between two of its corners)."""
    out = np.zeros(len(polys))
    for k in np.unique(sizes[polys]):
        m = np.flatnonzero(sizes[polys] == k)
        p = verts[lv[starts[polys[m]][:, None] + np.arange(k)]]  # (n, k, 3)
        nrm = newell(p)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        d = np.abs(np.einsum("nkj,nj->nk", p - p.mean(1, keepdims=True), nrm)).max(1)
        size = (
            np.sqrt(((p[:, :, None] - p[:, None]) ** 2).sum(-1).max((1, 2)))
            if k <= 64
            else np.linalg.norm(p.max(1) - p.min(1), axis=1)
        )
        out[m] = d / np.maximum(size, 1e-300)
    return out


def _ear_clip(pts, idx):
    """Triangulate one simple polygon (any concavity) given its 3D points; returns index triples."""
    n = newell(pts)
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


def prepare_patches(mesh: MeshInput, planar_tol=1e-3, area_tol=1e-8, warn_planar=1e-2) -> Patches:
    """Validate input and convert to convex planar patches.

    planar_tol: a quad whose fourth corner is off the plane of the first three by more than
    planar_tol x its diagonal is split in two triangles. area_tol: patches (triangles and kept
    quads) whose area is below area_tol x (their own longest edge)^2 are degenerate: dropped and
    counted. The test is per patch, never relative to the scene's extent, so one object far away
    cannot make the others "degenerate". warn_planar: polygons (quads, n-gons) split here, not by
    the given triangulation, whose corners are off their mean plane by more than warn_planar x their
    size get a warning naming the object.
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
        raise InputError(
            f"Reflectance {tuple(np.round(rho[i], 4))} on {who(i)} is outside [0, 1): "
            "a diffuse surface cannot reflect all the light it receives."
        )
    bad = (em < 0).any(1)
    if bad.any():
        raise InputError(f"Negative emission on {who(int(np.argmax(bad)))}.")
    loop_poly = np.repeat(np.arange(P), mesh.loop_total)
    bad_loops = ~np.isfinite(verts[mesh.loop_verts]).all(1)
    if bad_loops.any():
        raise InputError(
            f"NaN or infinite vertex coordinates on {who(int(loop_poly[np.argmax(bad_loops)]))}."
        )

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
    n = newell(qp)
    nn = np.linalg.norm(n, axis=1, keepdims=True)
    nu = n / np.where(nn > 0, nn, 1)
    d_off = np.abs(np.einsum("ij,ij->i", qp[:, 3] - qp[:, 0], nu))
    d_off = np.maximum(d_off, np.abs(np.einsum("ij,ij->i", qp[:, 2] - qp[:, 0], nu)))
    diag_len = np.maximum(
        np.linalg.norm(qp[:, 2] - qp[:, 0], axis=1), np.linalg.norm(qp[:, 3] - qp[:, 1], axis=1)
    )
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
            raise InputError(
                "Triangulation (tri_loops) mixes the loops of several polygons at "
                f"{who(int(tpoly[np.argmax(bad), 0]))}."
            )
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
    reflex13 = (sturn[:, 0] <= 0) | (sturn[:, 2] <= 0)  # turn k is at corner k+1
    use02 = np.where(
        planar[own],
        ~reflex13,
        np.linalg.norm(qp[own][:, 2] - qp[own][:, 0], axis=1)
        <= np.linalg.norm(qp[own][:, 3] - qp[own][:, 1], axis=1),
    )
    tri_list.append(np.column_stack([sq, np.where(use02[:, None], sqv[:, [0, 1, 2]], sqv[:, [0, 1, 3]])]))
    tri_list.append(np.column_stack([sq, np.where(use02[:, None], sqv[:, [0, 2, 3]], sqv[:, [1, 2, 3]])]))

    for i in np.flatnonzero((sizes > 4) & ~given):
        idx = lv[starts[i] : starts[i] + sizes[i]]
        tri_list.append(
            np.array([(i, *tr) for tr in _ear_clip(verts[idx], idx)], dtype=np.int64).reshape(-1, 4)
        )

    tris = np.concatenate(tri_list).astype(np.int64)
    quads = np.concatenate(quad_list).astype(np.int64)
    poly = np.concatenate([tris[:, 0], quads[:, 0]])
    vidx = np.concatenate([np.column_stack([tris[:, 1:], tris[:, 3]]), quads[:, 1:]])
    nv = np.concatenate([np.full(len(tris), 3), np.full(len(quads), 4)])
    corners = verts[vidx]
    n = newell(corners)  # a padded triangle's repeated corner adds a zero-length edge
    area = 0.5 * np.linalg.norm(n, axis=1)
    edge2 = (np.diff(corners, axis=1, append=corners[:, :1]) ** 2).sum(-1).max(1)
    ok = (area > 0) & (area > area_tol * edge2)
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
        corners=corners,
        nv=nv[sel],
        vert_index=vidx,
        poly=poly[sel],
        object_id=np.asarray(mesh.object_id)[poly[sel]],
        reflectance=rho[poly[sel]].T.copy(),
        emission=em[poly[sel]].T.copy(),
        normal=n[sel] / (2 * area[sel, None]),
        area=area[sel],
        object_names=names,
        dropped=dropped,
        face=None if mesh.face_group is None else np.asarray(mesh.face_group, np.int64)[poly[sel]],
    )
    if dropped:
        lost = np.setdiff1d(np.arange(P), poly[ok])
        result.warnings.append(
            f"Dropped {dropped} degenerate polygon(s) (zero area or fewer than 3 vertices): "
            f"{_per_object(mesh, lost)}."
        )
    split = np.union1d(q[~keep], np.flatnonzero(sizes > 4))
    # those split by the given triangulation are the triangles the render shows (a Subdivision
    # Surface's output, warned about as "flatten them" a user cannot follow): only ours may differ
    split = split[~given[split]]
    if len(split):
        off = _off_plane(verts, starts, sizes, lv, split)
        bad = off > warn_planar
        if bad.any():
            result.warnings.append(
                f"{int(bad.sum())} non-planar polygon(s) (corners up to {100 * off.max():.0f}% of their "
                f"size off their plane) were split into triangles: {_per_object(mesh, split[bad])}. The "
                "triangles may not be the surface you meant; flatten them (Mesh > Clean Up > Make Planar "
                "Faces) or triangulate them yourself."
            )
    if len(sel) == 0:
        raise InputError("All polygons are degenerate (zero area); nothing to compute radiosity on.")
    twins = coincident_patches(result)
    if len(twins):
        result.warnings.append(
            f"{len(twins)} polygon(s) lie exactly on another polygon facing the same way: "
            f"{_per_object(mesh, result.poly[twins])}. Each copy reflects and emits as if it were "
            "alone, so the room gets extra light; delete the duplicates (Mesh > Clean Up > Merge by "
            "Distance, or the duplicated object)."
        )
    return result


def coincident_patches(p: Patches, rel=1e-6):
    """Patches with the same corners (to rel x the scene's size) and facing the same way as an
    earlier patch: the second copy of a duplicated face (back-to-back faces are not duplicates)."""
    pts = p.corners.reshape(-1, 3)
    q = np.round(pts / max(float(np.ptp(pts, 0).max()) * rel, 1e-300)).astype(np.int64).reshape(-1, 4, 3)
    q = np.sort(q.view([("", q.dtype)] * 3).reshape(len(q), 4), axis=1).view(np.int64).reshape(len(q), 12)
    side = np.sign(np.round(p.normal, 3)).astype(np.int64)
    key = np.column_stack([q, side, p.nv])
    _, first = np.unique(key, axis=0, return_index=True)
    dup = np.ones(len(key), bool)
    dup[first] = False
    return np.flatnonzero(dup)


@dataclass
class SceneExtent:
    """Objects that lie far away from the rest of the scene (see isolated_objects)."""

    total_area: float  # all polygons
    main_area: float  # the main group of objects near each other (most polygons)
    main_size: float  # bounding-box diagonal of that group
    distant: list = field(default_factory=list)  # [(object name, distance to the group, own size)]

    @property
    def area_ratio(self):
        """main_area / total_area: scale an area threshold relative to the total area by this to
        make it relative to the main group only."""
        return self.main_area / self.total_area if self.total_area > 0 else 1.0


def isolated_objects(mesh: MeshInput, gap_ratio=10.0, max_objects=4000) -> SceneExtent:
    """Group the objects that lie near each other (single linkage: two objects are near when the gap
    between their bounding boxes is at most gap_ratio x the larger one's diagonal) and report the
    objects outside the main group: the one with the most polygons (where the scene was modelled;
    ties: the larger area).

    Such an object (a cube 50 km from the room) exchanges practically no light with the rest, but
    thresholds relative to the whole scene would change because of it: the total area (element
    sizes, Aeps) grows with its area. Callers use main_area instead of the total area for those
    thresholds, so the rest of the scene gets the same light with or without it."""
    verts = np.asarray(mesh.verts, float)
    lv = np.asarray(mesh.loop_verts)
    loop_poly, _ = loop_tables(mesh.loop_start, mesh.loop_total)
    area = 0.5 * np.linalg.norm(polygon_newell(verts, mesh.loop_start, mesh.loop_total, lv), axis=1)
    area[~np.isfinite(area)] = 0.0
    oid = np.asarray(mesh.object_id)
    names = list(mesh.object_names)
    ids = np.unique(oid)
    total = float(area.sum())
    if len(ids) < 2 or len(ids) > max_objects:
        pts = verts[lv]
        return SceneExtent(total, total, float(np.linalg.norm(pts.max(0) - pts.min(0))) if len(pts) else 0.0)
    obj_area = np.bincount(np.searchsorted(ids, oid), area, len(ids))
    lo = np.full((len(ids), 3), np.inf)
    hi = np.full((len(ids), 3), -np.inf)
    lobj = np.searchsorted(ids, oid[loop_poly])
    np.minimum.at(lo, lobj, verts[lv])
    np.maximum.at(hi, lobj, verts[lv])
    size = np.linalg.norm(hi - lo, axis=1)
    n = len(ids)

    def near(i, j):  # the pairs (i, j) whose boxes' gap is at most gap_ratio x the larger's size
        keep = []
        for s in range(0, len(i), 1 << 20):
            a, b = i[s : s + (1 << 20)], j[s : s + (1 << 20)]
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo[a] - hi[b], lo[b] - hi[a])), axis=1)
            keep.append(np.flatnonzero(gap <= gap_ratio * np.maximum(size[a], size[b])) + s)
        keep = np.concatenate(keep) if keep else np.zeros(0, np.int64)
        return i[keep], j[keep]

    # the same components as from all n^2 / 2 pairs (7.5 M for the furnished 100k room's 3,882
    # objects), from fewer: every object against the 64 largest (a room's walls reach everything),
    # then only the objects left outside the largest component against all (pairs within that
    # component cannot change the partition)
    big = np.argsort(-size, kind="stable")[:64]
    i, j = near(np.repeat(big, n), np.tile(np.arange(n), len(big)))
    root = components(n, i, j)
    u = np.flatnonzero(root != np.bincount(root).argmax())
    k, m = np.repeat(u, n), np.tile(np.arange(n), len(u))
    outside = np.zeros(n, bool)
    outside[u] = True
    k, m = k[~outside[m] | (m > k)], m[~outside[m] | (m > k)]  # a pair within u once
    k, m = near(k, m)
    root = components(n, np.r_[i, k], np.r_[j, m])
    groups, inv = np.unique(root, return_inverse=True)
    garea = np.bincount(inv, obj_area, len(groups))
    gpolys = np.bincount(inv, np.bincount(np.searchsorted(ids, oid), minlength=len(ids)), len(groups))
    main = int(np.lexsort((-garea, -gpolys))[0])
    m = inv == main
    mlo, mhi = lo[m].min(0), hi[m].max(0)
    far = []
    for k in np.flatnonzero(~m):
        d = float(np.linalg.norm(np.maximum(0.0, np.maximum(mlo - hi[k], lo[k] - mhi))))
        far.append((names[ids[k]] if 0 <= ids[k] < len(names) else str(ids[k]), d, float(size[k])))
    far.sort(key=lambda t: -t[1])
    return SceneExtent(total, float(garea[main]), float(np.linalg.norm(mhi - mlo)), far)
