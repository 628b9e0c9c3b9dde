"""Batched segment-occlusion queries against a fixed triangle soup (the scene's occluders).

Contract shared by every backend: the segment a->b is occluded iff some triangle meets it at a parameter
t strictly inside (TMIN, 1 - TMIN), TMIN = 1e-6 relative to the segment length, computed in float64. The
segment is open at both ends so that rays between points lying *on* surfaces never hit those surfaces;
triangles are two-sided (occluders block from both sides) with closed edges. Zero-length segments and
segments with non-finite ends are never occluded. Degenerate or non-finite input triangles are dropped:
they have no area, so block nothing.

Backends: "numpy" (always available, the float64 reference), "embree" (embreex, float32, fast),
"mathutils" (Blender's BVHTree, float32, one Python call per ray: for cross-checks inside Blender).
The float32 backends only *propose* hits: each proposal is re-tested in float64 with the numpy kernel,
and rays whose proposal is refuted (rounding self-hits of endpoints lying on surfaces) are re-traced by the
numpy backend. So all backends agree except for rays within ~1 float32 ulp of a triangle edge.

Only numpy is imported at module level: mathutils / embreex are imported lazily by their backends.

Threads (issue 23, docs/threads.md): `backend.threads` > 1 runs large occluded() / first_hit()
calls over fixed chunks of PARALLEL_CHUNK rays on core.parallel's threads (embreex and numpy
release the GIL); every ray's result is its own, so any thread count gives the same values. Inside
another batch map's worker a call runs inline. The backends keep no per-call state but the
diagnostic `last_retraced`.
"""

import threading

import numpy as np

from .boxes import spans
from .parallel import batch_map, in_worker, ranges

TMIN = 1e-6

# float32 backends: segments shorter than this fraction of their coordinates' magnitude (~500 float32 ulps)
# have too imprecise a float32 direction; they go to the numpy backend instead.
F32_SHORT = 2.0**-15


def _clean_triangles(triangles, return_index=False):
    """(T,3,3) float64 without non-finite or (numerically) zero-area triangles (and, with
    return_index, the index of each kept triangle in the input)."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    idx = np.flatnonzero(np.isfinite(tri).all(axis=(1, 2)))
    tri = tri[idx]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n2 = np.einsum("ij,ij->i", *(2 * [np.cross(e1, e2)]))
    # sin(angle) below 1e-12 is a sliver of no measurable area whose plane is ill-defined: drop it too
    ok = n2 > 1e-24 * np.einsum("ij,ij->i", e1, e1) * np.einsum("ij,ij->i", e2, e2)
    ok &= n2 > 0
    out = np.ascontiguousarray(tri[ok])
    return (out, idx[ok]) if return_index else out


def _triangle_rows(tri):
    """12 arrays (T,): rows of the 3x4 maps world -> (u, v, w), triangle at (0,0),(1,0),(0,1) in (u,v),
    w along the normal (cf. Baldwin-Weber): fewer numpy passes per ray/triangle pair than Moeller-Trumbore."""
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    n /= np.sqrt(np.linalg.norm(n, axis=1, keepdims=True))  # |n| ~ edge length: well conditioned
    # inverse of the matrix with columns (e1, e2, n): rows are cross products over the determinant
    inv = np.stack([np.cross(e2, n), np.cross(n, e1), np.cross(e1, e2)], axis=1)
    inv /= np.einsum("ij,ij->i", e1, inv[:, 0])[:, None, None]
    m = np.concatenate([inv, -np.einsum("tij,tj->ti", inv, v0)[:, :, None]], axis=-1).reshape(-1, 12)
    return [np.ascontiguousarray(m[:, k]) for k in range(12)]


def _row(g, k, x, y, z):
    """g[k] x + g[k + 1] y + g[k + 2] z, updated in place (one temporary)."""
    r = g[k] * x
    r += g[k + 1] * y
    r += g[k + 2] * z
    return r


def _hit_plane(g, ox, oy, oz, dx, dy, dz):
    """(t, inside): the segment parameter where o + t d meets each triangle's plane, and whether
    that point lies inside the triangle (closed edges: a ray through an edge shared by two
    triangles is blocked, as in watertight tracers). In-place updates keep the number of
    temporaries (the cost in numpy) low. Call under np.errstate(all="ignore")."""
    t = _row(g, 8, ox, oy, oz)
    t += g[11]
    wd = _row(g, 8, dx, dy, dz)
    np.divide(t, wd, out=t)  # parallel rays give inf / nan, which fail every comparison below
    np.negative(t, out=t)
    px, py, pz = t * dx, t * dy, t * dz
    px += ox
    py += oy
    pz += oz
    u = _row(g, 0, px, py, pz)
    u += g[3]
    v = _row(g, 4, px, py, pz)
    v += g[7]
    hit = u >= 0
    hit &= v >= 0
    u += v
    hit &= u <= 1
    return t, hit


def _hit_kernel(g, ox, oy, oz, dx, dy, dz):
    """Segments o + t d vs triangles with rows g, broadcasting: t in (TMIN, 1 - TMIN) and inside."""
    t, hit = _hit_plane(g, ox, oy, oz, dx, dy, dz)
    t -= 0.5
    np.abs(t, out=t)
    hit &= t < 0.5 - TMIN
    return hit


def _hit_t_kernel(g, ox, oy, oz, dx, dy, dz):
    """As _hit_kernel, but the segment parameter t of the hit (inf where the segment misses)."""
    t, hit = _hit_plane(g, ox, oy, oz, dx, dy, dz)
    hit &= np.abs(t - 0.5) < 0.5 - TMIN
    return np.where(hit, t, np.inf)


class RayBackend:
    """Base class: input normalisation shared by all backends; subclasses implement `_occluded`."""

    name = "base"
    threads = 1  # threads for large ray batches (core.parallel; 1: inline)
    _identity = False  # (a backend made before the flag: source's gather, as before)
    PARALLEL_CHUNK = 1 << 16  # rays per batch on threads: fixed, so results do not depend on threads

    def __init__(self, triangles):
        # source[i]: index in the input array of the i-th kept triangle (first_hit reports input indices)
        self.triangles, self.source = _clean_triangles(triangles, return_index=True)
        # every input triangle kept, in order: first_hit's indices need no mapping
        self._identity = bool(np.array_equal(self.source, np.arange(len(self.source))))
        if len(self.triangles):
            lo, hi = self.triangles.min(axis=(0, 1)), self.triangles.max(axis=(0, 1))
        else:
            lo = hi = np.zeros(3)
        self.half_extent = max(float(np.max(hi - lo)) / 2, 1e-30)
        # The float32 tracers work relative to this point: the median of the triangles' centres,
        # so that one object far from the rest does not move it (and the precision of every
        # other ray with it) out of the scene.
        self.center = np.median(self.triangles.mean(1), axis=0) if len(self.triangles) else np.zeros(3)

    def occluded(self, a, b):
        """a, b: (..., 3), broadcastable. Boolean (...): True where the open segment a->b hits a triangle."""
        a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
        shape = a.shape[:-1]
        a, b = a.reshape(-1, 3), b.reshape(-1, 3)
        d = b - a
        dd = np.einsum("ij,ij->i", d, d)
        # finite coordinates, nonzero length (row reductions written as matmul / einsum: 4x faster)
        live = np.isfinite(a @ np.ones(3)) & np.isfinite(dd) & (dd > 0)
        out = np.zeros(len(a), dtype=bool)
        if len(self.triangles) and live.any():
            if live.all():
                out = self._map(self._occluded, a, d)
            else:
                out[live] = self._map(self._occluded, a[live], d[live])
        return out.reshape(shape)

    def occluded_cm(self, a, d, per=1):
        """occluded() of the segments a -> a + d given component-major, a, d (3, N) float64 (d: the
        b - a that occluded() computes): the same values without its row-major (N, 3) passes.
        per: each origin a[:, j] starts the `per` consecutive segments j per .. (j + 1) per - 1
        (a (3, N / per): a point's shadow rays without copies of its origin; the same values).
        Runs inline (a caller on threads calls it per batch)."""
        with np.errstate(over="ignore", invalid="ignore"):  # silent, as occluded()'s einsum
            dd = (d[0] * d[0] + d[2] * d[2]) + d[1] * d[1]  # einsum's order for rows of 3
            live = np.isfinite((a[0] + a[1]) + a[2])
            live = (np.repeat(live, per) if per > 1 else live) & np.isfinite(dd) & (dd > 0)
        out = np.zeros(d.shape[1], dtype=bool)
        if not len(self.triangles) or not live.any():
            return out
        if live.all():
            return self._occluded_cm(a, d, dd, per)
        i = np.flatnonzero(live)
        out[i] = self._occluded_cm(a[:, i // per], d[:, i], dd[i])
        return out

    def _occluded_cm(self, a, d, dd, per=1):
        if per > 1:
            a = np.repeat(a, per, axis=1)
        return self._occluded(np.ascontiguousarray(a.T), np.ascontiguousarray(d.T))

    def _map(self, kernel, a, d, *more):
        """kernel(a, d, *more) over chunks of PARALLEL_CHUNK rays (rows of a, d and every array of
        more) on self.threads threads, concatenated (a tuple of arrays per chunk for first_hit's
        kernel)."""
        if len(a) <= self.PARALLEL_CHUNK or in_worker():  # 1 thread: the same chunks, inline
            return kernel(a, d, *more)
        parts = batch_map(
            lambda i, j: kernel(a[i:j], d[i:j], *(x[i:j] for x in more)),
            ranges(len(a), self.PARALLEL_CHUNK),
            self.threads,
        )
        if isinstance(parts[0], tuple):
            return tuple(np.concatenate(x) for x in zip(*parts))
        return np.concatenate(parts)

    def _occluded(self, a, d):  # segments a -> a + d, (R,3) float64, finite, nonzero length
        raise NotImplementedError

    def first_hit(self, origins, directions, tmax, sure=None, per=None):
        """Nearest hit of rays o + t d, t in (TMIN tmax, (1 - TMIN) tmax) (the open segment
        o -> o + tmax d of occluded(): a ray hits something iff that segment is occluded).
        origins, directions (R, 3), tmax scalar or (R,). Returns (index of the triangle hit in the
        array given to the backend, -1 for none (R,) int64; t (R,) float64 in units of d, inf for
        none). Float64 decides every reported hit, as for occluded(); with `sure` (float32
        tracers) only those within sure x the segment of one of its ends, the others keep the
        tracer's hit and t (see _Float32Backend._first). per: rays per origin (an int or (S,)
        counts): origins (S, 3), origin i starting per[i] consecutive rays (a sample's hemisphere
        rays without a copy of its origin per ray: the same values as the origins repeated)."""
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        n = len(d)
        # (one tmax for all: d times the scalar, the same products as by a broadcast column)
        scale = float(tmax) if np.ndim(tmax) == 0 else np.broadcast_to(np.asarray(tmax, np.float64), (n,))
        d = d * (scale if np.ndim(scale) == 0 else scale[:, None])
        rep = None if per is None else np.broadcast_to(np.asarray(per, np.int64), (len(o),))
        prim = np.full(n, -1, np.int64)
        t = np.full(n, np.inf)
        # finite rows by columns (.all(1) over an axis of 3 loops per row: 2.4 s CPU of the 100k
        # room's gather precompute); the origins' once per origin
        fin = np.isfinite(o)
        good = fin[:, 0] & fin[:, 1] & fin[:, 2]
        if rep is not None:
            good = np.repeat(good, rep)
        dd = np.einsum("ij,ij->i", d, d)  # (the squared lengths: _first's too, made once)
        good &= dd > 0
        # d's coordinates are finite where d . d is (a non-finite one makes it inf or nan); the
        # others tested by coordinate (a finite d whose square overflows)
        odd = np.flatnonzero(~np.isfinite(dd))
        if len(odd):
            good[odd] &= np.isfinite(d[odd]).all(1)
        every = bool(good.all())  # (no copies of the rays when all are good)
        ok = None if every else np.flatnonzero(good)
        if (every or len(ok)) and n and len(self.triangles):
            if rep is not None and not every:  # (rare: rays one by one, as without per)
                o, rep = np.repeat(o, rep, 0), None
            if rep is None:
                kernel = lambda a, d, dd: self._first(a, d, sure, dd)  # noqa: E731
                p, ts = self._map(kernel, *((o, d, dd) if every else (o[ok], d[ok], dd[ok])))
            else:
                p, ts = self._map_per(o, rep, d, dd, sure)
            hit = p >= 0
            if every:  # (the rays' own rows: no scatter through ok)
                if self._identity:  # (every triangle kept: its own index, no gather)
                    prim = np.where(hit, p, -1).astype(np.int64, copy=False)
                else:
                    prim = np.where(hit, self.source[np.maximum(p, 0)] if len(self.source) else -1, -1)
                t = np.where(hit, ts, np.inf)
            else:
                prim[ok[hit]] = self.source[p[hit]]
                t[ok[hit]] = ts[hit]
        return prim, t * scale

    def _map_per(self, o, rep, d, dd, sure):
        """_first over the rays of origins o (S, 3), rep (S,) rays each, by chunks of whole origins
        of about PARALLEL_CHUNK rays on self.threads threads (as _map: every ray's result its own)."""
        cum = np.zeros(len(o) + 1, np.int64)
        np.cumsum(rep, out=cum[1:])

        def kernel(i, j):
            a, b = cum[i], cum[j]
            return self._first(o[i:j], d[a:b], sure, dd[a:b], rep[i:j])

        if len(d) <= self.PARALLEL_CHUNK or in_worker():
            return kernel(0, len(o))
        step = max(self.PARALLEL_CHUNK // max(int(rep.max(initial=1)), 1), 1)
        parts = batch_map(kernel, ranges(len(o), step), self.threads)
        return tuple(np.concatenate(x) for x in zip(*parts))

    def _first(self, a, d, sure=None, dd=None, per=None):  # segments a -> a + d: (kept triangle or -1,
        # segment parameter t); dd: the rows' d . d if known (einsum's); per: a's rows each start
        # per[i] consecutive segments (first_hit's)
        raise NotImplementedError

    def __repr__(self):
        return f"<{type(self).__name__} {len(self.triangles)} triangles>"


# ---------------------------------------------------------------------------------------------- numpy


class NumpyBackend(RayBackend):
    """Float64 reference: brute force for tiny scenes, else a uniform grid walked by a vectorised 3D-DDA.

    Grid: cells ~ GRID_DENSITY x triangles; a triangle is listed in every cell its (padded) bounding box
    overlaps *and* its plane crosses (drops most cells of big slanted triangles). All rays of a chunk step
    one cell per iteration in lockstep, test the cell's triangles over the whole segment (any hit anywhere
    counts), and drop out once occluded or past their end: occluded rays stop early, unlike in a
    breadth-first BVH traversal. Measured (benchmarks/bench_rays.py, spheres in a box): 2.2x (2k
    triangles) to 2.7x (20k triangles) faster than a vectorised BVH2, so the BVH was dropped.
    """

    name = "numpy"
    BRUTE_MAX = 80  # up to this many triangles brute force beats the grid walk (measured)
    GRID_DENSITY = 2.0  # cells per triangle; 0.5..4 measured within 15%
    MAX_CELL_REFS = 1 << 24  # caps (cell, triangle) candidates when big slanted triangles span many cells
    CHUNK_RAYS = 1 << 16  # rays walked together
    CHUNK_PAIRS = 1 << 20  # (ray, triangle) index pairs expanded at once
    CHUNK_ELEMS = 1 << 14  # ray x triangle elements per kernel call: temporaries stay in cache

    def __init__(self, triangles, grid=None):
        super().__init__(triangles)
        tri = self.triangles
        self._m = _triangle_rows(tri)
        self.grid = len(tri) > self.BRUTE_MAX if grid is None else bool(grid) and len(tri) > 0
        if self.grid:
            self._build_grid(tri)

    def _build_grid(self, tri):
        pad = 1e-9 * self.half_extent
        lo, hi = tri.min(axis=(0, 1)) - 2 * pad, tri.max(axis=(0, 1)) + 2 * pad
        ext = hi - lo
        h = (np.prod(np.maximum(ext, 1e-3 * ext.max())) / (self.GRID_DENSITY * len(tri))) ** (1 / 3)
        while True:  # coarsen until the candidate list fits
            res = np.clip(np.ceil(ext / h), 1, 512).astype(np.intp)
            size = ext / res
            c0 = np.floor((tri.min(axis=1) - pad - lo) / size).astype(np.intp).clip(0, res - 1)
            c1 = np.floor((tri.max(axis=1) + pad - lo) / size).astype(np.intp).clip(0, res - 1)
            span = c1 - c0 + 1
            cnt = span.prod(axis=1)
            if cnt.sum() <= self.MAX_CELL_REFS or res.max() == 1:
                break
            h *= 1.5
        # enumerate the bounding-box cells of every triangle
        t = np.repeat(np.arange(len(tri)), cnt)
        k = np.arange(len(t)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ijk = np.empty((len(t), 3), dtype=np.intp)
        for ax in range(3):
            ijk[:, ax] = c0[t, ax] + k % span[t, ax]
            k //= span[t, ax]
        # keep cells whose box the triangle's plane crosses (conservatively padded)
        nrm = np.cross(tri[t, 1] - tri[t, 0], tri[t, 2] - tri[t, 0])
        dist = np.einsum("ij,ij->i", lo + (ijk + 0.5) * size - tri[t, 0], nrm)
        reach = (np.abs(nrm) * (0.5 * size + pad)).sum(axis=1) * (1 + 1e-9)
        keep = np.abs(dist) <= reach
        cell = np.ravel_multi_index(ijk[keep].T, res)
        order = np.argsort(cell, kind="stable")
        self._cell_tri = t[keep][order]
        self._cell_start = np.searchsorted(cell[order], np.arange(res.prod() + 1))
        self._lo, self._size, self._res = lo, size, res

    def _occluded(self, a, d):
        with np.errstate(all="ignore"):
            if not self.grid:
                return self._brute(a, d)
            out = np.zeros(len(a), dtype=bool)
            for s in range(0, len(a), self.CHUNK_RAYS):
                out[s : s + self.CHUNK_RAYS] = self._walk(
                    a[s : s + self.CHUNK_RAYS], d[s : s + self.CHUNK_RAYS]
                )
            return out

    def _first(self, a, d, sure=None, dd=None, per=None):  # float64 decides every hit: sure is moot
        if per is not None:
            a = np.repeat(a, per, 0)
        with np.errstate(all="ignore"):
            if not self.grid:
                return self._brute(a, d, nearest=True)
            prim = np.empty(len(a), np.int64)
            t = np.empty(len(a))
            for s in range(0, len(a), self.CHUNK_RAYS):
                sl = slice(s, s + self.CHUNK_RAYS)
                prim[sl], t[sl] = self._walk(a[sl], d[sl], nearest=True)
            return prim, t

    def _brute(self, a, d, nearest=False):
        """Every ray against every triangle: occlusion (R,) bool; nearest: (nearest kept triangle or
        -1, its t)."""
        g = [m[None, :] for m in self._m]
        step = max(1, self.CHUNK_ELEMS // len(self.triangles))
        out = np.empty(len(a), dtype=bool)
        prim, t = np.empty(len(a), np.int64), np.empty(len(a))
        for s in range(0, len(a), step):
            o, e = a[s : s + step, :, None], d[s : s + step, :, None]
            rows = (o[:, 0], o[:, 1], o[:, 2], e[:, 0], e[:, 1], e[:, 2])
            if nearest:
                tt = _hit_t_kernel(g, *rows)
                k = np.argmin(tt, axis=1)
                t[s : s + step] = tt[np.arange(len(k)), k]
                prim[s : s + step] = np.where(np.isfinite(t[s : s + step]), k, -1)
            else:
                out[s : s + step] = _hit_kernel(g, *rows).any(axis=1)
        return (prim, t) if nearest else out

    def _hit_pairs(self, ad, ray, tri, kernel=_hit_kernel):
        """kernel per pair (ray[i], tri[i]): hit (_hit_kernel) or t (_hit_t_kernel); ad: the rays'
        6 coordinate rows (a, d). In CHUNK_ELEMS slices."""
        out = np.empty(len(ray), dtype=bool if kernel is _hit_kernel else np.float64)
        for s in range(0, len(ray), self.CHUNK_ELEMS):
            r, t = ray[s : s + self.CHUNK_ELEMS], tri[s : s + self.CHUNK_ELEMS]
            out[s : s + self.CHUNK_ELEMS] = kernel([m[t] for m in self._m], *(x[r] for x in ad))
        return out

    def _walk(self, a, d, nearest=False):
        """Occlusion (R,) bool; nearest: (nearest kept triangle or -1, its t) instead, the walk going
        on until the best hit found lies before the current cell's exit."""
        lo, size, res = self._lo[:, None], self._size[:, None], self._res[:, None]
        a, d = a.T, d.T  # (3, R): per-axis rows are contiguous
        ad = np.ascontiguousarray(np.concatenate([a, d]))
        # zero direction components -> tiny positive ones: the walk never steps along that axis and the
        # slab test never computes 0 * inf
        inv = 1.0 / np.where(np.abs(d) < 1e-200, 1e-200, d)
        t0, t1 = (lo - a) * inv, (lo + res * size - a) * inv
        t_in = np.maximum(np.minimum(t0, t1).max(axis=0), 0.0)
        t_out = np.minimum(np.maximum(t0, t1).min(axis=0), 1.0)
        out = np.zeros(a.shape[1], dtype=bool)
        best_t = np.full(a.shape[1], np.inf)
        best_p = np.full(a.shape[1], -1, np.int64)
        ray = np.flatnonzero(t_in <= t_out)  # segments that touch the grid
        a, inv, t_out = a[:, ray], inv[:, ray], t_out[ray]
        fwd = inv > 0
        cell = np.floor((a + t_in[ray] * d[:, ray] - lo) / size).astype(np.intp)
        np.clip(cell, 0, res - 1, out=cell)
        t_next = (lo + (cell + fwd) * size - a) * inv  # per axis, the t at which the walk leaves the cell
        t_step = np.abs(size * inv)
        step = np.where(fwd, 1, -1)
        start, cell_tri = self._cell_start, self._cell_tri
        stride = np.array([[res[1, 0] * res[2, 0]], [res[2, 0]], [1]])
        while len(ray):
            c = (cell * stride).sum(axis=0)
            first = start[c]
            cnt = start[c + 1] - first
            occ = np.zeros(len(ray), dtype=bool)
            end = np.cumsum(cnt)
            # blocks of ~CHUNK_PAIRS (ray, triangle) pairs bound the index arrays in crowded cells
            cuts = np.unique(np.searchsorted(end, np.arange(0, end[-1], self.CHUNK_PAIRS)[1:]))
            for i, j in zip([0, *cuts], [*cuts, len(ray)]):
                n = cnt[i:j]
                if not n.any():
                    continue
                pair, k = spans(first[i:j], first[i:j] + n)
                pair += i
                tri = cell_tri[k]
                if nearest:
                    tt = self._hit_pairs(ad, ray[pair], tri, _hit_t_kernel)
                    h = np.flatnonzero(np.isfinite(tt))
                    if len(h):
                        # per ray the smallest t: sort by (ray, t), first of each ray
                        o = np.lexsort((tt[h], pair[h]))
                        h = h[o]
                        firsts = np.r_[True, pair[h][1:] != pair[h][:-1]]
                        h = h[firsts]
                        r = ray[pair[h]]
                        better = tt[h] < best_t[r]
                        best_t[r[better]] = tt[h][better]
                        best_p[r[better]] = tri[h][better]
                else:
                    occ[pair[self._hit_pairs(ad, ray[pair], tri)]] = True
            out[ray[occ]] = True
            # step along the axis whose cell wall comes first
            tx, ty, tz = t_next
            t_exit = np.minimum(np.minimum(tx, ty), tz)
            if nearest:
                occ = best_t[ray] <= t_exit  # the best hit lies in a cell already walked
            alive = ~occ & (t_exit < t_out)
            mx = (tx <= ty) & (tx <= tz)
            my = ~mx & (ty <= tz)
            for k, m in enumerate((mx, my, ~(mx | my))):
                np.add(cell[k], step[k], out=cell[k], where=m)
                np.add(t_next[k], t_step[k], out=t_next[k], where=m)
            np.clip(cell, 0, res - 1, out=cell)  # rounding at the grid's far side
            ray, t_out = ray[alive], t_out[alive]
            cell, t_next, t_step, step = cell[:, alive], t_next[:, alive], t_step[:, alive], step[:, alive]
        return (best_p, best_t) if nearest else out


# ---------------------------------------------------------------------------------------------- float32


def _rows32(e):
    """(N, 3) float32 rows of component-major float64 e (3, N): e.T's cast, one component at a
    time (no transposed float64 pass)."""
    out = np.empty((e.shape[1], 3), np.float32)
    for k in range(3):
        out[:, k] = e[k]
    return out


def _sum_rows32(o, e, s, per=1, idx=None):
    """(N, 3) float32 rows of o + s e, the float64 sum's cast, from component-major o (3, N /
    per: each column the origin of `per` consecutive segments) and e (3, N), at segments idx
    (None: all): a component at a time, without (3, N) float64 temporaries (the same values)."""
    n = e.shape[1] if idx is None else len(idx)
    out = np.empty((n, 3), np.float32)
    oi = None if idx is None else (idx // per if per > 1 else idx)
    for k in range(3):
        t = (e[k] if idx is None else np.take(e[k], idx)) * s
        if idx is None and per > 1:
            t.reshape(-1, per)[...] += o[k][:, None]
        else:
            t += o[k] if idx is None else np.take(o[k], oi)
        out[:, k] = t
    return out


class _Float32Backend(RayBackend):
    """Shared by the float32 tracers: they propose each ray's nearest hit, float64 decides.

    Coordinates are shifted to the scene centre (halves their magnitude, hence their rounding) and the
    segment is traced over t in [TMIN, 1 - TMIN]. Rounding to float32 can still put an endpoint lying on a
    surface just behind it, so the nearest hit proposed by the tracer (triangle index or -1) is re-tested
    in float64 on the original segment; rays whose proposal is refuted (such self-hits, mostly of grazing
    or in-plane rays: ~2% of rays between random points *on* surfaces, ~1e-5 once endpoints are offset
    1e-6 x scene size along normals) and segments too short for float32 (F32_SHORT) are re-traced by the
    numpy backend.
    What is left of float32: misses of rays passing within ~1 float32 ulp of an edge, or of a hit within
    ~1 ulp of TMIN. A float64 check of the hit alone would not do: ray_cast/rtcIntersect1 report only the
    nearest hit, and a refuted one may hide a genuine one behind it.
    occluded() with an any-hit query (Embree's rtcOccluded1) asks it first for the middle of each
    segment, where a proposed hit would be trusted anyway (SURE), and the nearest hit only of the
    segments clear there.
    """

    _exact = None  # the numpy backend for re-traced rays, built on first need (_numpy())
    last_retraced = 0  # diagnostics: rays of the last call that the numpy backend re-traced

    def __init__(self, triangles):
        super().__init__(triangles)
        self._rows = _triangle_rows(self.triangles)  # float64 rows deciding every proposed hit
        self._lock = threading.Lock()  # the numpy backend is built once, whichever thread needs it
        pad = 1e-9 * self.half_extent  # (as the numpy grid's)
        lo, hi = self.triangles.min(axis=1) - pad, self.triangles.max(axis=1) + pad
        self._boxes = [(np.ascontiguousarray(lo[:, k]), np.ascontiguousarray(hi[:, k])) for k in range(3)]
        self._boxed = 0  # (segment, triangle) box tests of _retrace so far

    def _numpy(self):
        with self._lock:
            if self._exact is None:
                self._exact = NumpyBackend(self.triangles)
        return self._exact

    # _retrace's box tests before it builds the numpy grid instead: a few re-traced segments per
    # call (a light event's ~4 M shadow rays on the 100k room: ~5) cost ~0.3 ms each at 100k
    # triangles, the grid's build 0.3 s
    BOXED_MAX = 1 << 25

    def _retrace(self, a, d):
        """The numpy backend's occlusion of segments a -> a + d (R, 3): against the triangles whose
        bounding box meets the segment's while few were (BOXED_MAX), else on the numpy grid."""
        n = len(a) * len(self.triangles)
        with self._lock:
            boxed = self._exact is None and self._boxed + n <= self.BOXED_MAX
            self._boxed += n if boxed else 0
        if not boxed:
            return self._numpy()._occluded(a, d)
        out = np.zeros(len(a), dtype=bool)
        step = max(1, (1 << 22) // len(self.triangles))
        for s in range(0, len(a), step):
            o, e = a[s : s + step], d[s : s + step]
            slo, shi = np.minimum(o, o + e), np.maximum(o, o + e)
            meet = np.ones((len(o), len(self.triangles)), dtype=bool)
            for k, (lo, hi) in enumerate(self._boxes):  # per axis: (R, T) rows, not a last axis of 3
                meet &= lo <= shi[:, k, None]
                meet &= hi >= slo[:, k, None]
            ray, tri = np.nonzero(meet)
            with np.errstate(all="ignore"):
                hit = _hit_kernel([m[tri] for m in self._rows], *o[ray].T, *e[ray].T)
            out[s + ray[hit]] = True
        return out

    # Proposed hits farther than this (relative to the segment) from both ends are genuine: a
    # rounding self-hit of an endpoint lying on a surface happens next to that endpoint (a ray
    # would have to graze its surface within float32 noise over 1% of its length otherwise).
    SURE = 1e-2

    def _nearest(self, o, d, tfar):
        """float32 o, d (R,3), tfar (R,): (index of the nearest triangle hit on o + t d, t in
        [0, tfar], or -1; its t)."""
        raise NotImplementedError

    def _occluded(self, a, d):
        # component-major rows (3, N): the per-axis passes below run over contiguous rows
        dd = np.einsum("ij,ij->i", d, d)
        return self._occluded_cm(np.ascontiguousarray(a.T), np.ascontiguousarray(d.T), dd)

    def _occluded_cm(self, a, d, dd, per=1):
        """_occluded() of component-major a, d (3, N), dd = |d|^2 (N,) (per: occluded_cm's). A
        tracer with an any-hit query (_any_hit: it stops at the first hit found, ~40% cheaper than
        the nearest on a blocked ray) answers the middle of each segment, t in [SURE, 1 - SURE],
        where a float32 hit is trusted; only the segments clear there ask for their nearest hit,
        which float64 re-tests when it lies within SURE of an end (as without the any-hit query)."""
        o = a - self.center[:, None]
        length = np.sqrt(dd)
        r = np.sqrt((o[0] * o[0] + o[2] * o[2]) + o[1] * o[1])
        mag = (np.repeat(r, per) if per > 1 else r) + length  # >= the ray's largest |coord|
        short = length < F32_SHORT * mag
        if per > 1 and short.any():  # (rare: every segment its own origin)
            a, o, per = np.repeat(a, per, axis=1), np.repeat(o, per, axis=1), 1
        trace = np.flatnonzero(~short) if short.any() else None  # None: all (saves two gathers)
        o, e = (o, d) if trace is None else (o[:, trace], d[:, trace])
        ray = np.arange(e.shape[1]) if trace is None else trace  # indices into d of o, e
        out = np.zeros(d.shape[1], dtype=bool)
        e32 = _rows32(e)
        if self.any_hit:
            tfar = np.full(len(e32), 1.0 - 2.0 * self.SURE, dtype=np.float32)
            mid = self._any_hit(_sum_rows32(o, e, self.SURE, per), e32, tfar)
            out[ray[mid]] = True
            clear = np.flatnonzero(~mid)
            o32 = _sum_rows32(o, e, TMIN, per, clear)
            e32, ray = e32[clear], ray[clear]
        else:
            o32 = _sum_rows32(o, e, TMIN, per)
        tfar = np.full(len(e32), 1.0 - 2.0 * TMIN, dtype=np.float32)
        prim, t_hit = self._nearest(o32, e32, tfar)
        hit = prim >= 0
        sure = hit & (t_hit > self.SURE) & (t_hit < 1.0 - self.SURE)
        out[ray[sure]] = True
        check = hit & ~sure
        ray, prim = ray[check], prim[check]
        with np.errstate(all="ignore"):
            ok = _hit_kernel([m[prim] for m in self._rows], *a[:, ray // per], *d[:, ray])
        out[ray[ok]] = True
        retry = np.concatenate([ray[~ok], np.flatnonzero(short)])
        if len(retry):
            ar, dr = (np.ascontiguousarray(v[:, retry // k].T) for v, k in ((a, per), (d, 1)))
            out[retry] = self._retrace(ar, dr)
        self.last_retraced = len(retry)
        return out

    any_hit = False  # whether the tracer has _any_hit

    def _any_hit(self, o, d, tfar):
        """float32 o, d (R,3), tfar (R,): whether o + t d hits a triangle for some t in [0, tfar]."""
        raise NotImplementedError

    def _first(self, a, d, sure=None, dd=None, per=None):
        """The tracer proposes the nearest hit, float64 re-tests it on the
        original segment (and gives its t); refuted proposals and short segments go to numpy.
        sure: proposals farther than this (relative to the segment) from both ends keep the
        tracer's t, no re-test (the final gather's hemisphere rays: 1e-4 x their 4 x the scene's
        size, ~1 cm, is ~5000 float32 ulps of the coordinates, where a rounding self-hit needs a
        ray within ~1e-4 rad of its surface; what float32 alone misses, a ray through an edge
        within an ulp, takes the triangle beside: 7 of 2.56 M rays on the 100k room, the t of 2 off).
        per: a (S, 3) the origins, a[i] starting per[i] consecutive segments (each origin's offset
        and magnitude made once, not per segment: the same values)."""
        length = np.sqrt(np.einsum("ij,ij->i", d, d) if dd is None else dd)
        o = a - self.center
        mag = np.sqrt(np.einsum("ij,ij->i", o, o))
        R = len(d)
        start = TMIN * d
        if per is not None:
            cum = np.cumsum(per)
            rows = lambda r: a[np.searchsorted(cum, r, "right")]  # noqa: E731  (the origins of segments r)
            k = int(per[0]) if len(per) else 0
            if len(per) and k * len(per) == R and (per == k).all():
                # (as many segments per origin: the origins added by broadcasting, not repeated;
                # the same sums, each of two terms)
                start.reshape(-1, k, 3)[:] += o[:, None]
                mag = np.add(length.reshape(-1, k), mag[:, None]).ravel()
            else:
                start += np.repeat(o, per, 0)
                mag = np.repeat(mag, per) + length
        else:
            rows = a.__getitem__
            start += o
            mag += length
        short = length < F32_SHORT * mag
        prim, t32 = self._nearest(
            start.astype(np.float32), d.astype(np.float32), np.full(R, 1.0 - 2.0 * TMIN, dtype=np.float32)
        )
        del start
        any_short = bool(short.any())
        prim = (np.where(short, -1, prim) if any_short else prim).astype(np.int64, copy=False)
        if sure is not None:  # t32 is measured from the shifted origin a + TMIN d
            # (masks over all rays: no index lists for the ~87% sure hits)
            ok = t32 > sure
            ok &= t32 < 1.0 - sure
            ok &= prim >= 0
            t = np.where(ok, TMIN + t32, np.inf).astype(np.float64)
            ray = np.flatnonzero(~ok & (prim >= 0))
        else:
            t = np.full(R, np.inf)
            ray = np.flatnonzero(prim >= 0)
        with np.errstate(all="ignore"):
            t[ray] = _hit_t_kernel([m[prim[ray]] for m in self._rows], *rows(ray).T, *d[ray].T)
        bad = ray[~np.isfinite(t[ray])]
        prim[bad] = -1
        retry = np.concatenate([bad, np.flatnonzero(short)]) if any_short else bad
        if len(retry):
            prim[retry], t[retry] = self._numpy()._first(rows(retry), d[retry])
        self.last_retraced = len(retry)
        return prim, t


class EmbreeBackend(_Float32Backend):
    """Intel Embree through `embreex` (float32, watertight, two-sided), one rtcIntersect1 per ray in C."""

    name = "embree"
    CHUNK = 1 << 20  # bounds embreex's per-call output arrays
    any_hit = True

    def __init__(self, triangles):
        super().__init__(triangles)
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcs.EmbreeScene()
        if len(self.triangles):
            TriangleMesh(self._scene, (self.triangles - self.center).astype(np.float32))

    def _nearest(self, o, d, tfar):
        # embreex traces from tnear = 0 (hence the shifted origins) up to `dists`; "INTERSECT" returns the
        # nearest primID (-1 if none), the id of a triangle in the order given to TriangleMesh, and
        # its tfar (in units of d)
        prim = np.empty(len(o), dtype=np.intp)
        t = np.empty(len(o), dtype=np.float32)
        for s in range(0, len(o), self.CHUNK):
            sl = slice(s, s + self.CHUNK)
            res = self._scene.run(o[sl], d[sl], dists=tfar[sl], query="INTERSECT", output=1)
            prim[sl], t[sl] = res["primID"], res["tfar"]
        return prim, t

    def _any_hit(self, o, d, tfar):
        # "OCCLUDED" (rtcOccluded1: stops at the first hit found) returns 0 for a hit, -1 for none
        hit = np.empty(len(o), dtype=bool)
        for s in range(0, len(o), self.CHUNK):
            sl = slice(s, s + self.CHUNK)
            hit[sl] = self._scene.run(o[sl], d[sl], dists=tfar[sl], query="OCCLUDED") == 0
        return hit


class MathutilsBackend(_Float32Backend):
    """Blender's `mathutils.bvhtree.BVHTree` (float32, two-sided): one Python-level ray_cast per segment.

    ray_cast normalises the direction and takes a distance in world units; it returns (location, normal,
    index, distance) of the nearest hit or Nones.
    """

    name = "mathutils"

    def __init__(self, triangles):
        super().__init__(triangles)
        from mathutils.bvhtree import BVHTree

        verts = (self.triangles - self.center).reshape(-1, 3)
        self._tree = BVHTree.FromPolygons(
            verts.tolist(), np.arange(len(verts)).reshape(-1, 3).tolist(), all_triangles=True
        )

    def _nearest(self, o, d, tfar):
        length = np.linalg.norm(d, axis=1)
        cast = self._tree.ray_cast
        hits = [cast(oi, di, li)[2:] for oi, di, li in zip(o.tolist(), d.tolist(), (tfar * length).tolist())]
        prim = np.array([-1 if i is None else i for i, _ in hits], dtype=np.intp)
        t = np.array([0.0 if x is None else x for _, x in hits]) / np.maximum(length, 1e-300)
        return prim, t


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
    """Names of the backends usable in this process ("embree" first when present)."""
    return [n for n in ("embree", "numpy", "mathutils") if _importable(n)]


def make_backend(triangles, prefer="auto", threads=1):
    """Backend for `triangles` (T,3,3). "auto": embree if importable, else numpy. threads: for large
    ray batches (core.parallel.resolve_threads: None every core)."""
    if prefer == "auto":
        prefer = "embree" if _importable("embree") else "numpy"
    if prefer not in _BACKENDS:
        raise ValueError(f"unknown ray backend {prefer!r}; expected auto or one of {sorted(_BACKENDS)}")
    backend = _BACKENDS[prefer](triangles)
    backend.threads = threads
    return backend


def first_hit_within(backend, origins, directions, reach, tmax, sure=None, per=None):
    """backend.first_hit of unit rays to `reach`, then of the misses on to `tmax`. The contract's
    minimum distance is relative to the segment: one segment as long as a scene with a stray object
    50 km away (tmax 100 km) would skip every hit within 10 cm; `reach` (a few times the size of
    the main group of objects) keeps it relative to the rays' own surroundings. sure, per:
    first_hit's."""
    prim, t = backend.first_hit(origins, directions, reach, sure, per)
    if tmax > reach:
        miss = np.flatnonzero(prim < 0)
        if len(miss):
            start = reach * (1 - 4 * TMIN)  # overlaps the first segment's open end
            o = origins[miss] if per is None else origins[np.repeat(np.arange(len(origins)), per)[miss]]
            p2, t2 = backend.first_hit(o + start * directions[miss], directions[miss], tmax, sure)
            hit = p2 >= 0
            prim[miss[hit]], t[miss[hit]] = p2[hit], start + t2[hit]
    return prim, t


def visibility_fraction(backend, a, b):
    """a, b broadcastable to (N, S, 3) (S segments per row): fraction of unoccluded segments, (N,)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    if a.ndim != 3 or a.shape[1] == 0:
        raise ValueError(f"expected (N, S, 3) with S > 0, got {a.shape}")
    return 1.0 - backend.occluded(a, b).mean(axis=1)
