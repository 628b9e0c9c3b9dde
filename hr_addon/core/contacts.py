"""Contacts: which parts of a surface are covered by geometry touching it (a block standing on a
floor, a book on a board, a light panel a hair below the ceiling), so they get no light.

Meshes that touch without being cut leave the covered part of the receiver in the model. Its
points see nothing (every ray from them hits the covering object), but HR's push-down hands them
the light of links made at coarser levels, and pulls it back into the visible part: light leaks
under the block and the band beside it comes out too dark. This module finds covered points
geometrically, without rays, in each receiver plane:

- covering faces: polygons parallel to the receiver within `gap` in front of it, facing it (a
  box's bottom on the floor) or facing the same way (the light panel below the ceiling);
- crossing chains: where the faces of another connected piece of mesh meet or cross the
  receiver's plane (snapped within `gap`), as segments oriented by the faces' normals
  (s = m x n). A solid with outward normals standing on, or sunk into, the receiver gives a
  closed chain of generalised winding number -1 inside its footprint (open-bottomed blocks
  included); a room's inward walls give +1, an isolated wall or a sphere's tangent point at most
  +-1/2 in magnitude, so only winding < -1/2 counts as covered.

Pieces are connected by shared vertices; each chain's winding is summed on its own, so a room's
+1 never cancels a block's -1. Everything is vectorised over (point, chain segment) pairs found
through per-chain bounding boxes, so the cost follows the number of contacts, not all pairs.
"""

import copy

import numpy as np

from .boxes import box_grid, box_pairs, csr_rows, points_in_boxes, row_groups, sorted_index
from .formfactor import row_range
from .geometry import components
from .parallel import batch_map, ranges
from .planes import frames, plane_ids
from .slots import SlotMouths

# points per batch of the covered test on threads (core.parallel): fixed, never by the thread count;
# every point's answer is its own, so the batches do not change it
POINT_BATCH = 1 << 15
# (plane, occluder patch) pairs per chunk of the chain segments: the segments' order follows the
# chunks, so this is fixed (it was the serial code's chunk: the same chains, bit for bit)
SEGMENT_CHUNK = 500_000
# pairs per step of a chunk's near test (_segments): its temporaries stay in the cache
NEAR_STEP = 1 << 16
# box_chains: parts per side of a box whose chains are listed apart (a point tests its part's)
BOX_CELLS = 2


class Contacts(SlotMouths):
    """Covered-point test for points on the patches of `patches` (geometry.Patches).

    gap: how far (scene units) in front of a receiver a face may be and still cover it, and how
    close to its plane an edge or vertex is taken as lying on it. threads: the build's box pairs
    (boxes.box_pairs) and chain segments on threads (None: serial)."""

    def __init__(self, patches, gap, threads=None):
        pt = self.patches = patches
        K = len(pt.nv)
        self.gap = float(gap)
        size = float(np.sqrt(pt.area.sum())) or 1.0
        self.pen = 1e-6 * size  # a face this far behind a receiver (or level with it) is not in front
        # a gap narrower than this is a contact, not a slot (gather samples keep about this far inside
        # their patch: none could stand in it)
        self.min_gap = 5e-5 * size
        self.plane = plane_ids(pt.normal, pt.corners[:, 0], size)
        G = int(self.plane.max()) + 1 if K else 0
        first = np.zeros(G, np.int64)
        first[self.plane[::-1]] = np.arange(K)[::-1]
        self.n_g, self.o_g = pt.normal[first], pt.corners[first, 0]
        self.u_g, self.v_g = frames(self.n_g) if G else (np.zeros((0, 3)), np.zeros((0, 3)))
        self.piece = self._pieces(size)
        self._build(threads)

    def _pieces(self, size):
        """Connected pieces: patches sharing an input vertex, or a corner position within one
        object (faces modelled apart, like the Cornell blocks', are one solid)."""
        pt = self.patches
        jj, kk = np.nonzero(pt.vert_index >= 0)
        q = np.round(pt.corners[jj, kk] / (1e-5 * size)).astype(np.int64)
        ii, jn = [], []
        for key in (pt.vert_index[jj, kk][:, None], np.column_stack([pt.object_id[jj], q])):
            inv = row_groups(key)[0]
            order = np.argsort(inv, kind="stable")
            same = inv[order][1:] == inv[order][:-1]
            ii.append(jj[order][:-1][same])
            jn.append(jj[order][1:][same])
        return components(len(pt.nv), np.concatenate(ii), np.concatenate(jn))

    # -- chains per receiver plane --------------------------------------------------------------------
    def _segments(self, gi, t):
        """Chain segments (plane, a2d, b2d, chain id, signed, piece, height, wall) of occluder
        patches t in the planes gi (height: how far in front of the plane the segment really is:
        a covering face's distance, a crossing chain's snapped corners'; 0 where a solid touches or
        crosses; wall: the patch whose reflectance stands for the gap's other wall, -1: black)."""
        pt, g = self.patches, self.gap
        c = pt.corners
        cc = c.transpose(1, 2, 0).reshape(12, -1)  # row 3 k + j: corner k, axis j
        keep = []
        # the pairs near enough, by steps of NEAR_STEP pairs (most are not: only their rows go on;
        # each row is its own, so the same rows in the same order as of the whole chunk at once,
        # whose (12, 500k) temporaries were faulted in fresh per chunk: issue 23, session 36)
        for i in range(0, max(len(t), 1), NEAR_STEP):
            gs, ts = gi[i : i + NEAR_STEP], t[i : i + NEAR_STEP]
            # (P, 4) corner heights over the plane: einsum("pkj,pj->pk", c[t] - o[:, None], n) by
            # rows per corner and coordinate (its order, (x + z) + y, from +0: the same bits), 1.6x
            # faster
            ct = np.take(cc, ts, 1)
            oT, nT = np.ascontiguousarray(self.o_g[gs].T), np.ascontiguousarray(self.n_g[gs].T)
            d = np.empty((4, len(ts)))
            for k in range(4):
                x, y, z = (ct[3 * k + j] - oT[j] for j in range(3))
                d[k] = (x * nT[0] + z * nT[2]) + y * nT[1]
            d = np.ascontiguousarray(d.T) + 0.0
            tri = pt.nv[ts] == 3
            d[tri, 3] = d[tri, 2]
            mn, mx = row_range(d)
            near = np.flatnonzero((mn <= g) & (mx >= -g))
            keep.append((i + near, d[near], mn[near], mx[near]))
        near, d, mn, mx = (np.concatenate(x) for x in zip(*keep))
        gi, t = gi[near], t[near]
        nv, n = pt.nv[t], self.n_g[gi]
        cosang = np.einsum("ij,ij->i", pt.normal[t], n)
        flat = (np.abs(cosang) > 1 - 1e-6) & (mx - mn <= g)
        cover = flat & (((cosang < 0) & (d.mean(1) >= -self.pen)) | ((cosang > 0) & (mn > self.pen)))
        cover &= mx <= g
        segs = []  # (plane, a2d, b2d, chain, signed, piece, height, wall)
        # covering faces: their outline as a chain of its own, |winding| = 1 inside
        cv = np.flatnonzero(cover)
        if len(cv):
            p2 = self._to2d(gi[cv], c[t[cv]])  # (C, 4, 2)
            pc = self.piece[t[cv]]
            nxt = np.array([1, 2, 3, 0])
            for k in range(4):
                use = (k < nv[cv]) if k < 3 else (nv[cv] == 4)
                kn = np.where((k == 2) & (nv[cv] == 3), 0, nxt[k])
                a = p2[np.flatnonzero(use), k]
                b = p2[np.flatnonzero(use), kn[use]]
                hgt = np.maximum(d[cv][use].mean(1), 0.0)
                # the slot's other wall: the covering face if it faces the receiver, else its back
                # (black: a one-sided surface reflects nothing behind it)
                wall = np.where(cosang[cv][use] < 0, t[cv][use], -1)
                segs.append((gi[cv][use], a, b, t[cv][use], np.zeros(use.sum(), bool), pc[use], hgt, wall))
        # crossing chains: the zero set of the snapped heights on each polygon reaching in front of
        # the plane (a thick table top's own sides, below its top, are not)
        cr = np.flatnonzero(~flat & (mx > g))
        if len(cr):
            ds = np.where(np.abs(d[cr]) <= g, 0.0, d[cr])
            P3 = c[t[cr]]
            cand = np.full((len(cr), 8, 3), np.nan)
            cand_h = np.zeros((len(cr), 8))  # true height over the plane (snapped corners: up to gap)
            for k in range(4):
                kn = np.where((k == 2) & (nv[cr] == 3), 0, (k + 1) % 4)
                valid = (k < nv[cr]) if k < 3 else (nv[cr] == 4)
                dk, dn = ds[:, k], ds[np.arange(len(cr)), kn]
                on = valid & (dk == 0)
                cand[on, 2 * k] = P3[on, k]
                cand_h[on, 2 * k] = np.maximum(d[cr][on, k], 0.0)
                x = valid & (dk * dn < 0)
                tt = (dk / np.where(x, dk - dn, 1.0))[:, None]
                pk, pn = P3[:, k], P3[np.arange(len(cr)), kn]
                cand[x, 2 * k + 1] = (pk + tt * (pn - pk))[x]
            s_dir = np.cross(pt.normal[t[cr]], n[cr])  # chain direction m x n
            proj = np.einsum("pkj,pj->pk", cand, s_dir)
            okp = ~np.isnan(proj)
            has = okp.sum(1) >= 2
            lo_k = np.where(okp, proj, np.inf).argmin(1)
            hi_k = np.where(okp, proj, -np.inf).argmax(1)
            r = np.arange(len(cr))
            a3, b3 = cand[r, lo_k], cand[r, hi_k]
            long = has & (np.linalg.norm(b3 - a3, axis=1) > self.pen)
            sel = np.flatnonzero(long)
            if len(sel):
                a2 = self._to2d(gi[cr][sel], a3[sel][:, None])[:, 0]
                b2 = self._to2d(gi[cr][sel], b3[sel][:, None])[:, 0]
                pc = self.piece[t[cr][sel]]
                hgt = (cand_h[r, lo_k] + cand_h[r, hi_k])[sel] / 2  # > 0: a solid near, not on, the plane
                segs.append((gi[cr][sel], a2, b2, -1 - pc, np.ones(len(sel), bool), pc, hgt, t[cr][sel]))
        return segs

    def _build(self, threads=None):
        pt = self.patches
        c = pt.corners
        lo, hi = c.min(1), c.max(1)
        g = self.gap
        K, plane = len(pt.nv), self.plane.astype(np.int64)

        def key(i, j):  # (plane, occluder patch) of a patch and another one off its plane
            keep = (i != j) & (plane[i] != plane[j])
            return plane[i[keep]] * K + j[keep]

        # (plane, occluder patch), once each: keyed inside box_pairs' blocks (the same sorted keys
        # as of all its pairs, without their unique)
        pair = box_pairs(lo - g, hi + g, lo, hi, threads=threads, key=key)
        gi, t = pair // K, pair % K
        # bounded temporaries at any scene size; each chunk's segments are its own (on threads: the
        # same chunks, so the same segments in the same order)
        chunks = ranges(len(t), SEGMENT_CHUNK)
        if threads is None:
            parts = [self._segments(gi[i:j], t[i:j]) for i, j in chunks]
        else:
            parts = batch_map(lambda i, j: self._segments(gi[i:j], t[i:j]), chunks, threads)
        segs = [x for part in parts for x in part]
        if segs:
            g_, a_, b_, ch_, sg_, pc_, hg_, op_ = (np.concatenate(x) for x in zip(*segs))
        else:
            g_, ch_, pc_, op_ = (np.zeros(0, np.int64) for _ in range(4))
            sg_, a_, b_, hg_ = np.zeros(0, bool), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
        # chain = (plane, piece or covering patch): sort segments by chain
        key = row_groups(np.column_stack([g_, ch_]))[0]
        order = np.argsort(key, kind="stable")
        self.seg_a, self.seg_b, self.seg_chain = a_[order], b_[order], key[order]
        nC = int(key.max()) + 1 if len(key) else 0
        self.chain_start = np.searchsorted(self.seg_chain, np.arange(nC + 1))
        first = self.chain_start[:-1]
        self.chain_plane = g_[order][first] if nC else np.zeros(0, np.int64)
        self.chain_signed = sg_[order][first] if nC else np.zeros(0, bool)
        self.chain_piece = pc_[order][first] if nC else np.zeros(0, np.int64)
        self.seg_height = hg_[order]
        self.seg_wall = op_[order]
        self.seg_open = self._open_edges(g_[order], sg_[order])
        # a slot's mouth: an open edge of a gap (height > 0); close_mouths() shuts those a surface
        # closes (a book's bottom edge on its board)
        self.seg_mouth = self.seg_open & (self.seg_height > self.min_gap)
        self._mouth = None  # the slots' mouths (slot_mouths()), built when first needed
        self._mouths_probed = False
        # a chain whose segments all touch the plane (a box standing on the floor) makes no slot
        # under it, even where another chain's slot reaches; one standing off it anywhere (a
        # tilted block) may
        self.chain_gap = np.zeros(nC)
        np.maximum.at(self.chain_gap, self.seg_chain, self.seg_height)
        both = np.concatenate([self.seg_a, self.seg_b])
        ch2 = np.concatenate([self.seg_chain, self.seg_chain])
        # chain boxes in the plane's frame (a third coordinate 0, as box_pairs takes 3D boxes)
        self.chain_lo, self.chain_hi = np.full((nC, 3), np.inf), np.full((nC, 3), -np.inf)
        self.chain_lo[:, 2] = self.chain_hi[:, 2] = 0.0
        for k in range(2):
            np.minimum.at(self.chain_lo[:, k], ch2, both[:, k])
            np.maximum.at(self.chain_hi[:, k], ch2, both[:, k])
        # receivers that have a chain over them
        self.receivers = self._receivers()

    def _open_edges(self, plane, signed):
        """True for the segments through which light can enter a gap between receiver and occluder:
        every crossing chain's, and a covering face's edges except those shared with another
        covering face in the same plane (a subdivided face's inner edges)."""
        out = np.ones(len(signed), bool)
        i = np.flatnonzero(~signed)
        if len(i):
            q = np.round(np.concatenate([self.seg_a[i], self.seg_b[i]], 1) / max(self.pen, 1e-12))
            q = q.astype(np.int64)
            fwd = np.column_stack([plane[i], q])
            rev = np.column_stack([plane[i], q[:, 2:], q[:, :2]])
            inv, cnt = row_groups(np.concatenate([fwd, rev]))
            out[i[cnt[inv[: len(i)]] > 1]] = False
        return out

    def _to2d(self, gi, p):
        """Points p (N, M, 3) into the frame of planes gi (N,): (N, M, 2)."""
        q = p - np.take(self.o_g, gi, 0)[:, None]  # (rows by take: 3x faster than fancy indexing)
        return np.stack(
            [
                np.einsum("nmj,nj->nm", q, np.take(self.u_g, gi, 0)),
                np.einsum("nmj,nj->nm", q, np.take(self.v_g, gi, 0)),
            ],
            -1,
        )

    def _receivers(self):
        """Patches whose 2D box meets a chain box of their plane."""
        pt = self.patches
        K = len(pt.nv)
        self.touch = np.zeros(0, np.int64)
        if not len(self.chain_plane):
            return np.zeros(0, np.int64)
        p2 = self._to2d(self.plane, pt.corners)
        z = np.zeros((K, 1))
        lo, hi = np.concatenate([p2.min(1), z], 1), np.concatenate([p2.max(1), z], 1)
        i, ch = box_pairs(lo, hi, self.chain_lo, self.chain_hi, self.plane, self.chain_plane)
        # (receiver patch, touching piece) keys: their links are refined (Refiner.refine)
        self.touch = np.unique(i * K + self.chain_piece[ch])
        return np.unique(i)

    def touching(self, p, q):
        """True where patch q belongs to a piece with a contact over patch p, or the reverse."""
        K = len(self.patches.nv)
        return (sorted_index(self.touch, p * K + self.piece[q]) >= 0) | (
            sorted_index(self.touch, q * K + self.piece[p]) >= 0
        )

    @property
    def any(self):
        return len(self.receivers) > 0

    # -- the covered-point test -----------------------------------------------------------------------
    def covered(
        self, points, patch, budget=4_000_000, chunk=200_000, open_edge=0.0, threads=None, boxes=None
    ):
        """Boolean (N,): points (N, 3) lying on patches patch (N,) are covered (in chunks of
        points: the temporaries stay small whatever the scene size). threads: batches of
        POINT_BATCH points as a batch map on that many threads (core.parallel; None: serial, in
        chunks).

        open_edge > 0: a point under a covering face or solid at a gap h in front of it (a book's
        side 2 mm from its neighbour's) counts as covered only farther than open_edge x h from the
        gap's open outline: light entering the slot between two parallel faces a distance h apart reaches a
        point at depth x with the opening's view factor (1 - x / sqrt(x^2 + h^2)) / 2, about
        h^2 / (4 x^2); its integral over the depth is h / 2, of which x > c h holds a share
        1 / (2 c) (open_edge 5: 10%). Touching faces (h = 0) and crossing solids are unchanged.

        boxes: (row (N,), table): each point's row of table (box_chains(): the chains that may
        cover a box it lies in, -1: none known), searched in place of the grid's cells (the same
        answers)."""
        points, patch = np.asarray(points, float), np.asarray(patch, np.int64)

        def part(i, j):
            return None if boxes is None else (boxes[0][i:j], boxes[1])

        if threads is not None:
            parts = batch_map(
                lambda i, j: self.covered(
                    points[i:j], patch[i:j], budget, chunk, open_edge, boxes=part(i, j)
                ),
                ranges(len(points), POINT_BATCH),
                threads,
            )
            return np.concatenate(parts) if parts else np.zeros(0, bool)
        if len(points) > chunk:
            return np.concatenate(
                [
                    self.covered(
                        points[s : s + chunk],
                        patch[s : s + chunk],
                        budget,
                        chunk,
                        open_edge,
                        boxes=part(s, s + chunk),
                    )
                    for s in range(0, len(points), chunk)
                ]
            )
        out = np.zeros(len(points), bool)
        pairs = self._pairs(points, patch, budget, open_edge, boxes)
        if pairs is not None:
            i, ch, hit, near = pairs[:4]
            out[i[hit & ~near]] = True
        return out

    def covered_pairs(self, points, patch, budget=4_000_000, chunk=200_000, boxes=None):
        """(covered(points, patch) (N,), its (point, chain) pairs (_pairs'; None: none)), one
        search for both: slots(points[c], patch[c], pairs=pairs_of(pairs, c, N)) then finds the
        covered points' slots without searching again (the same pairs: each point's in its chains'
        order, whatever other points are searched with it; the same answers). In chunks of points,
        as covered(); boxes as covered()'s."""
        points, patch = np.asarray(points, float), np.asarray(patch, np.int64)
        out = np.zeros(len(points), bool)
        parts = []
        for s in range(0, len(points), chunk):
            b = None if boxes is None else (boxes[0][s : s + chunk], boxes[1])
            p = self._pairs(points[s : s + chunk], patch[s : s + chunk], budget, boxes=b)
            if p is not None:
                i, ch, hit, near = p[:4]
                out[s + i[hit & ~near]] = True
                parts.append((s + i, ch, hit, near))
        return out, (tuple(np.concatenate(x) for x in zip(*parts)) if parts else None)

    def _table(self, key, make):
        """The table `key`, made by make() on first use from the static chains and segments (their
        box grid, component-major segments, discs: no light event changes them), in a dict that
        deep copies share (__deepcopy__): every light event's copy of a system
        (RadiositySystem.copy deep-copies the hierarchy) reuses what any of them built, where each
        built its own before (0.2 s of an AUTO event's serial CPU at 100k). One assignment:
        threads may race to make it, never half."""
        tables = self.__dict__.setdefault("_tables", {})
        got = tables.get(key)
        if got is None:
            got = tables[key] = make()
        return got

    def __deepcopy__(self, memo):
        """A deep copy sharing _table's tables (not copied: read-only)."""
        new = object.__new__(type(self))
        memo[id(self)] = new
        tables = self.__dict__.setdefault("_tables", {})
        memo[id(tables)] = tables
        for k, v in self.__dict__.items():
            new.__dict__[k] = copy.deepcopy(v, memo)
        return new

    def box_chains(self, gi, lo2, hi2, piece, cells=BOX_CELLS):
        """The chains that may cover a point in a box: covered(..., boxes=)'s table (a node's,
        for the points found in it: the hits of the gather's rays on an HR leaf). Box b (B,) in
        plane gi[b] from lo2[b] to hi2[b] (B, 2), split into cells x cells equal parts (each part's
        chains fewer than the box's), part (u, v) row b cells^2 + u cells + v: CSR rows (start,
        chains), each in chain order, of the chains of that plane whose boxes overlap the part
        (grown by pad, a thousandth of the box's size and pen, on each side: the parts a point is
        put in by rounding hold it) and whose piece is not piece[b] (_pairs' own-piece rule: the
        points' patch's piece). Returns (start, chains, lo2, hi2, cells, the entries' chain boxes
        (x lo, x hi, y lo, y hi), each (entries,): _in_boxes' test reads them in entry order)."""
        lo2, hi2 = np.asarray(lo2, float), np.asarray(hi2, float)
        B, k = len(gi), np.arange(cells)
        pad = (1e-3 * (hi2 - lo2).max(1, initial=0.0) + self.pen)[:, None, None]
        step = ((hi2 - lo2) / cells)[:, None]  # (B, 1, 2)
        u, v = np.repeat(k, cells), np.tile(k, cells)
        f0, f1 = np.stack([u, v], 1)[None], np.stack([u + 1, v + 1], 1)[None]
        clo = (lo2[:, None] + f0 * step - pad).reshape(-1, 2)
        chi = (lo2[:, None] + f1 * step + pad).reshape(-1, 2)
        z = np.zeros((len(clo), 1))
        g = np.repeat(np.asarray(gi, np.int64), cells * cells)
        r, ch = box_pairs(
            np.concatenate([clo, z], 1),
            np.concatenate([chi, z], 1),
            self.chain_lo,
            self.chain_hi,
            g,
            self.chain_plane,
        )
        keep = self.chain_piece[ch] != np.asarray(piece)[r // (cells * cells)]
        r, ch = r[keep], ch[keep]  # (by part, then chain: box_pairs' order)
        ent = tuple(np.ascontiguousarray(b[ch, ax]) for ax in (0, 1) for b in (self.chain_lo, self.chain_hi))
        return np.searchsorted(r, np.arange(B * cells * cells + 1)), ch, lo2, hi2, cells, ent

    def patch_boxes(self, patch, faces=None):
        """box_chains of patches `patch` (K,), row k patch[k]'s box in its plane (faces: (corners
        (K, 4, 3), nv (K,)) of finer faces on the patches, their boxes instead, as may_slot's), for
        covered(..., boxes=) of points on them: a point of patch[k]'s plane and piece then searches
        its part's chains, not the grid's cells (the same pairs; slot_split's 256 test points per
        patch)."""
        patch = np.asarray(patch, np.int64)
        c, nv = (self.patches.corners[patch], self.patches.nv[patch]) if faces is None else faces
        c = np.array(c, float)
        c[nv == 3, 3] = c[nv == 3, 2]  # (a triangle's padding corner: its own third)
        gi = self.plane[patch]
        p2 = self._to2d(gi, c)
        return self.box_chains(gi, p2.min(1), p2.max(1), self.piece[patch])

    def _in_boxes(self, p2, gi, patch, boxes):
        """points_in_boxes' pairs (i, ch) of 2D points p2 (N, 2) in planes gi, their own pieces'
        chains left out (_pairs' rule): a point inside its row's box (boxes: covered's) tests the
        chains of the part it lies in, which hold every chain box containing it; the rest the
        grid's cells. The same pairs in the same order (by point, then chain)."""
        row, (start, chains, blo, bhi, cells, (x0, x1, y0, y1)) = boxes
        row = np.asarray(row, np.int64)
        r = np.maximum(row, 0)
        inb, part = row >= 0, r * (cells * cells)
        px, py = np.ascontiguousarray(p2[:, 0]), np.ascontiguousarray(p2[:, 1])
        for q, ax, w in ((px, 0, cells), (py, 1, 1)):
            lo = np.take(blo[:, ax], r)
            with np.errstate(divide="ignore", invalid="ignore"):  # (a box flat on an axis: none in)
                t = np.floor((q - lo) / (np.take(bhi[:, ax], r) - lo) * cells)
            inb &= (t >= 0) & (t < cells)
            part += np.where(inb, t, 0).astype(np.int64) * w
        a = np.flatnonzero(inb)
        pr, k = csr_rows(start, part[a])
        # points_in_boxes' test (the chain's box holds the point) on both axes at once, the chains'
        # bounds read per table entry (contiguous by part): the same pairs, x0.7 of the CPU of
        # two passes gathering chain_lo[chain, axis] (session 37)
        qx, qy = px[a].take(pr), py[a].take(pr)
        keep = (x0.take(k) <= qx) & (x1.take(k) >= qx) & (y0.take(k) <= qy) & (y1.take(k) >= qy)
        keep = np.flatnonzero(keep)
        i, ch = a[pr[keep]], chains[k[keep]]
        rest = np.flatnonzero(~inb)
        if len(rest):
            j, cj = self._grid_pairs(p2[rest], gi[rest], patch[rest])
            i, ch = np.concatenate([i, rest[j]]), np.concatenate([ch, cj])
            o = np.lexsort((ch, i))
            i, ch = i[o], ch[o]
        return i, ch

    def _grid_pairs(self, p2, gi, patch):
        """(i, ch): points_in_boxes' pairs of 2D points p2 in planes gi (the chains' box grid),
        their own pieces' chains left out."""
        lo = np.concatenate([p2, np.zeros((len(p2), 1))], 1)
        grid = self._table("grid", lambda: box_grid(self.chain_lo, self.chain_hi, self.chain_plane))
        i, ch = points_in_boxes(grid, lo, gi)
        # a piece never covers itself (a room's walls its floor, a table's sides its top)
        own = self.chain_piece[ch] == self.piece[patch[i]]
        return i[~own], ch[~own]

    def _pairs(self, points, patch, budget, open_edge=0.0, boxes=None):
        """The (point, chain) pairs of points (N, 3) on patches (N,) with the point in the chain's
        box: (i, ch, covering (the chain's winding covers the point), near (within open_edge x h of
        one of its open edges)); None without pairs. boxes: covered()'s."""
        if not len(self.chain_plane) or not len(points):
            return None
        gi = self.plane[patch]
        p2 = self._to2d(gi, points[:, None])[:, 0]
        if boxes is None:
            i, ch = self._grid_pairs(p2, gi, patch)
        else:
            i, ch = self._in_boxes(p2, gi, patch, boxes)
        if not len(i):
            return None
        w = np.zeros(len(i))
        near = np.zeros(len(i), bool)  # in the open band of a gap (open_edge)
        px, py = np.ascontiguousarray(p2[:, 0]), np.ascontiguousarray(p2[:, 1])
        pi, pch = i, ch  # all pairs (returned)
        # a closed chain's winding number is its centre's within the disc about the centre that
        # meets none of its segments, and 0 outside the circle about the centre that holds them
        # all; farther than its widest open band (open_edge) from both circles no point is near
        # an open edge: only the pairs between the two are summed
        cx, cy, r_in, r_out, wc, band = self._discs()
        r = np.sqrt((px[i] - cx[ch]) ** 2 + (py[i] - cy[ch]) ** 2)
        wide = open_edge * band[ch] if open_edge > 0 else 0.0
        inside, beyond = r < r_in[ch] - wide, r > r_out[ch] + wide
        w[inside] = wc[ch[inside]]
        rest = np.flatnonzero(~inside & ~beyond)
        i, ch = i[rest], ch[rest]
        n_seg = self.chain_start[ch + 1] - self.chain_start[ch]
        wr = np.zeros(len(i))
        nr = np.zeros(len(i), bool)
        step = max(1, budget // max(int(n_seg.max(initial=1)), 1))
        seg = self._table(
            "seg_cm",
            lambda: tuple(np.ascontiguousarray(x[:, k]) for x in (self.seg_a, self.seg_b) for k in (0, 1)),
        )
        for s in range(0, len(i), step):
            sl = slice(s, s + step)
            ns = n_seg[sl]
            pr, sg = csr_rows(self.chain_start, ch[sl])
            # per component over contiguous rows (the (P, 2) rows' gathers and einsum cost 2x); the
            # same values bit for bit: einsum's dot adds the products to 0 (+ 0.0 turns -0 into +0,
            # which arctan2 tells apart)
            ip = i[sl][pr]
            qx, qy = px[ip], py[ip]
            ax, ay, bx, by = seg[0][sg] - qx, seg[1][sg] - qy, seg[2][sg] - qx, seg[3][sg] - qy
            ang = np.arctan2(ax * by - ay * bx, (ax * bx + ay * by) + 0.0)
            wr[sl] = np.bincount(pr, ang, len(ns)) / (2 * np.pi)
            if open_edge <= 0:  # no band (below: open_edge x height x open, 0 or nan)
                continue
            band = open_edge * self.seg_height[sg] * self.seg_open[sg]
            if not (band > 0).any():
                continue
            a = np.column_stack([ax, ay])
            b = np.column_stack([bx, by])
            e = b - a
            t = np.clip(-np.einsum("ij,ij->i", a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
            d = np.linalg.norm(a + t[:, None] * e, axis=1)  # to the segment's nearest point
            nr[sl] = np.bincount(pr, d < band, len(ns)) > 0  # within the band of an open edge of a gap
        w[rest], near[rest] = wr, nr
        hit = np.where(self.chain_signed[pch], w < -0.5, np.abs(w) > 0.5)
        return pi, pch, hit, near

    def _discs(self):
        """Per chain (centre x, y, r_in, r_out, winding at the centre, widest open band per unit
        open_edge): the mean of its segments' starts, the distance from it to the nearest segment
        (shrunk by 1e-9 of it; 0 for a chain that is not closed: its starts not the same points as
        its ends) and to the farthest segment end (grown by 1e-9 of it), the largest height of its
        open segments: _pairs' exact shortcut. Built once."""
        return self._table("disc", self._make_discs)

    def _make_discs(self):
        a, b, st = self.seg_a, self.seg_b, self.chain_start
        nC, cnt = len(st) - 1, np.diff(st)
        ch = np.repeat(np.arange(nC), cnt)
        c = np.stack([np.bincount(ch, a[:, k], nC) for k in (0, 1)], 1) / np.maximum(cnt, 1)[:, None]
        u, v = a - c[ch], b - c[ch]
        e = v - u
        t = np.clip(-np.einsum("ij,ij->i", u, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
        q = u + t[:, None] * e
        d_in, d_out = np.full(nC, np.inf), np.zeros(nC)
        np.minimum.at(d_in, ch, np.einsum("ij,ij->i", q, q))
        np.maximum.at(d_out, ch, np.maximum(np.einsum("ij,ij->i", u, u), np.einsum("ij,ij->i", v, v)))
        # closed: per chain the same multiset of points as starts and as ends (exact coordinates)
        ka, kb = (np.lexsort((x[:, 1], x[:, 0], ch)) for x in (a, b))
        same = (a[ka] == b[kb]).all(1)
        closed = np.bincount(ch, ~same, nC) == 0
        r_in = np.where(closed & (cnt > 0), np.sqrt(d_in) * (1 - 1e-9), 0.0)
        r_out = np.where(closed & (cnt > 0), np.sqrt(d_out) * (1 + 1e-9), np.inf)
        wc = self._winding(np.arange(nC), c) if nC else np.zeros(0)
        band = np.zeros(nC)  # (a NaN height opens no band: d < NaN is False)
        np.maximum.at(band, ch, np.nan_to_num(self.seg_height * self.seg_open, nan=0.0))
        return c[:, 0].copy(), c[:, 1].copy(), r_in, r_out, wc, band * (1 + 1e-9)

    # -- the slots' mouths ----------------------------------------------------------------------------
    def _winding(self, ch, q):
        """Winding number of chains ch (M,) around 2D points q (M, 2) in their planes."""
        pr, sg = csr_rows(self.chain_start, ch)
        u, v = self.seg_a[sg] - q[pr], self.seg_b[sg] - q[pr]
        ang = np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], np.einsum("ij,ij->i", u, v))
        return np.bincount(pr, ang, len(ch)) / (2 * np.pi)


def refine_contacts(h, contacts: Contacts, min_area, k=(6, 4), max_nodes=2_000_000, threads=None):
    """Split the nodes of contact receivers that are partly covered down to min_area and set
    every node's exposure (uncovered area fraction, from k x k stratified points: k[0] on the
    receivers, which may be large, k[1] below; internal nodes the area-weighted mean of their
    children). Returns the number of nodes added. threads: the covered test's (Contacts.covered)."""
    n0 = h.n
    frontier = np.asarray(contacts.receivers, np.int64)
    kk = k[0]
    while len(frontier):
        cov = _covered_samples(h, contacts, frontier, kk, threads)
        kk = k[1]
        frac = cov.mean(1)
        h.exposure[frontier] = 1.0 - frac
        split = (frac > 0) & (frac < 1) & (h.area[frontier] > min_area) & (h.child0[frontier] < 0)
        if h.n - n0 + 4 * int(split.sum()) > max_nodes:
            break
        h.subdivide(frontier[split])
        frontier = h.children(frontier[split]).ravel()
    # internal nodes: area-weighted mean of their children, deepest first
    for lv in h.levels()[::-1]:
        inner = lv[h.child0[lv] >= 0]
        if len(inner):
            kids = h.children(inner)
            h.exposure[inner] = (h.exposure[kids] * h.area[kids]).sum(1) / h.area[inner]
    return h.n - n0


def _covered_samples(h, contacts, nodes, k, threads=None):
    """(len(nodes), k * k): which of the k x k stratified points of each node are covered. On
    threads by batches of nodes (about POINT_BATCH points: every node's points and answers are
    its own, so the same as serially), the points made inside the batches."""
    from . import formfactor as ff

    def batch(i, j):
        pts = ff.sample_points(h.corners[nodes[i:j]], h.nv[nodes[i:j]], k)
        return contacts.covered(pts.reshape(-1, 3), np.repeat(h.patch[nodes[i:j]], k * k)).reshape(-1, k * k)

    if threads is None:
        return batch(0, len(nodes))
    parts = batch_map(batch, ranges(len(nodes), max(POINT_BATCH // (k * k), 1)), threads)
    return np.concatenate(parts) if parts else np.zeros((0, k * k), bool)


def exposed_points(h, contacts: Contacts, nodes, k, fp, seen):
    """Visibility sample points (len(nodes), k*k, 3) of partly covered nodes: each of the k x k
    stratified points that is covered is replaced by the nearest uncovered one of the finer grid
    fp (N, S, 3) (`seen`: its uncovered points), so the node's links see from the part that
    receives light. Nodes without an uncovered point keep theirs."""
    from . import formfactor as ff

    nodes = np.asarray(nodes, np.int64)
    base = ff.sample_points(h.corners[nodes], h.nv[nodes], k)
    if not len(nodes):
        return base
    cb = contacts.covered(base.reshape(-1, 3), np.repeat(h.patch[nodes], k * k)).reshape(-1, k * k)
    cf = ~seen
    d2 = np.sum((base[:, :, None] - fp[:, None]) ** 2, -1)  # (N, s, S)
    d2 = np.where(cf[:, None], np.inf, d2)
    best = d2.argmin(-1)
    alt = np.take_along_axis(fp, best[..., None].repeat(3, -1), 1)
    swap = cb & np.isfinite(d2.min(-1))
    return np.where(swap[..., None], alt, base)
