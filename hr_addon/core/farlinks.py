"""Far links: links with a cluster end, how their transfer enters the solver, and the linking
that makes them (HSA refinement from the root's self-pair down through the face clusters of
cluster.py into the patch quadtrees). numpy only."""

import numpy as np

from .cluster import (
    CURVED,
    GRAD_CONE,
    SH_CLAMPED,
    SH_LINEAR,
    SLOTS,
    ClusterTree,
    Ends,
    EndTable,
    decode,
    encode,
    estimate,
    faces,
    sample_normals,
    sample_points,
    sh9,
    visibility_points,
)
from .formfactor import dot3, row_range, unoccluded_share
from .parallel import add_counts, batch_map, ranges, spans


class FarLinks:
    """Links with at least one cluster end: ends a, b (shared ids), visibility (fraction and the
    mask of unoccluded sample segments), and whether each end is partial (its members do not all
    face the other end: SH kernel of the clamped cosine) or faces wholly (exact linear kernel).
    Their transfer weights live in the solver's extended index space: cluster c's 9 SH slots at
    9c .. 9c + 8, patch node i at 9C + i (so nodes added later do not shift them)."""

    def __init__(
        self, tree: ClusterTree, a, b, vis, mask, part_a=None, part_b=None, eps=0.0, grad_eps=0.0, scale=None
    ):
        self.tree, self.eps = tree, eps  # eps: the sample points' offset off their surfaces
        self.grad_eps = grad_eps  # gradients only where they matter (terms())
        # visibility of weak links traced with 4 segments only (their mask is full)
        self.scale = np.ones(len(a)) if scale is None else np.asarray(scale, float)
        self.a, self.b, self.vis = np.asarray(a, np.int64), np.asarray(b, np.int64), np.asarray(vis, float)
        self.mask = np.asarray(mask, np.uint16)
        z = np.zeros(len(self.a), bool)
        self.part_a = z if part_a is None else np.asarray(part_a, bool)
        self.part_b = z if part_b is None else np.asarray(part_b, bool)

    def __len__(self):
        return len(self.a)

    def remap(self, remap):
        """After Hierarchy.compact: renumber the patch-node ends."""
        ren = lambda x: np.where(x >= 0, remap[np.maximum(x, 0)], x)
        return FarLinks(
            self.tree,
            ren(self.a),
            ren(self.b),
            self.vis,
            self.mask,
            self.part_a,
            self.part_b,
            self.eps,
            self.grad_eps,
            self.scale,
        )

    def terms(self, h, threads=1):
        """The links' transfer in two passes through one intermediate value per link direction
        (slot 2 l for "a gathers from b", 2 l + 1 for the reverse):

        pass 1 (t_slot, t_src, t_w): t = sum of t_w x the source's slots (X space: a cluster's
          SH power, a node's radiance);
        pass 2 (recv, r_slot, r_w, is_gradient): the receiver's slots (Y space: a cluster's SH
          irradiance and gradient, a node's gathered radiance) += r_w x t.

        The kernel is averaged over the link's 4 x 4 sample segments (those the visibility mask
        says are unoccluded): V cos cos / (pi r^2), with a node end's cosine and a cluster end's
        SH kernel evaluated along each segment, so the transfer stays accurate for ends that are
        not small against their distance; each end's factor is its kernel-weighted mean over
        the segments (rank one), and the same factor serves it as a source and as a receiver,
        so one symmetric kernel serves both directions (reciprocity). Flat, wholly facing cluster
        ends also weight their members by the kernel's gradient over the end, where the link is
        strong and uneven enough (link form factor x relative change over the cluster above
        grad_eps): as receivers through gradient slots, as sources through their power's first
        moment, so the kernel stays symmetric.

        By chunks of TERMS_CHUNK links on `threads` threads (core.parallel: each chunk its own terms,
        concatenated in order, so the same for any thread count)."""
        if not len(self.a):
            return tuple(
                tuple(np.zeros(0, dt) for dt in (np.int64, np.int64, float, bool)[:n]) for n in (3, 4)
            )
        parts = batch_map(lambda a, b: self._terms(h, a, b), ranges(len(self.a), TERMS_CHUNK), threads)
        p1, p2 = [x for p, _ in parts for x in p], [x for _, p in parts for x in p]
        # each of the seven arrays concatenated on its own (threads)
        cols = batch_map(lambda *x: np.concatenate(x), [*zip(*p1), *zip(*p2)], threads)
        return tuple(cols[:3]), tuple(cols[3:])

    def _terms(self, h, i, end):
        """terms()' pass 1 and pass 2 parts of links i..end."""
        tree = self.tree
        off = SLOTS * tree.C
        p1, p2 = [], []
        sl = slice(i, end)
        a, b = self.a[sl], self.b[sl]
        ea, eb = Ends(tree, h, a), Ends(tree, h, b)
        (pa, wa), (pb, wb) = sample_points(tree, h, a, self.eps), sample_points(tree, h, b, self.eps)
        d = pb[:, None, :, :] - pa[:, :, None, :]  # (N, 4 on a, 4 on b, 3)
        r2 = np.maximum(np.einsum("nijk,nijk->nij", d, d), 1e-300)
        u = d / np.sqrt(r2)[..., None]
        vis = ((self.mask[sl, None] >> np.arange(16)) & 1).reshape(-1, 4, 4)
        kg = 1.0 / (np.pi * r2) * wa[:, :, None] * wb[:, None, :]  # geometry only: the gradient fit
        k = vis * self.scale[sl, None, None] * kg
        K = k.sum((1, 2))
        Kn = np.where(K > 0, K, 1.0)
        fa = (
            np.einsum(
                "nis,nisc->nc",
                k,
                _end_factors(a, ea, self.part_a[sl], u.reshape(-1, 16, 3)).reshape(-1, 4, 4, 9),
            )
            / Kn[:, None]
        )
        fb = (
            np.einsum(
                "nis,nisc->nc",
                k,
                _end_factors(b, eb, self.part_b[sl], -u.reshape(-1, 16, 3)).reshape(-1, 4, 4, 9),
            )
            / Kn[:, None]
        )
        link = 2 * (i + np.arange(len(a)))
        fmax = K * np.maximum(ea.area, eb.area)
        # relative gradients of the kernel over each cluster end (zero where not worth it)
        ga = self._grad(h, ea, pa, wa, kg, u, eb, self.part_a[sl])
        gb = self._grad(h, eb, pb, wb, kg.transpose(0, 2, 1), -u.transpose(0, 2, 1, 3), ea, self.part_b[sl])
        for g_, e_ in ((ga, ea), (gb, eb)):
            g_ *= (fmax * np.linalg.norm(g_, axis=1) * e_.radius >= self.grad_eps)[:, None]
        for t, (r, er, fr, gr), (s_, es, fs, gs) in (
            (link, (a, ea, fa, ga), (b, eb, fb, gb)),
            (link + 1, (b, eb, fb, gb), (a, ea, fa, ga)),
        ):
            # pass 1: a node source's slot holds radiance, a cluster's its power (area inside)
            # and the power's first moment, weighted by the source-side gradient
            w1 = np.zeros((len(r), SLOTS))
            w1[:, :9] = K[:, None] * fs * np.where(es.cl, 1.0, es.area)[:, None]
            w1[:, 9:] = (K[:, None, None] * fs[:, 1:4, None] * gs[:, None, :]).reshape(-1, 9)
            S = _slots(s_, es, off)
            live = w1 != 0
            p1.append((np.broadcast_to(t[:, None], w1.shape)[live], S[live], w1[live]))
            # pass 2: the receiver's kernel, with its gradient about the cluster's centre
            # (members evaluate it at their absolute positions, hence the - G c term)
            R = _slots(r, er, off)
            w2 = np.zeros((len(r), SLOTS))
            w2[:, :9] = fr
            Gm = fr[:, 1:4, None] * gr[:, None, :]  # (N, 3, 3 axes)
            w2[:, 9:] = Gm.reshape(-1, 9)
            w2[:, 1:4] -= np.einsum("nmk,nk->nm", Gm, er.centre)
            live = w2 != 0
            p2.append(
                (
                    R[live],
                    np.broadcast_to(t[:, None], w2.shape)[live],
                    w2[live],
                    np.zeros(int(live.sum()), bool),
                )
            )
        return p1, p2

    @staticmethod
    def _grad(h, er, pr, wr, k, u, es, part_r):
        """(N, 3) relative gradient gamma of each link's kernel over one end (zero for nodes,
        partial ends and curved clusters): a least-squares linear fit over the end's sample
        points of the unoccluded scalar kernel (cosines about both ends' axes; which of four
        samples happen to be shadowed is too noisy to extrapolate). Member j of the end then
        couples with weight 1 + gamma . (x_j - c), as a receiver and as a source alike, so the
        kernel stays symmetric. Capped so that no member gets below half or above 1.5 times
        the mean."""
        gam = np.zeros((len(pr), 3))
        grad = er.cl & ~part_r & (er.theta < GRAD_CONE)
        if not grad.any():
            return gam
        x, wg = pr[grad], wr[grad]
        dx = x - np.einsum("ni,nij->nj", wg, x)[:, None]
        ug = u[grad]
        ks = (
            k[grad]
            * np.maximum(np.einsum("nisk,nk->nis", ug, er.axis[grad]), 0)
            * np.maximum(-np.einsum("nisk,nk->nis", ug, es.axis[grad]), 0)
        )
        Ki = ks.sum(2) / wg
        Km = np.einsum("ni,ni->n", Ki, wg)
        rel = np.where(Km[:, None] > 0, Ki / np.where(Km > 0, Km, 1)[:, None] - 1, 0)
        g = np.einsum("nki,ni->nk", np.linalg.pinv(dx, rcond=0.05), rel)
        gn = np.linalg.norm(g, axis=1) * er.radius[grad]
        gam[grad] = g * np.minimum(1.0, 0.5 / np.maximum(gn, 1e-300))[:, None]
        return gam


def _slots(ids, e, off):
    """(N, SLOTS) slot indices of link ends: a node's one slot (repeated), a cluster's SLOTS."""
    return np.where(
        ~e.cl[:, None],
        off + np.maximum(ids, 0)[:, None],
        SLOTS * decode(np.minimum(ids, -1))[:, None] + np.arange(SLOTS),
    )


def _end_factors(ids, e, part, u):
    """Kernel factors (N, S, 9) of one end of each link along the segments u (N, S, 3) leaving
    it: a patch node's cosine (slot 0); a cluster's SH kernel, linear (wholly facing) or the
    clamped cosine (partial)."""
    node = ~e.cl
    w = (
        sh9(u.reshape(-1, 3)).reshape(u.shape[:2] + (9,))
        * np.where(part[:, None], SH_CLAMPED, SH_LINEAR)[:, None, :]
    )
    w[node] = 0.0
    w[node, :, 0] = np.maximum(np.einsum("nsk,nk->ns", u[node], e.axis[node]), 0)
    return w


# -- linking through the clusters -----------------------------------------------------------------------
# pairs of a level classified per map (link_clusters): its outputs, about 40 bytes a pair, are held
# until the level's splits are made
LEVEL_PAIRS = 1 << 18
# far links per batch of their solver terms (FarLinks.terms): fixed, so the terms do not depend on
# the thread count
TERMS_CHUNK = 8192
# pairs per batch of the oracle and the shadow tests on threads (core.parallel): fixed, so the links
# do not depend on the thread count (up to 4x as many pairs per batch in large maps: parallel.spans)
PAIR_BATCH = 1 << 13
# pairs per batch of the levels' oracle (_cluster_levels, grown up to 4x in large levels as PAIR_BATCH)
LEVEL_BATCH = 1 << 15
# benchmarks/far_vis_check.py --all-links: keep the far links traced wholly occluded (they carry no
# transfer: mask or scale 0), so that every far link's traced visibility can be set against a dense one
KEEP_OCCLUDED = False
# strong far links kept on their oracle trace get their visibility from a second trace (link_clusters)
SECOND_TRACE = True
# segments of the second trace (far_visibility(second=True)): 16, all of the 4 x 4; 8: the
# segments i -> (i + s) mod 4, s in {0, 2} (each point in two; unbiased, noisier; measured by
# bld32, not taken: docs/scale.md)
SECOND_SEGMENTS = 16
# params.partial_both: a patch node end (at most Aeps) takes part too (its plane cutting the small
# cluster beside it)
PARTIAL_NODES = True
# pairs per block of the kernel variation (_variation): its (4, 4, pairs) temporaries stay in the cache
VAR_BLOCK = 1024


def link_clusters(refiner, tree: ClusterTree, progress=None):
    """HSA refinement from the root's self-pair down through the clusters.

    A pair with a cluster end becomes a far link when each end lies wholly in front of the other's
    members (`faces`), both estimated form factors are below Feps, the ends are small against
    their distance (radius sum < cluster_ratio x distance: the point-to-point kernel holds), and,
    for links above shadow_feps, visibility is not partial. Pairs wholly behind one end are
    dropped. Otherwise an end is split: a cluster into its children, a patch node into its
    quadtree children (_cluster_levels). Pairs of two patch nodes are returned for the ordinary
    patch refinement. Returns (FarLinks, node pairs p, q)."""
    h, prm = refiner.h, refiner.params
    # Visibility is not inherited from a parent pair: 16 segments between 4 samples per end miss
    # thin occluders (legs, gaps between books). Measured on the 20k furnished room: passing
    # "wholly visible" down made objects 3.9% brighter on average (121% at worst), dropping
    # "wholly occluded" pairs 9% darker (83%), and the extra tests cost more rays than they saved.
    table = EndTable(tree, h, refiner.eps, refiner.threads)
    dark = prm.dark_ratio > 0 or prm.dark_veps > 0 or not prm.dark_second
    lit = LitEnds(tree, h) if dark else None
    far, p, q = _cluster_levels(refiner, tree, table, lit, progress)
    table.update()
    if far is not None:
        fa_, fb_, fv, fm, pa_, pb_, ff_ = far
        # the oracle's traced links: a full mask with a fraction is far_visibility's one value
        # for a link with back-facing segments (1 where all 16 are unoccluded: the same)
        fs = np.where(fm == 0xFFFF, np.nan_to_num(fv, nan=1.0), 1.0)
        todo = np.flatnonzero(np.isnan(fv))
        decided = ~np.isnan(fv)  # traced by the oracle (strong links kept on 0 or 1)

        def shadows(i, j):  # every batch writes its own links
            t = todo[i:j]
            fv[t], fm[t], fs[t] = far_visibility(
                refiner, tree, fa_[t], fb_[t], ff_[t] < prm.shadow_feps, table
            )

        batch_map(shadows, spans(len(todo), PAIR_BATCH), refiner.threads)
        # The oracle keeps a strong link when its 16 segments read wholly visible or wholly
        # occluded, and splits it otherwise: a link kept on "1" keeps 1 (where its children's
        # fresh estimates would average its true visibility), one on "0" is dropped, so the
        # decision's own trace is biased by the decision (kept 1: high, dropped 0: low). Their
        # visibility is traced again from a second set of points on the same members.
        if not prm.dark_second:  # (their first trace's visibility kept, _classify)
            decided &= lit.ends(fa_) | lit.ends(fb_)
        again = np.flatnonzero(decided) if SECOND_TRACE else np.zeros(0, np.int64)
        ends = np.concatenate([fa_[again], fb_[again]])
        table.prepare_second(ends[ends >= 0])  # the nodes' second points, once per node

        def retrace(i, j):
            t = again[i:j]
            fv[t], fm[t], fs[t] = far_visibility(refiner, tree, fa_[t], fb_[t], None, table, second=True)

        # batches grown to 2 x PAIR_BATCH, not 4: at 4x (28k links at 100k) the second trace's
        # temporaries were faulted in fresh per batch (93k faults, 0.45 s system CPU, +16% CPU on one
        # thread against 8-16k links; issue 23, docs/threads.md, session 36)
        batch_map(retrace, spans(len(again), PAIR_BATCH, grow=2), refiner.threads)
        keep = fv > 0 if not KEEP_OCCLUDED else fv >= 0
        links = FarLinks(
            tree,
            fa_[keep],
            fb_[keep],
            fv[keep],
            fm[keep],
            pa_[keep],
            pb_[keep],
            refiner.eps,
            0.1 * prm.cluster_veps,
            fs[keep],
        )
    else:
        z = np.zeros(0)
        links = FarLinks(tree, z.astype(np.int64), z.astype(np.int64), z, z.astype(np.uint16))
    return links, p, q


def _cluster_levels(refiner, tree, table, lit, progress=None):
    """link_clusters' refinement, breadth-first: (far links' a, b, vis, mask, part_a, part_b, fmax
    or None, node pairs p, q).

    All the pairs of a level (those the previous level's splits made) are classified together, in
    maps of up to LEVEL_PAIRS pairs (the depth-first loop it replaced ran 685 maps of 2.7 batches
    each at 100k: issue 23, docs/threads.md, sessions 34-35). Every pair's decision is its own, so
    the levels decide what that loop decided; node ids and the links' order are the levels' own
    (a node's second visibility points are shifted by its id, cluster._node_points2: 43 of the 20k
    room's 55,855 far links traced from other points), fixed by LEVEL_PAIRS and not by the
    thread count."""
    h = refiner.h
    far, nodes = [], []
    a = b = encode([0])
    total_w = 0.5 * tree.area[0] ** 2
    done_w = 0.0

    def weight(a, b):
        aa, ab = _area(tree, h, a), _area(tree, h, b)
        return np.where(a == b, 0.5 * aa * aa, aa * ab).sum()

    while len(a):
        refiner.stats["cluster_pairs"] += len(a)
        new_a, new_b = [], []  # the next level's pairs
        same = a == b
        s = same & (a < 0)
        done_w += weight(a[same & ~s], a[same & ~s])
        if s.any():
            sa, sb = _self_pairs(tree, decode(a[s]))
            new_a.append(sa)
            new_b.append(sb)
        both = ~same & (a >= 0) & (b >= 0)
        if both.any():
            nodes.append((a[both], b[both]))
            done_w += weight(a[both], b[both])
        rest = ~same & ~both
        a, b = a[rest], b[rest]
        for i, j in ranges(len(a), LEVEL_PAIRS):
            x, y = a[i:j], b[i:j]
            table.update()  # the nodes subdivided by the last map (here, between maps; its rows on threads)
            parts = batch_map(
                lambda i, j: _level_batch(refiner, tree, x[i:j], y[i:j], table, lit),
                spans(len(x), LEVEL_BATCH),
                refiner.threads,
            )
            found, w, splits = zip(*parts)
            del parts
            for k in (0, 1):  # ok, take: the batches' pieces in batch order (the map's order)
                cols = [np.concatenate(c) for c in zip(*(f[k] for f in found))]
                if len(cols[0]):
                    far.append(tuple(cols))
            done_w += np.concatenate(w).sum()  # (the batches' sums: the progress only)
            for k in (0, 1):  # split_a, then split_b: clusters' children, then nodes'
                c, cv, nd, nv = (np.concatenate(z) for z in zip(*(sp[k] for sp in splits)))
                if len(c):
                    new_a.append(c)
                    new_b.append(cv)
                if len(nd):
                    h.subdivide(np.unique(nd))
                    new_a.append(h.children(nd).ravel())
                    new_b.append(np.repeat(nv, 4))
        if progress is not None:
            progress.update("clusters", done_w, total_w)
        z = np.zeros(0, np.int64)
        a, b = (np.concatenate(c) if c else z for c in (new_a, new_b))
    # the levels' far links and node pairs: each array concatenated on its own (threads)
    cat = batch_map(lambda *x: np.concatenate(x), [*zip(*far), *zip(*nodes)], refiner.threads)
    z = np.zeros(0, np.int64)
    p, q = cat[-2:] if nodes else (z, z)
    return (cat[:7] if far else None), p, q


def _level_batch(refiner, tree, x, y, table, lit):
    """_classify's batch of a level and what the level's loop needs of it, on the threads (issue
    23: serial, the far links' and splits' gathers and the clusters' children were a tenth of the
    100k build's serial CPU, docs/threads.md, session 37): per (ok, take) the far links' arrays,
    the progress weight, per (split_a, split_b) the split clusters' children with their other
    ends, and the split nodes with theirs. Each is row by row in the pairs' order, so the batches'
    pieces concatenated are the map's whole arrays: the same values and order."""
    drop, ok, take, split_a, split_b, vis, mask, pa, pb, fmax, w = _classify(refiner, tree, x, y, table, lit)
    found = [tuple(c[sel] for c in (x, y, vis, mask, pa, pb, fmax)) for sel in (ok, take)]
    splits = []
    for sel, u, v in ((split_a, x, y), (split_b, y, x)):
        us, vs = u[sel], v[sel]
        cl = us < 0
        c, owner = tree.children(decode(us[cl]))
        splits.append((c, vs[cl][owner], us[~cl], vs[~cl]))
    return found, w, splits


def _classify(refiner, tree, a, b, table=None, lit=None):
    """link_clusters' oracle for the pairs (a, b): every pair on its own (no hierarchy edits), so
    batches of pairs run on threads. Boolean arrays drop, ok (a far link), take (a far link: the
    end to split cannot be split), split_a, split_b (split that end); vis, mask, pa, pb, fmax of
    the far links; (1,) the settled pairs' progress weight (link_clusters' weight(), here on the
    threads)."""
    h, prm = refiner.h, refiner.params
    ea, eb = Ends(tree, h, a, table), Ends(tree, h, b, table)
    fa, ba, dmax = faces(ea, eb)
    fb, bb, _ = faces(eb, ea, dmax)
    f_ab, f_ba, dist = estimate(ea, eb, both=True)
    fmax = np.maximum(f_ab, f_ba)
    drop = ba | bb | (fmax <= 0)
    # A cluster end whose members do not all face the other end is "partial": its kernel is
    # the SH approximation of the clamped cosine, allowed on one end of weak links only (both
    # ends when both are small: params.partial_both). A patch node whose plane cuts the other end
    # cannot be partial (split the other end).
    pa, pb = ~fa & ~ba & ea.cl, ~fb & ~bb & eb.cl
    facing = (fa | pa) & (fb | pb) & ~(pa & pb)
    if prm.partial_both > 0:
        # Two small ends (params.partial_both), a crown's leaves: their clusters' normals spread
        # wide, so none faces anything wholly, and a patch node's plane cuts a cluster beside it;
        # they link with the clamped cosine on both ends (a node's: its own along each segment)
        # rather than down to every pair of their triangles
        aeps = prm.aeps * refiner.total_area
        tiny = lambda e: np.where(e.cl, e.area <= prm.partial_both * aeps, PARTIAL_NODES & (e.area <= aeps))
        both = ~facing & ~ba & ~bb & tiny(ea) & tiny(eb)
        pa, pb = pa | (both & ~fa & ea.cl), pb | (both & ~fb & eb.cl)
        facing |= both
    # Small against the distance: a cluster end is seen through 4 member samples and one
    # kernel direction, so its radius counts fully; a patch node end is integrated at 2 x 2
    # Gauss points, so half its radius counts. And the link's transfer times its relative
    # variation across either end below cluster_veps: strong, uneven links (near lights) go
    # down to where the variation is resolved.
    rho_a = np.where(ea.cl, np.where(ea.theta < GRAD_CONE, 1.0, CURVED), 0.5) * ea.radius
    rho_b = np.where(eb.cl, np.where(eb.theta < GRAD_CONE, 1.0, CURVED), 0.5) * eb.radius
    size = (rho_a + rho_b) / np.maximum(dist, 1e-300)
    ratio, veps = prm.cluster_ratio, prm.cluster_veps
    lit_ab = None if lit is None else lit.ends(a) | lit.ends(b)
    if lit_ab is not None:  # pairs of dark ends: their own criteria (params.dark_ratio)
        ratio = np.where(lit_ab, ratio, prm.dark_ratio or ratio)
        veps = np.where(lit_ab, veps, prm.dark_veps or veps)
    small = size < ratio
    cand = ~drop & facing & small
    var_a, var_b = np.zeros(len(a)), np.zeros(len(a))
    if cand.any():
        var_a[cand], var_b[cand] = _variation(tree, h, a[cand], b[cand], refiner.eps, table)
    even = fmax * np.maximum(var_a, var_b) < veps
    ok = ~drop & facing & small & even & (fmax < np.where(pa | pb, prm.partial_feps * prm.feps, prm.feps))
    vis, mask = np.full(len(a), np.nan), np.zeros(len(a), np.uint16)
    if prm.shadow_feps > 0:
        shadow = ok & (fmax > prm.shadow_feps)
        if shadow.any():
            # with SECOND_TRACE every link kept here is traced again (link_clusters): only the
            # decision is asked (partial, or 0 / 1), on the fewest segments that settle it
            # (a pair of dark ends without its second trace, params.dark_second: all of it here)
            dec = np.full(len(a), SECOND_TRACE)
            if not prm.dark_second and lit_ab is not None:
                dec &= lit_ab
            for d_ in (True, False):
                sh = shadow & (dec == d_)
                if sh.any():
                    vis[sh], mask[sh], _ = far_visibility(refiner, tree, a[sh], b[sh], table=table, decide=d_)
            ok &= ~(shadow & (vis > 0) & (vis < 1))
    # Which end to split, by the first test that failed. Facing (a node whose plane cuts the
    # other end, or two partial ends): the end whose cone, or angular radius seen from the
    # other, is larger (a node's cone is 0: its children share its plane). Size and shadow:
    # the end that looks larger. Feps: the end with the larger form factor as seen from the
    # other (as in HSA).
    todo = ~drop & ~ok
    phi_a = np.arcsin(np.clip(rho_a / np.maximum(dist, 1e-300), 0, 1))
    phi_b = np.arcsin(np.clip(rho_b / np.maximum(dist, 1e-300), 0, 1))
    face_a = np.maximum(np.where(~fa, ea.theta, 0), np.where(~fb, phi_a, 0))
    face_b = np.maximum(np.where(~fa, phi_b, 0), np.where(~fb, eb.theta, 0))
    by_face = ~facing
    by_size = ~by_face & ~small
    by_phi = by_size | ~even | (fmax < prm.feps)  # (within ~by_face)
    prefer_a = np.where(by_face, face_a >= face_b, np.where(by_phi, phi_a >= phi_b, f_ba >= f_ab))
    aeps = prm.aeps * refiner.total_area
    can_a = ea.cl | (ea.area > aeps)
    can_b = eb.cl | (eb.area > aeps)
    # Too strong, too uneven or half shadowed, but the end that should be split cannot be (a
    # patch node at Aeps): splitting the other end would not lower the form factor or the
    # variation on that end, so link here, as HSA does with two unsplittable nodes.
    take = todo & ~by_face & ~by_size & np.where(prefer_a, ~can_a, ~can_b)
    split_a = todo & ~take & can_a & (prefer_a | ~can_b)
    split_b = todo & ~take & ~split_a & can_b
    # the progress weight of the pairs settled here (weight(): a != b), summed in the batch
    done = drop | ok | take
    w = np.array([(ea.area[done] * eb.area[done]).sum()])
    return drop, ok, take, split_a, split_b, vis, mask, pa, pb, fmax, w


def _variation(tree, h, a, b, eps, table=None):
    """(var_a, var_b): relative range, over each end's sample points, of the kernel cos cos / r^2
    summed over the other end's samples (cosines about the samples' own normals; no visibility).
    By blocks of VAR_BLOCK pairs (every pair is its own: the same values)."""
    (pa, wa), (pb, wb) = sample_points(tree, h, a, eps, table), sample_points(tree, h, b, eps, table)
    na, nb = sample_normals(tree, h, a, table), sample_normals(tree, h, b, table)
    out = np.empty((2, len(a)))
    for i in range(0, len(a), VAR_BLOCK):
        s = slice(i, i + VAR_BLOCK)
        out[:, s] = _variation_block(pa[s], wa[s], pb[s], wb[s], na[s], nb[s])
    return out[0], out[1]


def _variation_block(pa, wa, pb, wb, na, nb):
    """_variation of one block: points pa, pb (N, 4, 3), weights wa, wb (N, 4), normals na, nb.
    Component major, (3, 4, 4, N): a row of N pairs per coordinate and segment (numpy is slow on a
    last axis of 3; the (N, 4, 4, 3) form's einsums and reductions over short axes looped per
    row). The same operations in the same order: einsum's dot products as dot3 ((x + z) + y),
    the sums over 4 samples in order, min and max by samples as row_range. (A zero's sign may
    differ from the einsums' (they add to +0): the values are only compared, never stored.)"""
    A, B = (np.ascontiguousarray(x.transpose(2, 1, 0)) for x in (pa, pb))  # (3, 4, N)
    NA, NB = (np.ascontiguousarray(x.transpose(2, 1, 0)) for x in (na, nb))
    D = B[:, None] - A[:, :, None]  # (3, 4 on a, 4 on b, N)
    r2 = np.maximum(dot3(D, D), 1e-300)
    k = np.maximum(dot3(D, NA[:, :, None]), 0) * np.maximum(-dot3(D, NB[:, None]), 0) / (r2 * r2)
    t = k * wb.T[None]  # summed over b's samples: each of a's
    ks_a = ((t[:, 0] + t[:, 1]) + t[:, 2]) + t[:, 3]
    t = k * wa.T[:, None]  # summed over a's samples: each of b's
    ks_b = ((t[0] + t[1]) + t[2]) + t[3]
    out = np.empty((2, pa.shape[0]))
    for o, ks in zip(out, (ks_a, ks_b)):  # (4 samples, N)
        m = (((ks[0] + ks[1]) + ks[2]) + ks[3]) / 4
        lo, hi = row_range(ks.T)
        o[:] = (hi - lo) / np.maximum(m, 1e-300) * (m > 0)
    return out


class LitEnds:
    """Which link ends hold a patch of the static emission (the base solution's sources): a
    patch node whose patch emits, a cluster with an emitting member. A pair of ends that are
    both dark carries that light only after a reflection (params.dark_ratio)."""

    def __init__(self, tree, h):
        self.h, self.patch = h, h.patches.emission.max(0) > 0
        c = np.r_[0, np.cumsum(self.patch[tree.perm])]
        self.cluster = c[tree.end] > c[tree.start]

    def ends(self, ids):
        """(N,) bool: whether each end (shared ids) is lit."""
        node = self.patch[self.h.patch[np.maximum(ids, 0)]]
        return np.where(ids < 0, self.cluster[decode(np.minimum(ids, -1))], node)


def _area(tree, h, ids):
    return np.where(ids < 0, tree.area[decode(np.minimum(ids, -1))], h.area[np.maximum(ids, 0)])


def _self_pairs(tree, c):
    """All pairs (i <= j) of the children of each cluster c; patch self-pairs left out (planar)."""
    cnt = tree.child_start[c + 1] - tree.child_start[c]
    out_a, out_b = [], []
    for k in np.unique(cnt):
        cs = c[cnt == k]
        kids = tree.child_ids[tree.child_start[cs][:, None] + np.arange(k)]
        iu, ju = np.triu_indices(k)
        pa, pb = kids[:, iu].ravel(), kids[:, ju].ravel()
        keep = (pa != pb) | (pa < 0)
        out_a.append(pa[keep])
        out_b.append(pb[keep])
    return np.concatenate(out_a), np.concatenate(out_b)


def far_visibility(refiner, tree, a, b, weak=None, table=None, second=False, decide=False):
    """(vis, mask, scale) of far links: the unoccluded fraction of the 4 x 4 segments between the
    ends' visibility points and which of them are unoccluded (bit 4 i + j: sample i of a, j of b).
    A cluster's visibility points lie on the kernel's sample members, spread over them
    (cluster.visibility_points), not at their centroids: segment i -> j stands for the same two
    members in the kernel (terms()), which evaluates it between their centroids.
    Weak links (mask `weak`) trace only the 4 segments i -> 3 - i: their mask is full and
    `scale` holds their visibility fraction instead (1 for the others).

    Only segments that leave both sample points on their front sides count (_facing_cm):
    a sample on a member that faces away from the other end (a partial end) sits eps in front of
    a face whose solid lies between it and the other end, so its segments are blocked by that
    member itself, while the link's kernel already gives such a member nothing (its clamped
    cosine). Counted, they made every partial end's visibility dark (the draft furnished room
    lost 1.5% of its light). A link with such segments gets the unoccluded share of its
    front-facing segments' kernel cos cos / r^2 (formfactor.unoccluded_share) as `scale` and a full mask (one
    visibility for the link, as weak links have; weak links' share is weighted alike); a link
    with no front-facing segment keeps what was traced.

    second: the points of visibility_points(second=True), on other members than the kernel's: a
    strong link gets one visibility too (full mask, scale). link_clusters traces the links its
    oracle kept on their first trace again so (SECOND_TRACE).

    decide: the oracle's question only, whether a (strong) link's visibility is partial, 0 or 1
    (_classify with SECOND_TRACE, which traces every link it keeps again): only the segments
    that count are traced (a link with front-facing and other segments: the front-facing ones),
    first up to DECIDE_FIRST of them (_decide); a link whose first ones already read both
    occluded and unoccluded, so that its visibility is surely in (0, 1), gets 0.5 and no more
    rays; every other link the value the full trace gives (its counting segments are all
    traced: the same bits). The mask is then 0 (the second trace gives every kept link its own).
    Each segment's answer is its own (the same origin and direction whatever else is traced).

    The segments are traced component major (occluded_cm, each point's origin once for its 4
    segments): the same segments, so the same answers as occluded() of the rows."""
    import time

    t0 = time.perf_counter()
    h, eps = refiner.h, refiner.eps
    # a cluster's points spread over its members (not their centroids: visibility_points)
    (pa, ca, na), (pb, cb, nb) = (visibility_points(tree, h, x, eps, table, second) for x in (a, b))
    weak = np.zeros(len(a), bool) if weak is None else np.asarray(weak, bool)
    if decide and weak.any():
        raise ValueError("far_visibility(decide=True) is for strong links")
    vis, mask, scale = np.empty(len(a)), np.empty(len(a), np.uint16), np.ones(len(a))
    st = ~weak
    if st.any():  # every segment of the 4 x 4
        i = None if st.all() else np.flatnonzero(st)
        pa_, pb_, na_, nb_, ca_, cb_ = (
            x if i is None else np.take(x, i, 0) for x in (pa, pb, na, nb, ca, cb)
        )
        A, D = _segments_cm(pa_, pb_)
        f, kw = _facing_segments_cm(D, na_, nb_)
        # a sample on a covered part (under a box, between touching faces) sees nothing; the
        # end's light leaves from its exposed part: its segments do not count either
        f &= ~(ca_[:, :, None] | cb_[:, None, :]).reshape(-1, 16)
        if decide:
            vis, rays = _decide(refiner.backend, A, D, f, kw)
            add_counts(refiner.stats, rays=rays, t_vis=time.perf_counter() - t0)
            return vis, np.zeros(len(a), np.uint16), np.ones(len(a))
        if second and SECOND_SEGMENTS < 16:  # a subset of the segments (the others do not count)
            sub = np.zeros(16, bool)
            sub[_SECOND_SUBSET] = True
            sel = np.broadcast_to(sub, f.shape)
            occ = np.zeros(f.shape, bool)
            occ[sel] = _trace(refiner.backend, A, D, sel)
            f = f & sub
            vis[st] = 1.0 - occ[:, sub].mean(1)
        else:
            occ = refiner.backend.occluded_cm(A.reshape(3, -1), D.reshape(3, -1), 4).reshape(-1, 16)
            vis[st] = 1.0 - occ.mean(1)
        mask[st] = ((~occ) * (1 << np.arange(16))).sum(1)
        nf = f.sum(1)
        # the second set's segments join other members than the kernel's: one visibility
        fix = (nf > 0) & ((nf < 16) | second)
        if fix.any():
            i = np.flatnonzero(st)[fix]
            vis[i] = scale[i] = unoccluded_share(f[fix], occ[fix], kw[fix])
            mask[i] = 0xFFFF
        if second:
            i = np.flatnonzero(st)[nf == 0]
            scale[i], mask[i] = vis[i], 0xFFFF
    if weak.any():  # the 4 segments i -> 3 - i only
        i = np.flatnonzero(weak)
        A = np.ascontiguousarray(np.take(pa, i, 0).transpose(2, 0, 1))  # (3, n, 4)
        D = np.ascontiguousarray(np.take(pb, i, 0)[:, ::-1].transpose(2, 0, 1)) - A  # to point 3 - i
        NA = np.ascontiguousarray(np.take(na, i, 0).transpose(2, 0, 1))
        NB = np.ascontiguousarray(np.take(nb, i, 0)[:, ::-1].transpose(2, 0, 1))
        f, kw = _facing_cm(D, NA, NB)
        f &= ~(np.take(ca, i, 0) | np.take(cb, i, 0)[:, ::-1])
        occ = refiner.backend.occluded_cm(A.reshape(3, -1), D.reshape(3, -1)).reshape(-1, 4)
        nf = f.sum(1)
        v = 1.0 - occ.mean(1)
        vis[weak] = scale[weak] = np.where(nf > 0, unoccluded_share(f, occ, kw), v)
        mask[weak] = 0xFFFF
    per = SECOND_SEGMENTS if second else 16
    add_counts(refiner.stats, rays=per * int(st.sum()) + 4 * int(weak.sum()), t_vis=time.perf_counter() - t0)
    return vis, mask, scale


# SECOND_SEGMENTS 8: the segments 4 i + (i + s) mod 4, s in {0, 2}
_SECOND_SUBSET = np.sort([4 * i + (i + s) % 4 for i in range(4) for s in (0, 2)])
# far_visibility(decide=True): the segments traced first (up to DECIDE_FIRST of a link's counting
# ones, in this order: the 4 x 4's two diagonals first, each of a's and b's points once in each)
DECIDE_FIRST = 4
DECIDE_ORDER = np.array([0, 5, 10, 15, 3, 6, 9, 12, 1, 2, 4, 7, 8, 11, 13, 14])
# a link's first segments read both ways: partial only if the occluded ones carry at least this
# share of its counting kernel (the share computed from all of them then is surely below 1)
DECIDE_SHARE = 1e-9


def _segments_cm(pa, pb):
    """Component-major origins A (3, N, 4) (the points pa (N, 4, 3)) and segments D (3, N, 4, 4),
    D[:, n, i, j] = pb[n, j] - pa[n, i] (the b - a of occluded()'s rows: the same values)."""
    A = np.ascontiguousarray(pa.transpose(2, 0, 1))
    B = np.ascontiguousarray(pb.transpose(2, 0, 1))
    return A, B[:, :, None, :] - A[:, :, :, None]


def _facing_segments_cm(D, na, nb):
    """Which of the segments D (3, N, 4, 4) (_segments_cm) and the samples' normals na,
    nb (N, 4, 3): (N, 16) whether each faces both ways and its kernel (_facing_cm)."""
    NA = np.ascontiguousarray(na.transpose(2, 0, 1))[:, :, :, None]  # (3, N, 4 on a, 1)
    NB = np.ascontiguousarray(nb.transpose(2, 0, 1))[:, :, None, :]  # (3, N, 1, 4 on b)
    front, kw = _facing_cm(D, NA, NB)
    return front.reshape(-1, 16), kw.reshape(-1, 16)


def _facing_cm(D, NA, NB):
    """Whether segments D (3, ...) leave both points on their front sides (normals NA at their
    starts, NB at their ends, broadcast) and their kernel cos cos / r^2 (0 where not facing): the
    row form's einsums as dot3 over rows per coordinate (einsum's order, (x + z) + y; a zero's
    sign may differ, and the values are only compared or kept where nonzero: the same results)."""
    ca, cb = dot3(D, NA), dot3(D, NB)
    r2 = np.maximum(dot3(D, D), 1e-300)
    front = (ca > 0) & (cb < 0)
    return front, np.where(front, -ca * cb / (r2 * r2), 0.0)


def _trace(backend, A, D, sel):
    """occluded() of the segments sel (N, 16) of strong links (A, D: _segments_cm), in order."""
    k = np.flatnonzero(sel.ravel())
    a = np.take(A.reshape(3, -1), k // 4, 1)
    return backend.occluded_cm(a, np.take(D.reshape(3, -1), k, 1))


def _decide(backend, A, D, front, kw):
    """far_visibility(decide=True)'s values: 0.5 for links surely partial after their first
    counting segments, far_visibility's value for the others (from all their counting segments),
    and the rays traced."""
    n = front.shape[0]
    nf = front.sum(1)
    some = (nf > 0) & (nf < 16)  # only the front-facing segments count (unoccluded_share)
    count = np.where(some[:, None], front, True)
    c = count[:, DECIDE_ORDER]
    first = np.zeros_like(count)
    first[:, DECIDE_ORDER] = c & (np.cumsum(c, 1) <= DECIDE_FIRST)
    occ = np.zeros((n, 16), bool)
    occ[first] = _trace(backend, A, D, first)
    blocked, clear = first & occ, first & ~occ
    mixed = blocked.any(1) & clear.any(1)
    # a weighted share (unoccluded_share, kernel K > 0) is surely in (0, 1) when its occluded
    # segments carry a share of K well above rounding and an unoccluded one a weight > 0; a
    # count (1 - occ.mean(1), or the plain share where K underflows) whenever both occur
    K = np.where(front, kw, 0.0).sum(1)
    weighted = some & (K > 0)
    sure = mixed & (
        ~weighted
        | ((np.where(blocked, kw, 0.0).sum(1) > DECIDE_SHARE * K) & (np.where(clear, kw, 0.0).sum(1) > 0))
    )
    rest = count & ~first & ~sure[:, None]
    occ[rest] = _trace(backend, A, D, rest)
    vis = np.full(n, 0.5)
    todo = ~sure
    plain = todo & ~some
    vis[plain] = 1.0 - occ[plain].mean(1)
    ws = todo & some
    if ws.any():
        vis[ws] = unoccluded_share(front[ws], occ[ws], kw[ws])
    return vis, int(first.sum() + rest.sum())
