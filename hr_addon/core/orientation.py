"""Surfaces facing the wrong way: found by rays, turned around before the hierarchy is built.

Surfaces are one-sided here (they emit and reflect on their front only), but Cycles renders a mesh
from both sides: a wall whose winding is reversed looks right in a render and bakes to black, taking
light from the rest of the room; a ceiling panel facing the ceiling sends its light into the strip of
ceiling right above it; a painting hung facing its wall bakes black. Two cases are turned around
(their corners reversed), as Cycles in effect shows them:

- a polygon whose front exchanges light with nothing (every ray leaving its front escapes the scene
  or meets the back of a surface) while at least MIN_BACK of the rays leaving its back meet the
  fronts of other surfaces (a reversed wall of a room: its front looks out of the room), unless it
  lies on a surface facing it (a sofa's bottom on the floor: covered, its front rays start under
  the floor);
- a polygon whose front faces a surface right in front of it (every front ray meets the front of a
  surface, on average within NEAR x its size) while its back sees the fronts of the scene, FAR
  times farther away: a ceiling panel turned towards the ceiling, a painting hung facing its wall
  (issue 20, the artist-made room), a rug facing the floor. Unless its back is the inside of a
  closed object: a box's side 5 cm from a wall, the leaning back of a sofa sunk into the box, sees
  the wall in front and the sunk back's fronts behind, but also its own object's backs; so no
  back ray may meet a back of the polygon's own object, and at most INSIDE of them a back at all
  (an open surface seen from behind, a rug facing the floor, is allowed).

Neither case holds for a polygon buried inside another object: a bowl's bottom sunk through its
plate into a table top meets the top's backs in front and the plate's underside behind, the
pattern of a reversed wall, but no render shows it. Buried: every sample point, just off either
side, has a generalised winding number above BURIED for some object its rays met (1 inside a
closed mesh with outward fronts, 1/2 on its surface, below 1/2 behind an open one such as the next
room's wall); it is neither turned around nor warned about.

Rays: SIDE_RAYS per side of each patch, stratified over the patch and cosine-weighted over the
hemisphere, traced to their first hit by the build's ray backend (first_hit_within: near hits
first, so a stray object far away does not blur them). Decisions are per input polygon (the counts
of all its patches), so a polygon is never split; per user's face when Vertex Spacing subdivided it
(MeshInput.face_group): a finer face under a rug alone sees only the rug's back, the whole floor
face sees the room.
"""

import numpy as np

from .planes import frames
from .visibility import first_hit_within

SIDE_RAYS = 16  # rays per side of each patch (a 4 x 4 stratification)
MIN_BACK = 0.25  # share of a polygon's back rays that must meet the fronts of other surfaces
NEAR = 0.25  # front rays hitting this close (x its size) face "a surface right in front of it"
FAR = 4.0  # ... while its back rays travel this many times farther
INSIDE = 0.25  # back rays meeting backs beyond this share: the back is the inside of a closed object
GAP = 1e-3  # faces this close (x sqrt(total area), as contacts' gap) facing each other touch
BURIED = 0.75  # winding number of another object above which a point lies inside it (1 inside, 1/2 on it)
CHUNK = 1 << 21  # points x triangles per winding-number batch


def _touching(pt, cand, pts, n, gap):
    """(len(cand), S) whether each sample point `pts` of the patches `cand` lies on another patch
    facing it (opposite normal, within `gap` of its plane): the face lies on another surface."""
    out = np.zeros(pts.shape[:2], bool)
    lo, hi = pt.corners.min(1) - gap, pt.corners.max(1) + gap
    for i, k in enumerate(cand):
        p = pts[i]
        near = np.flatnonzero(
            (n @ n[k] < -0.999)
            & (np.abs(np.einsum("ij,j->i", pt.corners[:, 0] - p.mean(0), n[k])) <= gap)
            & (lo <= p.max(0)).all(1)
            & (hi >= p.min(0)).all(1)
        )
        for q in near:
            c = pt.corners[q, : pt.nv[q]]
            e = np.roll(c, -1, 0) - c  # point in the convex patch: left of every edge (seen from q)
            side = np.einsum("ek,sek->se", np.cross(np.broadcast_to(n[q], e.shape), e), p[:, None] - c[None])
            out[i] |= (side >= -gap * np.linalg.norm(e, axis=1)).all(1)
    return out


def _winding(tri, p):
    """(M,) generalised winding number of the triangles tri (T, 3, 3) about the points p (M, 3): 1
    inside a closed mesh with outward fronts, 0 outside, 1/2 on its surface, below 1/2 beside an
    open one (Van Oosterom and Strackee's solid angle of each triangle, summed)."""
    w = np.zeros(len(p))
    step = max(1, CHUNK // max(len(tri), 1))
    for s in range(0, len(p), step):
        r = tri[None] - p[s : s + step, None, None]  # (m, T, 3, 3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("mtk,mtk->mt", np.cross(a, b), c)
        dot = (
            la * lb * lc
            + np.einsum("mtk,mtk->mt", a, b) * lc
            + np.einsum("mtk,mtk->mt", a, c) * lb
            + np.einsum("mtk,mtk->mt", b, c) * la
        )
        w[s : s + step] = np.arctan2(det, dot).sum(1) / (2 * np.pi)
    return w


def _buried(pt, cand, pts, n, out):
    """(len(cand),) whether every sample point of the patches `cand`, moved off it to either side,
    lies inside another object (its winding number above BURIED), one of those its rays met: a
    face sunk into a table top (or part in the top, part in a plate on it) is never seen, whichever
    way it faces. A face on another's surface has a side outside it (the offset: the rays' eps)."""
    obj = pt.object_id
    tri, tri_obj = pt.triangles, obj[pt.triangle_patch]
    seen = np.zeros((len(cand), max(len(pt.object_names), int(obj.max()) + 1)), bool)
    for hit, _, _ in out.values():
        h = hit[cand]
        seen[np.nonzero(h >= 0)[0], obj[h[h >= 0]]] = True
    seen[np.arange(len(cand)), obj[cand]] = False  # its own object: the face lies on it
    side = np.array([1.0, -1.0])[:, None, None] * n[cand, None, None]  # (C, 2, 1, 3)
    eps = 1e-6 * np.sqrt(pt.area.sum())  # as _trace's
    p = (pts[:, None] + eps * side).reshape(len(cand), -1, 3)
    w = np.zeros(p.shape[:2])  # per point, the largest winding number of those objects
    tri_lo, tri_hi = tri.min(1), tri.max(1)
    p_lo, p_hi = p.min(1), p.max(1)
    for o in np.flatnonzero(seen.any(0)):
        m = tri_obj == o  # a point inside it lies in its bounds: the face's bounds overlap them
        rows = np.flatnonzero(
            seen[:, o] & (p_hi >= tri_lo[m].min(0)).all(1) & (p_lo <= tri_hi[m].max(0)).all(1)
        )
        if len(rows):
            wo = _winding(tri[m], p[rows].reshape(-1, 3)).reshape(len(rows), -1)
            w[rows] = np.maximum(w[rows], wo)
    return (w > BURIED).all(1)


def _stratified(n, rng):
    """(n, 2) stratified samples in [0, 1)^2 (n a square number), in a random order."""
    k = int(round(np.sqrt(n)))
    i, j = np.divmod(np.arange(k * k), k)
    s = np.stack([(i + rng.random(k * k)) / k, (j + rng.random(k * k)) / k], 1)
    return s[rng.permutation(k * k)]


def _trace(pt, backend, seed):
    """SIDE_RAYS rays per side of each patch: (pts, n, {side: (hit, facing, dist)}), the (K, S)
    sample points, the unit normals and per side the patch each ray hit (-1: none), whether it met
    its front, and how far it went (0 when it escaped)."""
    K = len(pt.nv)
    rng = np.random.default_rng(seed)
    S = SIDE_RAYS
    lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
    L = 2.0 * float(np.linalg.norm(hi - lo)) or 1.0  # longer than any path inside the scene
    size = float(np.sqrt(pt.area.sum()))
    eps = 1e-6 * size  # as the refiner's
    owner = pt.triangle_patch
    # points: bilinear over the (padded) corners, stratified; a triangle's repeated corner folds the
    # square onto it
    uv = _stratified(S, rng)
    u, v = uv[:, 0][None, :, None], uv[:, 1][None, :, None]
    c = pt.corners[:, None]
    pts = (
        (1 - u) * (1 - v) * c[:, :, 0]
        + u * (1 - v) * c[:, :, 1]
        + u * v * c[:, :, 2]
        + (1 - u) * v * c[:, :, 3]
    )
    ab = _stratified(S, rng)
    r, phi = np.sqrt(ab[:, 0]), 2 * np.pi * ab[:, 1]
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1 - ab[:, 0], 0))], 1)
    n = pt.normal / np.maximum(np.linalg.norm(pt.normal, axis=1, keepdims=True), 1e-300)
    t, b = frames(n)
    out = {}
    for side in (1.0, -1.0):
        ns = side * n
        dirs = (
            local[None, :, :1] * t[:, None]
            + local[None, :, 1:2] * (side * b)[:, None]
            + local[None, :, 2:] * ns[:, None]
        )
        o = (pts + eps * ns[:, None]).reshape(-1, 3)
        prim, dist = first_hit_within(backend, o, dirs.reshape(-1, 3), min(4.0 * size, L), L)
        hit = np.where(prim >= 0, owner[np.maximum(prim, 0)], -1).reshape(K, S)
        hit[hit == np.arange(K)[:, None]] = -1  # a grazing ray meeting its own patch
        dist = np.where(prim >= 0, dist, 0.0).reshape(K, S)
        h = hit >= 0
        facing = np.zeros((K, S), bool)
        facing[h] = np.einsum("ij,ij->i", dirs[h], n[hit[h]]) < 0  # met the front of what it hit
        out[side] = (hit, facing, dist)
    return pts, n, out


def _voters(pt):
    """(K,) the polygon whose decision each patch votes for: its user's face, else its own."""
    return pt.poly if pt.face is None else pt.face


def find_reversed(patches, backend, seed=0):
    """(flip, reasons): boolean (K,) per patch, True for the patches of polygons to turn around, and
    {input polygon: "back" | "facing" | "emitter"} of those polygons ("emitter": facing, and it emits).
    Votes are pooled per input polygon, or per user's face (patches.face: Vertex Spacing's finer
    faces, keyed by the face's first polygon) when given."""
    pt = patches
    K = len(pt.nv)
    if K == 0:
        return np.zeros(0, bool), {}
    S = SIDE_RAYS
    pts, n, out = _trace(pt, backend, seed)
    poly = _voters(pt)
    npoly = int(poly.max()) + 1
    rays = np.bincount(poly, minlength=npoly) * S

    def per_poly(x):
        return np.bincount(poly, x.sum(1), minlength=npoly)

    (fh, ff, fd), (bhit, bf, bd) = out[1.0], out[-1.0]
    fh, bh = fh >= 0, bhit >= 0
    front_front, back_front = per_poly(ff), per_poly(bf)
    front_hits, back_hits = per_poly(fh), per_poly(bh)
    has = rays > 0
    reasons = {}
    back = has & (front_front == 0) & (back_front >= MIN_BACK * rays)
    if back.any():  # a face lying on another one (a sofa's bottom on the floor) is covered, not reversed
        gap = GAP * np.sqrt(pt.area.sum())
        cand = np.flatnonzero(back[poly])
        touching = _touching(pt, cand, pts[cand], n, gap)
        lying = np.bincount(poly[cand], touching.sum(1), minlength=npoly)
        back &= lying < MIN_BACK * rays
    emits = np.bincount(poly, pt.emission.max(0) * pt.area, minlength=npoly) > 0
    size = np.sqrt(np.bincount(poly, pt.area, minlength=npoly))
    front_mean = per_poly(np.where(fh, fd, 0.0)) / np.maximum(front_hits, 1)
    back_mean = per_poly(np.where(bh, bd, 0.0)) / np.maximum(back_hits, 1)
    facing = (
        has
        & ~back
        & (front_front == rays)  # every front ray meets the front of a surface facing it ...
        & (front_mean < NEAR * size)  # ... right in front of it
        & (back_front >= MIN_BACK * rays)  # the back sees the fronts of the scene ...
        & (back_mean > FAR * front_mean)  # ... far away
        # ... and is not the inside of a closed object (a sofa's side 5 cm from the wall, its leaning
        # back sunk into it: its back rays meet the back's fronts, and its own backs)
        & (back_hits - back_front <= INSIDE * rays)
        & (per_poly(bh & ~bf & (pt.object_id[np.maximum(bhit, 0)] == pt.object_id[:, None])) == 0)
    )
    # a face inside another solid (a bowl's bottom sunk through its plate into a table top: its front
    # meets the top's backs, its back the plate's underside) is never seen: left alone, not warned
    turn = back | facing
    if turn.any():
        cand = np.flatnonzero(turn[poly])
        seen = np.bincount(poly[cand], ~_buried(pt, cand, pts[cand], n, out), minlength=npoly)  # points out
        turn &= seen > 0
    for p in np.flatnonzero(turn & back):
        reasons[int(p)] = "back"
    for p in np.flatnonzero(turn & facing):
        reasons[int(p)] = "emitter" if emits[p] else "facing"
    flip = np.isin(poly, np.array(sorted(reasons), np.int64))
    return flip, reasons


def turn_around(patches, flip):
    """Reverse the corner order (and vert_index) of the patches `flip` in place: their front becomes
    their back. Triangles keep the padded convention (corner 3 repeats corner 2)."""
    pt = patches
    if not flip.any():
        return
    quad = flip & (pt.nv == 4)
    tri = flip & (pt.nv == 3)
    pt.corners[quad] = pt.corners[quad][:, [0, 3, 2, 1]]
    pt.vert_index[quad] = pt.vert_index[quad][:, [0, 3, 2, 1]]
    pt.corners[tri] = pt.corners[tri][:, [0, 2, 1, 1]]
    vi = pt.vert_index[tri][:, [0, 2, 1, 3]]
    pt.vert_index[tri] = vi
    pt.normal[flip] = -pt.normal[flip]


def _count_by_object(patches, polys):
    names = list(patches.object_names)
    first = {}
    for k, p in zip(patches.object_id, _voters(patches)):
        first.setdefault(int(p), int(k))
    per = {}
    for p in polys:
        oid = first[int(p)]
        per[oid] = per.get(oid, 0) + 1
    parts = [
        f"{cnt} in '{names[oid] if 0 <= oid < len(names) else oid}'"
        for oid, cnt in sorted(per.items(), key=lambda x: -x[1])[:5]
    ]
    more = f" and {len(per) - 5} more object(s)" if len(per) > 5 else ""
    return ", ".join(parts) + more


def orient(patches, backend, seed=0):
    """Find and turn around the polygons facing the wrong way (find_reversed) in `patches`; returns
    the messages naming them (also appended to patches.warnings)."""
    flip, reasons = find_reversed(patches, backend, seed)
    msgs = []
    if reasons:
        turn_around(patches, flip)
        back = [p for p, r in reasons.items() if r == "back"]
        emit = [p for p, r in reasons.items() if r == "emitter"]
        facing = [p for p, r in reasons.items() if r == "facing"]
        if back:
            msgs.append(
                f"{len(back)} polygon(s) faced away from everything they could light, with their back "
                f"towards the scene: {_count_by_object(patches, back)}. They were turned around (Cycles "
                "renders both sides of a face); flip their normals (Mesh > Normals > Flip) to make "
                "the mesh say what the bake uses."
            )
        if emit:
            msgs.append(
                f"{len(emit)} emitting polygon(s) faced a surface right in front of them, with their "
                f"back towards the scene: {_count_by_object(patches, emit)}. They were turned around "
                "to shine into the scene (as Cycles shows them); flip their normals (Mesh > Normals > "
                "Flip) if that is what you meant."
            )
        if facing:
            msgs.append(
                f"{len(facing)} polygon(s) faced a surface right in front of them, with their back "
                "towards the scene (as a painting facing the wall it hangs on): "
                f"{_count_by_object(patches, facing)}. "
                "They were turned around (Cycles renders both sides of a face); flip their normals "
                "(Mesh > Normals > Flip) to make the mesh say what the bake uses."
            )
    patches.warnings.extend(msgs)
    return msgs
