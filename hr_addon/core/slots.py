"""Narrow gaps (slots): a surface under a face a gap h > 0 in front of it (books standing side by
side, a bookcase's side 1 cm from its first book) gets light through the gap's open edges, its
mouths (docs/gather.md, *Narrow gaps*). `SlotMouths` finds the mouths and a point's transfer
through them (mixed into contacts.Contacts, whose planes, chains and pairs it reads); below it,
the 2D slot model between parallel walls and its tables."""

import numpy as np

from .boxes import box_pairs, csr_rows, ray_exit, sorted_index


def pairs_of(pairs, rows, n):
    """The (point, chain) pairs (Contacts._pairs' arrays) of points `rows` (sorted) of the n
    points they were found for, the points numbered as in rows (slots(pairs=))."""
    if pairs is None:
        return tuple(np.zeros(0, np.int64) for _ in range(3))
    at = np.full(n, -1, np.int64)
    at[rows] = np.arange(len(rows))
    i = at[pairs[0]]
    k = np.flatnonzero(i >= 0)
    return (i[k], *(p[k] for p in pairs[1:]))


class SlotMouths:
    """Contacts' slot methods (see contacts.Contacts for the planes and chains they use)."""

    def slots(self, points, patch, budget=4_000_000, chunk=200_000, pairs=None):
        """Points (N, 3) on patches (N,) covered only at a gap, inside a slot: no chain covering
        them touches their plane all along (chain_gap: a box standing on the floor) and a covering
        face parallel to it has a mouth (slot_mouths: an open edge of the gap, a height h > min_gap
        wide, the light enters by: a neighbour book's side 2 mm away). Returns (depth (N,): distance
        to the nearest mouth of their covering faces, h (N,) of that mouth, foot (N, 3): its
        nearest point, on the points' plane, chain (N,): the chain it belongs to, mouth (N,): its
        index in slot_mouths()); h = 0, depth inf, chain and mouth -1 for the other points.
        pairs: these points' (point, chain) pairs if known (pairs_of(Contacts.covered_pairs'));
        every point's answer is its own, so they are not cut into chunks then."""
        points, patch = np.asarray(points, float), np.asarray(patch, np.int64)
        if len(points) > chunk and pairs is None:
            parts = [
                self.slots(points[s : s + chunk], patch[s : s + chunk], budget, chunk)
                for s in range(0, len(points), chunk)
            ]
            return tuple(np.concatenate(x) for x in zip(*parts))
        n = len(points)
        depth, hgap, foot, chain = np.full(n, np.inf), np.zeros(n), points.copy(), np.full(n, -1, np.int64)
        mouth = np.full(n, -1, np.int64)
        pairs = self._pairs(points, patch, budget) if pairs is None else pairs
        if pairs is None or not len(pairs[0]):
            return depth, hgap, foot, chain, mouth
        i, ch, hit = pairs[:3]
        i, ch = i[hit], ch[hit]
        touching = np.bincount(i, self.chain_gap[ch] <= self.min_gap, n) > 0
        # per point the covering face (parallel to the plane, as the transfer's walls are: not a
        # crossing solid's outline, a vase's curved side) with the nearest mouth
        keep = ~self.chain_signed[ch] & ~touching[i]
        i, ch = i[keep], ch[keep]
        M = self.slot_mouths()
        pr, mk = csr_rows(M["start"], ch)
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
        return self.slot_transfers(points, patch, chain, [(rho, reflectance)])[0]

    def slot_transfers(self, points, patch, chain, walls):
        """[slot_transfer(points, patch, chain, rho, reflectance) for (rho, reflectance) in walls],
        the same values: the mouths' geometry found once for every pair of reflectances (the
        gather's slot samples take two: their own, and black walls for the mouths' view factor)."""
        walls = [(np.asarray(rho, float), reflectance) for rho, reflectance in walls]
        outs = [np.zeros(rho.shape) for rho, _ in walls]
        j = np.flatnonzero(np.asarray(chain) >= 0)
        if not len(j):
            return outs
        c = np.asarray(chain)[j]
        M = self.slot_mouths()
        pr, sg = csr_rows(M["start"], c)
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
            t = np.stack([ray_exit(f, u, c[:, i], c[:, (i + 1) % 4]) for i in range(4)], 1)
            ext[q] = np.where((t > 0).sum(1) % 2 == 1, t.max(1), 0.0)  # 0: the foot is off the patch
        side = []  # (facing, mouths, their depth and extension in gap widths, frac, rows)
        for fc in (False, True):
            w = np.flatnonzero(own == fc)
            side.append((fc, w, x[w] / hs[w], ext[w] / hs[w], frac[w, None], j[pr[w]]))
        for (rho, reflectance), out in zip(walls, outs):
            other = self._other_wall(sg, reflectance)
            C = rho.shape[1]
            # grey walls (the gather's black pair for the mouths' view factor): every channel's
            # sums are the same numbers, so one channel is computed and copied (GREY_ONCE)
            grey = GREY_ONCE and C > 1 and (rho == rho[:, :1]).all() and (other == other[:, :1]).all()
            if grey:
                rho, other = rho[:, :1], other[:, :1]
            E = np.zeros((len(sg), rho.shape[1]))
            for fc, w, xw, ew, fw, rw in side:
                E[w] = fw * slot_irradiance(xw, rho[rw], other[w], ew, fc)
            for k in range(rho.shape[1]):
                out[j, k] = np.bincount(pr, E[:, k], len(j))
            if grey:
                out[j, 1:] = out[j, :1]
        return outs

    def _other_wall(self, mouth, reflectance):
        """(M, C) the reflectance of the gap's other wall at mouths (M,): 0 where the occluder's
        back faces the slot (a one-sided surface reflects nothing behind it)."""
        wall = self.slot_mouths()["wall"][mouth]
        return np.where((wall >= 0)[:, None], np.asarray(reflectance)[:, np.maximum(wall, 0)].T, 0.0)

    def through_mouth(self, mouth, xi, rho, reflectance):
        """(N, C) irradiance / pi that points of reflectance rho (N, C) at depth xi (N,) gap widths
        behind mouths (N,) (slots()) receive straight through them from an outside of radiance 1:
        the mouth's view factor, or where the covering face goes on beyond the surface's own edge,
        the outside past it and its light (slots.slot_seen). What their gather finds there."""
        M = self.slot_mouths()
        own = M["own"][mouth]
        out = np.repeat(slot_mouth(xi)[:, None], np.shape(rho)[1], 1)
        w = np.flatnonzero(own)
        h = M["height"][mouth[w]]
        out[w] = slot_seen(
            xi[w], np.asarray(rho)[w], self._other_wall(mouth[w], reflectance), M["ext"][mouth[w]] / h
        )
        return out

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
        i, k = box_pairs(qq - tol, qq + tol, lo - tol, hi + tol, gi, self.plane)
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
        i, k = box_pairs(lo_s, hi_s, lo_r, hi_r, self.chain_plane[ch_s], rg)
        seg, pa, pb = self._cut(self.seg_a[s], self.seg_b[s], i, ra[k], rb[k])
        on = self._in_surface(self.chain_plane[ch_s[seg]], (pa + pb) / 2, tol)
        parts = [(ch_s[seg[on]], pa[on], pb[on], np.zeros(on.sum(), bool))]
        # the surface's edges, cut where the face's outline crosses them, strictly inside the face
        c = np.flatnonzero(cov)
        i, k = box_pairs(lo_r, hi_r, self.chain_lo[c] - tol, self.chain_hi[c] + tol, rg, self.chain_plane[c])
        if len(i):
            ch = c[k]
            pr, sg = csr_rows(self.chain_start, ch)
            seg, pa, pb = self._cut(ra[i], rb[i], pr, self.seg_a[sg], self.seg_b[sg])
            mid = (pa + pb) / 2
            w = self._winding(ch[seg], mid)
            # its distance to the face's outline: a surface edge along the face's edge is that edge
            pr2, sg2 = csr_rows(self.chain_start, ch[seg])
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
        pr, sg = csr_rows(self.chain_start, ch[k])
        t = ray_exit(
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

    def may_slot(self, patch, corners=None):
        """Boolean (K,): patches (K,) that slots() may find points in a slot on: their 2D box meets
        the box of a covering face of another piece (not a crossing solid's outline) standing off
        their plane by more than min_gap, with an open mouth (after close_mouths, if called).
        corners (K, 4, 3): the boxes of these instead (a finer face on each patch, in its plane)."""
        patch = np.asarray(patch, np.int64)
        M = self.slot_mouths()
        ch = np.flatnonzero(~self.chain_signed & (self.chain_gap > self.min_gap))
        ch = ch[np.isin(ch, M["chain"][M["open"]])]
        gi = self.plane[patch]
        p2 = self._to2d(gi, self.patches.corners[patch] if corners is None else corners)
        z = np.zeros((len(patch), 1))
        lo, hi = np.concatenate([p2.min(1), z], 1), np.concatenate([p2.max(1), z], 1)
        i, j = box_pairs(lo, hi, self.chain_lo[ch], self.chain_hi[ch], gi, self.chain_plane[ch])
        out = np.zeros(len(patch), bool)
        out[i[self.chain_piece[ch[j]] != self.piece[patch[i]]]] = True
        return out

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
# slot_transfers: walls of one reflectance in every channel (the gather's black pair) looked up in
# one channel, copied to the others (the same numbers: each channel's arithmetic is its own)
GREY_ONCE = True
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
        # one update (threads may race to build them: a reader sees none or all of them)
        T = {k: np.stack(v) for k, v in T.items()}
        _SLOT.update(T, logx=np.log(x), p=p, ext=np.log1p(np.array(SLOT_EXT)))
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
    # only the 8 table entries around each point (interpolating whole (E, P) planes first cost
    # the furnished room's precompute 23 s of 63); the same operations in the same order
    j, m, f, fe = j[:, None], m[:, None], f[:, None], fe[:, None]
    _, P, n = T[names[0]].shape  # (E, P, n), every table
    at = (m * P + k) * n + j  # (N, C) the flat index of entry (m, k, j): one index for all 8 takes
    out = []
    for name in names:
        M = T[name].ravel()

        def at_p(b):  # (N, C): interpolated in depth, then in ext, at flat entries b (N, C)
            return (M.take(b) * (1 - f) + M.take(b + 1) * f) * (1 - fe) + (
                M.take(b + P * n) * (1 - f) + M.take(b + P * n + 1) * f
            ) * fe

        out.append(at_p(at) * (1 - fq) + at_p(at + n) * fq)
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
