"""A light shape's direct light from visibility toward its HOST plane (issue 19; on: DirectLight._shape
of a shape that moves (LightShape.moves) wholly on surfaces; docs/events.md, sessions 28 hv34 / hvp,
29 hvon and 30 hvmove).

A light shape lying on a wall is emission on static geometry: the visibility from a gather sample
toward points of that wall does not depend on the shape. So its bits, per (gather level, host plane,
cell level, cell, sample), are fixed: one estimator, evaluated two ways that give the same values bit
for bit. A TILE of the plane traced whole and stored is read by every later event with no rays; an
event traces only the segments it reads that no event traced before (its own samples' to the cells
the shape overlaps: the same points, eps and clear shafts) and keeps them (POLICY "lazy"). What is
traced when is speed only: no value depends on it, so none on the history of events
(benchmarks/host_visibility.py measured the estimator: `pin`).

- The plane's own 2D frame: the origin is the plane's point nearest the world origin (d n), the
  axes planes.frames(n). Nothing of a shape enters it: a tile's bits depend only on the level's
  samples, the plane, the cell level and the tile's index, never on which shape or event made it
  be traced first (history independence).
- Cells: h = base 2^(-L/2), L = 0, 1, 2, ... (half octaves), base = 4096 x the level's `unit`
  (FinalGather.unit, a power of two from the scene's size: so h scales exactly with the scene
  under 2^k scaling, and the same L is reused by every later shape of a similar size). A shape of
  area A takes the coarsest L with h <= sqrt(A / points) (`level_for`): between `points` and
  2 x `points` stored points fall inside it per sample (POINTS, POINTS_SECOND; hv34: 64 at the
  top level for half main's 16 rays' error, 16 at the second level for half of its 8 rays' p95;
  the product takes 32 / 8, hvon: the first event's rays).
- Tiles: T x T cells (T = `tile`, TILE by default: 16 bits, 2 bytes per sample), tile (L, ti, tj)
  holds cells [ti T, (ti + 1) T) x [tj T, (tj + 1) T) in the plane's frame; its rows are the
  level's samples facing it (not dark, in front of the plane, a corner of the tile not below
  their horizon by more than eps); per row and cell one bit: the segment from the sample (eps
  along its normal) to the cell's point (eps in front of the plane) got through. The point: each
  sample its OWN shift r of the lattice, hash_uniform(seed, sample key, STREAM + L), y = (c + r) h
  (uniform in the cell; every sample its own points, as final.py's rotated Hammersley sets). Rows
  whose shaft to the tile's box is certainly clear (planes.ClearShafts) get all ones, no rays.
- `visible` / `direct`: the `pin` estimator. Over the cells the shape overlaps (overlap area > 0,
  clipped exactly), a sample whose stored bits there are all 1 reads V = 1 exactly (F x 1 = F bit
  for bit), all 0 reads 0 (both by a popcount of its packed bytes); the others the ratio
  sum k v / sum k over their points inside the shape (k = cos_x cos_y / r^2, the area density's
  weight, as main's area rays; cos_y = z / r with z the sample's height over the plane, a
  constant per sample: the ratio uses k / z = cos_x / r^3). A cell wholly inside counts its
  point without a test; a partly covered one only if the point is inside the rings (even-odd:
  any outline, holes too). A sample none of whose points fell inside with weight (a shape small
  for its cells) reads the ratio over every overlapped cell's point weighted by its overlap area
  (hv34's `ovl`, biased only there); with no weight at all 1.
"""

import itertools

import numpy as np

from ..clip import _clip_halfplane, overlap_areas, polygon_area_2d
from ..parallel import batch_map, ranges, release_free_memory
from ..planes import frames
from .sampling import hash_uniform

# on: a light shape that moves (LightShape.moves: its first read pays at its second place) wholly on
# surfaces gets its direct light from this estimator at every gather level (store_for;
# DirectLight._shape); off (benchmarks, A/B) and for still shapes: main's shadow rays
ENABLED = True
# stored points per shape (top level, second level): an event reading cells no event traced costs
# about 1.6 x points rays a sample (the border cells too); reads of traced cells cost no ray. 32 / 8
# (the 100k FE window's first event: x2.3 main's gathered output's CPU, p95 x0.66 of main's) rather
# than 64 / 16 (x4.0, x0.48) (docs/events.md, session 29 hvon)
# (at the draft preset's 16 / 8 shadow rays; a level takes them in proportion to its own: points_for)
POINTS = 32
POINTS_SECOND = 8
STREAM = 0x5A17  # the host visibility's own random stream (+ the cell level)
TILE = 4  # cells per tile side (16 bits: the 100k window traces x0.7 the rays of 8 x 8 tiles)
BASE = 4096.0  # base cell = BASE x the level's unit (a power of two near the scene's size)
MAX_LEVEL = 24  # finest cell: base / 4096 (about 2 mm in a 10 m room)
CHUNK = 1 << 20  # (samples x cells) entries per batch of an event's weights
# (sample, cell) segments per batch of rays (_fill): a batch's temporaries are ~0.1 KB a segment
# (the segments in float64, the tracer's float32 rows, indices and masks), and the first frame of
# the 100k vertex bake peaks inside the window's trace: 2^20 held ~0.1 GB of them (docs/scale.md,
# session 37 mem37)
TRACE_CHUNK = 1 << 16
# the heap's freed pages given back after each tile's trace that traced rays (release_free_memory): a
# tile's segments, their batches' temporaries and the part's grown arrays free pages the next tile's do
# not fill, so they pile up over an event's tiles (the 100k vertex bake's first frame: +0.26 GB of
# resident heap over the window's part at a flat heap in use, its peak; docs/scale.md, session 38
# mem38). No values change; False: none
TRIM_TRACED = True
# what a store keeps (speed only: the values are the same either way, module doc; HostVisibility._tile):
# "lazy" every segment an event traced (each traced at most once, only when read), "second" / "always"
# a tile traced whole on its second / first read, "never" nothing
POLICY = "lazy"
# what is kept (speed only, never values; session 30 hvkeep): a level's stores at most MEMORY bytes
# (+ the tile being made), the tiles read longest ago dropped first (trim); the precompute's side
# file the most recently read tiles of all levels up to DISK bytes as held in memory (kept; the
# file, deflated, ~1/20 of that). At 100k a top-level tile holds ~1.3 MB (9 bytes for each of the
# ~58% of the level's samples facing it): MEMORY ~100 such tiles a level, 5x the FE window's
# 24-step sweep (19 tiles over 3 levels, 17.9 MB); DISK 3.6x that sweep's stores.
# A level's cap is at least TRIM_FLOOR tiles of all its samples: an event reads up to ~9 tiles a
# level (a shape takes 32-64 cells, 16 a tile), and a cap below what one event reads makes LRU drop
# the tiles the next step reads again (at 100k, 4 MB a level traced x9.5 the sweep's rays, more than
# main's shadow rays)
MEMORY = 128 << 20
TRIM_FLOOR = 16
DISK = 64 << 20
_TICK = itertools.count()  # the order of tile reads, over every store (LRU)
_POP = np.array([bin(i).count("1") for i in range(256)], np.uint8)  # bits set per byte
_POP16 = (_POP[:, None] + _POP[None, :]).ravel()  # bits set per uint16


def cell_overlaps(rings2d, x0, y0, h, nx, ny):
    """(ny, nx) the area of an outline (outer ring, then holes) inside each h x h cell of the block
    whose first cell's corner is (x0, y0) (clip.overlap_areas: the cells are convex nodes)."""
    gx, gy = np.meshgrid(x0 + h * np.arange(nx), y0 + h * np.arange(ny))
    sq = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], np.float64) * h
    cells = np.stack([gx.ravel(), gy.ravel()], -1)[:, None] + sq[None]
    return overlap_areas(rings2d, cells).reshape(ny, nx)


def inside_boxes(rings2d, corners, h):
    """(lo, hi) (P, 2): per h x h cell whose first corner is corners (P, 2), a box holding every
    point of the cell the even-odd test can call inside the outline: the box of each ring's part in
    the cell (clipped as clip.overlap_areas, about the outer ring's box centre; an even-odd inside
    point is inside some ring), padded by 1e-6 h (the tests' rounding: ~1e-16 of the coordinates);
    empty where no ring meets the cell."""
    o = 0.5 * (np.min(rings2d[0], 0) + np.max(rings2d[0], 0))
    c = np.asarray(corners, np.float64) - o
    nodes = c[:, None] + np.array([(0, 0), (1, 0), (1, 1), (0, 1)], np.float64)[None] * h
    lo, hi = np.full((len(c), 2), np.inf), np.full((len(c), 2), -np.inf)
    for ring in rings2d:
        r = np.asarray(ring, np.float64) - o
        r = r if polygon_area_2d(r) >= 0 else r[::-1]
        x = np.broadcast_to(r[:, 0], (len(c), len(r)))
        y = np.broadcast_to(r[:, 1], (len(c), len(r)))
        for i in range(4):
            x, y = _clip_halfplane(x, y, nodes[:, i], nodes[:, (i + 1) % 4])
        got = x.any(1) | y.any(1)  # (clip: a part left empty is all zeros)
        lo[got] = np.minimum(lo[got], np.column_stack([x.min(1), y.min(1)])[got])
        hi[got] = np.maximum(hi[got], np.column_stack([x.max(1), y.max(1)])[got])
    pad = 1e-6 * h
    return lo + o - pad, hi + o + pad


def inside_rings(q, rings):
    """(...,) even-odd test of 2D points q (..., 2) against rings (outer, then holes): planar._in_rings'
    answer, edge by edge over the points whose height the edge spans (the same crossing test and
    abscissa for each such point, the parity of their count: the same booleans; x0.35 of its CPU on a
    million points against a 4-edge ring, which _in_rings tests as (points, edges) arrays)."""
    q = np.asarray(q, np.float64)
    px, py = q[..., 0].ravel(), q[..., 1].ravel()
    inside = np.zeros(len(px), bool)
    for r in rings:
        r = np.asarray(r, np.float64)
        for (ax, ay), (bx, by) in zip(r.tolist(), np.roll(r, -1, 0).tolist()):
            c = np.flatnonzero((ay > py) != (by > py))  # (never where ay == by)
            if len(c):
                t = (py[c] - ay) / (by - ay)
                inside[c] ^= px[c] < ax + t * (bx - ax)
    return inside.reshape(q.shape[:-1])


def ring_area(rings2d):
    """Area of an outline (outer ring, then holes) in 2D."""
    return abs(polygon_area_2d(rings2d[0])) - sum(abs(polygon_area_2d(r)) for r in rings2d[1:])


class HostVisibility:
    """The stored visibility of one gather level's samples toward one host plane, by tiles (module
    doc). lv: a FinalGather level (points, normals, dark, keys, seed, eps, unit, n, system.backend,
    threads); normal, point: the plane; points: the stored points per shape the cell rule aims at;
    shafts: the plane's planes.ClearShafts (events.direct.clear_shafts) or None (every row traced);
    tile: cells per tile side (tile^2 a multiple of 8)."""

    def __init__(self, lv, normal, point, points=64, shafts=None, threads=None, tile=TILE, policy=None):
        n = np.asarray(normal, np.float64)
        self.n = n / np.linalg.norm(n)
        self.o = float(np.asarray(point, np.float64) @ self.n) * self.n
        U, V = frames(self.n[None])
        self.U, self.V = U[0], V[0]
        self.lv, self.points, self.shafts = lv, points, shafts
        assert tile * tile % 8 == 0 and tile * tile <= 64  # (a row's cells in one integer: _fill)
        self.tile = tile
        self.threads = getattr(lv, "threads", 1) if threads is None else threads
        self.base = BASE * lv.unit
        self.tiles = {}  # (L, ti, tj) -> (rows (sorted sample indices), bits (rows, tile^2 / 8) uint8)
        self.rays = 0  # rays traced into stored tiles
        self.policy = POLICY if policy is None else policy
        self.part = {}  # tile -> [rows, bits, known, tested]: a tile events traced parts of
        self.event_rays = 0  # rays traced by events for their own reads (tiles not traced whole)
        self.used = {}  # tile -> _TICK of its last read (trim, kept)

    # -- the lattice --------------------------------------------------------------------------------
    def cell(self, L):
        """The cell size of level L."""
        return self.base * 2.0 ** (-L / 2)

    def level_for(self, area):
        """The coarsest level whose cells put at least `points` stored points in a shape of this
        area (h <= sqrt(area / points)), clamped to [0, MAX_LEVEL]."""
        t = np.sqrt(max(area, 1e-300) / self.points)
        return int(np.clip(np.ceil(2 * np.log2(self.base / t) - 1e-9), 0, MAX_LEVEL))

    def to2d(self, P):
        d = np.asarray(P, np.float64) - self.o
        return np.column_stack([d @ self.U, d @ self.V])

    def tiles_of(self, rings2d, L):
        """The tiles (L, ti, tj) that an outline's box overlaps, in row-major order."""
        allr = np.concatenate(rings2d)
        s = self.tile * self.cell(L)
        t0 = np.floor(allr.min(0) / s).astype(int)
        t1 = np.floor(allr.max(0) / s).astype(int)
        return [(L, ti, tj) for tj in range(t0[1], t1[1] + 1) for ti in range(t0[0], t1[0] + 1)]

    def _corners(self, key):
        L, ti, tj = key
        s = self.tile * self.cell(L)
        return np.array([self.o + (ti + a) * s * self.U + (tj + b) * s * self.V for a, b in np.ndindex(2, 2)])

    def facing(self, key, among=None):
        """The level's samples (of `among`, sorted, if given) a tile stores: not dark, in front of the
        plane (by eps / 2), a corner of the tile at most eps below their horizon (a superset of those
        any point of it can light with weight). Each sample's own products, written out: the same
        answer for a sample whatever else is asked (a tile traced whole or an event's part of it);
        the plane's front samples of the whole level tested once a store (_front)."""
        lv = self.lv
        dot = lambda a, b: (a[:, 0] * b[0] + a[:, 1] * b[1]) + a[:, 2] * b[2]  # noqa: E731
        if among is None:
            got = self.__dict__.get("_front")
            if got is None:
                got = self._front = self._in_front(np.arange(lv.n), dot)
            i, xn = got
        else:
            i, xn = self._in_front(np.asarray(among), dot)
        nx = lv.normals[i]
        top = np.full(len(i), -np.inf)
        for c in self._corners(key):
            top = np.maximum(top, dot(nx, c) - xn)
        return i[top > -lv.eps]

    def _in_front(self, i, dot):
        """(samples of i not dark and in front of the plane by eps / 2, their x . n_x)."""
        lv = self.lv
        x, nx = lv.points[i], lv.normals[i]
        ok = ~lv.dark[i] & (dot(x - self.o, self.n) > 0.5 * lv.eps)
        i, x, nx = i[ok], x[ok], nx[ok]
        return i, (x[:, 0] * nx[:, 0] + x[:, 1] * nx[:, 1]) + x[:, 2] * nx[:, 2]

    def shifts(self, L, rows):
        """(len(rows), 2) each sample's own shift of level L's lattice, in [0, 1)."""
        return hash_uniform(self.lv.seed, self.lv.keys[rows], STREAM + L)

    def segments(self, key, rows, cells=None):
        """(origins (3, l), d (3, l x c)) of the tile's segments from samples rows to its cells
        (cell (i, j) of the tile at j T + i, T = self.tile; by default all T^2 of them, in that
        order), to (c + r) h in the plane's frame: each segment's values whichever others are asked."""
        L, ti, tj = key
        lv, h, T = self.lv, self.cell(L), self.tile
        cells = np.arange(T * T) if cells is None else np.asarray(cells)
        eps = lv.eps
        r = self.shifts(L, rows)
        a = (ti * T + cells[None] % T + r[:, :1]) * h  # (l, c)
        b = (tj * T + cells[None] // T + r[:, 1:]) * h  # (l, c)
        org = (lv.points[rows] + eps * lv.normals[rows]).T  # (3, l)
        p0 = self.o + eps * self.n
        d = np.empty((3,) + a.shape)
        for k in range(3):  # (p0 + a U + b V) - org, per component in place: the same floats
            np.multiply(a, self.U[k], out=d[k])
            d[k] += p0[k]
            d[k] += b * self.V[k]
            d[k] -= org[k][:, None]
        return org, d.reshape(3, -1)

    # -- tracing ------------------------------------------------------------------------------------
    def trace(self, keys):
        """Trace and store the tiles of keys whole (each tile on its own: its bits are the same in
        any order, batching or thread count, and the same as those events traced of it)."""
        for key in keys:
            if key not in self.tiles:
                P = self.part.pop(key, None) or self._new_part(key)
                self.rays += self._fill(
                    key, P, np.arange(len(P[0])), np.full(self.tile**2 // 8, 255, np.uint8)
                )
                self.tiles[key] = (P[0], P[1])

    def missing(self, rings, L=None):
        """The tiles a shape (rings on the plane) reads that are not stored whole yet ([]: `visible`
        traces no ray): an event traces the segments of them it reads and has not traced before."""
        _, _, keys, c0, _, ov = self.layout(rings, L)
        return [key for key in keys if key not in self.tiles and self._cells_of(key, c0, ov > 0).any()]

    def _window(self, key, c0, nbx, nby):
        """(block's slices, tile's slices) (y, x) of tile key's cells inside a block of nbx x nby
        cells whose first is c0, or None where they do not meet."""
        _, ti, tj = key
        T = self.tile
        i0, j0 = ti * T - c0[0], tj * T - c0[1]  # the tile's first cell in the block
        bi0, bi1, bj0, bj1 = max(i0, 0), min(i0 + T, nbx), max(j0, 0), min(j0 + T, nby)
        if bi0 >= bi1 or bj0 >= bj1:
            return None
        return (slice(bj0, bj1), slice(bi0, bi1)), (slice(bj0 - j0, bj1 - j0), slice(bi0 - i0, bi1 - i0))

    def _cells_of(self, key, c0, over):
        """(T, T) bool the cells of tile key that a shape overlaps (over: its block's, from c0)."""
        m = np.zeros((self.tile, self.tile), bool)
        w = self._window(key, c0, over.shape[1], over.shape[0])
        if w is not None:
            m[w[1]] = over[w[0]]
        return m

    def _new_part(self, key, among=None):
        """[rows, bits, known, tested] of a tile nothing of which is traced yet: its rows (of
        `among`, if given), their packed bits and which of them are known (none), and whether
        each row's shaft was tested (none)."""
        trim(self.lv, self)  # (the tile about to be made is not in the store yet: kept)
        rows = self.facing(key, among).astype(np.int32)
        C8 = self.tile**2 // 8
        z = lambda: np.zeros((len(rows), C8), np.uint8)  # noqa: E731
        return [rows, z(), z(), np.zeros(len(rows), bool)]

    def _fill(self, key, P, sel, mask):
        """Make the bits of rows P[0][sel] over the cells of `mask` (packed) known: rows whose shaft
        to the tile's box is certainly clear (planes.ClearShafts, tested once a row) all 1 with no
        rays, the unknown (row, cell) segments traced, grouped by their cells (each segment the same
        values in any group or batch). Returns the rays traced."""
        lv, T = self.lv, self.tile
        rows, bits, known, tested = P
        new = sel[~tested[sel]]
        if self.shafts is not None and len(new):
            c = self._corners(key)
            e = lv.eps * self.n
            o = lv.points[rows[new]] + lv.eps * lv.normals[rows[new]]
            clear = new[self.shafts.clear(o, c.min(0) + e, c.max(0) + e)]
            bits[clear] = known[clear] = 255
        tested[new] = True
        need = ~known[sel] & mask
        # (a TILE 4 row's two bytes as one uint16: numpy's any over an axis of 2 is a slow reduction)
        todo = np.flatnonzero(need.view(np.uint16)[:, 0] if need.shape[1] == 2 else need.any(1))
        if not len(todo):
            return 0
        # the rows by their cells to trace (a row's packed bytes as one integer: np.unique's axis=0
        # sorts rows of bytes 10-100x slower)
        code = np.zeros(len(todo), np.uint64)
        for b in range(need.shape[1]):
            code = (code << np.uint64(8)) | need[todo, b].astype(np.uint64)
        groups, first, inv = np.unique(code, return_index=True, return_inverse=True)
        rays = 0
        for k in range(len(groups)):
            gm = need[todo[first[k]]]
            at = sel[todo[inv.ravel() == k]]
            cells = np.flatnonzero(np.unpackbits(gm, count=T * T))

            def part(a, b, at=at, cells=cells):
                r = at[a:b]
                org, d = self.segments(key, rows[r], cells)
                vis = ~lv.system.backend.occluded_cm(org, d, len(cells)).reshape(len(r), len(cells))
                v = np.unpackbits(bits[r], axis=1, count=T * T).astype(bool)
                v[:, cells] = vis
                bits[r] = np.packbits(v, axis=1)

            batch_map(part, ranges(len(at), max(TRACE_CHUNK // len(cells), 1)), self.threads)
            known[at] |= gm
            rays += len(at) * len(cells)
        return rays

    def _tile(self, key, idx, cells):
        """(rows, bits, p) of tile key for an event at samples idx reading its cells (tile-local
        indices), p each sample's row in rows (_rows_of) where it was looked up here, else None:
        the segments of them not traced before traced now (the same bits as a tile
        traced whole: the values do not depend on which were traced when). POLICY: "lazy" keeps
        what events traced (each segment traced at most once, only when read: a ski rental's
        buying a tile would trace segments no event read, and its renting would trace read ones
        again); "second" traces a tile whole on its second read, "always" on its first; "never"
        keeps nothing (every event traces what it reads)."""
        self.used[key] = next(_TICK)
        got = self.tiles.get(key)
        if got is not None:
            return got + (None,)
        pol = self.policy
        if pol == "always" or (pol == "second" and key in self.part):
            self.trace([key])
            return self.tiles[key] + (None,)
        P = self.part.get(key)
        if P is None:
            P = self._new_part(key, idx if pol == "never" else None)
            if pol != "never":
                self.part[key] = P
        p = self._rows_of(P[0], idx, self.lv.n)
        sel = p[p >= 0]
        mask = np.packbits(np.isin(np.arange(self.tile**2), cells))
        rays = self._fill(key, P, sel, mask)
        self.event_rays += rays
        if rays and TRIM_TRACED:
            release_free_memory()
        return P[0], P[1], p

    # -- an event -----------------------------------------------------------------------------------
    def layout(self, rings, L=None):
        """(rings2d, L, tile keys, c0, c1, ov) of a shape on the plane: its rings in the plane's
        frame, the cell level (by default level_for its area), the tiles its box overlaps, its
        block of cells [c0, c1) (x, y) and their overlap areas ov (nby, nbx)."""
        rings2d = [self.to2d(r) for r in rings]
        if L is None:
            L = self.level_for(ring_area(rings2d))
        h = self.cell(L)
        allr = np.concatenate(rings2d)
        c0 = np.floor(allr.min(0) / h).astype(int)
        c1 = np.floor(allr.max(0) / h).astype(int) + 1
        ov = cell_overlaps(rings2d, c0[0] * h, c0[1] * h, h, *(c1 - c0))
        return rings2d, L, self.tiles_of(rings2d, L), c0, c1, ov

    def visible(self, rings, idx, L=None):
        """(len(idx),) the visible fraction of a shape (rings (M, 3) on the plane, outer first) from
        samples idx (sorted; the caller's culls: in front of the shape, a vertex above the horizon),
        by the bits of the cells it overlaps: stored tiles read, the others' segments traced (_tile).
        L: the cell level (by default level_for the shape's area)."""
        rings2d, L, keys, c0, c1, ov = self.layout(rings, L)
        h = self.cell(L)
        idx = np.asarray(idx).astype(np.int32)  # (the tiles' rows' type: no casts in the look-ups)
        nbx, nby = c1 - c0
        ci, cj = np.arange(c0[0], c1[0]), np.arange(c0[1], c1[1])
        over = ov > 0
        full = ov >= h * h * (1 - 1e-9)
        part = over & ~full
        V = np.zeros(len(idx))
        # per tile, its cells the shape overlaps as packed bytes: a sample's counts of stored and of
        # visible overlapped cells by a popcount of its bytes (no unpacking but for the mixed ones)
        # (a tile of TILE 4 holds a row's 16 bits in one uint16: its popcount is one look-up)
        masks, tiles, look, wide = [], {}, {}, self.tile == 4
        for key in keys:
            m = self._cells_of(key, c0, over)
            if m.any():
                rows, bits, p = self._tile(key, idx, np.flatnonzero(m.ravel()))
                tiles[key] = (rows, bits)
                if len(rows):
                    mb = np.packbits(m.ravel())
                    masks.append((key, mb.view(np.uint16)[0] if wide else mb, int(m.sum())))
                    # each sample's row in the tile (-1: not stored), looked up once per event
                    look[key] = self._rows_of(rows, idx, self.lv.n) if p is None else p
        step = max(1, CHUNK // max(nbx * nby, 1))
        boxes = None
        for s0 in range(0, len(idx), step):
            sl = slice(s0, s0 + step)
            rows = idx[sl]
            n1 = np.zeros(len(rows), np.int64)
            ns = np.zeros(len(rows), np.int64)
            for key, m, cnt in masks:
                p = look[key][sl]
                f = np.flatnonzero(p >= 0)
                b = tiles[key][1]
                if wide:  # (the same counts: a byte's bits are a uint16's, either byte order)
                    n1[f] += _POP16[np.ascontiguousarray(b).view(np.uint16)[p[f], 0] & m]
                else:
                    n1[f] += _POP[b[p[f]] & m].sum(1, dtype=np.int64)
                ns[f] += cnt
            Vc = np.zeros(len(rows))
            Vc[(n1 == ns) & (ns > 0)] = 1.0  # every stored overlapped bit 1: exactly 1 (0: exactly 0)
            mix = np.flatnonzero((n1 > 0) & (n1 < ns))
            if len(mix):
                at = {key: look[key][sl][mix] for key, _, _ in masks}
                vis = self.block(list(at), rows[mix], c0, c1, at, tiles)[0]
                if boxes is None and part.any():  # (once an event, where a ratio tests points)
                    pj, pi = np.nonzero(part)
                    boxes = inside_boxes(rings2d, np.column_stack([ci[pi], cj[pj]]) * h, h)
                Vc[mix] = self._ratio(rows[mix], L, ci, cj, full, part, ov, vis, rings2d, boxes)
            V[sl] = Vc
        return V

    @staticmethod
    def _rows_of(trows, idx, n=0):
        """(len(idx),) each sample's row in a tile's rows trows, -1 where the tile has no row. n: the
        level's sample count: where idx holds at least n / 16 samples, by a map over the level's
        samples (a look-up each, not a binary search: the same answer, x0.3-0.45 of its CPU at 100k)."""
        if not len(trows):
            return np.full(len(idx), -1, np.int64)
        if 16 * len(idx) >= n > 0:
            inv = np.full(n, -1, np.int64)
            inv[trows] = np.arange(len(trows))
            return inv[idx]
        pos = np.minimum(np.searchsorted(trows, idx), len(trows) - 1)
        return np.where(trows[pos] == idx, pos, -1)

    def block(self, keys, rows, c0, c1, at=None, tiles=None):
        """(vis, stored) (len(rows), c1 - c0 reversed) bool: the stored bits of samples rows over
        the cells [c0, c1) (x, y) from the tiles keys (of `tiles`, by default the stored ones), and
        where a tile stores the sample (at: the samples' rows in each tile, _rows_of, if known)."""
        tiles = self.tiles if tiles is None else tiles
        nbx, nby = c1 - c0
        nl = len(rows)
        vis = np.zeros((nl, nby, nbx), bool)
        stored = np.zeros((nl, nby, nbx), bool)
        for key in keys:
            if key not in tiles:  # (a tile of the box none of whose cells the shape overlaps)
                continue
            trows, tbits = tiles[key]
            w = self._window(key, c0, nbx, nby)
            if w is None or not len(trows):
                continue
            p = at[key] if at is not None else self._rows_of(trows, rows)
            f = np.flatnonzero(p >= 0)
            t = (
                np.unpackbits(tbits[p[f]], axis=1, count=self.tile * self.tile)
                .reshape(-1, self.tile, self.tile)
                .astype(bool)
            )
            vis[(f, *w[0])] = t[(slice(None), *w[1])]
            stored[(f, *w[0])] = True
        return vis, stored

    def _ratio(self, rows, L, ci, cj, full, part, ov, vis, rings2d, boxes=None):
        """The pin ratio at samples rows (each its block of bits vis (l, nby, nbx)); boxes: the
        partly covered cells' inside_boxes (the points outside them are outside the outline: only
        the others take the even-odd test)."""
        lv, h = self.lv, self.cell(L)
        r = self.shifts(L, rows)
        a = (ci[None] + r[:, :1]) * h  # (l, i): the points' 2D coordinates, as traced
        b = (cj[None] + r[:, 1:]) * h  # (l, j)
        x2 = self.to2d(lv.points[rows])
        z = (lv.points[rows] - self.o) @ self.n
        N = lv.normals[rows]
        nu, nv, nw = N @ self.U, N @ self.V, N @ self.n
        # float32 from here, lengths in cells (the points' offsets from the sample in float64 above:
        # no cancellation; a common factor h^3 per sample, out of the ratio; no float32 overflow
        # at any scene scale)
        f32 = np.float32
        da, db = ((a - x2[:, :1]) / h).astype(f32), ((b - x2[:, 1:]) / h).astype(f32)
        z = (z / h).astype(f32)
        nu, nv, nw = (v.astype(f32) for v in (nu, nv, nw))
        # cos_x r = d . N with d = da U + db V - z n; r^2 = da^2 + db^2 + z^2 (separable terms)
        cx = (da * nu[:, None])[:, None, :] + (db * nv[:, None] - (z * nw)[:, None])[:, :, None]
        r2 = (da * da)[:, None, :] + (db * db + (z * z)[:, None])[:, :, None]
        k = np.maximum(cx, 0) / (r2 * r2)
        m = np.broadcast_to(full[None], k.shape)
        if part.any():
            pj, pi = np.nonzero(part)  # the partly covered cells: their points tested (even-odd)
            qa, qb = a[:, pi], b[:, pj]  # (l, P) each
            m = m.copy()
            if boxes is None:
                m[:, pj, pi] = inside_rings(np.stack([qa, qb], -1), rings2d)
            else:  # (by component: no (l, P, 2) stack for the boxes' test)
                (xlo, ylo), (xhi, yhi) = boxes[0].T, boxes[1].T
                near = (qa >= xlo) & (qa <= xhi) & (qb >= ylo) & (qb <= yhi)
                ins = np.zeros(near.shape, bool)
                ins[near] = inside_rings(np.stack([qa[near], qb[near]], -1), rings2d)
                m[:, pj, pi] = ins
        w = k * m
        ws = w.sum((1, 2))
        wv = (w * vis).sum((1, 2))
        out = np.where(ws > 0, wv / np.where(ws > 0, ws, 1), 1.0)
        none = np.flatnonzero(ws <= 0)  # no point inside with weight: the overlap-weighted ratio
        if len(none):
            wo = k[none] * ov[None]
            s = wo.sum((1, 2))
            out[none] = np.where(s > 0, (wo * vis[none]).sum((1, 2)) / np.where(s > 0, s, 1), 1.0)
        return out

    def direct(self, rings, idx, F, L=None):
        """(len(idx),) float64 F x V: the shape's direct light at samples idx from their exact
        unoccluded form factors F (main's shape_form_factors) and the stored visibility."""
        return np.asarray(F, np.float64) * self.visible(rings, idx, L)

    def light(self, em, L=None):
        """(n,) float32 the unit direct light of a light shape's Emitter em (its rings on this
        plane) at every sample of the level: main's culls (DirectLight.direct_batch), the stored
        visibility, the form factor only where it is not 0 (as main)."""
        from ..events.direct import shape_form_factors

        lv = self.lv
        x, nx = lv.points, lv.normals
        out = np.zeros(lv.n)
        i = culled(lv, em)
        if len(i):
            V = self.visible(em.rings, i, L)
            seen = np.flatnonzero(V != 0)
            F = shape_form_factors(x[i[seen]], nx[i[seen]], em.rings, em.corners, em.nv, lv.eps)
            out[i[seen]] = F * V[seen]
        return out.astype(np.float32)

    # -- on disk (not yet in the precompute file) ----------------------------------------------------
    def state(self):
        """The store as arrays (for a precompute file): its frame, its rule and every tile, a tile's
        rows as a bitmap over the level's samples (n / 8 bytes: a fifth of int32 rows or less)."""
        keys = sorted(self.tiles)
        C8 = self.tile * self.tile // 8
        n = self.lv.n
        masks = np.zeros((len(keys), (n + 7) // 8), np.uint8)
        for k, key in enumerate(keys):
            m = np.zeros(n, bool)
            m[self.tiles[key][0]] = True
            masks[k] = np.packbits(m)
        return dict(
            frame=np.stack([self.n, self.o, self.U, self.V]),
            rule=np.array([self.points, self.tile, self.base, n]),
            keys=np.array(keys, np.int64).reshape(-1, 3),
            rows=masks,
            bits=np.concatenate([self.tiles[k][1] for k in keys] or [np.zeros((0, C8), np.uint8)]),
        )

    @classmethod
    def from_state(cls, lv, a, shafts=None, threads=None, policy=None):
        """The store of state() on the level lv (the same samples: its unit must give the same base,
        its sample count the same), its tiles as saved (no rays), new tiles traced as before."""
        n, o, U, V = (np.array(v) for v in a["frame"])
        points, tile, base, count = a["rule"]
        H = cls(lv, n, o, int(points), shafts, threads, int(tile), policy)
        if H.base != base or lv.n != count:
            raise ValueError("a host visibility store of another scale or other samples")
        H.n, H.o, H.U, H.V = n, o, U, V  # (bit for bit as saved)
        at = 0
        for k, key in enumerate(map(tuple, np.asarray(a["keys"]).tolist())):
            rows = np.flatnonzero(np.unpackbits(a["rows"][k], count=lv.n)).astype(np.int32)
            H.tiles[key] = (rows, np.array(a["bits"][at : at + len(rows)]))
            at += len(rows)
        return H

    @property
    def nbytes(self):
        """The bytes of the tiles traced whole and of the parts events traced of the others."""
        whole = sum(r.nbytes + b.nbytes for r, b in self.tiles.values())
        return whole + sum(a.nbytes for P in self.part.values() for a in P)


def culled(lv, em):
    """The samples of level lv main's culls keep for Emitter em (DirectLight.direct_batch): not
    dark, in front of the shape by eps, a vertex above their horizon by eps. (The horizon's max is
    taken before subtracting x . n_x: rounding is monotonic, so max(v - c) = max(v) - c exactly,
    without the (samples, vertices) differences. x . n_x is the level's, once (_x_dot_n); the max
    once per run of samples with the same normal (a second level's leaf's k x k, a flat face's
    samples): each sample's own products either way, 1/9 of the second level's rows at 100k.)"""
    x, nx = lv.points, lv.normals
    i = np.flatnonzero(~lv.dark & ((x - em.point) @ em.normal > lv.eps))
    ni = nx[i]
    head = np.ones(len(i), bool)
    head[1:] = (ni[1:] != ni[:-1]).any(1)
    at = np.flatnonzero(head)
    top = np.repeat((ni[at] @ em.verts.T).max(1), np.diff(np.append(at, len(i))))
    return i[top - _x_dot_n(lv)[i] > lv.eps]


def _x_dot_n(lv):
    """(n,) each sample's x . n_x at level lv (culled's), kept on the level for its points and
    normals (each row's own einsum: the same values as on any subset of rows)."""
    got = lv.__dict__.get("_xdotn")
    if got is None or got[0] is not lv.points or got[1] is not lv.normals:
        got = lv._xdotn = (lv.points, lv.normals, np.einsum("mk,mk->m", lv.points, lv.normals))
    return got[2]


def points_for(lv):
    """The stored points per shape at a gather level: POINTS at the top level, POINTS_SECOND at a
    second level (_leaf_nodes), at the draft preset's 16 / 8 shadow rays, in proportion to the
    level's own (medium's and high's 32 / 64 rays get 2x / 4x the points, as their rays)."""
    second = getattr(lv, "_leaf_nodes", None) is not None
    return max(1, round((POINTS_SECOND / 8 if second else POINTS / 16) * lv.shadow_rays))


def store_for(lv, normal, point, points):
    """The level's HostVisibility of the plane (normal, point), made on first use and kept on the
    level (lv._host_stores), keyed as events.direct.clear_shafts keys its grids (the normal to
    1e-12, the offset to 1e-3 eps): shapes on one plane share it whatever patch or point they name
    it by, and its frame is made from the key alone (the rounded normal, the rounded offset), so
    it is the same whichever shape asked first."""
    margin = 1e-3 * lv.eps
    nq = np.round(np.asarray(normal, np.float64), 12) + 0.0  # + 0.0: no -0.0
    return _store_at(lv, (nq.tobytes(), round(float(np.asarray(point, np.float64) @ nq) / margin), points))


def _store_at(lv, key):
    """The level's HostVisibility for a store_for key, made empty if it has none (its frame from
    the key alone)."""
    from ..events.direct import clear_shafts

    stores = lv.__dict__.setdefault("_host_stores", {})
    H = stores.get(key)
    if H is None:
        nq = np.frombuffer(key[0], np.float64)
        n = nq / np.linalg.norm(nq)
        p = (key[1] * (1e-3 * lv.eps)) * n
        H = stores[key] = HostVisibility(lv, n, p, key[2], shafts=clear_shafts(lv.system, p, n))
    return H


# -- kept across bakes, trimmed (session 30 hvkeep) -----------------------------------------------------


def params():
    """The module's settings a kept store was made under (the samples are the precompute's)."""
    return dict(
        points=POINTS, points_second=POINTS_SECOND, stream=STREAM, tile=TILE, base=BASE, max_level=MAX_LEVEL
    )


def host_levels(gather):
    """The levels of a final gather that keep host stores, in a fixed order: each level (top first,
    then FinalGather.second) followed by its slot samples' facing copy (its _slot's f), if any."""
    out = []
    while gather is not None:
        out.append(gather)
        slot = getattr(gather, "_slot", None)
        if slot is not None:
            out.append(slot["f"])
        gather = getattr(gather, "second", None)
    return out


def _tile_bytes(H, key):
    t = H.tiles.get(key)
    return sum(a.nbytes for a in (t if t is not None else H.part[key]))


def trim(lv, extra=None, cap=None):
    """Keep the stores of a level (and `extra`, a store not made by store_for) within cap bytes
    (MEMORY, at least TRIM_FLOOR tiles of the level's samples): above it, the tiles (whole or
    events' parts) read longest ago are dropped until 3/4 of cap remain (not every new tile trims).
    By tile, least recently read: a tile is the unit that is read and kept, and a moving shape
    reads next the tiles it read last, where a rule by plane or by event would drop the current
    shape's tiles with the rest. Speed only: a dropped tile's segments are traced again when read,
    with the same bits. Returns the bytes dropped."""
    row = 5 + 2 * (TILE * TILE // 8)  # a row's bytes in a part (rows, bits, known, tested)
    cap = max(MEMORY if cap is None else cap, TRIM_FLOOR * row * lv.n)
    stores = list(lv.__dict__.get("_host_stores", {}).values())
    if extra is not None and all(H is not extra for H in stores):
        stores.append(extra)
    items = [
        (H.used.get(k, -1), i, k, _tile_bytes(H, k))
        for i, H in enumerate(stores)
        for k in (*H.tiles, *H.part)
    ]
    total = sum(it[3] for it in items)
    if total <= cap:
        return 0
    dropped = 0
    for _, i, k, b in sorted(items, key=lambda it: it[:2]):
        if total <= 3 * cap // 4:
            break
        H = stores[i]
        H.tiles.pop(k, None)
        H.part.pop(k, None)
        H.used.pop(k, None)
        total, dropped = total - b, dropped + b
    return dropped


def kept(gather, cap=None):
    """(arrays, info) of every level's stores for the precompute's side file (io/precompute.keep):
    the tiles read most recently first, up to cap bytes as held in memory (DISK), saved oldest
    first (restore_kept gives them their read order back). A tile: its rows as a bitmap over the
    level's samples, per row its bits, which are known and whether its shaft was tested (a whole
    tile: all). info: tiles and bytes saved, tiles left out, and the rays traced into the stores
    since they were made or restored (0: nothing new to save)."""
    cap = DISK if cap is None else cap
    lvls = host_levels(gather)
    C8 = TILE * TILE // 8
    items, rays = [], 0
    for li, lv in enumerate(lvls):
        for skey, H in lv.__dict__.get("_host_stores", {}).items():
            rays += H.rays + H.event_rays
            if H.tile == TILE:
                items += [(H.used.get(k, -1), li, skey, H, k) for k in (*H.tiles, *H.part)]
    items.sort(key=lambda it: it[:2], reverse=True)
    chosen, total = [], 0
    for it in items:
        b = _tile_bytes(it[3], it[4])  # (as held once loaded: what the file's arrays restore to)
        if total + b > cap:
            break
        chosen.append(it)
        total += b
    chosen.reverse()
    skeys, sinfo, snormal, tinfo, rows, bits, known, tested = {}, [], [], [], [], [], [], []
    for _, li, skey, H, k in chosen:
        s = skeys.get((li, skey))
        if s is None:
            s = skeys[(li, skey)] = len(sinfo)
            sinfo.append((li, skey[1], skey[2]))
            snormal.append(np.frombuffer(skey[0], np.float64))
        whole = k in H.tiles
        r, b, kn, te = H.tiles[k] + (None, None) if whole else H.part[k]
        m = np.zeros(H.lv.n, bool)
        m[r] = True
        tinfo.append((s, *k, whole))
        rows.append(np.packbits(m))
        bits.append(b)
        known.append(np.full(b.shape, 255, np.uint8) if whole else kn)
        tested.append(np.ones(len(r), bool) if whole else te)
    cat = lambda a, shape, t: np.concatenate(a) if a else np.zeros(shape, t)  # noqa: E731
    arrays = dict(
        level_n=np.array([lv.n for lv in lvls], np.int64),
        store_info=np.array(sinfo, np.int64).reshape(-1, 3),
        store_normal=np.array(snormal, np.float64).reshape(-1, 3),
        tile_info=np.array(tinfo, np.int64).reshape(-1, 5),
        rows=cat(rows, 0, np.uint8),
        bits=cat(bits, (0, C8), np.uint8),
        known=cat(known, (0, C8), np.uint8),
        tested=cat(tested, 0, bool),
    )
    return arrays, dict(tiles=len(chosen), bytes=total, left_out=len(items) - len(chosen), rays=rays)


def restore_kept(gather, a):
    """Put kept()'s stores back on the gather's levels (its samples must be those they were traced
    from: the caller checks the precompute they belong to), each tile read in its saved order (the
    newest last). Returns the tiles restored; raises ValueError where they do not fit the gather."""
    lvls = host_levels(gather)
    if list(a["level_n"]) != [lv.n for lv in lvls]:
        raise ValueError("the final gather's levels have other samples")
    stores = []
    for (li, off, pts), nq in zip(a["store_info"].tolist(), a["store_normal"]):
        stores.append(_store_at(lvls[li], (np.ascontiguousarray(nq, np.float64).tobytes(), off, pts)))
    ar = am = 0
    for s, L, ti, tj, whole in a["tile_info"].tolist():
        H = stores[s]
        nb = (H.lv.n + 7) // 8
        r = np.flatnonzero(np.unpackbits(a["rows"][am : am + nb], count=H.lv.n)).astype(np.int32)
        sl = slice(ar, ar + len(r))
        am, ar = am + nb, ar + len(r)
        key = (L, ti, tj)
        if whole:
            H.tiles[key] = (r, a["bits"][sl].copy())
        else:
            H.part[key] = [r, a["bits"][sl].copy(), a["known"][sl].copy(), a["tested"][sl].copy()]
        H.used[key] = next(_TICK)
    if am != len(a["rows"]) or not ar == len(a["bits"]) == len(a["known"]) == len(a["tested"]):
        raise ValueError("the kept tiles' arrays do not add up")
    return len(a["tile_info"])
