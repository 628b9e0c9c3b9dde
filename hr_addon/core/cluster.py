"""Face clusters above the input patches (numpy only); the links between them are in farlinks.py.

Why face clusters: HR links between nodes whose form factors are both below Feps. Without a
hierarchy above the patches every pair of patches has to be looked at, which is quadratic in the
polygon count. With clusters (Smits, Arvo & Greenberg 1994; Sillion 1995), linking starts at the
root's self-pair and refines down, so distant groups of small objects exchange light through one
link, and links per input polygon stay roughly constant as the scene grows.

Structure. Patches are first split into six orientation classes (dominant axis and sign of their
normal) and each class into a binary bounding-volume hierarchy (split at the middle of the longest
axis of the centroids' box, at the median when one side would be empty) down to leaf clusters of
at most `leaf_size` patches. So every cluster holds faces of similar orientation, as in face
clusters (Willmott, Heckbert & Garland 1999), while its members need not be adjacent: the tops of
all the books on a shelf form one cluster. A root cluster joins the classes. Every cluster covers
a contiguous range of `perm` (the patches in tree order), which makes its sums prefix-sum
differences.

Transfer (orientation-aware; the links themselves are in farlinks.py). A cluster end is
described towards a direction u by spherical harmonics up to l = 2 of its members' cosines: for
ends whose members all face the other end (`faces`) the kernel n . u is linear and exact (l = 1);
an end whose members face both ways ("partial", allowed on weak links only) uses the clamped
cosine max(0, n . u) in SH (Ramamoorthi & Hanrahan 2001). Each cluster therefore has SLOTS = 18
values per channel in the solver: 9 SH coefficients of its power (as a source) or irradiance (as
a receiver), and 9 for the first moment / gradient of flat clusters, so a strong link's
irradiance falls off across a wide flat cluster instead of being uniform. One symmetric kernel
per link serves both directions: reciprocity and energy balance hold by construction.
`power` sums members' radiance into source slots, `distribute` hands the received slots back to
members by orientation and position, both through prefix sums over contiguous leaf ranges.
"""

import numpy as np

from . import formfactor as ff
from . import parallel
from .boxes import csr_rows, spans

N_CLASSES = 6
# patches per batch of a level's splits in ClusterTree (whole segments; fixed: the same tree on any
# thread count)
TREE_BATCH = 1 << 15


def encode(c):
    """Cluster index -> id in the shared id space of link ends (patch nodes are >= 0)."""
    return -1 - np.asarray(c, np.int64)


decode = encode  # the map is its own inverse


class ClusterTree:
    """Clusters as flat arrays. Cluster 0 is the root; ids grow with depth.

    start/end: range of `perm` (patches in tree order) each cluster holds; parent; depth;
    child_start/child_ids: CSR children, ids in the shared space (clusters < 0, patches >= 0);
    area, avec (sum A n), centre (area-weighted), radius (bounding sphere about centre),
    lo/hi (box), axis + cos_t/sin_t (normal cone), samples/sample_n (points for visibility rays).
    """

    def __init__(self, patches, leaf_size=4, n_samples=4, exposure=None, sample_at=None, threads=1):
        """exposure (K,): uncovered fraction of each patch, and sample_at (K, 3): a point on its
        uncovered part (contacts.py); visibility samples are stratified by uncovered area, so a
        box's bottom on the floor is never one. threads: the depths' boxes and cones (core.parallel)."""
        K = len(patches.nv)
        self.K = K
        nrm, area = patches.normal, patches.area
        nv = patches.nv
        c = patches.corners
        cen = (c[:, 0] + c[:, 1] + c[:, 2] + np.where(nv[:, None] == 4, c[:, 3], 0)) / nv[:, None]
        lo_p = np.where((nv == 4)[:, None], c.min(1), c[:, :3].min(1))
        hi_p = np.where((nv == 4)[:, None], c.max(1), c[:, :3].max(1))
        ax = np.argmax(np.abs(nrm), 1)
        cls = 2 * ax + (nrm[np.arange(K), ax] < 0)
        perm = np.argsort(cls, kind="stable")
        bounds = np.searchsorted(cls[perm], np.arange(N_CLASSES + 1))
        # Clusters as (start, end, parent, depth); top-down splits, one level at a time.
        starts, ends, parents, depths = [0], [K], [-1], [0]
        level = []
        for k in range(N_CLASSES):
            if bounds[k + 1] > bounds[k]:
                level.append(len(starts))
                starts.append(bounds[k]), ends.append(bounds[k + 1]), parents.append(0), depths.append(1)
        level = np.array(level, np.int64)
        depth = 1
        while len(level):
            s, e = np.array(starts)[level], np.array(ends)[level]
            big = e - s > leaf_size
            level, s, e = level[big], s[big], e[big]
            if not len(level):
                break

            # split each segment at the middle of the longest axis of its centroids' box (compact
            # clusters: their radius bounds the point-to-point kernel's error); the median when
            # all centroids fall on one side. Every segment is its own (its range of perm): by
            # batches of whole segments of about TREE_BATCH patches on threads (issue 23: serial,
            # docs/threads.md, session 37), each reordering its own ranges of perm
            def split(i, j, s=s, e=e):
                s, e = s[i:j], e[i:j]
                pos, idx = spans(s, e)
                pc = cen[perm[idx]]
                cut = np.r_[0, np.cumsum(e - s)[:-1]]
                lo_s, hi_s = np.minimum.reduceat(pc, cut, axis=0), np.maximum.reduceat(pc, cut, axis=0)
                axis = np.argmax(hi_s - lo_s, 1)
                key = pc[np.arange(len(idx)), axis[pos]]
                order = np.lexsort((key, pos))
                perm[idx] = perm[idx[order]]
                key = key[order]
                half = 0.5 * (lo_s + hi_s)[np.arange(len(s)), axis]
                ext = (hi_s - lo_s)[np.arange(len(s)), axis]
                # centroids on the midplane (regular grids) go left at any scale
                below = key <= (half + 1e-9 * ext)[pos]
                mid = s + np.bincount(pos, weights=below, minlength=len(s)).astype(np.int64)
                bad = (mid <= s) | (mid >= e)
                return np.where(bad, (s + e) // 2, mid)

            cum = np.cumsum(e - s)
            at = np.searchsorted(cum, np.arange(1, -(-int(cum[-1]) // TREE_BATCH)) * TREE_BATCH) + 1
            edges = np.unique(np.clip(np.r_[0, at, len(s)], 0, len(s)))
            mid = np.concatenate(parallel.batch_map(split, list(zip(edges[:-1], edges[1:])), threads))
            depth += 1
            first, n = len(starts), len(level)
            starts += np.column_stack([s, mid]).ravel().tolist()
            ends += np.column_stack([mid, e]).ravel().tolist()
            parents += np.repeat(level, 2).tolist()
            depths += [depth] * (2 * n)
            level = first + np.arange(2 * n)
        self.perm = perm
        self.start, self.end = np.array(starts, np.int64), np.array(ends, np.int64)
        self.parent, self.depth = np.array(parents, np.int64), np.array(depths, np.int64)
        C = self.C = len(self.start)
        self.levels = [np.flatnonzero(self.depth == d) for d in range(int(self.depth.max()) + 1)]
        # children: the clusters one level down, else (leaf clusters) the patches of the range
        nkids = np.bincount(self.parent[1:], minlength=C)
        self.is_leaf = nkids == 0
        ccount = np.where(self.is_leaf, self.end - self.start, nkids)
        self.child_start = np.r_[0, np.cumsum(ccount)]
        kids = np.empty(int(ccount.sum()), np.int64)
        corder = 1 + np.argsort(self.parent[1:], kind="stable")
        kids[self.child_start[self.parent[corder]] + _rank_within(self.parent[corder])] = encode(corder)
        leaf = np.flatnonzero(self.is_leaf)
        owner, idx = spans(self.start[leaf], self.end[leaf])
        kids[self.child_start[leaf][owner] + _rank_within(owner)] = perm[idx]
        self.child_ids = kids
        self.leaf_of = np.empty(K, np.int64)
        self.leaf_of[perm[idx]] = leaf[owner]
        # sums over ranges: prefix sums in tree order
        w = area[perm]
        self.area = _range_sum(w, self.start, self.end)
        self.avec = _range_sum(w[:, None] * nrm[perm], self.start, self.end)
        self.centre = (
            _range_sum(w[:, None] * cen[perm], self.start, self.end) / np.maximum(self.area, 1e-300)[:, None]
        )
        self.axis = self.avec / np.maximum(np.linalg.norm(self.avec, axis=1), 1e-300)[:, None]
        # exact boxes, bounding radii and normal cones: the clusters of one depth hold disjoint
        # ranges, so each depth is one pass over (at most) all patches
        self.lo, self.hi = np.empty((C, 3)), np.empty((C, 3))
        self.radius, theta = np.empty(C), np.empty(C)

        def depth_pass(ids):
            owner, idx = spans(self.start[ids], self.end[ids])
            p, oc = perm[idx], ids[owner]
            cut = np.r_[0, np.cumsum(self.end[ids] - self.start[ids])[:-1]]
            lo, hi = np.minimum.reduceat(lo_p[p], cut, axis=0), np.maximum.reduceat(hi_p[p], cut, axis=0)
            r = np.maximum.reduceat(np.linalg.norm(c[p] - self.centre[oc][:, None], axis=2).max(1), cut)
            dots = np.einsum("ij,ij->i", nrm[p], self.axis[oc])
            return lo, hi, r, np.arccos(np.clip(np.minimum.reduceat(dots, cut), -1, 1))

        # the depths on threads (each its own clusters; issue 23: a tenth of the 100k build's
        # serial CPU, docs/threads.md, session 37)
        for ids, got in zip(
            self.levels, parallel.batch_map(depth_pass, [(x,) for x in self.levels], threads)
        ):
            self.lo[ids], self.hi[ids], self.radius[ids], theta[ids] = got
        # a cluster whose area vector nearly cancels has no meaningful axis: treat as unbounded
        flat = np.linalg.norm(self.avec, axis=1) > 1e-9 * np.maximum(self.area, 1e-300)
        self.theta = np.where(flat, theta, np.pi)
        self.cos_t, self.sin_t = np.cos(self.theta), np.sin(self.theta)
        # visibility samples: area-stratified member patches (their centroids), in tree order
        ws = w if exposure is None else w * np.asarray(exposure, float)[perm]
        cum = np.cumsum(ws)
        tgt = (cum[self.start] - ws[self.start])[:, None] + (np.arange(n_samples) + 0.5)[
            None
        ] / n_samples * _range_sum(ws[:, None], self.start, self.end)[:, 0][:, None]
        pos = np.clip(np.searchsorted(cum, tgt), self.start[:, None], self.end[:, None] - 1)
        self.samples = (cen if sample_at is None else sample_at)[perm[pos]]
        self.sample_n = nrm[perm[pos]]
        self.sample_patch = perm[pos]  # (sample_covered)
        self._transfer_tables(nrm, area, cen)

    # -- per-iteration transfer helpers ------------------------------------------------------------
    def power(self, L):
        """(C, SLOTS) source slots of every cluster from L (K,), the radiance of the patch roots:
        the SH power coefficients sum A L Y(n) (the l = 1 part is the power vector sum A L n,
        times SH_C1), then the first moment of the l = 1 part about the cluster's centre,
        sum A L Y1(n) (x - c) (3 components x 3 axes). Leaf clusters sum their patches (their
        ranges tile the tree order), the others their children, level by level."""
        out = np.empty((self.C, SLOTS))
        for g in range(self.groups()):
            self.power_group(L, g, out)
        return self.power_root(out)

    def power_group(self, L, g, out):
        """power()'s sums of the clusters below the root in group g (a set of orientation classes:
        its own rows of `out`, so the groups may run on threads), with their first moments except
        the classes' (the root sums those first)."""
        p0, p1, leaf, first, up, _, _, _ = self._groups[g]
        out[leaf] = np.add.reduceat(self._aYT[:, p0:p1] * np.take(L, self.perm[p0:p1]), first, axis=1).T
        # rows by np.take(axis=0): 3x faster than fancy indexing (out[kids]), the same rows
        for ids, kids in up:
            s = np.take(out, kids[:, 0], 0)  # the children in order, as sum(1) adds them (the same bits)
            for j in range(1, kids.shape[1]):
                s += np.take(out, kids[:, j], 0)
            out[ids] = s
        c = getattr(self, "_centre9", None)  # the centres repeated to the 9 moment slots (not stored)
        if c is None:
            c = self._centre9 = np.tile(self.centre, 3)
        for a, b in self._group_runs()[g][1]:  # (the moments' clusters: a few runs of ids)
            # _moments over rows of 9 (its products and differences, 1.6x faster)
            out[a:b, 9:] -= np.take(out[a:b], _MOMENT_SLOTS, 1) * c[a:b]

    def power_root(self, out):
        """power() after every group's power_group(): the root's sum and the first moments of the
        root and the classes."""
        for ids, kids in self._up_root:
            out[ids] = out[kids].sum(1)
        _moments(out, self._top, self.centre)
        return out

    def distribute(self, E):
        """(K,) irradiance of every patch root from the clusters' gathered slots E (C, SLOTS):
        summed over the patch's clusters (root to leaf, level by level), the SH coefficients
        evaluated at the patch normal plus the l = 1 gradient terms at its centre."""
        acc, out = np.empty_like(E), np.zeros(self.K)
        acc[0] = E[0]
        for g in range(self.groups()):
            self.distribute_group(E, acc, g, out)
        return out

    def distribute_group(self, E, acc, g, out):
        """distribute() for the patches of group g: acc (C, SLOTS), scratch whose root row is E's,
        gets its clusters' sums from the root down; its patches' values are added to out (K,)
        (each group its own rows: the groups may run on threads)."""
        p0, p1 = self._groups[g][:2]
        own, down = self._group_runs()[g][0], self._group_runs()[g][2]
        for a, b in own:
            acc[a:b] = E[a:b]
        for (a, b), par in down:
            acc[a:b] += np.take(acc, par, 0)  # (rows by take: as power_group)
        a = np.take(acc, self._leaf_of_sorted[p0:p1], 0)
        out[self.perm[p0:p1]] += np.einsum("kj,kj->k", a[:, :9], self._Y[p0:p1]) + self._gradient_terms(
            a[:, 9:], p0, p1
        )

    def _gradient_terms(self, g, p0, p1):
        """(p1 - p0,) the l = 1 gradient terms of patches p0..p1 in tree order from their clusters'
        summed gradient slots g (k, 9): einsum("kmj,km,kj->k", g (k, 3, 3), Y1, X) written out in
        einsum's own order, (g Y) X summed m-major from the first term (the same bits, 2.3x faster:
        100k room, 3.7 -> 1.6 ms a channel); Y1 and X repeated to (K, 9) once (not stored)."""
        got = getattr(self, "_grad_rows", None)
        if got is None:
            got = self._grad_rows = (np.repeat(self._Y[:, 1:4], 3, 1), np.tile(self._X, 3))
        P = g * got[0][p0:p1]
        P *= got[1][p0:p1]
        s = P[:, 0].copy()
        for j in range(1, 9):
            s += P[:, j]
        return s

    def _transfer_tables(self, normal, area, centre):
        self._Y = sh9(normal[self.perm])
        aY = self._Y * area[self.perm, None]
        self._X = centre[self.perm]
        aY1x = (aY[:, 1:4, None] * self._X[:, None, :]).reshape(-1, 9)
        # level-by-level sums, deepest first: inner clusters by their number of children (two
        # below the classes), children one level down
        self._leaves = np.flatnonzero(self.is_leaf)
        self._up = []
        nk = self.child_start[1:] - self.child_start[:-1]
        for ids in self.levels[::-1]:
            inner = ids[~self.is_leaf[ids]]
            for k in np.unique(nk[inner]):
                sel = inner[nk[inner] == k]
                self._up.append((sel, decode(self.child_ids[self.child_start[sel][:, None] + np.arange(k)])))
        self._down = [(ids, self.parent[ids]) for ids in self.levels[1:]]
        self._leaf_of_sorted = self.leaf_of[self.perm]
        # patch weights of the source slots, slot-major for fast runs over the leaves' ranges
        self._aYT = np.ascontiguousarray(np.concatenate([aY, aY1x], 1).T)
        order = np.argsort(self.start[self._leaves], kind="stable")
        self._leaf_runs = (self._leaves[order], self.start[self._leaves][order])
        keys = []
        for pos in (self.start, self.end):
            order = np.argsort(pos, kind="stable")
            at, first = np.unique(pos[order], return_index=True)
            keys.append((order, at, first))
        self._by_start, self._by_end = keys

    def groups(self):
        """The number of groups of power_group() and distribute_group() (built on first use)."""
        if getattr(self, "_groups", None) is None:
            self._make_groups()
        return len(self._groups)

    def _make_groups(self):
        """power() and distribute() by groups of whole orientation classes (the root's children:
        contiguous ranges of the tree order), cut into GROUPS of about equal patch counts; each
        group's level steps are the full tree's restricted to its clusters, so the sums are the
        same as over the whole tree. The root's own sum follows the groups (_up_root)."""
        cls = self.levels[1] if len(self.levels) > 1 else np.zeros(0, np.int64)
        self._top = np.r_[0, cls]
        cuts = np.unique(np.r_[0, self.end[cls], self.K])  # class boundaries in the tree order
        want = np.linspace(0, self.K, GROUPS + 1)[1:-1]
        inner = cuts[np.clip(np.searchsorted(cuts, want), 0, len(cuts) - 1)]
        bounds = np.unique(np.r_[0, inner, self.K])
        grp = np.searchsorted(bounds, self.start, "right") - 1  # the root (whole range) is group 0
        grp[0] = -1 if not self.is_leaf[0] else 0
        leaf, first = self._leaf_runs
        groups = []
        for g in range(len(bounds) - 1):
            p0, p1 = int(bounds[g]), int(bounds[g + 1])
            lg = leaf[grp[leaf] == g]
            up = [(ids[grp[ids] == g], kids[grp[ids] == g]) for ids, kids in self._up]
            down = [(ids[grp[ids] == g], par[grp[ids] == g]) for ids, par in self._down]
            keep = lambda steps: [x for x in steps if len(x[0])]
            own = np.flatnonzero(grp == g)
            mom = np.setdiff1d(own, self._top)  # the classes' moments come after the root's sum
            groups.append((p0, p1, lg, first[grp[leaf] == g] - p0, keep(up), keep(down), own, mom))
        self._up_root = [
            (ids[grp[ids] < 0], kids[grp[ids] < 0]) for ids, kids in self._up if (grp[ids] < 0).any()
        ]
        self._groups = groups  # assigned whole: a thread never sees it half built

    def _group_runs(self):
        """Per group of _groups: (its clusters, their moments' clusters, the distribution's level
        steps (cluster span, parents)) as contiguous spans (a, b) of cluster ids: the clusters of
        a group's level are one run of ids, so slices instead of fancy indexing (the same values;
        built on first use, not stored: precompute_graph's _TRANSIENT)."""
        got = getattr(self, "_group_runs_", None)
        if got is None:
            got = []
            for _, _, _, _, _, down, own, mom in self._groups:
                steps = []
                for ids, par in down:
                    steps += [((a, b), par[i : i + b - a]) for a, b, i in _id_runs(ids)]
                got.append(tuple([x[:2] for x in _id_runs(ids)] for ids in (own, mom)) + (steps,))
            self._group_runs_ = got
        return got

    def children(self, c):
        """Children (shared ids) of clusters c: (flat ids, owner index into c)."""
        owner, idx = csr_rows(self.child_start, np.asarray(c, np.int64))
        return self.child_ids[idx], owner

    @property
    def nbytes(self):
        return sum(v.nbytes for v in self.__dict__.values() if isinstance(v, np.ndarray))


def _rank_within(groups):
    """0, 1, 2, ... within each run of equal values of a sorted (grouped) array."""
    groups = np.asarray(groups)
    if not len(groups):
        return np.zeros(0, np.int64)
    first = np.r_[True, groups[1:] != groups[:-1]]
    idx = np.arange(len(groups))
    return idx - np.maximum.accumulate(np.where(first, idx, 0))


def _id_runs(ids):
    """[(a, b, i)]: the runs of consecutive values in ids (a, a + 1, ..., b - 1 from position i)."""
    if not len(ids):
        return []
    i = np.r_[0, np.flatnonzero(np.diff(ids) != 1) + 1]
    n = np.diff(np.r_[i, len(ids)])
    return [(int(ids[p]), int(ids[p]) + int(k), int(p)) for p, k in zip(i, n)]


_MOMENT_SLOTS = np.repeat([1, 2, 3], 3)  # the l = 1 power slot of each of the 9 moment slots


def _moments(out, ids, centre):
    """power()'s first moments of clusters ids about their centres (from the origin's)."""
    out[ids, 9:] -= (out[ids, 1:4, None] * centre[ids, None, :]).reshape(-1, 9)


def _range_sum(w, start, end):
    """Sums of w over the ranges [start, end) (prefix-sum differences)."""
    cs = np.concatenate([np.zeros((1,) + w.shape[1:]), np.cumsum(w, axis=0)])
    return cs[end] - cs[start]


# -- second-order spherical harmonics ---------------------------------------------------------------
SH_C1 = 0.4886025119029199
# A cluster's slots in the solver's extended space: 9 SH coefficients (as a source its power,
# as a receiver its irradiance), then for the l = 1 part (3 components x 3 axes) the power's
# first moment about the cluster's centre (source) or the irradiance's gradient (receiver)
SLOTS = 18
# power() and distribute() in this many groups of orientation classes (threads: each group's
# clusters and patches are its own); fixed, so the sums never depend on the thread count
GROUPS = 2
# Irradiance gradients only for flat clusters (normal cone below ~2 degrees: walls, floors, the
# tops of things): on a curved one the members' orientations change along with their
# positions, which a linear fit of the distance falloff over four samples would mix up
GRAD_CONE = 0.03
# ... so a curved cluster hands a link's irradiance to its members by orientation alone: its
# radius counts this much more in the size test (measured on a sphere's interior: 1.4% against
# 3.4% at 1.0)
CURVED = 1.5
# max(0, n . u) ~ sum_lm A_l Y_lm(u) Y_lm(n) (Ramamoorthi & Hanrahan 2001: A = pi, 2 pi / 3, pi / 4)
SH_CLAMPED = np.array([np.pi] + [2 * np.pi / 3] * 3 + [np.pi / 4] * 5)
# n . u = sum_m Y_1m(u) Y_1m(n) / SH_C1^2: the exact kernel of ends that wholly face each other
SH_LINEAR = np.array([0.0] + [1 / SH_C1**2] * 3 + [0.0] * 5)


def sh9(d):
    """(N, 9) real spherical harmonics up to l = 2 of unit directions d (N, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack(
        [
            np.full_like(x, 0.28209479177387814),
            SH_C1 * y,
            SH_C1 * z,
            SH_C1 * x,
            1.0925484305920792 * x * y,
            1.0925484305920792 * y * z,
            0.31539156525252005 * (3 * z * z - 1),
            1.0925484305920792 * x * z,
            0.5462742152960396 * (x * x - y * y),
        ],
        1,
    )


# -- ends of links: patch nodes (>= 0) and clusters (< 0) in one vectorised view -----------------------
class EndTable:
    """What Ends, sample_points and sample_normals give for every cluster and every patch node,
    computed once per node: link_clusters asks for the same ends over and over (a third of its
    oracle's time went to building them). Rows: clusters 0..C-1, then patch node i at C + i;
    update() adds the nodes subdivided since (call it between batches, not on threads). The
    same expressions row by row, so the same values bit for bit. Valid while node ids hold (one
    linking pass: Hierarchy.compact renumbers them). Ends' vector and scalar fields are packed
    in one row per end (`packed` (cap, 17): one gather of rows per batch, transposed, gives
    every field as contiguous rows, which faces() and estimate() work on; a take of columns
    from a (17, cap) table missed the cache on every field at 100k), the arrays grown by
    doubling (not copied whole on every update)."""

    FIELDS = ("centre", "axis", "lo", "hi", "area", "radius", "cos_t", "sin_t", "theta", "pts", "w", "nrm")
    # columns of `packed`: 3 per vector field, then the scalars
    PACKED = ("centre", "axis", "lo", "hi", "area", "radius", "cos_t", "sin_t", "theta")
    # rows per batch of the rows' computation on threads (_rows)
    ROW_BATCH = 1 << 13

    def __init__(self, tree: ClusterTree, h, eps, threads=1):
        self.tree, self.h, self.eps, self.n, self.threads = tree, h, eps, 0, threads
        self.size = self.cap = 0
        t, C = tree, tree.C
        cols = dict(centre=t.centre, axis=t.axis, lo=t.lo, hi=t.hi, area=t.area, radius=t.radius)
        cols.update(cos_t=t.cos_t, sin_t=t.sin_t, theta=t.theta)
        cols.update(pts=t.samples + eps * t.sample_n, w=np.full((C, 4), 0.25), nrm=t.sample_n)
        cols = {k: np.asarray(v, float)[:C] for k, v in cols.items()}

        def spread(i, j):
            # the clusters' visibility points (visibility_points; a node's first set are its pts),
            # `cov` whether a row's visibility points are covered (a cluster's spread points, a
            # node's Gauss points), and the second set's
            ci = np.arange(i, j)
            vp, cov = spread_points(t, h, ci)
            m2 = second_members(t, h, ci)
            vp2, cov2 = spread_points(t, h, ci, SECOND, m2)
            return vp + eps * t.sample_n[i:j], cov, h.normal[m2], vp2, cov2

        # every cluster's rows are its own: by batches of rows on threads (issue 23: serial, they
        # were a sixth of the 100k build's serial CPU, docs/threads.md, session 37)
        vp, cols["cov"], self.nrm2, vp2, self.cov2 = self._rows(spread, C)
        self.vpts = cols["vis"] = vp
        self.vpts2 = vp2 + eps * self.nrm2
        # patch nodes' second visibility points (prepare_second), grown to the hierarchy's size
        self.has2, self.pts2, self.cov2n = np.zeros(0, bool), np.empty((0, 4, 3)), np.empty((0, 4), bool)
        self._append(cols)
        self.update()

    def _rows(self, fn, n):
        """fn(i, j)'s arrays for rows i..j, by batches of ROW_BATCH rows on the table's threads,
        each concatenated over the batches (batch bounds fixed: the same values on any count)."""
        parts = parallel.batch_map(fn, parallel.ranges(n, self.ROW_BATCH), self.threads)
        return [np.concatenate(x) for x in zip(*parts)]

    def _append(self, cols):
        m = len(cols["area"])
        new = {k: cols[k] for k in ("pts", "w", "nrm", "cov", "vis")}
        rows = np.hstack([np.reshape(cols[k], (m, -1)) for k in self.PACKED])  # (m, 17)
        end = self.size + m
        if end > self.cap:
            cap = max(end, 2 * self.cap)
            for k, v in new.items():
                grown = np.empty((cap,) + v.shape[1:], v.dtype)
                if self.size:
                    grown[: self.size] = getattr(self, k)[: self.size]
                setattr(self, k, grown)
            grown = np.empty((cap, rows.shape[1]))
            if self.size:
                grown[: self.size] = self.packed[: self.size]
            self.packed = grown
            self.cap = cap
        for k, v in new.items():
            getattr(self, k)[self.size : end] = v
        self.packed[self.size : end] = rows
        self.size = end

    def update(self):
        h, m, n = self.h, self.n, self.h.n
        if n <= m:
            return
        keys = (*self.PACKED, "pts", "w", "nrm", "cov")

        def rows(i, j):  # nodes m + i .. m + j: every node's rows its own
            ni = np.arange(m + i, m + j)
            c, k, nrm = h.corners[ni], j - i, h.normal[ni]
            pts, w = ff.quadrature(c, h.nv[ni], 2)
            radius = ff.norm3(c - h.centre[ni][:, None]).max(1)
            patch, expo = (np.repeat(x[ni][:, None], 4, 1) for x in (h.patch, h.exposure))
            cov = _covered(h, pts, patch, expo)
            box = (h.centre[ni], nrm, c.min(1), c.max(1), h.area[ni], radius)
            return box + (
                np.ones(k),
                np.zeros(k),
                np.zeros(k),
                pts + self.eps * nrm[:, None],
                w,
                np.repeat(nrm[:, None], 4, 1),
                cov,
            )

        new = dict(zip(keys, self._rows(rows, n - m)))
        new["vis"] = new["pts"]  # a node's first visibility points: its Gauss points
        self._append(new)
        self.n = n

    def prepare_second(self, ni):
        """Patch nodes ni's second visibility points (visibility_points(second=True): pushed eps
        off, and whether each is covered), made once per node and kept (link_clusters, before its
        second trace: a node ends many links). Call it serially; nodes added since are made
        there again."""
        h, m = self.h, len(self.has2)
        if m < h.n:
            grown = np.zeros(h.n, bool), np.empty((h.n, 4, 3)), np.empty((h.n, 4), bool)
            grown[0][:m], grown[1][:m], grown[2][:m] = self.has2, self.pts2, self.cov2n
            self.has2, self.pts2, self.cov2n = grown
        ni = np.unique(np.asarray(ni, np.int64))
        ni = ni[~self.has2[ni]]
        if len(ni):
            q, self.cov2n[ni] = _node_points2(h, ni)
            self.pts2[ni] = q + self.eps * h.normal[ni][:, None]
            self.has2[ni] = True

    def rows(self, ids):
        ids = np.asarray(ids, np.int64)
        return np.where(ids < 0, -1 - ids, self.tree.C + ids)


class Ends:
    """Geometry of link ends given by shared ids, for the oracle and the transfer weights
    (table: an EndTable holding them). The vector fields centre, axis, lo, hi (N, 3) also as
    rows per coordinate (3, N): centre_t, axis_t, lo_t, hi_t (what faces() and estimate() read;
    from a table contiguous rows, the (N, 3) fields their transposed views)."""

    def __init__(self, tree: ClusterTree, h, ids, table=None):
        self.tree = tree
        ids = np.asarray(ids, np.int64)
        self.ids = ids
        cl = ids < 0
        self.cl = cl
        if table is not None:
            # one gather of packed rows (each end's 17 values in one place), transposed: every
            # field a contiguous row (3 per vector)
            g = np.ascontiguousarray(np.take(table.packed, table.rows(ids), axis=0).T)
            self.centre_t, self.axis_t, self.lo_t, self.hi_t = g[0:3], g[3:6], g[6:9], g[9:12]
            self.centre, self.axis = self.centre_t.T, self.axis_t.T
            self.lo, self.hi = self.lo_t.T, self.hi_t.T
            self.area, self.radius, self.cos_t, self.sin_t, self.theta = g[12:17]
            return
        n = len(ids)
        ci, ni = decode(ids[cl]), ids[~cl]
        self.centre = np.empty((n, 3))
        self.axis = np.empty((n, 3))
        self.lo, self.hi = np.empty((n, 3)), np.empty((n, 3))
        self.area, self.radius, self.cos_t, self.sin_t, self.theta = (np.empty(n) for _ in range(5))
        self.centre[cl], self.axis[cl], self.area[cl] = tree.centre[ci], tree.axis[ci], tree.area[ci]
        self.lo[cl], self.hi[cl], self.radius[cl] = tree.lo[ci], tree.hi[ci], tree.radius[ci]
        self.cos_t[cl], self.sin_t[cl], self.theta[cl] = tree.cos_t[ci], tree.sin_t[ci], tree.theta[ci]
        c = h.corners[ni]
        self.centre[~cl], self.axis[~cl], self.area[~cl] = h.centre[ni], h.normal[ni], h.area[ni]
        self.lo[~cl], self.hi[~cl] = c.min(1), c.max(1)
        self.radius[~cl] = ff.norm3(c - h.centre[ni][:, None]).max(1)
        self.cos_t[~cl], self.sin_t[~cl], self.theta[~cl] = 1.0, 0.0, 0.0
        self.centre_t, self.axis_t, self.lo_t, self.hi_t = self.centre.T, self.axis.T, self.lo.T, self.hi.T


def _support(lo, hi, a, sign):
    """max (sign=+1) or min (sign=-1) of x . a over boxes [lo, hi] (rows per coordinate (3, N)):
    einsum's dot product of the rows, in its order (formfactor.dot3; a zero's sign may differ:
    faces() only compares)."""
    return ff.dot3(np.where(a * sign >= 0, hi, lo), a)


def faces(x: Ends, y: Ends, dmax=None):
    """(front, behind): front where y lies wholly in front of every member of x (each member's
    normal within x's cone), behind where y lies wholly behind all of them (no exchange).
    dmax: the boxes' farthest distance (symmetric: faces(y, x) returns it for reuse)."""
    if dmax is None:
        m = np.maximum(np.abs(y.hi_t - x.lo_t), np.abs(x.hi_t - y.lo_t))
        dmax = np.sqrt((m[0] * m[0] + m[1] * m[1]) + m[2] * m[2])  # (norm3's order)
    gap_front = _support(y.lo_t, y.hi_t, x.axis_t, -1) - _support(x.lo_t, x.hi_t, x.axis_t, +1)
    gap_back = _support(y.lo_t, y.hi_t, x.axis_t, +1) - _support(x.lo_t, x.hi_t, x.axis_t, -1)
    slack = x.sin_t * dmax
    # touching (a box standing on the floor) is decided the same at any scale: gaps within
    # rounding of zero count as in front, and as behind for what lies in the plane itself
    tol = 1e-9 * dmax
    front = (x.cos_t > 0) & (gap_front * x.cos_t >= slack - tol)
    behind = (x.cos_t > 0) & (gap_back * x.cos_t + slack <= tol)
    return front, behind, dmax


def estimate(x: Ends, y: Ends, both=False):
    """Conservative-ish F[x -> y] estimate from x's cone, y's projected area and the distance:
    S_y cos_x / (pi d^2 + S_y), with cosines widened by the cones and the ends' angular radii.
    Returns (F, distance), or with both (F[x -> y], F[y -> x], distance): estimate(y, x)'s
    cosines are this call's swapped (its d and u negated: the same values bit for bit). On rows
    per coordinate; the norm and the dot products in norm3's and einsum's orders (the same bits;
    the arccos of a zero is the same for either sign)."""
    d = y.centre_t - x.centre_t
    dist = np.sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2])
    u = d / np.maximum(dist, 1e-300)
    spread_y = np.arcsin(np.clip(y.radius / np.maximum(dist, 1e-300), 0, 1))
    spread_x = np.arcsin(np.clip(x.radius / np.maximum(dist, 1e-300), 0, 1))
    ax = np.arccos(np.clip(ff.dot3(x.axis_t, u), -1, 1))
    ay = np.arccos(np.clip(-ff.dot3(y.axis_t, u), -1, 1))
    cos_x = np.cos(np.clip(ax - x.theta - spread_y, 0, np.pi / 2))
    cos_y = np.cos(np.clip(ay - y.theta - spread_x, 0, np.pi / 2))
    s_y = y.area * cos_y
    f = np.clip(s_y * cos_x / (np.pi * dist**2 + s_y), 0, 1)
    if not both:
        return f, dist
    s_x = x.area * cos_x
    return f, np.clip(s_x * cos_y / (np.pi * dist**2 + s_x), 0, 1), dist


def sample_points(tree: ClusterTree, h, ids, eps, table=None):
    """(N, 4, 3) points on link ends, pushed eps off their surfaces, and their weights (N, 4):
    a cluster's area-stratified members (equal weights), a patch node's 2 x 2 Gauss points (the
    kernel is smooth over a node; Gauss points integrate it far better than cell centres).
    table: an EndTable made with this eps."""
    ids = np.asarray(ids, np.int64)
    if table is not None:
        r = table.rows(ids)
        return table.pts[r], table.w[r]
    out, w = np.empty((len(ids), 4, 3)), np.full((len(ids), 4), 0.25)
    cl = ids < 0
    ci = decode(ids[cl])
    out[cl] = tree.samples[ci] + eps * tree.sample_n[ci]
    ni = ids[~cl]
    pts, w[~cl] = ff.quadrature(h.corners[ni], h.nv[ni], 2)
    out[~cl] = pts + eps * h.normal[ni][:, None]
    return out, w


def sample_normals(tree: ClusterTree, h, ids, table=None):
    """(N, 4, 3) normals at the sample points of link ends."""
    ids = np.asarray(ids, np.int64)
    if table is not None:
        return table.nrm[table.rows(ids)]
    out = np.empty((len(ids), 4, 3))
    cl = ids < 0
    out[cl] = tree.sample_n[decode(ids[cl])]
    out[~cl] = h.normal[ids[~cl]][:, None]
    return out


def visibility_points(tree: ClusterTree, h, ids, eps, table=None, second=False):
    """(N, 4, 3) the points a far link's visibility segments leave from, pushed eps off their
    surfaces, (N, 4) whether each lies on a covered part (contacts.py) and (N, 4, 3) their
    normals. A patch node's: its 2 x 2 Gauss points (sample_points; they take no account of its
    covered part). A cluster's: its 4 area-stratified members (sample_points' members, the
    kernel's) at spread positions (spread_points), not their centroids: the kernel is smooth over
    a member and its centroid serves it, but visibility is not (what blocks a member's edges and
    corners, a neighbour, a shelf above, misses its centre: links traced from centroids read
    wholly visible where a dense estimate read 0.92-0.94). second: another set of 4 points an
    end for an estimate independent of a decision made on the first (link_clusters): a
    cluster's on other members (second_members) at positions shifted by SECOND, a node's at
    SPREAD's positions. table: an EndTable made with this eps."""
    ids = np.asarray(ids, np.int64)
    cl = ids < 0
    ci, ni = decode(ids[cl]), ids[~cl]
    if table is not None and not second:  # a node's: its Gauss points (the table's `vis` rows)
        r = table.rows(ids)
        return np.take(table.vis, r, 0), np.take(table.cov, r, 0), np.take(table.nrm, r, 0)
    pts, out, nrm = np.empty((len(ids), 4, 3)), np.empty((len(ids), 4), bool), np.empty((len(ids), 4, 3))
    if table is not None:
        pts[cl], out[cl], nrm[cl] = table.vpts2[ci], table.cov2[ci], table.nrm2[ci]
        has2 = table.has2
        if len(ni) and ni.max() < len(has2) and has2[ni].all():  # prepare_second's
            pts[~cl], out[~cl] = np.take(table.pts2, ni, 0), np.take(table.cov2n, ni, 0)
            nrm[~cl] = h.normal[ni][:, None]
            return pts, out, nrm
    else:
        m = second_members(tree, h, ci) if second else tree.sample_patch[ci]
        p, out[cl] = spread_points(tree, h, ci, SECOND if second else 0.0, m)
        nrm[cl] = h.normal[m]
        pts[cl] = p + eps * nrm[cl]
    if second:
        q, out[~cl] = _node_points2(h, ni)
    else:
        q = ff.quadrature(h.corners[ni], h.nv[ni], 2)[0]
        patch, expo = np.repeat(h.patch[ni][:, None], 4, 1), np.repeat(h.exposure[ni][:, None], 4, 1)
        out[~cl] = _covered(h, q, patch, expo)
    nrm[~cl] = h.normal[ni][:, None]
    pts[~cl] = q + eps * nrm[~cl]
    return pts, out, nrm


def _node_points2(h, ni):
    """(n, 4, 3) patch nodes' second visibility points (SPREAD's positions shifted per node along
    R2, on the node's surface) and (n, 4) whether each is covered."""
    ni = np.asarray(ni, np.int64)
    uv = np.mod(SPREAD[None] + (ni[:, None, None] + 1.0) * R2, 1.0)
    q = _in_polygon(h.corners[ni][:, None], h.nv[ni][:, None], uv[..., 0], uv[..., 1])
    patch, expo = np.repeat(h.patch[ni][:, None], 4, 1), np.repeat(h.exposure[ni][:, None], 4, 1)
    return q, _covered(h, q, patch, expo)


def second_members(tree: ClusterTree, h, ci):
    """(n, 4) the members of clusters ci that their second visibility points lie on: stratified
    by exposed area as the first (ClusterTree's samples: the middle of each quarter of the
    members' exposed area), at a position in each quarter shifted per cluster along the golden
    ratio's sequence, so that over the clusters every member is as likely as its exposed area
    (the first set's are fixed per cluster: a decision made on them must not choose the second's)."""
    ci = np.asarray(ci, np.int64)
    ws = h.area[tree.perm] * np.asarray(h.exposure[tree.perm], float)
    cum = np.cumsum(ws)
    lo = cum[tree.start[ci]] - ws[tree.start[ci]]
    tot = cum[tree.end[ci] - 1] - lo
    jit = np.mod(0.5 + (ci + 1.0) * 0.6180339887498949, 1.0)
    tgt = lo[:, None] + (np.arange(4)[None] + jit[:, None]) / 4 * tot[:, None]
    pos = np.clip(np.searchsorted(cum, tgt), tree.start[ci][:, None], tree.end[ci][:, None] - 1)
    return tree.perm[pos]


def sample_covered(tree: ClusterTree, h, ids, table=None):
    """(N, 4) whether the visibility points of link ends (visibility_points) lie on covered parts
    (contacts.py): a patch node's Gauss points take no account of its covered part; a cluster's
    point on a partly covered member is moved off the covered part where one of SPREAD_TRIES
    positions is uncovered, else it is the member's exposed centre, which may lie under what
    covers it (the centroid of a ring of floor around a box is under the box)."""
    return visibility_points(tree, h, ids, 0.0, table)[1]


# A cluster end's visibility points (spread_points): sample k of cluster c in its member at the
# unit-square position SPREAD[k] + (c + 1) R2 (mod 1): a rotated 2 x 2 grid (each axis stratified
# in quarters, so the 4 samples of a one-member cluster spread over it), shifted per cluster along
# the R2 sequence (Roberts' plastic-number sequence), so that over the clusters every position in
# a member is as likely (the mean visibility of a member by area, not its centre's). On a partly
# covered member the first uncovered of SPREAD_TRIES positions (the next ones along R2).
SPREAD = np.array([(0.375, 0.125), (0.875, 0.375), (0.125, 0.625), (0.625, 0.875)])
R2 = np.array([0.7548776662466927, 0.5698402909980532])
SPREAD_TRIES = 8
# the second set's shift (visibility_points(second=True)): the rotated grid's other four cells' points
SECOND = 0.5


def spread_points(tree: ClusterTree, h, ci, offset=0.0, members=None):
    """(n, 4, 3) visibility points of clusters ci on their surfaces (not pushed off) and (n, 4)
    whether each is covered (see SPREAD; a wholly covered member's: covered). offset: added to
    the unit-square positions, members (n, 4): the members (the kernel's samples' if None; the
    second set: SECOND, second_members)."""
    ci = np.asarray(ci, np.int64)
    m = tree.sample_patch[ci] if members is None else members  # (n, 4)
    uv = np.mod(SPREAD[None] + (ci[:, None, None] + 1.0) * R2 + offset, 1.0)  # (n, 4, 2)
    pts = _in_polygon(h.corners[m], h.nv[m], uv[..., 0], uv[..., 1])
    expo = np.asarray(h.exposure[m], float)
    cov = expo <= 0
    part = (expo > 0) & (expo < 1)
    if part.any() and h.contacts is not None:
        i = np.flatnonzero(part.ravel())
        mm = m.ravel()[i]
        tries = np.mod(
            uv.reshape(-1, 2)[i][:, None] + np.arange(SPREAD_TRIES)[:, None] * R2, 1.0
        )  # (p, T, 2)
        # the first try of every point, the others only where it is covered (each point's
        # position and covered test are its own: the same first uncovered try)
        cand = np.empty((len(i), SPREAD_TRIES, 3))
        hid = np.zeros((len(i), SPREAD_TRIES), bool)
        for rows, T in ((np.arange(len(i)), slice(0, 1)), (None, slice(1, SPREAD_TRIES))):
            if rows is None:
                rows = np.flatnonzero(hid[:, 0])
            n = T.stop - T.start
            cand[rows, T] = _in_polygon(
                np.repeat(h.corners[mm[rows]], n, 0),
                np.repeat(h.nv[mm[rows]], n),
                tries[rows, T, 0].ravel(),
                tries[rows, T, 1].ravel(),
            ).reshape(-1, n, 3)
            hid[rows, T] = h.contacts.covered(cand[rows, T].reshape(-1, 3), np.repeat(mm[rows], n)).reshape(
                -1, n
            )
        ok = ~hid
        first = ok.argmax(1)
        got = ok.any(1)
        flat, fc = pts.reshape(-1, 3), cov.reshape(-1)
        flat[i[got]] = cand[np.flatnonzero(got), first[got]]
        # none uncovered: the member's exposed centre (the kernel's sample), covered or not (the
        # second set's members: its point stays, covered)
        k = i[~got]
        if members is not None:
            fc[k] = True
        elif len(k):
            fc[k] = h.contacts.covered(tree.samples[ci].reshape(-1, 3)[k], mm[~got])
            flat[k] = tree.samples[ci].reshape(-1, 3)[k]
    return pts, cov


def _in_polygon(c, nv, u, v):
    """Points of polygons (corners c (..., 4, 3), nv (...)) at unit-square positions u, v (...):
    bilinear on quads (area-uniform on parallelograms), folded barycentric on triangles
    (area-uniform)."""
    u, v = u[..., None], v[..., None]
    quad = np.asarray(nv) == 4
    if not quad.all():
        f = u + v > 1
        tu, tv = np.where(f, 1 - u, u), np.where(f, 1 - v, v)
        t = c[..., 0, :] + tu * (c[..., 1, :] - c[..., 0, :]) + tv * (c[..., 2, :] - c[..., 0, :])
        if not quad.any():
            return _full(t, quad)
    q = (
        (1 - u) * (1 - v) * c[..., 0, :]
        + u * (1 - v) * c[..., 1, :]
        + u * v * c[..., 2, :]
        + (1 - u) * v * c[..., 3, :]
    )
    if quad.all():  # (the triangles' form only where there are triangles: the same values)
        return _full(q, quad)
    return np.where(quad[..., None], q, t)


def _full(x, quad):
    """x broadcast to np.where(quad[..., None], x, x)'s shape, as a new array."""
    shape = np.broadcast_shapes(x.shape, quad.shape + (3,))
    return x if shape == x.shape else np.broadcast_to(x, shape).copy()


def _covered(h, pts, patch, expo):
    """(N, 4) points pts (N, 4, 3) on patches patch (N, 4) of exposure expo (N, 4) (their node's,
    or their patch's for a cluster's samples) are covered: all of a wholly covered node's, by
    the contact test on partly covered ones."""
    expo = np.asarray(expo, float)
    out = expo <= 0
    part = (expo > 0) & (expo < 1)
    if part.any() and h.contacts is not None:
        out[part] = h.contacts.covered(pts[part], patch[part])
    return out
