"""Planes of the input patches: plane ids, in-plane frames, and the conservative shaft tests that
use them (refinement's link visibility and AUTO's first bounce skip rays with Occluders; the final
gather's direct light and AUTO's first bounce on large scenes with ClearShafts)."""

import numpy as np

from .boxes import row_groups
from .parallel import batch_map, ranges

# triangles per batch of ClearShafts' grid on threads (fixed, never by the thread count: every
# triangle's box and grid cells are its own and are concatenated in order, so the same grid)
TRI_BATCH = 1 << 14


def plane_ids(normal, point, size):
    """Integer id per polygon (K,), one per plane: unit normals (K, 3) to 1e-6, the offset of a
    point on each (K, 3) to 1e-6 x size (the scene's length scale, sqrt of its area)."""
    offset = np.einsum("ij,ij->i", normal, point)
    key = np.column_stack([np.round(normal * 1e6), np.round(offset / (1e-6 * (size or 1.0)))])
    return row_groups(key)[0]


def frames(normal):
    """Orthonormal tangent frames (u, v) of unit normals (N, 3), u x v = n: u is n x the axis
    (x, or y for normals near x) least aligned with n."""
    axis = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(normal, axis)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(normal, u)


class Occluders:
    """The patches' triangles as occluders: bounds and plane ids for the shaft test.

    A segment between two points in front of planes P and Q cannot hit a triangle lying in P or Q
    (surfaces are one-sided and the segment leaves P and Q on their front side), so such triangles
    are ignored."""

    def __init__(self, patches):
        pt = patches
        tri_patch = np.concatenate([np.arange(len(pt.nv)), np.flatnonzero(pt.nv == 4)])  # Patches.triangles
        tris = pt.triangles
        self.lo, self.hi = tris.min(1), tris.max(1)
        size = float(np.sqrt(pt.area.sum()))
        self.patch_plane = plane_ids(pt.normal, pt.corners[:, 0], size)
        self.plane = self.patch_plane[tri_patch]

    def __len__(self):
        return len(self.lo)

    def maybe_occluded(self, lo, hi, plane_a, plane_b, budget=4_000_000):
        """Conservative shaft test of N joint boxes lo, hi (N, 3) between two ends in planes
        plane_a and plane_b ((N,) or scalars): False where no occluder triangle outside both
        planes meets the box, so the segments inside it are certainly unoccluded."""
        n = len(lo)
        out = np.ones(n, bool)
        pa = np.broadcast_to(np.asarray(plane_a), (n,))
        pb = np.broadcast_to(np.asarray(plane_b), (n,))
        step = max(1, budget // max(len(self.lo), 1))
        for s in range(0, n, step):
            sl = slice(s, s + step)
            hit = (self.plane[None] != pa[sl, None]) & (self.plane[None] != pb[sl, None])
            # one axis at a time on (boxes, triangles): 4.5x faster than np.all over a last axis of 3
            for k in range(3):
                hit &= self.lo[None, :, k] <= hi[sl, k, None]
                hit &= self.hi[None, :, k] >= lo[sl, k, None]
            out[sl] = hit.any(1)
        return out


class ClearShafts:
    """Where the segments from points to a planar emitter certainly meet no triangle, so that all
    their shadow rays would come back unoccluded (the visibility ratio is exactly 1 there, and
    neither the rays nor their sampling are needed). Conservative, as planes.Occluders' shaft
    test, for any number of triangles: the segments from a point are bounded by STEPS boxes along
    their length (the box at t between (1 - t) x + t lo and (1 - t) x + t hi of the emitter's box,
    linear in t); a box is clear when it meets the box of no occluder triangle. Triangles wholly
    behind the emitter's plane are no occluders (the segments lie in front of it); the triangles
    of large planes (a room's walls, floor and ceiling: every sample lying on one would see its
    own plane's triangles in the grid cells around it) are tested by their plane's box, the rest
    through a uniform grid of counts (a summed-volume table: a box is clear if its cells hold no
    triangle box)."""

    CELLS = 96  # grid cells along the longest side
    STEPS = 4  # boxes along the segments
    BIG_PLANES = 24  # planes tested by their own box

    def __init__(self, tris, plane, point, normal, margin, threads=1):
        """threads: core.parallel's threads for the triangles' boxes and cells (a new emitter
        plane's grid is serial work of a light event otherwise: 0.05-0.1 s at 100k)."""
        parts = batch_map(  # (one batch of none without triangles)
            lambda a, b: self._boxes(tris[a:b], plane[a:b], point, normal),
            ranges(max(len(tris), 1), TRI_BATCH),
            threads,
        )
        lo, hi, plane, area = (np.concatenate(x) for x in zip(*parts))
        self.m = margin
        ids, inv = np.unique(plane, return_inverse=True)
        per = np.bincount(inv.ravel(), area, len(ids))
        # large planes (at least 1% of the area, the 24 largest): one box each
        top = np.argsort(-per, kind="stable")[: self.BIG_PLANES]
        big = ids[top[per[top] >= 0.01 * area.sum()]]
        isbig = np.isin(plane, big)
        self.big_lo = np.array([lo[plane == b].min(0) for b in big]).reshape(-1, 3)
        self.big_hi = np.array([hi[plane == b].max(0) for b in big]).reshape(-1, 3)
        lo, hi = lo[~isbig], hi[~isbig]
        if len(lo) == 0:
            self.sat = None
            return
        self.o = lo.min(0)
        ext = np.maximum(hi.max(0) - self.o, 1e-12)
        self.size = np.maximum(np.ceil(ext / ext.max() * self.CELLS), 1).astype(np.int64)
        self.cell = ext / self.size
        # boxes per cell by a difference array: +-1 at the 8 corners of each box's cell range (one
        # bincount; the cumulative sums in int32: exact counts as before, half the bytes of float64
        # for a new emitter plane's grid in a light event)
        dims = tuple(self.size + 1)
        flat = np.concatenate(
            batch_map(
                lambda a, b: self._corners(lo[a:b], hi[a:b], dims), ranges(len(lo), TRI_BATCH), threads
            ),
            1,
        )
        sign = np.array([(-1.0) ** sum(c) for c in np.ndindex(2, 2, 2)])
        diff = np.bincount(flat.ravel(), np.repeat(sign, flat.shape[1]), int(np.prod(dims))).astype(np.int32)
        cum = lambda v: v.cumsum(0, np.int32).cumsum(1, np.int32).cumsum(2, np.int32)
        full = cum(diff.reshape(dims))[:-1, :-1, :-1] > 0
        sat = np.zeros(dims, np.int32)
        sat[1:, 1:, 1:] = cum(full)
        self.sat = sat

    @staticmethod
    def _boxes(tris, plane, point, normal):
        """(lo, hi, plane, area) of the triangles not wholly behind (or in) the emitter's plane: the
        others block no segment."""
        keep = np.einsum("tvk,k->tv", tris - point, normal).max(1) > 0
        area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        return tris[keep].min(1), tris[keep].max(1), plane[keep], area[keep]

    def _corners(self, lo, hi, dims):
        """(8, M) flat grid indices of the 8 corners of boxes lo, hi's cell ranges."""
        a, b = self._cells(lo), self._cells(hi) + 1
        idx = np.stack([np.where(c, b, a) for c in np.ndindex(2, 2, 2)])  # (8, M, 3)
        return np.ravel_multi_index((idx[..., 0], idx[..., 1], idx[..., 2]), dims)

    def _cells(self, p):
        return np.clip(np.floor((p - self.o) / self.cell), 0, self.size - 1).astype(np.int64)

    def _empty(self, lo, hi):
        """(N,) True where the boxes lo, hi (N, 3) meet no occluder triangle's box."""
        # every big plane at once: (N, P) comparisons per axis instead of a pass per plane
        meet = np.ones((len(lo), len(self.big_lo)), bool)
        for k in range(3):
            meet &= (lo[:, k, None] <= self.big_hi[:, k]) & (hi[:, k, None] >= self.big_lo[:, k])
        ok = ~meet.any(1)
        if self.sat is not None:
            # the box's 8 corners in the table by flat offsets per axis (one take each instead of
            # a 3-d fancy index)
            step = np.array(self.sat.strides) // self.sat.itemsize
            a, b = self._cells(lo) * step, (self._cells(hi) + 1) * step
            s = self.sat.reshape(-1)
            t = lambda i, j, k: np.take(s, i[:, 0] + j[:, 1] + k[:, 2])
            n = (
                t(b, b, b)
                - t(a, b, b)
                - t(b, a, b)
                - t(b, b, a)
                + t(a, a, b)
                + t(a, b, a)
                + t(b, a, a)
                - t(a, a, a)
            )
            ok &= n < 0.5
        return ok

    def clear(self, o, elo, ehi):
        """(N,) True where every segment from o (N, 3) to a point of the box elo, ehi (3,) is
        certainly unoccluded."""
        # the last box of every segment holds the emitter's own box: when that meets an occluder's
        # box (a wall or an object touching the emitter, within a grid cell), no shaft is clear
        if not self._empty((elo - self.m)[None], (ehi + self.m)[None])[0]:
            return np.zeros(len(o), bool)
        ok = np.ones(len(o), bool)
        for k in range(self.STEPS):
            t0, t1 = k / self.STEPS, (k + 1) / self.STEPS
            i = np.flatnonzero(ok)
            x = o[i]
            lo = np.minimum((1 - t0) * x + t0 * elo, (1 - t1) * x + t1 * elo) - self.m
            hi = np.maximum((1 - t0) * x + t0 * ehi, (1 - t1) * x + t1 * ehi) + self.m
            ok[i] = self._empty(lo, hi)
        return ok
