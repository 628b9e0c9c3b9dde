"""HSA refinement (Hanrahan, Salzman, Aupperle 1991), vectorised over batches of node pairs.

Pairs (p, q) are unordered. A pair becomes a link once both form factor estimates are below Feps
(or BF, the estimate weighted by reflectance and source radiosity, is below BFeps), or neither node
may be split (area below Aeps). Otherwise the node that looks larger from the other is split and
the pair is replaced by four child pairs. A link partly occluded (0 < V < 1) with a form factor
above shadow_feps is split further so shadow boundaries get resolution.

One geometric computation serves both directions: F is integrated from the smaller node to the
larger (sample points on the small one, exact contour integral over the large one) and the other
direction follows from reciprocity, so A_p F_pq = A_q F_qp exactly and neither exceeds 1.
"""

import time

import numpy as np

from . import formfactor as ff
from .boxes import sorted_index
from .corrections import push_corrections
from .hierarchy import Hierarchy
from .links import Links
from .parallel import add_counts, batch_map, ranges, spans
from .params import RefineParams
from .planes import Occluders
from .progress import NO_PROGRESS

# RefineParams, Links and push_corrections have their own modules; importable from here as before
__all__ = [
    "Links",
    "RefineParams",
    "Refiner",
    "initial_pairs",
    "link_form_factors",
    "push_corrections",
]

# node pairs of a level per map of Refiner.refine (its outputs held until the level's splits are made)
LEVEL_PAIRS = 1 << 18
# links per batch of the final form factors and shadow tests on threads (core.parallel): fixed, so
# the values do not depend on the thread count; small enough that a 10k-triangle room has many (up
# to 4x as many links per batch in large maps: parallel.spans)
LINK_BATCH = 1 << 13
# pairs per batch of the refinement rounds' oracle and nodes per batch of the exposed-part form
# factors (grown up to 4x in large maps, as LINK_BATCH): many numpy calls on each batch's arrays
# that hold the GIL for their set-up, so on two threads each call can hand the GIL over (a futex
# wake, a switch: docs/threads.md, session 38); larger batches make fewer calls per pair
ORACLE_BATCH = 1 << 15
EXPOSED_BATCH = LINK_BATCH
# patch links' visibility from the segments that leave both points in front (visibility())
FRONT_ONLY = True
# patch links that neither end can split (area <= aeps) and whose form factor is above shadow_feps
# (the oracle would have shadow-tested them): their visibility from 2 x 2 points an end (16
# segments, _unsplit_visibility) instead of vis_k^2; False: vis_k^2 as for every other link
# (issue 19, pl32: the draft's one ray read them 0 or 1)
UNSPLIT_2X2 = True
UNSPLIT_SEGMENTS = 16  # 16: every pair of the 2 x 2 points; 4: point i to 3 - i (as weak links)
# benchmarks/kernel_split.py --all-links: keep the patch links traced wholly occluded (their
# visibility 0: no transfer), so that their exact exchange can be measured
KEEP_OCCLUDED = False
# partly covered nodes per batch of their exposed grids and visibility points (Refiner.contacts):
# a batch's distance array is (N, vis_k^2, its largest exposed count, 3), up to 100 MB at 1024
# nodes, and every thread holds one
NODE_BATCH = 1 << 8


def _facing(h, p, q, tol):
    """True where some corner of q is in front of p's plane and vice versa (else no exchange).
    The second test only on the pairs that pass the first (each row is its own: the same answer)."""

    def front(x, y):  # (rows by np.take: contiguous, 1.4x faster than fancy indexing here)
        o, n = np.take(h.centre, x, 0), np.take(h.normal, x, 0)
        g = np.einsum("nkj,nj->nk", np.take(h.corners, y, 0) - o[:, None], n) > tol
        return (g[:, 0] | g[:, 1]) | (g[:, 2] | g[:, 3])  # .any(1) over 4 columns costs 10x

    out = front(p, q)
    i = np.flatnonzero(out)
    out[i] = front(q[i], p[i])
    return out


def initial_pairs(h: Hierarchy, chunk=2_000_000):
    """All root pairs that can exchange light (by plane-side tests)."""
    k = len(h.patches.nv)
    tol = 1e-9 * np.sqrt(h.patches.area.sum())
    ps, qs = [], []
    iu, ju = np.triu_indices(k, 1)
    for s in range(0, len(iu), chunk):
        p, q = iu[s : s + chunk], ju[s : s + chunk]
        ok = _facing(h, p, q, tol)
        ps.append(p[ok])
        qs.append(q[ok])
    return np.concatenate(ps) if ps else np.zeros(0, np.int64), np.concatenate(qs) if qs else np.zeros(
        0, np.int64
    )


def link_form_factors(h: Hierarchy, a, b, max_order=3):
    """Unoccluded F[a->b] and F[b->a] by integrating from the smaller node to the larger, with
    at most max_order x max_order Gauss points on it."""
    small = h.area[a] <= h.area[b]
    s, big = np.where(small, a, b), np.where(small, b, a)
    d2 = np.sum((h.centre[s] - h.centre[big]) ** 2, axis=1)
    size2 = h.area[s] + h.area[big]
    # Gauss points by proximity: the contour integral over the large node is exact, the error comes
    # from the small node's extent, which matters only when it is close (3 x 3 Gauss: ~1e-4 on
    # touching unit squares, measured).
    k = np.minimum(np.where(d2 < 4 * size2, 3, np.where(d2 < 40 * size2, 2, 1)), max_order)
    f_sl = np.zeros(len(s))
    for kk in (1, 2, 3):
        m = np.flatnonzero(k == kk)
        if len(m) == 0:
            continue
        # the small nodes' Gauss points and the large ones' planes once per node (a node is an
        # end of several links; every node's values are its own: the same values)
        us, js = np.unique(s[m], return_inverse=True)
        pts, w = ff.quadrature(h.corners[us], h.nv[us], kk)  # (U, kk^2, 3)
        ns = kk * kk
        ub, jb = np.unique(big[m], return_inverse=True)
        c = ff._padded(h.corners[ub], h.nv[ub])
        qn, qa = ff.polygon_normal_area(c)
        normal = h.normal[s[m]]
        # the (link, Gauss point) rows gathered block by block, not all at once: a batch's rows
        # (up to 2^15 links x 9) made arrays of tens of MB, memory traffic and, when malloc hands
        # them back, page faults (issue 23, docs/threads.md, session 36); every row is its own:
        # the same values
        step = max(min(ff.POINT_BLOCK // ns, len(m)), 1)
        # each row's link in the block (np.repeat's copies hold the GIL throughout: takes do not)
        rows = np.repeat(np.arange(step), ns)
        for i in range(0, len(m), step):
            bs, r = js[i : i + step], rows[: ns * len(js[i : i + step])] + i
            bb = np.take(jb, r)
            vals = ff._point_to_polygon(pts[bs].reshape(-1, 3), np.take(normal, r, 0), c[bb], qn[bb], qa[bb])
            f_sl[m[i : i + step]] = np.sum(vals.reshape(-1, ns) * w[bs], axis=1)
    f_sl = np.clip(f_sl, 0.0, 1.0)
    f_ls = f_sl * h.area[s] / h.area[big]
    return np.where(small, f_sl, f_ls), np.where(small, f_ls, f_sl)


class Refiner:
    """Builds and edits the link set of a hierarchy."""

    def __init__(self, h: Hierarchy, backend, params: RefineParams):
        self.h, self.backend, self.params = h, backend, params
        self.total_area = float(h.patches.area.sum())
        self.eps = 1e-6 * np.sqrt(self.total_area)  # ray end offset along normals
        self.progress = NO_PROGRESS
        self._contacts = None  # contacts.Contacts when some surface is touched
        # partly covered nodes (sorted) and their exposed sample points, centres, and form factor
        # points: node i's are _ff_pts[_ff_ptr[i] : _ff_ptr[i + 1]] (CSR: their count varies)
        self._vis_nodes = self._vis_pts = self._ex_centre = None
        self._vis_pts2 = None  # partly covered nodes' 2 x 2 points for _unsplit_visibility
        self._ff_pts, self._ff_ptr = np.zeros((0, 3)), np.zeros(1, np.int64)
        self.stats = {
            "rays": 0,
            "pairs_tested": 0,
            "pairs_culled": 0,
            "unsplit_links": 0,
            "cluster_pairs": 0,
            "t_vis": 0.0,
            "t_ff": 0.0,
            "t_refine": 0.0,
        }
        self.occluders = Occluders(h.patches)

    @property
    def threads(self):
        return self.backend.threads

    def _maybe_occluded(self, a, b, boxes=None):
        """Shaft test of node pairs (planes.Occluders): False where the pair is certainly
        unoccluded and needs no rays. boxes: (lo_a, hi_a, lo_b, hi_b) when the caller has them."""
        h = self.h
        if len(self.occluders) > 512:
            # measured: past a few hundred occluders, the brute-force box test costs more than the rays
            return np.ones(len(a), bool)
        if boxes is None:
            boxes = (h.corners[a].min(1), h.corners[a].max(1), h.corners[b].min(1), h.corners[b].max(1))
        lo = np.minimum(boxes[0], boxes[2]) - self.eps
        hi = np.maximum(boxes[1], boxes[3]) + self.eps
        plane = self.occluders.patch_plane
        return self.occluders.maybe_occluded(lo, hi, plane[h.patch[a]], plane[h.patch[b]])

    def visibility(self, a, b, weak=None):
        """Fraction of vis_k^2 x vis_k^2 segments between the two nodes that are unoccluded;
        weak links (mask) trace only the vis_k^2 segments from point i to point s - 1 - i."""
        t0 = time.perf_counter()
        h, k = self.h, self.params.vis_k
        vis = np.ones(len(a))
        test = self._maybe_occluded(a, b)
        a, b = a[test], b[test]
        weak = np.zeros(len(a), bool) if weak is None else np.asarray(weak, bool)[test]
        if len(a) == 0:
            add_counts(self.stats, pairs_culled=len(test), t_vis=time.perf_counter() - t0)
            return vis
        pa = self.sample_points(a) + self.eps * h.normal[a][:, None]
        pb = self.sample_points(b) + self.eps * h.normal[b][:, None]
        s = k * k
        out = np.empty(len(a))
        st = ~weak
        rays = 0
        if FRONT_ONLY:
            out[:] = self._front_visibility(a, b, pa, pb, weak)
            rays = int(st.sum()) * s * s + int(weak.sum()) * s
            redo = np.flatnonzero(np.isnan(out))
            if len(redo):  # no segment leaves both points in front: the 2 x 2 points' segments
                out[redo], n2 = self._front_visibility_2x2(a[redo], b[redo], weak[redo])
                rays += n2
        else:
            if st.any():
                ra = np.repeat(pa[st], s, axis=1).reshape(-1, 3)
                rb = np.tile(pb[st], (1, s, 1)).reshape(-1, 3)
                out[st] = 1.0 - self.backend.occluded(ra, rb).reshape(-1, s * s).mean(1)
            if weak.any():
                out[weak] = 1.0 - self.backend.occluded(pa[weak], pb[weak][:, ::-1]).mean(1)
            rays = int(st.sum()) * s * s + int(weak.sum()) * s
        vis[test] = out
        add_counts(
            self.stats,
            pairs_culled=len(test) - len(a),
            rays=rays,
            t_vis=time.perf_counter() - t0,
        )
        return vis

    def _front_visibility(self, a, b, pa, pb, weak, cov_a=None, cov_b=None):
        """visibility()'s value from the segments between points pa (N, s, 3) and pb that leave
        both points in front of the other node's plane (and neither on a covered part, cov_*
        (N, s) if given): the unoccluded share of their kernel cos cos / r^2 (strong: every pair
        of points; weak: point i to s - 1 - i); nan where no segment counts. A segment leaving a
        point behind the other node (nodes that face each other only partly: a book's side and
        the board under it, a bookcase side and a shelf) starts or ends on the far side of a
        face whose own solid blocks it, while the form factor gives that part nothing: counted,
        it read such links dark or dropped them (issue 19, kern31)."""
        h, s = self.h, pa.shape[1]
        na, nb = h.normal[a], h.normal[b]
        out = np.full(len(a), np.nan)
        for sel, strong in ((~weak, True), (weak, False)):
            if not sel.any():
                continue
            A, B = pa[sel], pb[sel]
            if strong:
                A = np.repeat(A, s, axis=1)
                B = np.tile(B, (1, s, 1))
            else:
                B = B[:, ::-1]
            d = B - A
            ca = np.einsum("nsk,nk->ns", d, na[sel])
            cb = -np.einsum("nsk,nk->ns", d, nb[sel])
            r2 = np.maximum(np.einsum("nsk,nsk->ns", d, d), 1e-300)
            front = (ca > 0) & (cb > 0)
            if cov_a is not None:
                ia = np.repeat(cov_a[sel], s, axis=1) if strong else cov_a[sel]
                ib = np.tile(cov_b[sel], (1, s)) if strong else cov_b[sel][:, ::-1]
                front &= ~(ia | ib)
            occ = self.backend.occluded(A.reshape(-1, 3), B.reshape(-1, 3)).reshape(front.shape)
            v = ff.unoccluded_share(front, occ, ca * cb / (r2 * r2))
            out[np.flatnonzero(sel)] = np.where(front.any(1), v, np.nan)
        return out

    def _front_visibility_2x2(self, a, b, weak):
        """_front_visibility of links none of whose segments count, from their nodes' 2 x 2 Gauss
        points (points on covered parts left out; weak links: the 4 segments i -> 3 - i); 0 where
        none counts there either. Returns (visibility, rays traced)."""
        h = self.h
        # points and covered flags once per distinct node (a node ends many links; bld32's
        # profile at 100k: the per-link covered test 1.5 s, the points 0.5 s): the same values
        u, inv = np.unique(np.r_[a, b], return_inverse=True)
        pu = ff.sample_points(h.corners[u], h.nv[u], 2) + self.eps * h.normal[u][:, None]
        cu = np.zeros((len(u), 4), bool)
        if self._contacts is not None:
            cu = self._contacts.covered(pu.reshape(-1, 3), np.repeat(h.patch[u], 4)).reshape(-1, 4)
        ia, ib = inv[: len(a)], inv[len(a) :]
        v = self._front_visibility(a, b, pu[ia], pu[ib], weak, cu[ia], cu[ib])
        return np.nan_to_num(v, nan=0.0), 16 * int((~weak).sum()) + 4 * int(weak.sum())

    def _unsplit_visibility(self, a, b):
        """Visibility of strong patch links neither end of which can be split (area <= aeps; the
        oracle could not shadow-test them): _front_visibility of the 16 segments between the
        nodes' 2 x 2 points (on a partly covered node, 4 points spread over its exposed part:
        Refiner.contacts), 0 where none counts. With vis_k 1 such a link's one ray read it 0
        or 1 at one point: a book's side and the board it stands on, the bookcase side beside
        it, dropped whole (8.7% of the 20k room's exchange at a dense visibility of 0.24, issue
        19, pl32). Culled pairs (_maybe_occluded) read 1. Returns (visibility, rays)."""
        h = self.h
        vis = np.ones(len(a))
        test = self._maybe_occluded(a, b)
        a, b = a[test], b[test]
        if not len(a):
            return vis, 0
        u, inv = np.unique(np.r_[a, b], return_inverse=True)  # points once per distinct node
        pu = ff.sample_points(h.corners[u], h.nv[u], 2)
        if self._vis_pts2 is not None:
            i = self._partial(u)
            hit = i >= 0
            pu[hit] = self._vis_pts2[i[hit]]
        pu += self.eps * h.normal[u][:, None]
        ia, ib = inv[: len(a)], inv[len(a) :]
        weak = np.full(len(a), UNSPLIT_SEGMENTS == 4)
        v = self._front_visibility(a, b, pu[ia], pu[ib], weak)
        vis[test] = np.nan_to_num(v, nan=0.0)
        return vis, UNSPLIT_SEGMENTS * len(a)

    def leaf_visibility(self, leaf, src, batch=1 << 14):
        """Visibility of source nodes from leaves (push corrections, corrections.py): the unoccluded
        share of the vis_k^2 segments of a weak link (point i to point s - 1 - i), each weighted by
        the kernel cos cos / r^2 that the transfer weights it with. An unweighted fraction counts a
        grazing segment that a box on the floor hides as much as a steep one that it does not: it
        read the visible share of a wall behind a panel 0.714 where it is 0.766 (weighted: 0.763,
        tests/test_refine_rowsum.py) and the band beside a box too dark."""

        h = self.h
        # the pairs repeat their leaves and sources: points and boxes once per distinct node
        u, inv = np.unique(np.r_[leaf, src], return_inverse=True)
        pts = self.sample_points(u) + self.eps * h.normal[u][:, None]
        lo, hi = h.corners[u].min(1), h.corners[u].max(1)
        ia, ib = inv[: len(leaf)], inv[len(leaf) :]

        def part(i, j):
            a, b, xa, xb = leaf[i:j], src[i:j], ia[i:j], ib[i:j]
            out = np.ones(len(a))
            test = np.flatnonzero(self._maybe_occluded(a, b, (lo[xa], hi[xa], lo[xb], hi[xb])))
            if len(test) == 0:
                return out
            a, b, pa, pb = a[test], b[test], pts[xa[test]], pts[xb[test]][:, ::-1]
            d = pb - pa
            w = np.maximum(np.einsum("nkj,nj->nk", d, h.normal[a]), 0) * np.maximum(
                -np.einsum("nkj,nj->nk", d, h.normal[b]), 0
            )
            w /= np.maximum(np.einsum("nkj,nkj->nk", d, d), 1e-300) ** 2
            # no segment in front of both (the pair's corners exchange light, its sample points not)
            w[w.sum(1) <= 0] = 1.0
            seen = ~self.backend.occluded(pa, pb)
            out[test] = (w * seen).sum(1) / w.sum(1)
            add_counts(self.stats, rays=pa.shape[0] * pa.shape[1])
            return out

        parts = batch_map(part, ranges(len(leaf), batch), self.threads)
        return np.concatenate(parts) if parts else np.zeros(0)

    def contacts(self):
        """Refine partly covered receivers along their contacts and set node exposures
        (contacts.py) before any link is made. Returns the Contacts (None if off or none)."""
        from .contacts import Contacts, exposed_points, refine_contacts

        prm, h = self.params, self.h
        if not prm.contacts:
            return None
        c = Contacts(h.patches, prm.contact_gap * np.sqrt(self.total_area), self.threads)
        self._contacts = h.contacts = c if c.any else None
        if c.any:
            min_area = prm.aeps * self.total_area / 4**prm.contact_levels
            self.stats["contact_nodes"] = refine_contacts(h, c, min_area, threads=self.threads)
            ex = h.view("exposure")
            part = np.flatnonzero((ex > 0) & (ex < 1))
            # visibility points and centres of partly covered nodes: from about 6 x 6 points on
            # their exposed part (_exposed_grid)
            fp, seen = self._exposed_grid(part, ex[part])

            # by blocks of nodes, each cut to its own largest count: exposed_points compares every
            # sample point with every grid point, (N, vis_k^2, M, 3), 1.1 GB at once at 100k
            def block(i, j):
                m = max(int(seen[i:j].sum(1).max()), 1)
                return exposed_points(h, c, part[i:j], prm.vis_k, fp[i:j, :m], seen[i:j, :m])

            vis_pts = batch_map(block, ranges(len(part), NODE_BATCH), self.threads)
            self._vis_nodes = part
            self._vis_pts = np.concatenate(vis_pts) if vis_pts else np.zeros((0, prm.vis_k**2, 3))
            if prm.vis_k < 2 and UNSPLIT_2X2:
                # _unsplit_visibility's 2 x 2 points on a partly covered node: 4 of its exposed
                # grid's points (in grid order) at the quarters of their count, spread over the
                # exposed part. Tried first: vis_k 2's rule (exposed_points: each covered point
                # moved to the nearest exposed one, next to what covers it): the links with a
                # partly covered end read 0.38 against a dense 0.46 (the 20k room), here 0.56
                # over the whole class against 0.58 (issue 19, pl32)
                n = seen.sum(1)
                pick = np.minimum(((np.arange(4) + 0.5) / 4 * n[:, None]).astype(np.int64), fp.shape[1] - 1)
                self._vis_pts2 = ff.sample_points(h.corners[part], h.nv[part], 2)
                has2 = n > 0
                self._vis_pts2[has2] = np.take_along_axis(fp, pick[..., None], 1)[has2]
            # the near links' form factors from a coarser grid of their own (params.ff_exposed)
            fq, sq = self._exposed_grid(part, ex[part], prm.ff_exposed)
            self._ff_pts, self._ff_ptr = fq[sq], np.r_[0, np.cumsum(sq.sum(1))]
            # the oracle estimates F from centres: a partly covered node's is that of its exposed
            # part (its own centre may lie under a box, behind the box's side)
            has = seen.any(1)
            w = seen / np.maximum(seen.sum(1, keepdims=True), 1)
            self._ex_centre = h.centre[part].copy()
            self._ex_centre[has] = np.einsum("nk,nkj->nj", w[has], fp[has])
        self.stats["contact_receivers"] = len(c.receivers)
        return c

    def _exposed_grid(self, nodes, exposure, target=6):
        """Form-factor points of partly covered nodes: a k x k grid per node with k such that about
        target^2 points fall on its exposed part (k = target / sqrt(exposure), at most 4 x
        target), the exposed ones first. Returns points (N, M, 3) and seen (N, M) (padding: False)."""
        h, c = self.h, self._contacts
        k = np.clip(np.ceil(target / np.sqrt(np.maximum(exposure, 1e-12))), target, 4 * target).astype(int)

        def group(kk, sel):  # the nodes sel, all with a kk x kk grid; every node's points are its own
            pts = ff.sample_points(h.corners[nodes[sel]], h.nv[nodes[sel]], kk)
            ok = ~c.covered(pts.reshape(-1, 3), np.repeat(h.patch[nodes[sel]], kk * kk)).reshape(len(sel), -1)
            order = np.argsort(~ok, axis=1, kind="stable")  # exposed points first, in grid order
            return sel, np.take_along_axis(pts, order[..., None], 1), np.take_along_axis(ok, order, 1)

        batches = []
        for kk in np.unique(k):
            sel = np.flatnonzero(k == kk)
            batches += [(int(kk), sel[i:j]) for i, j in ranges(len(sel), NODE_BATCH)]
        groups = batch_map(group, batches, self.threads)
        M = max([max(int(g[2].sum(1).max()), 1) for g in groups] + [target * target])
        fp, seen = np.empty((len(nodes), M, 3)), np.empty((len(nodes), M), bool)

        def fill(sel, pts, ok):  # every node is in one group: its rows, padded with its centre
            m = min(M, pts.shape[1])
            fp[sel, :m], seen[sel, :m] = pts[:, :m], ok[:, :m]
            fp[sel, m:], seen[sel, m:] = h.centre[nodes[sel]][:, None], False

        # the rows written on the threads (issue 23: serial, the (nodes, M, 3) array's fresh pages
        # and its fill, docs/threads.md, session 37)
        batch_map(fill, groups, self.threads)
        return fp, seen

    def _exposed_form_factors(self, a, b, f_ab, f_ba, chunk=None):
        """Links with a partly covered end: F integrated over that end's exposed part (its
        covered part sees nothing; a box's side, say, is behind it), the other direction by
        reciprocity, so the kernel stays symmetric (in place)."""
        if self._vis_nodes is None or not len(self._vis_nodes):
            return
        h = self.h
        ia, ib = self._partial(a), self._partial(b)
        n = np.diff(self._ff_ptr)
        ia[ia >= 0] = np.where(n[ia[ia >= 0]] > 0, ia[ia >= 0], -1)
        ib[ib >= 0] = np.where(n[ib[ib >= 0]] > 0, ib[ib >= 0], -1)
        # far apart, the kernel is smooth across the node: its Gauss points do (as in
        # link_form_factors' choice of order)
        near = np.sum((h.centre[a] - h.centre[b]) ** 2, 1) < 40 * (h.area[a] + h.area[b])
        use_a = near & (ia >= 0) & ((ib < 0) | (h.area[a] <= h.area[b]))
        use_b = near & (ib >= 0) & ~use_a
        for sel, x, y, ix in ((use_a, a, b, ia), (use_b, b, a, ib)):
            m = np.flatnonzero(sel)

            def batch(i, j, x=x, y=y, ix=ix, m=m):  # every batch writes its own links
                mm = m[i:j]
                xs, ys = x[mm], y[mm]
                fx = np.clip(self._exposed_ff(ix[mm], xs, ys), 0.0, 1.0)
                # reciprocity; the larger end integrated can give the smaller one F > 1: clipped
                fy = np.minimum(fx * h.area[xs] / h.area[ys], 1.0)
                fx = fy * h.area[ys] / h.area[xs]
                if x is a:
                    f_ab[mm], f_ba[mm] = fx, fy
                else:
                    f_ba[mm], f_ab[mm] = fx, fy

            batch_map(batch, spans(len(m), chunk or EXPOSED_BATCH), self.threads)

    def _exposed_ff(self, k, x, y):
        """F from the exposed part of partly covered nodes x (k: their index in _vis_nodes) to
        polygons y: the point form factor averaged over their exposed form-factor points. Only
        those are evaluated: a grid padded to the largest count cost 3.8x (152 for 40 on average,
        20k furnished room)."""
        h = self.h
        start, n = self._ff_ptr[k], np.diff(self._ff_ptr)[k]
        row = np.repeat(np.arange(len(k)), n)
        first = np.cumsum(n) - n  # each row's first entry in the flat (pair, point) arrays
        pts = self._ff_pts[start[row] + np.arange(len(row)) - first[row]]
        qn, qa = ff.polygon_normal_area(h.corners[y], h.nv[y])  # once per link, not per point
        y = y[row]
        vals = ff.point_to_polygon(pts, h.normal[x][row], h.corners[y], h.nv[y], (qn[row], qa[row]))
        return np.bincount(row, vals * (1.0 / np.maximum(n, 1))[row], minlength=len(k))

    def leaf_form_factors(self, leaf, src, chunk=20_000):
        """(F, mask): for leaves partly covered by contacts (mask), the point form factor to the
        polygons src averaged over the leaf's exposed part; the push corrections take the shape
        of a link's form factor from it (a single point beside a contact line is no mean: there
        F falls from 0.5 to a few percent across one leaf)."""
        k = self._partial(leaf)
        has = k >= 0
        out = np.zeros(len(leaf))
        if not has.any():
            return out, has
        has[has] = np.diff(self._ff_ptr)[k[has]] > 0
        m = np.flatnonzero(has)
        for s0 in range(0, len(m), chunk):
            mm = m[s0 : s0 + chunk]
            out[mm] = self._exposed_ff(k[mm], leaf[mm], src[mm])
        return out, has

    def centres(self, nodes):
        """Node centres for the oracle, of the exposed part where a node is partly covered."""
        c = self.h.centre[nodes]
        i = self._partial(nodes)
        hit = i >= 0
        if hit.any():
            c[hit] = self._ex_centre[i[hit]]
        return c

    def sample_points(self, nodes):
        """Visibility sample points (N, vis_k^2, 3): stratified over each node, moved off its
        covered part for partly covered nodes."""
        h, k = self.h, self.params.vis_k
        pts = ff.sample_points(h.corners[nodes], h.nv[nodes], k)
        i = self._partial(nodes)
        hit = i >= 0
        if hit.any():
            pts[hit] = self._vis_pts[i[hit]]
        return pts

    def _partial(self, nodes):
        """Index of each node among the partly covered ones (_vis_nodes, sorted), -1 if not one."""
        return sorted_index(np.zeros(0, np.int64) if self._vis_nodes is None else self._vis_nodes, nodes)

    def refine(self, p, q, good_enough=None):
        """HSA loop from candidate pairs (p, q); returns the new Links.

        good_enough(p, q, f_pq, f_qp) -> bool mask may replace the Feps test (BF refinement).
        A pair whose shadow test found all its vis_k^2 x vis_k^2 segments unoccluded hands that
        on: the pairs it splits into need no rays (as in HR).

        Breadth-first: a level's pairs (those the last level's splits made) in maps of up to
        LEVEL_PAIRS pairs (issue 23: the depth-first loop over sets of up to 100k pairs it replaced
        ran 81 maps at 100k, docs/threads.md, sessions 34-35); node ids and the links' order are
        the levels' own, fixed by LEVEL_PAIRS and not by the thread count."""
        t0 = time.perf_counter()
        h, prm = self.h, self.params
        aeps = prm.aeps * self.total_area
        out = []
        p, q = np.asarray(p, np.int64), np.asarray(q, np.int64)
        kv = np.full(len(p), np.nan)  # 1: known to be wholly visible, nan: unknown
        tol = 1e-9 * np.sqrt(self.total_area)
        done, total = 0, len(p)
        while len(p):
            self.stats["pairs_tested"] += len(p)
            kids = []  # the next level's pairs (p, q, kv)
            for i, j in ranges(len(p), LEVEL_PAIRS):
                x, y, k = p[i:j], q[i:j], kv[i:j]
                done += j - i
                self.progress.update("linking", done, total)
                # the oracle by batches of pairs on threads (each pair on its own), then the splits
                parts = batch_map(
                    lambda i, j: self._oracle(x[i:j], y[i:j], k[i:j], good_enough, aeps, tol),
                    spans(len(x), ORACLE_BATCH),
                    self.threads,
                )
                x, y, vis, link, split_p, split_q = (np.concatenate(c) for c in zip(*parts))
                del parts
                if link.any():
                    out.append((x[link], y[link], vis[link]))
                sp_p, sp_q = x[split_p], y[split_p]  # p split: pairs (child of p, q)
                sq_p, sq_q = x[split_q], y[split_q]  # q split: pairs (p, child of q)
                h.subdivide(np.unique(np.concatenate([sp_p, sq_q])))
                total += 4 * (len(sp_p) + len(sq_p))
                kn = np.where(vis == 1, 1.0, np.nan)
                kids.append(
                    (
                        np.concatenate([h.children(sp_p).ravel(), np.repeat(sq_p, 4)]),
                        np.concatenate([np.repeat(sp_q, 4), h.children(sq_q).ravel()]),
                        np.concatenate([np.repeat(kn[split_p], 4), np.repeat(kn[split_q], 4)]),
                    )
                )
            p, q, kv = (np.concatenate(c) for c in zip(*kids)) if kids else (p[:0], q[:0], kv[:0])
        self.stats["t_refine"] += time.perf_counter() - t0
        return self._finish(out)

    def _oracle(self, p, q, kv, good_enough, aeps, tol):
        """refine's test of the pairs (p, q) (kv: known visibility): every pair on its own, no
        hierarchy edit, so batches of pairs run on threads. Returns the pairs that can exchange
        light, their visibility (nan: not tested) and the masks link, split p, split q."""
        h, prm = self.h, self.params
        # the estimates only of the pairs that face and are exposed (27% of them in the 20k room):
        # every pair's estimate is its own, so the same values
        may = np.flatnonzero((h.exposure[p] > 0) & (h.exposure[q] > 0))
        may = may[_facing(h, p[may], q[may], tol)]
        p, q, kv = p[may], q[may], kv[may]
        cp, cq = self.centres(p), self.centres(q)
        f_pq = ff.estimate(cp, h.normal[p], h.area[p], h.corners[q], cq, h.normal[q], h.area[q])
        f_qp = ff.estimate(cq, h.normal[q], h.area[q], h.corners[p], cp, h.normal[p], h.area[p])
        fmax = np.maximum(f_pq, f_qp)
        alive = fmax > 0
        p, q, f_pq, f_qp, fmax, kv = p[alive], q[alive], f_pq[alive], f_qp[alive], fmax[alive], kv[alive]
        cp, cq = cp[alive], cq[alive]
        ok = fmax < prm.feps if good_enough is None else good_enough(p, q, f_pq, f_qp)
        can_p, can_q = h.area[p] > aeps, h.area[q] > aeps
        # Push-down hands a link's average to every descendant of the receiver, so what matters
        # is how much the point form factor varies across each node; measure it where it can be
        # large (near pairs) and split the node whose variation is larger.
        v_p, v_q = np.zeros(len(p)), np.zeros(len(p))
        near = ok & (np.sum((cp - cq) ** 2, 1) < prm.near * (h.area[p] + h.area[q]))
        if prm.veps > 0 and near.any():
            v_p[near], v_q[near] = _variation(h, p[near], q[near]), _variation(h, q[near], p[near])
            ok &= np.maximum(v_p, v_q) < prm.veps
        vis = kv.copy()
        # Links that pass the oracle but straddle a shadow boundary get split further.
        shadow = (
            ok & (fmax > prm.shadow_feps) & (can_p | can_q) & np.isnan(vis)
            if prm.shadow_feps > 0
            else np.zeros(len(p), bool)
        )
        if shadow.any():
            vis[shadow] = self.visibility(p[shadow], q[shadow])
            ok &= ~(shadow & (vis > 0) & (vis < 1))
        if self._contacts is not None:
            # An object and the surface it stands on exchange the strongest light of all, half
            # hidden from each other: the few rays of a coarse pair can all miss it (a floor
            # quad mostly under a box and the box's side), so such pairs with a partly covered
            # end that see nothing are split rather than dropped (down to Aeps).
            touch = ok & (can_p | can_q) & ((h.exposure[p] < 1) | (h.exposure[q] < 1))
            touch[touch] = self._contacts.touching(h.patch[p[touch]], h.patch[q[touch]])
            todo = touch & np.isnan(vis)
            if todo.any():
                vis[todo] = self.visibility(p[todo], q[todo])
            ok &= ~(touch & (vis == 0))
        by_var = (v_p + v_q) > 0
        prefer_q = np.where(by_var, v_q > v_p, f_pq >= f_qp)
        split_q = ~ok & can_q & (prefer_q | ~can_p)
        split_p = ~ok & ~split_q & can_p
        link = ~split_q & ~split_p
        return p, q, vis, link, split_p, split_q

    def _finish(self, out):
        if not out:
            return Links.empty()
        a, b, vis = (np.concatenate(x) for x in zip(*out))
        t0 = time.perf_counter()
        f_ab, f_ba = np.empty(len(a)), np.empty(len(a))

        def form_factors(i, j):  # every batch writes its own links
            f_ab[i:j], f_ba[i:j] = link_form_factors(self.h, a[i:j], b[i:j], self.params.ff_order)

        batch_map(form_factors, spans(len(a), LINK_BATCH), self.threads)
        self._exposed_form_factors(a, b, f_ab, f_ba)
        self.stats["t_ff"] += time.perf_counter() - t0
        # links too weak to need a shadow test need no more than a few rays either
        weak = np.maximum(f_ab, f_ba) < self.params.shadow_feps
        todo = np.isnan(vis)
        unsplit = np.zeros(len(a), bool)
        if UNSPLIT_2X2 and self.params.vis_k < 2:
            aeps = self.params.aeps * self.total_area
            unsplit = todo & ~weak & (self.h.area[a] <= aeps) & (self.h.area[b] <= aeps)
        todo, unsplit = np.flatnonzero(todo & ~unsplit), np.flatnonzero(unsplit)

        def shadows(i, j):
            t = todo[i:j]
            vis[t] = self.visibility(a[t], b[t], weak[t])

        def unsplit_shadows(i, j):
            t = unsplit[i:j]
            t0 = time.perf_counter()
            vis[t], rays = self._unsplit_visibility(a[t], b[t])
            add_counts(self.stats, rays=rays, unsplit_links=len(t), t_vis=time.perf_counter() - t0)

        batch_map(shadows, spans(len(todo), LINK_BATCH), self.threads)
        batch_map(unsplit_shadows, spans(len(unsplit), LINK_BATCH), self.threads)
        keep = (vis > 0 if not KEEP_OCCLUDED else vis >= 0) & ((f_ab > 0) | (f_ba > 0))
        return Links(a[keep], b[keep], f_ab[keep], f_ba[keep], vis[keep])

    def build(self):
        """Initial HSA refinement: down from the root cluster's self-pair (clustering), or over
        all pairs of patches (quadratic: small scenes only)."""
        # every phase reports its end, however fast it was (reports are throttled)
        t0 = time.perf_counter()
        self.contacts()
        self.stats["t_contacts"] = time.perf_counter() - t0
        if not self.params.cluster:
            links = self.refine(*initial_pairs(self.h))
            self.progress.done("linking")
            return links
        from .cluster import ClusterTree
        from .farlinks import link_clusters

        t0 = time.perf_counter()
        K = len(self.h.patches.nv)
        covered = self._contacts is not None
        tree = ClusterTree(
            self.h.patches,
            leaf_size=self.params.cluster_leaf,
            exposure=self.h.exposure[:K] if covered else None,
            sample_at=self.centres(np.arange(K)) if covered else None,
            threads=self.threads,
        )
        self.stats["t_tree"] = time.perf_counter() - t0
        self.stats["clusters"] = tree.C
        far, p, q = link_clusters(self, tree, self.progress)
        self.progress.done("clusters")
        self.stats["t_clusters"] = time.perf_counter() - t0
        links = self.refine(p, q)
        self.progress.done("linking")
        links.far = far
        return links

    def refine_bf(self, links: Links, B):
        """One BF pass: links whose rho x F x B_source exceeds bfeps (relative to the brightest
        emitter) are replaced by links between their children. B: (3, n) radiosity of all nodes;
        new children inherit their parent's B. Returns the new link set."""
        h, prm = self.h, self.params
        rho = h.patches.reflectance
        bref = max(float(h.patches.emission.max()), 1e-30)
        thr = prm.bfeps * bref

        def bf(p, q, f_pq, f_qp):
            Bn = h.extend(B)
            return (
                np.maximum(
                    (rho[:, h.patch[p]] * Bn[:, q]).max(0) * f_pq,
                    (rho[:, h.patch[q]] * Bn[:, p]).max(0) * f_qp,
                )
                < thr
            )

        f_ab, f_ba = links.f_ab * links.vis, links.f_ba * links.vis
        bad = ~bf(links.a, links.b, f_ab, f_ba)
        aeps = prm.aeps * self.total_area
        bad &= (h.area[links.a] > aeps) | (h.area[links.b] > aeps)
        if not bad.any():
            return links
        return links.select(~bad).concat(self.refine(links.a[bad], links.b[bad], good_enough=bf))


def _variation(h, x, y):
    """Range of the point form factor to polygon y over x's corners and centre. The corners are
    pulled 1% towards the centre: a corner on an edge shared with y is a singular configuration."""
    pts = np.concatenate([h.corners[x], h.centre[x][:, None]], 1)
    pts += 0.01 * (h.centre[x][:, None] - pts)
    qn, qa = ff.polygon_normal_area(h.corners[y], h.nv[y])
    f = ff.point_to_polygon(
        pts.reshape(-1, 3),
        np.repeat(h.normal[x], 5, 0),
        np.repeat(h.corners[y], 5, 0),
        np.repeat(h.nv[y], 5),
        (np.repeat(qn, 5, 0), np.repeat(qa, 5)),
    ).reshape(-1, 5)
    lo, hi = ff.row_range(f)
    return hi - lo
