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

import numpy as np

from .geometry import components
from .planes import frames, plane_ids


def sorted_index(table, keys):
    """Index of each key in the sorted array table, -1 where it is absent."""
    keys = np.asarray(keys)
    if not len(table):
        return np.full(keys.shape, -1, np.int64)
    i = np.minimum(np.searchsorted(table, keys), len(table) - 1)
    return np.where(table[i] == keys, i, -1)


def _cells(lo, hi, origin, size, dims, group):
    """(box index, cell key) for every grid cell each box overlaps; boxes of different groups
    never share a cell."""
    c0 = np.floor((lo - origin) / size).astype(np.int64)
    c1 = np.floor((hi - origin) / size).astype(np.int64)
    span = c1 - c0 + 1
    cnt = span.prod(1)
    box = np.repeat(np.arange(len(lo)), cnt)
    k = np.arange(len(box)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    key = np.zeros(len(box), np.int64) if group is None else np.asarray(group, np.int64)[box]
    for ax in range(3):
        key = key * dims[ax] + c0[box, ax] + k % span[box, ax]
        k //= span[box, ax]
    return box, key


def _box_pairs(lo_a, hi_a, lo_b, hi_b, group_a=None, group_b=None, max_refs=4_000_000):
    """Index pairs (i, j) whose axis-aligned boxes overlap (and whose groups are equal, if
    given), through a uniform grid: cells about the median box size, coarsened until the cell
    lists fit, so the cost follows the overlaps rather than all pairs."""
    if not len(lo_a) or not len(lo_b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    origin = np.minimum(lo_a.min(0), lo_b.min(0))
    ext = np.maximum(hi_a.max(0), hi_b.max(0)) - origin
    span = float(ext.max()) or 1.0
    size = max(float(np.median(np.concatenate([hi_a - lo_a, hi_b - lo_b]).max(1))), 1e-3 * span)
    while True:
        n = sum(
            int(np.prod(np.floor((top - origin) / size) - np.floor((bot - origin) / size) + 1, axis=1).sum())
            for bot, top in ((lo_a, hi_a), (lo_b, hi_b))
        )
        if n <= max_refs or size >= span:
            break
        size *= 2
    dims = (np.floor(ext / size) + 1).astype(np.int64)
    ba, ka = _cells(lo_a, hi_a, origin, size, dims, group_a)
    bb, kb = _cells(lo_b, hi_b, origin, size, dims, group_b)
    order = np.argsort(kb, kind="stable")
    kb, bb = kb[order], bb[order]
    first = np.searchsorted(kb, ka, "left")
    cnt = np.searchsorted(kb, ka, "right") - first
    # candidate pairs in blocks of about max_refs: their temporaries stay bounded
    ends = np.cumsum(cnt)
    cuts = np.searchsorted(ends, np.arange(max_refs, int(ends[-1]) if len(ends) else 0, max_refs))
    keys = []
    for s, e in zip(np.r_[0, cuts], np.r_[cuts, len(ka)]):
        c = cnt[s:e]
        i = np.repeat(ba[s:e], c)
        j = bb[np.repeat(first[s:e], c) + np.arange(len(i)) - np.repeat(np.cumsum(c) - c, c)]
        ok = np.all((lo_b[j] <= hi_a[i]) & (hi_b[j] >= lo_a[i]), axis=1)
        keys.append(np.unique(i[ok] * len(lo_b) + j[ok]))
    key = np.unique(np.concatenate(keys)) if keys else np.zeros(0, np.int64)
    return key // len(lo_b), key % len(lo_b)


def _ray_exit(f, u, a, b):
    """(M,) how far rays from 2D points f (M, 2) along unit u (M, 2) go before they cross the
    segments a, b (M, 2) (0: they do not)."""
    d = b - a
    den = u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0]
    safe = np.where(den == 0, 1.0, den)
    w = a - f
    t = (w[:, 0] * d[:, 1] - w[:, 1] * d[:, 0]) / safe
    s = (w[:, 0] * u[:, 1] - w[:, 1] * u[:, 0]) / safe
    return np.where((den != 0) & (s >= 0) & (s <= 1) & (t > 0), t, 0.0)


class Contacts:
    """Covered-point test for points on the patches of `patches` (geometry.Patches).

    gap: how far (scene units) in front of a receiver a face may be and still cover it, and how
    close to its plane an edge or vertex is taken as lying on it."""

    def __init__(self, patches, gap):
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
        self._build()

    def _pieces(self, size):
        """Connected pieces: patches sharing an input vertex, or a corner position within one
        object (faces modelled apart, like the Cornell blocks', are one solid)."""
        pt = self.patches
        jj, kk = np.nonzero(pt.vert_index >= 0)
        q = np.round(pt.corners[jj, kk] / (1e-5 * size)).astype(np.int64)
        ii, jn = [], []
        for key in (pt.vert_index[jj, kk][:, None], np.column_stack([pt.object_id[jj], q])):
            inv = np.unique(key, axis=0, return_inverse=True)[1].ravel()
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
        n, o = self.n_g[gi], self.o_g[gi]
        d = np.einsum("pkj,pj->pk", c[t] - o[:, None], n)  # (P, 4) corner heights over the plane
        nv = pt.nv[t]
        d[nv == 3, 3] = d[nv == 3, 2]
        mn, mx = d.min(1), d.max(1)
        near = (mn <= g) & (mx >= -g)
        gi, t, d, nv, n, o = gi[near], t[near], d[near], nv[near], n[near], o[near]
        cosang = np.einsum("ij,ij->i", pt.normal[t], n)
        flat = (np.abs(cosang) > 1 - 1e-6) & (d.max(1) - d.min(1) <= g)
        cover = flat & (((cosang < 0) & (d.mean(1) >= -self.pen)) | ((cosang > 0) & (d.min(1) > self.pen)))
        cover &= d.max(1) <= g
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
        cr = np.flatnonzero(~flat & (d.max(1) > g))
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

    def _build(self):
        pt = self.patches
        c = pt.corners
        lo, hi = c.min(1), c.max(1)
        g = self.gap
        i, j = _box_pairs(lo - g, hi + g, lo, hi)
        keep = (i != j) & (self.plane[i] != self.plane[j])
        gi, t = self.plane[i[keep]], j[keep]
        pair = np.unique(gi.astype(np.int64) * len(pt.nv) + t)  # (plane, occluder patch), once each
        gi, t = pair // len(pt.nv), pair % len(pt.nv)
        segs = []
        for s0 in range(0, len(t), 500_000):  # bounded temporaries at any scene size
            segs += self._segments(gi[s0 : s0 + 500_000], t[s0 : s0 + 500_000])
        if segs:
            g_, a_, b_, ch_, sg_, pc_, hg_, op_ = (np.concatenate(x) for x in zip(*segs))
        else:
            g_, ch_, pc_, op_ = (np.zeros(0, np.int64) for _ in range(4))
            sg_, a_, b_, hg_ = np.zeros(0, bool), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
        # chain = (plane, piece or covering patch): sort segments by chain
        key = np.unique(np.column_stack([g_, ch_]), axis=0, return_inverse=True)[1].ravel()
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
        # chain boxes in the plane's frame (a third coordinate 0, as _box_pairs takes 3D boxes)
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
            _, inv, cnt = np.unique(
                np.concatenate([fwd, rev]), axis=0, return_inverse=True, return_counts=True
            )
            out[i[cnt[inv.ravel()[: len(i)]] > 1]] = False
        return out

    def _to2d(self, gi, p):
        """Points p (N, M, 3) into the frame of planes gi (N,): (N, M, 2)."""
        q = p - self.o_g[gi][:, None]
        return np.stack(
            [np.einsum("nmj,nj->nm", q, self.u_g[gi]), np.einsum("nmj,nj->nm", q, self.v_g[gi])], -1
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
        i, ch = _box_pairs(lo, hi, self.chain_lo, self.chain_hi, self.plane, self.chain_plane)
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
    def covered(self, points, patch, budget=4_000_000, chunk=200_000, open_edge=0.0):
        """Boolean (N,): points (N, 3) lying on patches patch (N,) are covered (in chunks of
        points: the temporaries stay small whatever the scene size).

        open_edge > 0: a point under a covering face or solid at a gap h in front of it (a book's
        side 2 mm from its neighbour's) counts as covered only farther than open_edge x h from the
        gap's open outline: light entering the slot between two parallel faces a distance h apart reaches a
        point at depth x with the opening's view factor (1 - x / sqrt(x^2 + h^2)) / 2, about
        h^2 / (4 x^2); its integral over the depth is h / 2, of which x > c h holds a share
        1 / (2 c) (open_edge 5: 10%). Touching faces (h = 0) and crossing solids are unchanged."""
        points, patch = np.asarray(points, float), np.asarray(patch, np.int64)
        if len(points) > chunk:
            return np.concatenate(
                [
                    self.covered(points[s : s + chunk], patch[s : s + chunk], budget, chunk, open_edge)
                    for s in range(0, len(points), chunk)
                ]
            )
        out = np.zeros(len(points), bool)
        pairs = self._pairs(points, patch, budget, open_edge)
        if pairs is not None:
            i, ch, hit, near = pairs[:4]
            out[i[hit & ~near]] = True
        return out

    def slots(self, points, patch, budget=4_000_000, chunk=200_000):
        """Points (N, 3) on patches (N,) covered only at a gap, inside a slot: no chain covering
        them touches their plane all along (chain_gap: a box standing on the floor) and a covering
        face parallel to it has a mouth (slot_mouths: an open edge of the gap, a height h > min_gap
        wide, the light enters by: a neighbour book's side 2 mm away). Returns (depth (N,): distance
        to the nearest mouth of their covering faces, h (N,) of that mouth, foot (N, 3): its
        nearest point, on the points' plane, chain (N,): the chain it belongs to, mouth (N,): its
        index in slot_mouths()); h = 0, depth inf, chain and mouth -1 for the other points."""
        points, patch = np.asarray(points, float), np.asarray(patch, np.int64)
        if len(points) > chunk:
            parts = [
                self.slots(points[s : s + chunk], patch[s : s + chunk], budget, chunk)
                for s in range(0, len(points), chunk)
            ]
            return tuple(np.concatenate(x) for x in zip(*parts))
        n = len(points)
        depth, hgap, foot, chain = np.full(n, np.inf), np.zeros(n), points.copy(), np.full(n, -1, np.int64)
        mouth = np.full(n, -1, np.int64)
        pairs = self._pairs(points, patch, budget)
        if pairs is None:
            return depth, hgap, foot, chain, mouth
        i, ch, hit = pairs[:3]
        i, ch = i[hit], ch[hit]
        touching = np.bincount(i, self.chain_gap[ch] <= self.min_gap, n) > 0
        # per point the covering face (parallel to the plane, as the transfer's walls are: not a
        # crossing solid's outline, a vase's curved side) with the nearest mouth
        keep = ~self.chain_signed[ch] & ~touching[i]
        i, ch = i[keep], ch[keep]
        M = self.slot_mouths()
        ns = M["start"][ch + 1] - M["start"][ch]
        pr = np.repeat(np.arange(len(i)), ns)
        mk = np.repeat(M["start"][ch] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
        gi = self.plane[patch]
        p2 = self._to2d(gi, points[:, None])[:, 0]
        a, e = M["a"][mk] - p2[i[pr]], M["b"][mk] - M["a"][mk]
        t = np.clip(-np.einsum("ij,ij->i", a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
        q = a + t[:, None] * e  # the mouth's nearest point, relative to the point
        d = np.where(M["open"][mk], np.linalg.norm(q, axis=1), np.inf)
        o = np.lexsort((d, i[pr]))
        o = o[np.r_[True, i[pr][o][1:] != i[pr][o][:-1]]] if len(o) else o  # each point's nearest
        o = o[np.isfinite(d[o])]
        p = i[pr[o]]
        depth[p], hgap[p], chain[p], mouth[p] = d[o], M["height"][mk[o]], ch[pr[o]], mk[o]
        foot[p] += q[o, :1] * self.u_g[gi[p]] + q[o, 1:] * self.v_g[gi[p]]
        return depth, hgap, foot, chain, mouth

    def slot_transfer(self, points, patch, chain, rho, reflectance):
        """(N, C) irradiance / pi at points (N, 3) on patches (N,) in the slots of chains (N,)
        (slots(); -1: none, 0) for an outside of radiance 1 beyond the mouths, every bounce
        between the walls included: the sum over the chain's mouths (slot_mouths) of
        slot_irradiance at the point's depth behind each, with the wall that goes on beyond it
        (rho (N, C): the point's reflectance, the other wall's from reflectance (C, K) of the
        mouth's wall, 0 where the occluder's back faces the slot),
        times the share of an endless mouth's view factor that the segment's extent along its
        edge subtends, (atan(s / x) + s x / (s^2 + x^2)) / pi between its ends (thin strips:
        h^2 x / (2 pi (s^2 + x^2)^2) ds)."""
        rho = np.asarray(rho, float)
        out = np.zeros(rho.shape)
        j = np.flatnonzero(np.asarray(chain) >= 0)
        if not len(j):
            return out
        c = np.asarray(chain)[j]
        M = self.slot_mouths()
        ns = M["start"][c + 1] - M["start"][c]
        pr = np.repeat(np.arange(len(j)), ns)
        sg = np.repeat(M["start"][c] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
        m = M["open"][sg]
        pr, sg = pr[m], sg[m]
        hs = M["height"][sg]
        p2 = self._to2d(self.plane[np.asarray(patch)[j]], np.asarray(points, float)[j][:, None])[:, 0]
        a, b = M["a"][sg] - p2[pr], M["b"][sg] - p2[pr]
        e = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-300)[:, None]
        x = np.maximum(np.abs(a[:, 0] * e[:, 1] - a[:, 1] * e[:, 0]), 1e-9 * hs)

        def share(s):
            return (np.arctan(s / x) + s * x / (s * s + x * x)) / np.pi

        frac = share(np.einsum("ij,ij->i", b, e)) - share(np.einsum("ij,ij->i", a, e))
        other = self._other_wall(sg, reflectance)
        # the wall that goes on beyond the mouth: the face beyond the surface's own edge (ext of the
        # mouth), or the surface beyond the face's edge (to its patch's edge, on the perpendicular)
        own = M["own"][sg]
        ext = M["ext"][sg].copy()
        if RECEIVER_EXT:
            q = np.flatnonzero(~own)
            perp = a[q] - np.einsum("ij,ij->i", a[q], e[q])[:, None] * e[q]  # to the mouth's line
            pq = np.asarray(patch)[j][pr[q]]
            c = self._to2d(self.plane[pq], self.patches.corners[pq])
            f, u = p2[pr[q]] + perp, perp / x[q, None]
            t = np.stack([_ray_exit(f, u, c[:, i], c[:, (i + 1) % 4]) for i in range(4)], 1)
            ext[q] = np.where((t > 0).sum(1) % 2 == 1, t.max(1), 0.0)  # 0: the foot is off the patch
        E = np.zeros((len(sg), rho.shape[1]))
        for fc in (False, True):
            w = np.flatnonzero(own == fc)
            E[w] = frac[w, None] * slot_irradiance(x[w] / hs[w], rho[j][pr[w]], other[w], ext[w] / hs[w], fc)
        for k in range(rho.shape[1]):
            out[j, k] = np.bincount(pr, E[:, k], len(j))
        return out

    def _other_wall(self, mouth, reflectance):
        """(M, C) the reflectance of the gap's other wall at mouths (M,): 0 where the occluder's
        back faces the slot (a one-sided surface reflects nothing behind it)."""
        wall = self.slot_mouths()["wall"][mouth]
        return np.where((wall >= 0)[:, None], np.asarray(reflectance)[:, np.maximum(wall, 0)].T, 0.0)

    def through_mouth(self, mouth, xi, rho, reflectance):
        """(N, C) irradiance / pi that points of reflectance rho (N, C) at depth xi (N,) gap widths
        behind mouths (N,) (slots()) receive straight through them from an outside of radiance 1:
        the mouth's view factor, or where the covering face goes on beyond the surface's own edge,
        the outside past it and its light (contacts.slot_seen). What their gather finds there."""
        M = self.slot_mouths()
        own = M["own"][mouth]
        out = np.repeat(slot_mouth(xi)[:, None], np.shape(rho)[1], 1)
        w = np.flatnonzero(own)
        h = M["height"][mouth[w]]
        out[w] = slot_seen(
            xi[w], np.asarray(rho)[w], self._other_wall(mouth[w], reflectance), M["ext"][mouth[w]] / h
        )
        return out

    def _pairs(self, points, patch, budget, open_edge=0.0):
        """The (point, chain) pairs of points (N, 3) on patches (N,) with the point in the chain's
        box: (i, ch, covering (the chain's winding covers the point), near (within open_edge x h of
        one of its open edges)); None without pairs."""
        if not len(self.chain_plane) or not len(points):
            return None
        gi = self.plane[patch]
        p2 = self._to2d(gi, points[:, None])[:, 0]
        lo = np.concatenate([p2, np.zeros((len(p2), 1))], 1)
        i, ch = _box_pairs(lo, lo, self.chain_lo, self.chain_hi, gi, self.chain_plane)
        # a piece never covers itself (a room's walls its floor, a table's sides its top)
        own = self.chain_piece[ch] == self.piece[patch[i]]
        i, ch = i[~own], ch[~own]
        if not len(i):
            return None
        n_seg = self.chain_start[ch + 1] - self.chain_start[ch]
        w = np.zeros(len(i))
        near = np.zeros(len(i), bool)  # in the open band of a gap (open_edge)
        step = max(1, budget // max(int(n_seg.max()), 1))
        for s in range(0, len(i), step):
            sl = slice(s, s + step)
            ns = n_seg[sl]
            pr = np.repeat(np.arange(len(ns)), ns)
            sg = np.repeat(self.chain_start[ch[sl]] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
            a = self.seg_a[sg] - p2[i[sl]][pr]
            b = self.seg_b[sg] - p2[i[sl]][pr]
            ang = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.einsum("ij,ij->i", a, b))
            w[sl] = np.bincount(pr, ang, len(ns)) / (2 * np.pi)
            band = open_edge * self.seg_height[sg] * self.seg_open[sg]
            if not (band > 0).any():
                continue
            e = b - a
            t = np.clip(-np.einsum("ij,ij->i", a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
            d = np.linalg.norm(a + t[:, None] * e, axis=1)  # to the segment's nearest point
            near[sl] = np.bincount(pr, d < band, len(ns)) > 0  # within the band of an open edge of a gap
        hit = np.where(self.chain_signed[ch], w < -0.5, np.abs(w) > 0.5)
        return i, ch, hit, near

    # -- the slots' mouths ----------------------------------------------------------------------------
    def _winding(self, ch, q):
        """Winding number of chains ch (M,) around 2D points q (M, 2) in their planes."""
        ns = self.chain_start[ch + 1] - self.chain_start[ch]
        pr = np.repeat(np.arange(len(ch)), ns)
        sg = np.repeat(self.chain_start[ch] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
        u, v = self.seg_a[sg] - q[pr], self.seg_b[sg] - q[pr]
        ang = np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], np.einsum("ij,ij->i", u, v))
        return np.bincount(pr, ang, len(ch)) / (2 * np.pi)

    def _surface_edges(self, planes):
        """The outline of the surface in planes (sorted ids): the edges (plane, a (E, 2), b (E, 2),
        CCW: the surface on their left) of the plane's patches that no other patch of it shares."""
        pt = self.patches
        k = np.flatnonzero(sorted_index(planes, self.plane) >= 0)
        c = self._to2d(self.plane[k], pt.corners[k])  # (k, 4, 2); a triangle repeats corner 2
        a, b = c.reshape(-1, 2), np.roll(c, -1, 1).reshape(-1, 2)
        g = np.repeat(self.plane[k], 4)
        ok = np.linalg.norm(b - a, axis=1) > self.pen
        a, b, g = a[ok], b[ok], g[ok]
        q = np.round(np.concatenate([a, b], 1) / self.pen).astype(np.int64)
        fwd, rev = np.column_stack([g, q]), np.column_stack([g, q[:, 2:], q[:, :2]])
        _, inv, cnt = np.unique(np.concatenate([fwd, rev]), axis=0, return_inverse=True, return_counts=True)
        alone = cnt[inv.ravel()[: len(a)]] == 1
        return g[alone], a[alone], b[alone]

    def _in_surface(self, gi, q, tol):
        """True where 2D points q (M, 2) of planes gi (M,) lie on one of the plane's patches, or
        within tol of one."""
        pt = self.patches
        c = self._to2d(self.plane, pt.corners)
        z = np.zeros((len(q), 1))
        lo = np.concatenate([c.min(1), np.zeros((len(c), 1))], 1)
        hi = np.concatenate([c.max(1), np.zeros((len(c), 1))], 1)
        qq = np.concatenate([q, z], 1)
        i, k = _box_pairs(qq - tol, qq + tol, lo - tol, hi + tol, gi, self.plane)
        e = np.roll(c[k], -1, 1) - c[k]
        ln = np.linalg.norm(e, axis=-1)
        w = q[i][:, None] - c[k]
        d = (e[..., 0] * w[..., 1] - e[..., 1] * w[..., 0]) / np.maximum(ln, 1e-300)  # > 0 inside (CCW)
        d = np.where(ln > 0, d, np.inf).min(1)
        return np.bincount(i, d >= -tol, len(q)) > 0

    @staticmethod
    def _cut(a, b, pi, ca, cb):
        """Pieces of segments a, b (S, 2) cut where they cross segments ca, cb (P, 2) paired with
        them by pi (P,): (segment index, piece start, piece end)."""
        e, f = b[pi] - a[pi], cb - ca
        den = e[:, 0] * f[:, 1] - e[:, 1] * f[:, 0]
        w = ca - a[pi]
        safe = np.where(den == 0, 1.0, den)
        t = (w[:, 0] * f[:, 1] - w[:, 1] * f[:, 0]) / safe
        u = (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / safe
        x = (den != 0) & (t > 0) & (t < 1) & (u >= 0) & (u <= 1)
        s_ = np.concatenate([np.arange(len(a)), np.arange(len(a)), pi[x]])
        tt = np.concatenate([np.zeros(len(a)), np.ones(len(a)), t[x]])
        o = np.lexsort((tt, s_))
        s_, tt = s_[o], tt[o]
        j = np.flatnonzero((s_[1:] == s_[:-1]) & (tt[1:] > tt[:-1]))
        seg = s_[j]
        d = b[seg] - a[seg]
        return seg, a[seg] + tt[j, None] * d, a[seg] + tt[j + 1, None] * d

    def slot_mouths(self):
        """The mouths of each covering face's slot (chains not signed), built once: the outline of
        the part of the receiver plane's surface the face covers, that is the face's open gap edges
        (seg_mouth) where they lie on the surface, and the surface's own edges where they lie
        inside the face (a shorter book's top under its taller neighbour's side: the slot opens
        there; a face's edge beyond it, the neighbour's top, is no mouth of it). Returns a dict of
        a, b (M, 2), chain, height, wall (the gap's other wall, seg_wall), own (an edge of the
        surface), open (close_mouths()), start (chains + 1,): the mouths sorted by chain."""
        if self._mouth is not None:
            return self._mouth
        tol = self.min_gap  # edges nearer than a gap that counts are one edge
        cov = ~self.chain_signed
        # the faces' open gap edges, cut where the surface's outline crosses them
        s = np.flatnonzero(self.seg_mouth & cov[self.seg_chain])
        ch_s = self.seg_chain[s]
        planes = np.unique(self.chain_plane[np.flatnonzero(cov)])
        rg, ra, rb = self._surface_edges(planes)

        def boxes(a, b, pad):
            z = np.zeros((len(a), 1))
            lo, hi = np.minimum(a, b) - pad, np.maximum(a, b) + pad
            return np.concatenate([lo, z], 1), np.concatenate([hi, z], 1)

        lo_s, hi_s = boxes(self.seg_a[s], self.seg_b[s], tol)
        lo_r, hi_r = boxes(ra, rb, tol)
        i, k = _box_pairs(lo_s, hi_s, lo_r, hi_r, self.chain_plane[ch_s], rg)
        seg, pa, pb = self._cut(self.seg_a[s], self.seg_b[s], i, ra[k], rb[k])
        on = self._in_surface(self.chain_plane[ch_s[seg]], (pa + pb) / 2, tol)
        parts = [(ch_s[seg[on]], pa[on], pb[on], np.zeros(on.sum(), bool))]
        # the surface's edges, cut where the face's outline crosses them, strictly inside the face
        c = np.flatnonzero(cov)
        i, k = _box_pairs(lo_r, hi_r, self.chain_lo[c] - tol, self.chain_hi[c] + tol, rg, self.chain_plane[c])
        if len(i):
            ch = c[k]
            ns = self.chain_start[ch + 1] - self.chain_start[ch]
            pr = np.repeat(np.arange(len(i)), ns)
            sg = np.repeat(self.chain_start[ch] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
            seg, pa, pb = self._cut(ra[i], rb[i], pr, self.seg_a[sg], self.seg_b[sg])
            mid = (pa + pb) / 2
            w = self._winding(ch[seg], mid)
            # its distance to the face's outline: a surface edge along the face's edge is that edge
            ns2 = ns[seg]
            pr2 = np.repeat(np.arange(len(seg)), ns2)
            sg2 = np.repeat(self.chain_start[ch[seg]] - (np.cumsum(ns2) - ns2), ns2) + np.arange(len(pr2))
            u, e = self.seg_a[sg2] - mid[pr2], self.seg_b[sg2] - self.seg_a[sg2]
            t = np.clip(-np.einsum("ij,ij->i", u, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0, 1)
            dist = np.full(len(seg), np.inf)
            np.minimum.at(dist, pr2, np.linalg.norm(u + t[:, None] * e, axis=1))
            inside = (np.abs(w) > 0.5) & (dist > tol)
            # where the surface really ends: not an edge between two of its patches that do not
            # share it (a T-junction), past which the surface goes on
            e = (pb - pa) / np.maximum(np.linalg.norm(pb - pa, axis=1), 1e-300)[:, None]
            past = mid + 2 * tol * np.column_stack([e[:, 1], -e[:, 0]])
            inside &= ~self._in_surface(rg[i[seg]], past, 0.0)
            parts.append((ch[seg[inside]], pa[inside], pb[inside], np.ones(inside.sum(), bool)))
        ch, a, b, own = (np.concatenate(x) for x in zip(*parts))
        o = np.argsort(ch, kind="stable")
        ch, a, b, own = ch[o], a[o], b[o], own[o]
        first = self.chain_start[ch]  # a covering face's edges share its height and its wall
        # beyond the surface's own edge the face goes on (the taller book's side above the shorter
        # one's top): how far, from the edge's middle out (to its right: the surface is on its left)
        e = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-300)[:, None]
        ext = np.zeros(len(ch))
        k = np.flatnonzero(own)
        ns = self.chain_start[ch[k] + 1] - self.chain_start[ch[k]]
        pr = np.repeat(np.arange(len(k)), ns)
        sg = np.repeat(self.chain_start[ch[k]] - (np.cumsum(ns) - ns), ns) + np.arange(len(pr))
        t = _ray_exit(
            (a[k] + b[k])[pr] / 2, np.column_stack([e[k, 1], -e[k, 0]])[pr], self.seg_a[sg], self.seg_b[sg]
        )
        np.maximum.at(ext, k[pr], t)
        self._mouth = dict(
            a=a,
            b=b,
            chain=ch,
            height=self.chain_gap[ch],
            wall=self.seg_wall[first],
            own=own,
            ext=ext,
            open=self.chain_gap[ch] > self.min_gap,
            start=np.searchsorted(ch, np.arange(len(self.chain_plane) + 1)),
        )
        return self._mouth

    def close_mouths(self, occluded):
        """Shut the mouths a surface closes (a book's bottom edge on the board it stands on): a
        segment from h inside the slot, half way across the gap, to h outside it meets a surface.
        occluded(a, b) -> bool (M,): a ray backend's segment test. Once per Contacts."""
        if self._mouths_probed:
            return
        self._mouths_probed = True
        M = self.slot_mouths()
        m = np.flatnonzero(M["open"])
        if not len(m):
            return
        a, b, hh, ch = M["a"][m], M["b"][m], M["height"][m], M["chain"][m]
        e = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-300)[:, None]
        mid, perp = (a + b) / 2, np.column_stack([-e[:, 1], e[:, 0]])
        # which side is the slot's: the surface's own edges have it on their left (CCW), the face's
        # where its outline winds (the chain alone)
        inside = M["own"][m] | (np.abs(self._winding(ch, mid + 0.5 * hh[:, None] * perp)) > 0.5)
        inward = np.where(inside, 1.0, -1.0)[:, None] * perp
        gi = self.chain_plane[ch]

        def at(q2, height):
            return (
                self.o_g[gi]
                + q2[:, :1] * self.u_g[gi]
                + q2[:, 1:] * self.v_g[gi]
                + height[:, None] * self.n_g[gi]
            )

        shut = occluded(at(mid + hh[:, None] * inward, hh / 2), at(mid - hh[:, None] * inward, hh / 2))
        M["open"][m[shut]] = False


# 2D slot between parallel walls a gap h apart, open at depth 0 to an outside of radiance 1: wall a's
# irradiance / pi at depth xi = x / h is E_a = F_a + rho_b K E_b, E_b = F_b + rho_a K E_a (K: the
# view factor between strips of the facing walls, F the outside's), so (1 - p K K) E_a = F_a +
# rho_b K F_b with p = rho_a rho_b: tables of U_p = (1 - p K K)^-1 F_a and V_p = (1 - p K K)^-1 K F_b.
# One wall, L, may go on beyond the mouth in its plane by `ext` gap widths (a taller book's side
# beyond its neighbour's top; a bookcase's side beyond the book 1 cm from it): the other, S, then
# sees the outside only past that extension (F_S at depth + ext) and the extension in between,
# which the outside lights (its strips are part of L's system). The receiver may be either wall.
_SLOT = {}
RECEIVER_EXT = False  # the receiver's own continuation beyond a face's edge (a bookcase's side)
SLOT_EXT = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 1000.0)  # the tables' extensions, gap widths


def slot_mouth(xi):
    """View factor of a slot's mouth from its wall at depth xi gap widths (2D: an edge long
    against the gap)."""
    xi = np.asarray(xi, float)
    return 0.5 * (1.0 - xi / np.sqrt(xi * xi + 1.0))


def _slot_tables(n=240, ps=41, n_ext=40):
    if not _SLOT:
        inside = np.r_[0.0, np.geomspace(0.01, 2000.0, n)]
        x = (inside[:-1] + inside[1:]) / 2
        g = lambda s: s / np.sqrt(s * s + 1.0)  # noqa: E731
        p = np.linspace(0.0, 0.98, ps)
        T = {k: [] for k in ("UL", "VL", "US", "VS", "G0", "G1")}
        for ext in SLOT_EXT:
            el = inside if ext == 0 else np.r_[-np.geomspace(0.01, ext, n_ext)[::-1], inside]
            xl = (el[:-1] + el[1:]) / 2  # L's strips, its extension first
            ne = len(xl) - n
            K_LS = 0.5 * (g(inside[None, 1:] - xl[:, None]) - g(inside[None, :-1] - xl[:, None]))
            K_SL = 0.5 * (g(el[None, 1:] - x[:, None]) - g(el[None, :-1] - x[:, None]))
            F_L, F_S = slot_mouth(xl), slot_mouth(x + ext)
            # the receiver L: its strips beyond the mouth included in the solve
            A = np.eye(len(xl))[None] - p[:, None, None] * (K_LS @ K_SL)[None]
            sol = np.linalg.solve(A, np.stack([F_L, K_LS @ F_S], 1)[None].repeat(ps, 0))
            T["UL"].append(sol[:, -n:, 0])
            T["VL"].append(sol[:, -n:, 1])
            # the receiver S, and what its gather sees through the mouth: the outside past L's
            # extension and the extension's own light (G0 + rho_L G1)
            A = np.eye(n)[None] - p[:, None, None] * (K_SL @ K_LS)[None]
            sol = np.linalg.solve(A, np.stack([F_S, K_SL @ F_L], 1)[None].repeat(ps, 0))
            US, VS = sol[..., 0], sol[..., 1]
            Kx = K_SL[:, :ne] @ K_LS[:ne]
            T["US"].append(US)
            T["VS"].append(VS)
            T["G0"].append(F_S[None] + p[:, None] * np.einsum("ij,pj->pi", Kx, US))
            T["G1"].append((K_SL[:, :ne] @ F_L[:ne])[None] + p[:, None] * np.einsum("ij,pj->pi", Kx, VS))
        _SLOT.update({k: np.stack(v) for k, v in T.items()})
        _SLOT.update(logx=np.log(x), p=p, ext=np.log1p(np.array(SLOT_EXT)))
    return _SLOT


def _slot_lookup(names, xi, rho, rho_other, ext):
    """The tables `names` at depth xi (N,), p = rho rho_other (N, C), extension ext (N,) (None: 0):
    a list of (N, C) arrays, interpolated in log depth, p and log(1 + ext)."""
    T = _slot_tables()
    lx = np.log(np.maximum(np.asarray(xi, float), np.exp(T["logx"][0])))
    j = np.clip(np.searchsorted(T["logx"], lx) - 1, 0, len(T["logx"]) - 2)
    f = np.clip((lx - T["logx"][j]) / (T["logx"][j + 1] - T["logx"][j]), 0, 1)
    le = np.log1p(np.zeros(len(f)) if ext is None else np.clip(np.asarray(ext, float), 0, SLOT_EXT[-1]))
    m = np.clip(np.searchsorted(T["ext"], le) - 1, 0, len(T["ext"]) - 2)
    fe = np.clip((le - T["ext"][m]) / (T["ext"][m + 1] - T["ext"][m]), 0, 1)
    q = np.clip(np.asarray(rho, float) * np.asarray(rho_other, float), 0, T["p"][-1]) / T["p"][1]
    k = np.minimum(q.astype(np.int64), len(T["p"]) - 2)
    fq = q - k
    r = np.arange(len(f))
    out = []
    for name in names:
        M = T[name]  # (E, P, n)
        at = M[:, :, j] * (1 - f) + M[:, :, j + 1] * f  # (E, P, N)
        at = at[m, :, r] * (1 - fe)[:, None] + at[m + 1, :, r] * fe[:, None]  # (N, P)
        out.append(at[r[:, None], k] * (1 - fq) + at[r[:, None], k + 1] * fq)
    return out


def slot_irradiance(xi, rho, rho_other, ext=None, facing=False):
    """Irradiance / pi (outside radiance 1) on a slot's wall of reflectance rho (N, C) at depth xi
    (N,) gap widths from its mouth, facing a wall of reflectance rho_other (N, C), every bounce
    between the walls included (a semi-infinite slot between parallel walls, the mouth's edge
    long against the gap). ext (N,): how far (gap widths) the wall goes on beyond the mouth in its
    plane, the facing wall ending there (None: 0); facing: the facing wall goes on by ext, this
    one ends. Compare slot_mouth(xi): the first bounce only."""
    rho_other = np.asarray(rho_other, float)
    U, V = _slot_lookup(("US", "VS") if facing else ("UL", "VL"), xi, rho, rho_other, ext)
    return U + rho_other * V


def slot_seen(xi, rho, rho_other, ext):
    """Irradiance / pi (outside radiance 1) that a slot's wall of reflectance rho (N, C), ending
    at the mouth, receives straight through it at depth xi (N,) while the facing wall (rho_other)
    goes on beyond it by ext (N,) gap widths: the outside past the extension and the extension's
    light (slot_mouth(xi) for ext 0). What a gather inside such a mouth finds."""
    rho_other = np.asarray(rho_other, float)
    G0, G1 = _slot_lookup(("G0", "G1"), xi, rho, rho_other, ext)
    return G0 + rho_other * G1


def refine_contacts(h, contacts: Contacts, min_area, k=(6, 4), max_nodes=2_000_000):
    """Split the nodes of contact receivers that are partly covered down to min_area and set
    every node's exposure (uncovered area fraction, from k x k stratified points: k[0] on the
    receivers, which may be large, k[1] below; internal nodes the area-weighted mean of their
    children). Returns the number of nodes added."""
    from . import formfactor as ff

    n0 = h.n
    frontier = np.asarray(contacts.receivers, np.int64)
    kk = k[0]
    while len(frontier):
        pts = ff.sample_points(h.corners[frontier], h.nv[frontier], kk)
        cov = contacts.covered(pts.reshape(-1, 3), np.repeat(h.patch[frontier], kk * kk)).reshape(-1, kk * kk)
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
