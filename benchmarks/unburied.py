"""Texels a camera can see: none of their sub-samples inside another object's closed mesh, by a
winding-number test independent of our contacts code (furnished_vs_cycles.py's `_unburied` rows,
books_vertex.py)."""

import numpy as np


def _object_triangles(mesh):
    """{object name: (T, 3, 3) world triangles} of the scene's closed, outward-wound meshes (boxes,
    cylinders, spheres); open ones (the room's walls and floor, the light panel) are left out: they
    enclose nothing."""
    out = {}
    for oid, name in enumerate(mesh.object_names):
        polys = np.flatnonzero(mesh.object_id == oid)
        tris = []
        for p in polys:
            s, n = int(mesh.loop_start[p]), int(mesh.loop_total[p])
            v = mesh.loop_verts[s : s + n]
            tris += [(v[0], v[i], v[i + 1]) for i in range(1, n - 1)]
        if not tris:
            continue
        t = mesh.verts[np.array(tris)]
        # closed: every edge (vertex positions, welded to 1e-6) shared by exactly one reversed edge
        q = np.round(t / 1e-6).astype(np.int64)
        e = np.concatenate([np.stack([q[:, i], q[:, (i + 1) % 3]], 1) for i in range(3)])
        fwd = {tuple(x.ravel()) for x in e}
        if len(fwd) != len(e) or any(tuple(np.r_[x[1], x[0]]) not in fwd for x in e):
            continue
        vol = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6
        if vol > 0:
            out[name] = t
    return out


def _winding(p, t):
    """Generalised winding numbers (M,) of points p (M, 3) about the triangles t (T, 3, 3)."""
    a, b, c = (t[None, :, i] - p[:, None] for i in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    num = np.einsum("mtj,mtj->mt", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("mtj,mtj->mt", a, b) * lc + np.einsum("mtj,mtj->mt", b, c) * la
    den += np.einsum("mtj,mtj->mt", c, a) * lb
    return np.arctan2(num, den).sum(1) / (2 * np.pi)


def _inside_solids(p, solids, boxes, skip):
    """(N,) points inside any of `solids` but `skip` (winding number > 1/2), tested only within
    each solid's grown box, in chunks of about 200k point-triangle pairs."""
    inside = np.zeros(len(p), bool)
    for o, t in solids.items():
        if o == skip:
            continue
        cand = np.flatnonzero(np.all((p > boxes[o][0]) & (p < boxes[o][1]), 1) & ~inside)
        step = max(1, 200000 // len(t))
        for s in range(0, len(cand), step):
            c = cand[s : s + step]
            inside[c] = _winding(p[c], t) > 0.5
    return inside


def unburied_texels(rs, eps):
    """{object: (N,) texels none of whose sub-samples lies inside another object}: independent of
    our contacts code, a winding-number test of each sub-sample moved by `eps` along its triangle's
    normal against every other closed mesh (a floor texel under a box's bottom, a book's bottom on
    a board count as buried; texels straddling an outline as well)."""
    solids = _object_triangles(rs.scene_in.mesh)
    boxes = {n: (t.reshape(-1, 3).min(0) - eps, t.reshape(-1, 3).max(0) + eps) for n, t in solids.items()}
    out = {}
    for n in rs.objects:
        at = rs.atlases[n]
        nrm = np.cross(at.s_tri[:, 1] - at.s_tri[:, 0], at.s_tri[:, 2] - at.s_tri[:, 0])
        p = at.s_point + eps * nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
        out[n] = np.bincount(at.s_texel, _inside_solids(p, solids, boxes, n), at.n) == 0
    return out


def _solids_by_area(mesh, tol=1e-6):
    """{object name: (T, 3, 3) world triangles} of the scene's closed outward-wound meshes, closed
    by their area vectors (the sum of a closed surface's A n is 0) rather than by shared edges: a
    Vertex Spacing subdivision splits a bevelled sofa's long faces and not its narrow ones, whose
    T-junctions fail _object_triangles' edge test although the surface is still closed (the
    winding number counts it). Outward: positive volume (a room's flipped box is left out)."""
    out = {}
    for oid, name in enumerate(mesh.object_names):
        t = _triangles(mesh, oid)
        if t is None:
            continue
        an = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) / 2
        area = np.linalg.norm(an, axis=1).sum()
        if area <= 0 or np.linalg.norm(an.sum(0)) > tol * area:
            continue
        vol = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6
        if vol > 0:
            out[name] = t
    return out


def _triangles(mesh, oid):
    polys = np.flatnonzero(mesh.object_id == oid)
    tris = []
    for p in polys:
        s, n = int(mesh.loop_start[p]), int(mesh.loop_total[p])
        v = mesh.loop_verts[s : s + n]
        tris += [(v[0], v[i], v[i + 1]) for i in range(1, n - 1)]
    return mesh.verts[np.array(tris)] if tris else None


def _open_planes(mesh, solids, tol=1e-6):
    """{object name: (T, 3, 3) world triangles, unit normal (3,), offset} of the scene's planar
    meshes that are not solids (a floor plane, a rug, a painting): every triangle in one plane."""
    out = {}
    for oid, name in enumerate(mesh.object_names):
        if name in solids:
            continue
        t = _triangles(mesh, oid)
        if t is None:
            continue
        nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        a = np.linalg.norm(nrm, axis=1)
        if not (a > 0).any():
            continue
        n0 = nrm[np.argmax(a)] / a.max()
        d = t.reshape(-1, 3) @ n0
        if np.ptp(d) > tol * max(np.ptp(t.reshape(-1, 3), axis=0).max(), 1.0):
            continue  # not planar (a room's walls, a glass)
        out[name] = (t[a > 0], n0, float(d.mean()))
    return out


def _inside_outline(p, t, n):
    """(M,) points p (M, 3) whose projection along n falls inside one of the triangles t (T, 3, 3)."""
    q = p - np.outer(p @ n, n)
    inside = np.zeros(len(p), bool)
    for tri in t:
        a, b, c = tri - np.outer(tri @ n, n)
        s1 = np.cross(b - a, q - a) @ n
        s2 = np.cross(c - b, q - b) @ n
        s3 = np.cross(a - c, q - c) @ n
        inside |= ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    return inside


def visible_texels(rs, eps):
    """{object: (N,) texels a camera in the room may see}: unburied_texels' winding test against
    every solid closed by its area vectors (_solids_by_area: T-junctions allowed), and no
    sub-sample behind an open planar mesh the object is sunk through (its vertices on both sides of
    the plane inside the plane's outline: the artist room's Crate, 5 cm through the floor plane).
    An object wholly on one side of a plane (a rug on the floor) is not touched by it; a room's box
    crosses a painting's plane (walls on both sides within its outline), so the wall 1 cm behind
    the painting is left out too."""
    mesh = rs.scene_in.mesh
    solids = _solids_by_area(mesh)
    planes = _open_planes(mesh, solids)
    boxes = {n: (t.reshape(-1, 3).min(0) - eps, t.reshape(-1, 3).max(0) + eps) for n, t in solids.items()}
    name_id = {nm: i for i, nm in enumerate(mesh.object_names)}
    out = {}
    for n in rs.objects:
        at = rs.atlases[n]
        nrm = np.cross(at.s_tri[:, 1] - at.s_tri[:, 0], at.s_tri[:, 2] - at.s_tri[:, 0])
        p = at.s_point + eps * nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
        hid = _inside_solids(p, solids, boxes, n)
        own = _triangles(mesh, name_id[n]) if n in name_id else None
        own = None if own is None else own.reshape(-1, 3)
        for o, (t, pn, d) in planes.items():
            if o == n or own is None:
                continue
            s = own[_inside_outline(own, t, pn)] @ pn - d
            if not ((s > eps).any() and (s < -eps).any()):
                continue  # not sunk through this plane
            c = np.flatnonzero((p @ pn - d < -eps) & ~hid)
            hid[c[_inside_outline(p[c], t, pn)]] = True
        out[n] = np.bincount(at.s_texel, hid, at.n) == 0
    return out
