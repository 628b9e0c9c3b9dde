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
        bur = np.zeros(len(p), bool)
        for o, t in solids.items():
            if o == n:
                continue
            cand = np.flatnonzero(np.all((p > boxes[o][0]) & (p < boxes[o][1]), 1) & ~bur)
            for s in range(0, len(cand), max(1, 200000 // len(t))):
                c = cand[s : s + max(1, 200000 // len(t))]
                bur[c] = _winding(p[c], t) > 0.5
        out[n] = np.bincount(at.s_texel, bur, at.n) == 0
    return out
