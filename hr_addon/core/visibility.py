"""Batched segment-occlusion queries against a fixed triangle soup (the scene's occluders).

Contract shared by every backend: the segment a->b is occluded iff some triangle meets it at a parameter
t strictly inside (tmin, 1 - tmin), with tmin = TMIN = 1e-6 relative to the segment length. The segment is
open at both ends so that rays between points lying *on* surfaces never hit those surfaces; triangles are
two-sided (occluders block from both sides). Zero-length segments are never occluded. Degenerate or
non-finite input triangles are dropped: they have no area, so they cannot block anything.

Backends: "numpy" (always available, float64 reference), "embree" (embreex, float32, fast), "mathutils"
(Blender's BVHTree, float32, Python loop: only for cross-checking inside Blender). The float32 backends widen
tmin so that float32 rounding cannot turn an endpoint on a surface into a self-hit (see `_Float32Mixin`).

Only numpy is imported at module level: mathutils / embreex are imported lazily by their backends.
"""
import numpy as np

TMIN = 1e-6

# float32 backends: an endpoint lying on a surface moves off it by up to ~1 ulp of its coordinates when
# rounded to float32 (so do the triangle's vertices), so the open interval must start at least a few ulps
# (of the coordinate magnitude, not of the segment length) away from the endpoints. 2**-24 is half an ulp
# at 1.0; the factor was chosen by measuring self-hits of rays leaving surfaces (tests/test_visibility.py).
F32_SLACK = 64 * 2.0 ** -24


def _clean_triangles(triangles):
    """(T,3,3) float64 without non-finite or (numerically) zero-area triangles."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    tri = tri[np.isfinite(tri).all(axis=(1, 2))]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n2 = np.einsum("ij,ij->i", *(2 * [np.cross(e1, e2)]))
    # sin(angle) below 1e-12 is a sliver of no measurable area whose plane is ill-defined: drop it too
    ok = n2 > 1e-24 * np.einsum("ij,ij->i", e1, e1) * np.einsum("ij,ij->i", e2, e2)
    return np.ascontiguousarray(tri[ok & (n2 > 0)])


class RayBackend:
    """Base class: input normalisation shared by all backends; subclasses implement `_occluded`."""

    name = "base"

    def __init__(self, triangles):
        self.triangles = _clean_triangles(triangles)
        if len(self.triangles):
            lo, hi = self.triangles.min(axis=(0, 1)), self.triangles.max(axis=(0, 1))
        else:
            lo = hi = np.zeros(3)
        self.center = 0.5 * (lo + hi)
        self.half_extent = max(float(np.max(hi - lo)) / 2, 1e-30)

    def occluded(self, a, b):
        """a, b: (..., 3). Boolean (...): True where the open segment a->b hits a triangle."""
        a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
        shape = a.shape[:-1]
        a, b = a.reshape(-1, 3), b.reshape(-1, 3)
        out = np.zeros(len(a), dtype=bool)
        live = np.flatnonzero(np.isfinite(a).all(1) & np.isfinite(b).all(1) & (a != b).any(1))
        if len(self.triangles) and len(live):
            out[live] = self._occluded(a[live], b[live])
        return out.reshape(shape)

    def _occluded(self, a, b):  # a, b: (R,3) float64, finite, a != b
        raise NotImplementedError

    def __repr__(self):
        return f"<{type(self).__name__} {len(self.triangles)} triangles>"


# ---------------------------------------------------------------------------------------------- numpy

class NumpyBackend(RayBackend):
    """Vectorised breadth-first traversal of a balanced binary BVH, then a ray/triangle test per leaf.

    The tree is complete (triangle count padded with duplicates to LEAF * 2**depth) so that every level is
    a flat array and parents are `node // 2`: the build is `depth` batched argsorts (object-median split
    along each node's longest centroid axis) and the traversal is a few numpy ops per level on
    (ray, node) pairs. Scenes of <= BRUTE_MAX triangles use a single leaf (root box test + brute force).
    The triangle test maps each triangle to its barycentric frame (precomputed 3x4 matrix, cf.
    Baldwin-Weber), which needs fewer per-pair numpy passes than Moeller-Trumbore.
    """

    name = "numpy"
    LEAF = 8
    BRUTE_MAX = 64
    CHUNK_RAYS = 1 << 15   # rays traversed together: bounds the (ray, node) pair arrays
    CHUNK_ELEMS = 1 << 18  # (pair x triangle) elements per leaf-test batch: keeps temporaries in cache

    def __init__(self, triangles):
        super().__init__(triangles)
        tri = self.triangles
        T = len(tri)
        if T == 0:
            return
        leaf = T if T <= self.BRUTE_MAX else self.LEAF
        depth = int(np.ceil(np.log2(T / leaf))) if T > leaf else 0
        # duplicates of an existing triangle cannot change any answer, so they are safe padding
        order = np.concatenate([np.arange(T), np.full((leaf << depth) - T, T - 1)])
        cen = tri.mean(axis=1)
        for lvl in range(depth):
            seg = order.reshape(1 << lvl, -1)
            c = cen[seg]
            axis = np.argmax(c.max(axis=1) - c.min(axis=1), axis=1)
            key = np.take_along_axis(c, axis[:, None, None], axis=2)[..., 0]
            order = np.take_along_axis(seg, np.argsort(key, axis=1, kind="stable"), axis=1).ravel()
        tri = tri[order].reshape(1 << depth, leaf, 3, 3)

        # per-level boxes, root first; inflated so rounding in the slab test never culls a true hit
        pad = 1e-9 * self.half_extent
        lo, hi = tri.min(axis=(1, 2)) - pad, tri.max(axis=(1, 2)) + pad
        self._lo, self._hi = [lo], [hi]
        for _ in range(depth):
            lo, hi = lo.reshape(-1, 2, 3).min(axis=1), hi.reshape(-1, 2, 3).max(axis=1)
            self._lo.insert(0, lo)
            self._hi.insert(0, hi)

        # world -> (u, v, w): triangle at (0,0),(1,0),(0,1) in (u,v), w along the normal
        v0, e1, e2 = tri[..., 0, :], tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]
        n = np.cross(e1, e2)
        n /= np.sqrt(np.linalg.norm(n, axis=-1, keepdims=True))  # |n| ~ edge length: well conditioned
        inv = np.linalg.inv(np.stack([e1, e2, n], axis=-1))      # (L, leaf, 3, 3)
        m = np.concatenate([inv, -(inv @ v0[..., None])], axis=-1)  # (L, leaf, 3, 4)
        self._m = np.ascontiguousarray(m.reshape(1 << depth, leaf, 12).transpose(0, 2, 1))  # (L, 12, leaf)
        self.depth, self.leaf = depth, leaf

    @staticmethod
    def _slab(o, inv, lo, hi):
        """Segment o + t d, t in [0,1] (inv = 1/d) against boxes; all args (P,3)."""
        t0, t1 = (lo - o) * inv, (hi - o) * inv
        tn, tf = np.minimum(t0, t1), np.maximum(t0, t1)
        near = np.maximum(np.maximum(tn[:, 0], tn[:, 1]), np.maximum(tn[:, 2], 0.0))
        far = np.minimum(np.minimum(tf[:, 0], tf[:, 1]), np.minimum(tf[:, 2], 1.0))
        return near <= far

    def _hit_leaves(self, o, d, leaf):
        """Any hit of segment p (o, d: (P,3)) with the triangles of leaf p: (P,) bool."""
        g = self._m[leaf]  # (P, 12, leaf)
        ox, oy, oz = o[:, 0, None], o[:, 1, None], o[:, 2, None]
        dx, dy, dz = d[:, 0, None], d[:, 1, None], d[:, 2, None]

        def row(k):  # local coordinate k of the origin and of the direction
            return (g[:, 4 * k] * ox + g[:, 4 * k + 1] * oy + g[:, 4 * k + 2] * oz + g[:, 4 * k + 3],
                    g[:, 4 * k] * dx + g[:, 4 * k + 1] * dy + g[:, 4 * k + 2] * dz)

        wo, wd = row(2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -wo / wd  # parallel rays give inf / nan, which fail every comparison below
        uo, ud = row(0)
        vo, vd = row(1)
        u, v = uo + t * ud, vo + t * vd
        # closed triangle edges: a ray through a shared edge is blocked (as in watertight tracers)
        hit = (t > TMIN) & (t < 1 - TMIN) & (u >= 0) & (v >= 0) & (u + v <= 1)
        return hit.any(axis=1)

    def _occluded(self, a, b):
        d = b - a
        # zero direction components -> huge finite inverse, so the slab test never computes 0 * inf
        inv = 1.0 / np.where(np.abs(d) < 1e-200, 1e-200, d)
        out = np.zeros(len(a), dtype=bool)
        for s in range(0, len(a), self.CHUNK_RAYS):
            ray = np.arange(s, min(s + self.CHUNK_RAYS, len(a)))
            node = np.zeros(len(ray), dtype=np.intp)
            for lvl in range(self.depth + 1):
                keep = self._slab(a[ray], inv[ray], self._lo[lvl][node], self._hi[lvl][node])
                ray, node = ray[keep], node[keep]
                if lvl < self.depth:
                    ray, node = np.repeat(ray, 2), (2 * node[:, None] + np.arange(2)).ravel()
            step = max(1, self.CHUNK_ELEMS // self.leaf)
            for p in range(0, len(ray), step):
                r, n = ray[p:p + step], node[p:p + step]
                live = ~out[r]  # skip rays already found occluded
                r, n = r[live], n[live]
                out[r[self._hit_leaves(a[r], d[r], n)]] = True
        return out


# ---------------------------------------------------------------------------------------------- float32

class _Float32Mixin:
    """Segments prepared for float32 tracers.

    Coordinates are shifted to the scene centre (halves their magnitude, hence their rounding error), and
    the open interval becomes (tm, 1 - tm) with tm = max(TMIN, F32_SLACK * |coords| / length): the
    endpoints move inward by a few float32 ulps of the coordinate magnitude, far beyond the rounding that
    could put an on-surface endpoint behind its own surface. Consequences: a genuine occluder closer than
    ~64 ulps (~4e-6 x scene size) to an endpoint is missed, and segments shorter than ~8e-6 x scene size
    are reported unoccluded. The caller offsets endpoints along normals by much more than that anyway.
    Returns origins o, directions d (end = o + tfar d), tfar, and a mask of segments long enough to trace.
    """

    def _f32_segments(self, a, b):
        a, b = a - self.center, b - self.center
        d = b - a
        length = np.linalg.norm(d, axis=1)
        mag = np.maximum(self.half_extent, np.maximum(np.abs(a).max(1), np.abs(b).max(1)))
        tm = np.maximum(TMIN, F32_SLACK * mag / length)
        ok = tm < 0.5
        return a + tm[:, None] * d, d, 1.0 - 2.0 * tm, ok


class EmbreeBackend(_Float32Mixin, RayBackend):
    """Intel Embree through `embreex`: rtcOccluded1 per ray in C (float32, watertight, two-sided)."""

    name = "embree"
    CHUNK = 1 << 20  # bounds the float32 copies

    def __init__(self, triangles):
        super().__init__(triangles)
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        self._scene = rtcs.EmbreeScene()
        if len(self.triangles):
            TriangleMesh(self._scene, (self.triangles - self.center).astype(np.float32))

    def _occluded(self, a, b):
        o, d, tfar, ok = self._f32_segments(a, b)
        out = np.zeros(len(a), dtype=bool)
        idx = np.flatnonzero(ok)
        for s in range(0, len(idx), self.CHUNK):
            i = idx[s:s + self.CHUNK]
            # embreex's OCCLUDED query returns the geometry id of a hit, -1 if none (tnear is fixed at 0,
            # hence the shifted origin)
            hit = self._scene.run(np.ascontiguousarray(o[i], dtype=np.float32),
                                  np.ascontiguousarray(d[i], dtype=np.float32),
                                  dists=tfar[i].astype(np.float32), query="OCCLUDED")
            out[i] = hit >= 0
        return out


class MathutilsBackend(_Float32Mixin, RayBackend):
    """Blender's `mathutils.bvhtree.BVHTree` (float32): one Python-level ray_cast per segment.

    ray_cast normalises the direction and returns only the nearest hit, so each ray starts at the shifted
    origin and is limited to the shortened segment's length: any hit at all means occluded.
    """

    name = "mathutils"

    def __init__(self, triangles):
        super().__init__(triangles)
        from mathutils.bvhtree import BVHTree
        verts = (self.triangles - self.center).reshape(-1, 3)
        polys = np.arange(len(verts)).reshape(-1, 3)
        self._tree = BVHTree.FromPolygons(verts.tolist(), polys.tolist(), all_triangles=True)

    def _occluded(self, a, b):
        o, d, tfar, ok = self._f32_segments(a, b)
        dist = (tfar * np.linalg.norm(d, axis=1)).tolist()
        cast = self._tree.ray_cast
        o, d, ok = o.tolist(), d.tolist(), ok.tolist()
        return np.array([k and cast(oi, di, li)[3] is not None
                         for oi, di, li, k in zip(o, d, dist, ok)], dtype=bool)


# ---------------------------------------------------------------------------------------------- factory

_BACKENDS = {"numpy": NumpyBackend, "embree": EmbreeBackend, "mathutils": MathutilsBackend}


def _importable(name):
    # checked at call time (not cached) so tests can hide a module through sys.modules
    try:
        if name == "embree":
            import embreex.rtcore_scene  # noqa: F401
            import embreex.mesh_construction  # noqa: F401
        elif name == "mathutils":
            import mathutils.bvhtree  # noqa: F401  (inside Blender, or once the bpy module is imported)
        return True
    except ImportError:
        return False


def available_backends():
    """Names of the backends usable in this process, fastest first."""
    return [n for n in ("embree", "numpy", "mathutils") if _importable(n)]


def make_backend(triangles, prefer="auto"):
    """Backend for `triangles` (T,3,3). "auto": embree if importable, else numpy."""
    if prefer == "auto":
        prefer = "embree" if _importable("embree") else "numpy"
    if prefer not in _BACKENDS:
        raise ValueError(f"unknown ray backend {prefer!r}; expected auto or one of {sorted(_BACKENDS)}")
    return _BACKENDS[prefer](triangles)


def visibility_fraction(backend, a, b):
    """a, b broadcastable to (N, S, 3) (S segments per row): fraction of unoccluded segments, (N,)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    if a.ndim != 3 or a.shape[1] == 0:
        raise ValueError(f"expected (N, S, 3) with S > 0, got {a.shape}")
    return 1.0 - backend.occluded(a, b).mean(axis=1)
