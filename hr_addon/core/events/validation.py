"""Light shape validation (finite, planar, simple outline), its plane and the surfaces it lies on."""

from collections import OrderedDict

import numpy as np

from .. import clip
from ..geometry import InputError, newell
from .planar import _in_rings, _winding, slab_decomposition


def _size(rings):
    """Bounding-box diagonal of a shape's rings (its own size)."""
    pts = np.concatenate(rings)
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


def _plane_tolerance(rings, plane_tol):
    """Distance tolerance of "in the shape's plane" / "on a surface": plane_tol x the shape's own
    size, never the scene's (a far-away object must not change it), plus a floor for float32
    coordinates (Blender's) far from the origin."""
    pts = np.concatenate(rings)
    return plane_tol * _size(rings) + 1e-6 * float(np.abs(pts).max())


NEAR_SURFACE = 0.05  # a shape this close to a parallel surface (x its size) was meant to lie on it


def _length(d):
    """A distance in scene units (metres) as a user reads it: '1.0 mm', '2.5 cm', '1.2 m'."""
    d = abs(float(d))
    if d < 0.01:
        return f"{d * 1000:.1f} mm"
    if d < 1.0:
        return f"{d * 100:.1f} cm"
    return f"{d:.3g} m"


def outline_problem(rings2d, chunk=200_000):
    """'' if the rings (outer first, then holes; 2D) bound one well-defined region, else what is wrong.

    Well defined: no ring crosses itself or another ring, holes lie inside the outline and apart.
    Only then do the even-odd rule (NAIVE), signed clipped areas (FE, AR, AUTO) and the nonzero
    rule agree, so every method emits the same power. A self-intersecting outline (a pentagram,
    a bowtie) is refused rather than given a meaning that would differ from Blender's own."""
    rings = [np.asarray(r, float) for r in rings2d]
    size = max(float(np.linalg.norm(np.concatenate(rings).max(0) - np.concatenate(rings).min(0))), 1e-300)
    a = np.concatenate([r for r in rings])
    b = np.concatenate([np.roll(r, -1, 0) for r in rings])
    ring = np.concatenate([np.full(len(r), k) for k, r in enumerate(rings)])
    idx = np.concatenate([np.arange(len(r)) for r in rings])
    m = np.array([len(r) for r in rings])[ring]
    tol = 1e-9 * size * size
    E = len(a)
    touch = False
    # candidate pairs: edges whose bounding boxes overlap (sweep along x, then y), in chunks
    pad = 1e-9 * size
    lo, hi = np.minimum(a, b) - pad, np.maximum(a, b) + pad
    order = np.argsort(lo[:, 0], kind="stable")
    end = np.searchsorted(lo[order, 0], hi[order, 0], side="right")
    first = np.arange(E) + 1
    counts = np.maximum(end - first, 0)
    cum = np.cumsum(counts)
    r0 = 0
    while r0 < E:
        r1 = max(int(np.searchsorted(cum, (cum[r0 - 1] if r0 else 0) + chunk, side="right")), r0 + 1)
        r1 = min(r1, E)
        rws = np.arange(r0, r1)
        n = counts[rws]
        base = np.repeat(first[rws], n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        p1, p2 = order[np.repeat(rws, n)], order[base + k]
        r0 = r1
        ii, jj = np.minimum(p1, p2), np.maximum(p1, p2)
        ov = (lo[ii, 1] <= hi[jj, 1]) & (lo[jj, 1] <= hi[ii, 1])
        ii, jj = ii[ov], jj[ov]
        same = ring[ii] == ring[jj]
        adj = same & ((jj - ii == 1) | ((idx[ii] == 0) & (idx[jj] == m[jj] - 1)))
        ii, jj = ii[~adj], jj[~adj]

        def orient(p, q, r):
            return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

        o1, o2 = orient(a[ii], b[ii], a[jj]), orient(a[ii], b[ii], b[jj])
        o3, o4 = orient(a[jj], b[jj], a[ii]), orient(a[jj], b[jj], b[ii])
        cross = (
            (o1 * o2 < 0) & (o3 * o4 < 0) & (np.minimum.reduce([abs(o1), abs(o2), abs(o3), abs(o4)]) > tol)
        )
        if cross.any():
            k = np.flatnonzero(cross)[0]
            r1, r2 = sorted((int(ring[ii[k]]), int(ring[jj[k]])))
            if r1 == r2:
                return "its outline crosses itself" if r1 == 0 else f"hole {r1} crosses itself"
            return f"hole {r2} crosses its outline" if r1 == 0 else f"holes {r1} and {r2} cross"
        # a corner on another edge (or on another corner): weakly simple, checked below
        for o, p in ((o1, a[jj]), (o2, b[jj])):
            near = np.abs(o) <= tol * 1e3
            if near.any():
                t = np.einsum("ij,ij->i", (p - a[ii])[near], (b[ii] - a[ii])[near])
                L2 = np.einsum("ij,ij->i", (b[ii] - a[ii])[near], (b[ii] - a[ii])[near])
                touch |= bool(np.any((t >= 0) & (t <= L2) & (L2 > 0)))
    for k in range(1, len(rings)):
        if _in_rings(rings[k], rings[:1]).mean() < 0.5:
            return f"hole {k} lies outside its outline"
        for j in range(1, k):
            if _in_rings(rings[k], [rings[j]]).mean() >= 0.5 or _in_rings(rings[j], [rings[k]]).mean() >= 0.5:
                return f"holes {j} and {k} overlap"
    if touch:
        if E > 2000:
            return "its outline touches itself"
        edges = np.stack([a, b], 1)
        traps = slab_decomposition(edges, 1e-9 * size)
        if traps:
            mids = np.array([mid for _, mid in traps])
            w = np.stack([_winding(mids, r) for r in rings])  # (R, T)
            s = [np.sign(clip.polygon_area_2d(r)) or 1 for r in rings]
            for k in range(len(rings)):
                if not np.isin(w[k], (0, s[k])).all():
                    return "its outline crosses itself" if k == 0 else f"hole {k} crosses itself"
            inner = w[1:] != 0
            if (inner & (w[:1] == 0)).any():
                return "a hole lies outside its outline"
            if (inner.sum(0) > 1).any():
                return "holes overlap"
    return ""


def check_emission(emission, name):
    """The emission as 3 finite non-negative floats, else an InputError naming the shape."""
    em = np.asarray(emission, float).reshape(-1)
    if em.shape != (3,):
        raise InputError(f"Light shape '{name}': emission must be 3 values (RGB), got shape {em.shape}.")
    if not np.isfinite(em).all():
        raise InputError(f"Light shape '{name}': emission {tuple(em)} is not finite.")
    if (em < 0).any():
        raise InputError(f"Light shape '{name}': negative emission {tuple(em)}.")
    return em


class ShapeValidator:
    """Checks a LightShape before anything changes (finite, planar within plane_tol x its own size,
    simple outline); remembers the outline checks of the last shapes seen (a shape that did not
    change between frames is not checked again)."""

    def __init__(self, plane_tol):
        self.plane_tol = plane_tol
        self._outline_ok = OrderedDict()  # rings' bytes -> '' or the problem
        self._valid = OrderedDict()  # rings' and emission's bytes of shapes found valid

    def validate(self, key, shape):
        """(rings, emission, name) of a valid shape, else an InputError naming it."""
        name = getattr(shape, "name", "") or str(key)
        rings = getattr(shape, "rings", None)
        if rings is None or len(rings) == 0:
            raise InputError(f"Light shape '{name}' has no rings.")
        out = []
        for i, r in enumerate(rings):
            try:
                r = np.array(r, dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"Light shape '{name}': ring {i} is not an array of 3D points.") from None
            if r.ndim != 2 or r.shape[1] != 3 or len(r) < 3:
                raise InputError(f"Light shape '{name}': ring {i} must be (M >= 3, 3) points, got {r.shape}.")
            if not np.isfinite(r).all():
                raise InputError(f"Light shape '{name}': ring {i} has NaN or infinite coordinates.")
            out.append(r)
        em = check_emission(shape.emission, name)
        # a shape that did not change since it was found valid (every other shape of a Live edit)
        seen = (tuple((r.shape, r.tobytes()) for r in out), em.tobytes())
        if seen in self._valid:
            return out, em, name
        size = _size(out)
        nrm = newell(out[0])
        if np.linalg.norm(nrm) <= 1e-9 * size**2:
            # No net area (e.g. a bowtie whose two lobes cancel): the plane from the points instead
            pts = out[0]
            sv, vt = np.linalg.svd(pts - pts.mean(0), full_matrices=False)[1:]
            if len(sv) < 3 or sv[1] <= 1e-9 * max(sv[0], 1e-300):
                raise InputError(
                    f"Light shape '{name}': the outer ring has zero area (its points lie on a line)."
                )
            nrm = vt[2]
        n = nrm / np.linalg.norm(nrm)
        c = out[0].mean(0)
        off = max(float(np.abs((r - c) @ n).max()) for r in out)
        tol = _plane_tolerance(out, self.plane_tol)
        if off > tol:
            raise InputError(
                f"Light shape '{name}' is not planar: a point is {off:.3g} off its plane "
                f"(tolerance {tol:.3g}, {self.plane_tol:.2%} of its size)."
            )
        key = tuple(r.tobytes() for r in out)
        problem = self._outline_ok.get(key)
        if problem is None:
            u, v = _basis(n)
            problem = outline_problem([np.stack([(r - c) @ u, (r - c) @ v], -1) for r in out])
            self._outline_ok[key] = problem
            while len(self._outline_ok) > 256:
                self._outline_ok.popitem(last=False)
        if problem:
            raise InputError(
                f"Light shape '{name}': {problem}. A light shape must be a simple outline "
                "(no crossings; holes inside it and apart): redraw it, e.g. as faces that "
                "do not overlap."
            )
        if np.linalg.norm(newell(out[0])) <= 1e-9 * size**2:
            raise InputError(f"Light shape '{name}': the outer ring has zero area.")
        self._valid[seen] = True
        while len(self._valid) > 256:
            self._valid.popitem(last=False)
        return out, em, name


def _basis(n):
    """In-plane axes (u, v) of a shape with unit normal n: u is n x the coordinate axis least
    aligned with n (a shape's own frame; planes.frames is the patches')."""
    axis = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, axis)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def shape_plane(rec, plane_tol):
    """Set the shape's plane on its record: normal n, centre c, axes u, v, rings2d, tol, area."""
    nrm = newell(rec.rings[0])
    rec.n = nrm / np.linalg.norm(nrm)
    rec.c = rec.rings[0].mean(0)
    rec.u, rec.v = _basis(rec.n)
    rec.rings2d = [to2d(rec, r) for r in rec.rings]
    rec.tol = _plane_tolerance(rec.rings, plane_tol)
    a = [abs(clip.polygon_area_2d(r)) for r in rec.rings2d]
    rec.area = a[0] - sum(a[1:])
    if rec.area <= 0:
        raise InputError(f"Light shape '{rec.name}': its holes cover its whole area.")


def to2d(rec, p):
    """Points p (..., 3) into the shape's plane frame: (..., 2)."""
    d = np.asarray(p, float) - rec.c
    return np.stack([d @ rec.u, d @ rec.v], -1)


def find_surface(rec, system):
    """The input patches the shape lies on (rec.group: in its plane, facing its way; rec.roots: those
    it overlaps), the fraction of its area on them (rec.covered) and rec.on_surface."""
    pt = system.patches
    tol = rec.tol
    dist = np.abs((pt.corners - rec.c) @ rec.n).max(1)
    al = pt.normal @ rec.n
    cand = (dist <= tol) & (np.abs(al) >= 0.999)
    if (cand & (al > 0)).any():
        cand &= al > 0  # surfaces on both sides of the plane: the shape emits on its front side
    rec.group = np.flatnonzero(cand)
    rec.roots = np.zeros(0, np.int64)
    rec.covered = 0.0
    if len(rec.group):
        frac, _, out = classify(rec, system.h, rec.group)
        rec.roots = rec.group[~out]
        rec.covered = float(np.sum(frac[~out] * system.h.area[rec.roots])) / rec.area
    rec.on_surface = rec.covered > 1e-6
    if rec.on_surface and rec.covered < 0.999:
        rec.msgs.append(
            f"shape '{rec.name}': only {100 * rec.covered:.1f}% of its area lies on "
            "surfaces; the rest does not emit"
        )


def outline_crosses(rings, tris, face, n_faces, plane_tol=1e-3, rel_tol=1e-6):
    """(n_faces,) bool: the faces a light shape's outline crosses (the vertex output's finer faces:
    the light changes across them). rings: the shape's (3D, planar; the outline, then its holes);
    tris (T, 3, 3): the faces' triangles, face (T,) their faces. A face counts where its triangles
    in the shape's plane (within its tolerance, facing either way: find_surface's test) are covered
    in part: clip.overlap_areas summed over them strictly between 0 and their area (rel_tol). Wholly
    inside, wholly outside, or an outline that only runs along the face's edge: False."""
    rings = [np.asarray(r, np.float64) for r in rings]
    n = newell(rings[0])
    if not np.linalg.norm(n) > 0:  # an outline without area (a shape keyed flat on a frame): no edge
        return np.zeros(n_faces, bool)
    n = n / np.linalg.norm(n)
    c = rings[0].mean(0)
    tris = np.asarray(tris, np.float64)
    tn = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    area = 0.5 * np.linalg.norm(tn, axis=1)
    near = np.abs((tris - c) @ n).max(1) <= _plane_tolerance(rings, plane_tol)
    on = np.flatnonzero(near & (area > 0) & (np.abs(tn @ n) >= 0.999 * 2 * area))
    if not len(on):
        return np.zeros(n_faces, bool)
    u, v = _basis(n)
    flat = lambda p: np.stack([(p - c) @ u, (p - c) @ v], -1)  # noqa: E731
    nodes = flat(tris[on])
    nodes = np.concatenate([nodes, nodes[:, 2:]], 1)  # (triangles padded: corner 3 repeats 2)
    part = clip.overlap_areas([flat(r) for r in rings], nodes, np.full(len(on), 3))
    cover = np.bincount(face[on], part, n_faces)
    whole = np.bincount(face[on], area[on], n_faces)
    return (cover > rel_tol * whole) & (cover < (1 - rel_tol) * whole)


def off_surface_message(rec, system):
    """Why a shape that lies on no surface (rec.on_surface False, after _find_surface) looks as it
    does: NAIVE takes it as a separate emitter, so it shows on no surface. Names the nearest
    parallel surface under its outline (within NEAR_SURFACE x the shape's size: a shape meant to
    lie on it), the distance and the side."""
    pt = system.patches
    size = _size(rec.rings)
    al = pt.normal @ rec.n
    signed = ((pt.corners - rec.c) @ rec.n).mean(1)  # the patches' offset along the shape's normal
    cand = np.flatnonzero((np.abs(al) >= 0.999) & (np.abs(signed) <= NEAR_SURFACE * size))
    if len(cand):
        _, _, out = classify(rec, system.h, cand)
        cand = cand[~out]
    tail = f"(more than the plane tolerance {_length(rec.tol)})"
    if not len(cand):
        return (
            f"shape '{rec.name}' lies on no surface: handled by NAIVE as a separate emitter; it "
            "lights the scene, but no surface shows its glow. To show it on a wall, put it in "
            "the wall's plane (same coordinate), facing the same way"
        )
    k = cand[np.argmin(np.abs(signed[cand]))]
    names = list(system.mesh.object_names)
    oid = int(pt.object_id[k])
    obj = names[oid] if 0 <= oid < len(names) else f"object {oid}"
    d = _length(signed[k])
    if al[k] > 0 and signed[k] < 0:
        return (
            f"Light shape '{rec.name}' is {d} in front of the surface of '{obj}' {tail}: it is "
            f"handled as a separate emitter (NAIVE); it lights the scene, but '{obj}' does not "
            "show its glow (the surface under it lies in its shadow). Move the shape onto the "
            f"surface (same coordinate) to show it on '{obj}'"
        )
    if al[k] > 0:
        return (
            f"Light shape '{rec.name}' is {d} behind the surface of '{obj}' {tail}: it is "
            f"handled as a separate emitter (NAIVE) that shines into the back of '{obj}', so it "
            "lights nothing and does not show. Move the shape onto the surface (same coordinate)"
        )
    if signed[k] > 0:
        return (
            f"Light shape '{rec.name}' faces the surface of '{obj}' {d} in front of it {tail}: it "
            f"is handled as a separate emitter (NAIVE) whose light falls only on '{obj}' right "
            f"under it. Turn the shape to face away from '{obj}' (flip its normals) and move it "
            "onto the surface"
        )
    return (
        f"Light shape '{rec.name}' is {d} off the back of '{obj}' and faces away from it {tail}: it "
        "is handled as a separate emitter (NAIVE); no surface shows its glow"
    )


def classify(rec, h, nodes):
    """clip.classify of hierarchy nodes against the shape: (overlap fraction, inside, outside)."""
    return clip.classify(rec.rings2d, to2d(rec, h.corners[nodes]), h.nv[nodes])
