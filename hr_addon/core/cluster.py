"""Face clusters above the input patches, and the far-field links between them (numpy only).

Why face clusters: HR links between nodes whose form factors are both below Feps. Without a
hierarchy above the patches every pair of patches has to be looked at, which is quadratic in the
polygon count. With clusters (Smits, Arvo & Greenberg 1994; Sillion 1995), linking starts at the
root's self-pair and refines down, so distant groups of small objects exchange light through one
link, and links per input polygon stay roughly constant as the scene grows.

Structure. Patches are first split into six orientation classes (dominant axis and sign of their
normal) and each class into a binary bounding-volume hierarchy (median splits along the longest
axis of the centroids' box) down to leaf clusters of at most `leaf_size` patches. So every
cluster holds faces of similar orientation, as in face clusters (Willmott, Heckbert & Garland
1999), while its members need not be adjacent: the tops of all the books on a shelf form one
cluster. A root cluster joins the classes. Every cluster covers a contiguous range of `perm` (the
patches in tree order), which makes its sums prefix-sum differences.

Transfer (orientation-aware, "vector radiosity"). A cluster S emits towards direction u the
intensity P_S . u, with P_S = sum_i A_i L_i n_i (its power vector), and a cluster R receives the
vector irradiance G_R = sum over links of g (P_S . -w) w, w the unit direction to the source,
g = V / (pi d^2); a member j gets n_j . (sum of G over its ancestors). Both are exact for the
point-to-point kernel when every member faces the other end of every link it takes part in,
which the linking enforces (`faces`): a link is only made between ends that are wholly in front
of each other's members, so no negative cosine ever enters a sum. Reciprocity holds by
construction (one symmetric kernel per link) and so does energy balance.
"""
import numpy as np

from . import formfactor as ff

N_CLASSES = 6


def encode(c):
    """Cluster index -> id in the shared id space of link ends (patch nodes are >= 0)."""
    return -1 - np.asarray(c, np.int64)


decode = encode   # the map is its own inverse


class ClusterTree:
    """Clusters as flat arrays. Cluster 0 is the root; ids grow with depth.

    start/end: range of `perm` (patches in tree order) each cluster holds; parent; depth;
    child_start/child_ids: CSR children, ids in the shared space (clusters < 0, patches >= 0);
    area, avec (sum A n), centre (area-weighted), radius (bounding sphere about centre),
    lo/hi (box), axis + cos_t/sin_t (normal cone), samples/sample_n (points for visibility rays).
    """

    def __init__(self, patches, leaf_size=4, n_samples=4):
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
        # Clusters as (start, end, parent, depth); top-down median splits, one level at a time.
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
            # all centroids fall on one side
            pos, idx = _ranges(s, e)
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
            mid = s + np.bincount(pos, weights=key <= (half + 1e-9 * ext)[pos], minlength=len(s)).astype(np.int64)
            bad = (mid <= s) | (mid >= e)
            mid = np.where(bad, (s + e) // 2, mid)
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
        owner, idx = _ranges(self.start[leaf], self.end[leaf])
        kids[self.child_start[leaf][owner] + _rank_within(owner)] = perm[idx]
        self.child_ids = kids
        self.leaf_of = np.empty(K, np.int64)
        self.leaf_of[perm[idx]] = leaf[owner]
        # sums over ranges: prefix sums in tree order
        w = area[perm]
        self.area = _range_sum(w, self.start, self.end)
        self.avec = _range_sum(w[:, None] * nrm[perm], self.start, self.end)
        self.centre = _range_sum(w[:, None] * cen[perm], self.start, self.end) / np.maximum(self.area, 1e-300)[:, None]
        self.axis = self.avec / np.maximum(np.linalg.norm(self.avec, axis=1), 1e-300)[:, None]
        # exact boxes, bounding radii and normal cones: the clusters of one depth hold disjoint
        # ranges, so each depth is one pass over (at most) all patches
        self.lo, self.hi = np.empty((C, 3)), np.empty((C, 3))
        self.radius, theta = np.empty(C), np.empty(C)
        for ids in self.levels:
            owner, idx = _ranges(self.start[ids], self.end[ids])
            p, oc = perm[idx], ids[owner]
            cut = np.r_[0, np.cumsum(self.end[ids] - self.start[ids])[:-1]]
            self.lo[ids] = np.minimum.reduceat(lo_p[p], cut, axis=0)
            self.hi[ids] = np.maximum.reduceat(hi_p[p], cut, axis=0)
            self.radius[ids] = np.maximum.reduceat(np.linalg.norm(c[p] - self.centre[oc][:, None], axis=2).max(1), cut)
            dots = np.einsum("ij,ij->i", nrm[p], self.axis[oc])
            theta[ids] = np.arccos(np.clip(np.minimum.reduceat(dots, cut), -1, 1))
        # a cluster whose area vector nearly cancels has no meaningful axis: treat as unbounded
        flat = np.linalg.norm(self.avec, axis=1) > 1e-9 * np.maximum(self.area, 1e-300)
        self.theta = np.where(flat, theta, np.pi)
        self.cos_t, self.sin_t = np.cos(self.theta), np.sin(self.theta)
        # visibility samples: area-stratified member patches (their centroids), in tree order
        cum = np.cumsum(w)
        tgt = (cum[self.start] - w[self.start])[:, None] + \
            (np.arange(n_samples) + 0.5)[None] / n_samples * self.area[:, None]
        pos = np.clip(np.searchsorted(cum, tgt), self.start[:, None], self.end[:, None] - 1)
        self.samples = cen[perm[pos]]
        self.sample_n = nrm[perm[pos]]
        self._transfer_tables(nrm, area, cen)

    # -- per-iteration transfer helpers ------------------------------------------------------------
    def power(self, L):
        """(C, SLOTS) source slots of every cluster from L (K,), the radiance of the patch roots:
        the SH power coefficients sum A L Y(n) (the l = 1 part is the power vector sum A L n,
        times SH_C1), then the first moment of the l = 1 part about the cluster's centre,
        sum A L Y1(n) (x - c) (3 components x 3 axes). Leaf clusters sum their patches (their
        ranges tile the tree order), the others their children, level by level."""
        out = np.empty((self.C, SLOTS))
        leaf, first = self._leaf_runs
        out[leaf] = np.add.reduceat(self._aYT * L[self.perm], first, axis=1).T
        for ids, kids in self._up:
            out[ids] = out[kids].sum(1)
        out[:, 9:] -= (out[:, 1:4, None] * self.centre[:, None, :]).reshape(-1, 9)
        return out

    def distribute(self, E):
        """(K,) irradiance of every patch root from the clusters' gathered slots E (C, SLOTS):
        summed over the patch's clusters (root to leaf, level by level), the SH coefficients
        evaluated at the patch normal plus the l = 1 gradient terms at its centre."""
        acc = E.copy()
        for ids, par in self._down:
            acc[ids] += acc[par]
        acc = acc[self._leaf_of_sorted]
        out = np.empty(self.K)
        out[self.perm] = (np.einsum("kj,kj->k", acc[:, :9], self._Y)
                          + np.einsum("kmj,km,kj->k", acc[:, 9:].reshape(-1, 3, 3), self._Y[:, 1:4], self._X))
        return out

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

    def children(self, c):
        """Children (shared ids) of clusters c: (flat ids, owner index into c)."""
        c = np.asarray(c, np.int64)
        cnt = self.child_start[c + 1] - self.child_start[c]
        owner = np.repeat(np.arange(len(c)), cnt)
        return self.child_ids[np.repeat(self.child_start[c], cnt) + _rank_within(owner)], owner

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


def _ranges(start, end):
    """(owner, index): the concatenated ranges [start_i, end_i) and which range each index is in."""
    cnt = np.asarray(end) - np.asarray(start)
    owner = np.repeat(np.arange(len(cnt)), cnt)
    return owner, np.repeat(start, cnt) + _rank_within(owner)


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
SH_LINEAR = np.array([0.0] + [1 / SH_C1 ** 2] * 3 + [0.0] * 5)


def sh9(d):
    """(N, 9) real spherical harmonics up to l = 2 of unit directions d (N, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.stack([np.full_like(x, 0.28209479177387814), SH_C1 * y, SH_C1 * z, SH_C1 * x,
                     1.0925484305920792 * x * y, 1.0925484305920792 * y * z,
                     0.31539156525252005 * (3 * z * z - 1), 1.0925484305920792 * x * z,
                     0.5462742152960396 * (x * x - y * y)], 1)


# -- ends of links: patch nodes (>= 0) and clusters (< 0) in one vectorised view -----------------------
class Ends:
    """Geometry of link ends given by shared ids, for the oracle and the transfer weights."""

    def __init__(self, tree: ClusterTree, h, ids):
        self.tree = tree
        ids = np.asarray(ids, np.int64)
        self.ids = ids
        cl = ids < 0
        self.cl = cl
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
        self.radius[~cl] = np.linalg.norm(c - h.centre[ni][:, None], axis=2).max(1)
        self.cos_t[~cl], self.sin_t[~cl], self.theta[~cl] = 1.0, 0.0, 0.0


def _support(lo, hi, a, sign):
    """max (sign=+1) or min (sign=-1) of x . a over boxes [lo, hi]."""
    pick = (a * sign) >= 0
    return np.einsum("ij,ij->i", np.where(pick, hi, lo), a)


def faces(x: Ends, y: Ends):
    """(front, behind): front where y lies wholly in front of every member of x (each member's
    normal within x's cone), behind where y lies wholly behind all of them (no exchange)."""
    dmax = np.linalg.norm(np.maximum(np.abs(y.hi - x.lo), np.abs(x.hi - y.lo)), axis=1)
    gap_front = _support(y.lo, y.hi, x.axis, -1) - _support(x.lo, x.hi, x.axis, +1)
    gap_back = _support(y.lo, y.hi, x.axis, +1) - _support(x.lo, x.hi, x.axis, -1)
    slack = x.sin_t * dmax
    # touching (a box standing on the floor) is decided the same at any scale: gaps within
    # rounding of zero count as in front, and as behind for what lies in the plane itself
    tol = 1e-9 * dmax
    front = (x.cos_t > 0) & (gap_front * x.cos_t >= slack - tol)
    behind = (x.cos_t > 0) & (gap_back * x.cos_t + slack <= tol)
    return front, behind


def estimate(x: Ends, y: Ends):
    """Conservative-ish F[x -> y] estimate from x's cone, y's projected area and the distance:
    S_y cos_x / (pi d^2 + S_y), with cosines widened by the cones and the ends' angular radii."""
    d = y.centre - x.centre
    dist = np.linalg.norm(d, axis=1)
    u = d / np.maximum(dist, 1e-300)[:, None]
    spread_y = np.arcsin(np.clip(y.radius / np.maximum(dist, 1e-300), 0, 1))
    spread_x = np.arcsin(np.clip(x.radius / np.maximum(dist, 1e-300), 0, 1))
    ax = np.arccos(np.clip(np.einsum("ij,ij->i", x.axis, u), -1, 1))
    ay = np.arccos(np.clip(-np.einsum("ij,ij->i", y.axis, u), -1, 1))
    cos_x = np.cos(np.clip(ax - x.theta - spread_y, 0, np.pi / 2))
    cos_y = np.cos(np.clip(ay - y.theta - spread_x, 0, np.pi / 2))
    s_y = y.area * cos_y
    return np.clip(s_y * cos_x / (np.pi * dist ** 2 + s_y), 0, 1), dist


def sample_points(tree: ClusterTree, h, ids, eps):
    """(N, 4, 3) points on link ends, pushed eps off their surfaces, and their weights (N, 4):
    a cluster's area-stratified members (equal weights), a patch node's 2 x 2 Gauss points (the
    kernel is smooth over a node; Gauss points integrate it far better than cell centres)."""
    ids = np.asarray(ids, np.int64)
    out, w = np.empty((len(ids), 4, 3)), np.full((len(ids), 4), 0.25)
    cl = ids < 0
    ci = decode(ids[cl])
    out[cl] = tree.samples[ci] + eps * tree.sample_n[ci]
    ni = ids[~cl]
    pts, w[~cl] = ff.quadrature(h.corners[ni], h.nv[ni], 2)
    out[~cl] = pts + eps * h.normal[ni][:, None]
    return out, w


def sample_normals(tree: ClusterTree, h, ids):
    """(N, 4, 3) normals at the sample points of link ends."""
    ids = np.asarray(ids, np.int64)
    out = np.empty((len(ids), 4, 3))
    cl = ids < 0
    out[cl] = tree.sample_n[decode(ids[cl])]
    out[~cl] = h.normal[ids[~cl]][:, None]
    return out


class FarLinks:
    """Links with at least one cluster end: ends a, b (shared ids), visibility (fraction and the
    mask of unoccluded sample segments), and whether each end is partial (its members do not all
    face the other end: SH kernel of the clamped cosine) or faces wholly (exact linear kernel).
    Their transfer weights live in the solver's extended index space: cluster c's 9 SH slots at
    9c .. 9c + 8, patch node i at 9C + i (so nodes added later do not shift them)."""

    def __init__(self, tree: ClusterTree, a, b, vis, mask, part_a=None, part_b=None, eps=0.0, grad_eps=0.0,
                 scale=None):
        self.tree, self.eps = tree, eps   # eps: the sample points' offset off their surfaces
        self.grad_eps = grad_eps          # gradients only where they matter (terms())
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
        return FarLinks(self.tree, ren(self.a), ren(self.b), self.vis, self.mask, self.part_a, self.part_b,
                        self.eps, self.grad_eps, self.scale)

    def terms(self, h, chunk=8192):
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
        moment, so the kernel stays symmetric."""
        tree = self.tree
        off = SLOTS * tree.C
        p1, p2 = [], []
        for i in range(0, len(self.a), chunk):
            sl = slice(i, i + chunk)
            a, b = self.a[sl], self.b[sl]
            ea, eb = Ends(tree, h, a), Ends(tree, h, b)
            (pa, wa), (pb, wb) = sample_points(tree, h, a, self.eps), sample_points(tree, h, b, self.eps)
            d = pb[:, None, :, :] - pa[:, :, None, :]                          # (N, 4 on a, 4 on b, 3)
            r2 = np.maximum(np.einsum("nijk,nijk->nij", d, d), 1e-300)
            u = d / np.sqrt(r2)[..., None]
            vis = ((self.mask[sl, None] >> np.arange(16)) & 1).reshape(-1, 4, 4)
            kg = 1.0 / (np.pi * r2) * wa[:, :, None] * wb[:, None, :]     # geometry only: the gradient fit
            k = vis * self.scale[sl, None, None] * kg
            K = k.sum((1, 2))
            Kn = np.where(K > 0, K, 1.0)
            fa = np.einsum("nis,nisc->nc", k, _end_factors(a, ea, self.part_a[sl], u.reshape(-1, 16, 3)).reshape(-1, 4, 4, 9)) / Kn[:, None]
            fb = np.einsum("nis,nisc->nc", k, _end_factors(b, eb, self.part_b[sl], -u.reshape(-1, 16, 3)).reshape(-1, 4, 4, 9)) / Kn[:, None]
            link = 2 * (i + np.arange(len(a)))
            fmax = K * np.maximum(ea.area, eb.area)
            # relative gradients of the kernel over each cluster end (zero where not worth it)
            ga = self._grad(h, ea, pa, wa, kg, u, eb, self.part_a[sl])
            gb = self._grad(h, eb, pb, wb, kg.transpose(0, 2, 1), -u.transpose(0, 2, 1, 3), ea, self.part_b[sl])
            for g_, e_ in ((ga, ea), (gb, eb)):
                g_ *= (fmax * np.linalg.norm(g_, axis=1) * e_.radius >= self.grad_eps)[:, None]
            for t, (r, er, fr, gr), (s_, es, fs, gs) in ((link, (a, ea, fa, ga), (b, eb, fb, gb)),
                                                         (link + 1, (b, eb, fb, gb), (a, ea, fa, ga))):
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
                Gm = fr[:, 1:4, None] * gr[:, None, :]                           # (N, 3, 3 axes)
                w2[:, 9:] = Gm.reshape(-1, 9)
                w2[:, 1:4] -= np.einsum("nmk,nk->nm", Gm, er.centre)
                live = w2 != 0
                p2.append((R[live], np.broadcast_to(t[:, None], w2.shape)[live], w2[live],
                           np.zeros(int(live.sum()), bool)))
        cat = lambda parts, n: tuple(np.concatenate(x) for x in zip(*parts)) if parts else \
            tuple(np.zeros(0, dt) for dt in (np.int64, np.int64, float, bool)[:n])
        return cat(p1, 3), cat(p2, 4)

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
        ks = k[grad] * np.maximum(np.einsum("nisk,nk->nis", ug, er.axis[grad]), 0) \
            * np.maximum(-np.einsum("nisk,nk->nis", ug, es.axis[grad]), 0)
        Ki = ks.sum(2) / wg
        Km = np.einsum("ni,ni->n", Ki, wg)
        rel = np.where(Km[:, None] > 0, Ki / np.where(Km > 0, Km, 1)[:, None] - 1, 0)
        g = np.einsum("nki,ni->nk", np.linalg.pinv(dx, rcond=0.05), rel)
        gn = np.linalg.norm(g, axis=1) * er.radius[grad]
        gam[grad] = g * np.minimum(1.0, 0.5 / np.maximum(gn, 1e-300))[:, None]
        return gam


def _slots(ids, e, off):
    """(N, SLOTS) slot indices of link ends: a node's one slot (repeated), a cluster's SLOTS."""
    return np.where(~e.cl[:, None], off + np.maximum(ids, 0)[:, None],
                    SLOTS * decode(np.minimum(ids, -1))[:, None] + np.arange(SLOTS))


def _end_factors(ids, e, part, u):
    """Kernel factors (N, S, 9) of one end of each link along the segments u (N, S, 3) leaving
    it: a patch node's cosine (slot 0); a cluster's SH kernel, linear (wholly facing) or the
    clamped cosine (partial)."""
    node = ~e.cl
    w = sh9(u.reshape(-1, 3)).reshape(u.shape[:2] + (9,)) * np.where(part[:, None], SH_CLAMPED, SH_LINEAR)[:, None, :]
    w[node] = 0.0
    w[node, :, 0] = np.maximum(np.einsum("nsk,nk->ns", u[node], e.axis[node]), 0)
    return w


# -- linking through the clusters -----------------------------------------------------------------------
CHUNK = 200_000


def link_clusters(refiner, tree: ClusterTree, progress=None):
    """HSA refinement from the root's self-pair down through the clusters.

    A pair with a cluster end becomes a far link when each end lies wholly in front of the other's
    members (`faces`), both estimated form factors are below Feps, the ends are small against
    their distance (radius sum < cluster_ratio x distance: the point-to-point kernel holds), and,
    for links above shadow_feps, visibility is not partial. Pairs wholly behind one end are
    dropped. Otherwise an end is split: a cluster into its children, a patch node into its
    quadtree children. Pairs of two patch nodes are returned for the ordinary patch refinement.
    Returns (FarLinks, node pairs p, q, and their known visibility: 1 or nan)."""
    h, prm = refiner.h, refiner.params
    aeps = prm.aeps * refiner.total_area
    far, nodes = [], []
    root = encode([0])
    total_w = 0.5 * tree.area[0] ** 2
    done_w = 0.0
    # pending pairs carry what is known of their visibility: nan unknown, 1 wholly visible (a
    # parent's 16 segments were all unoccluded: its children need no rays, as in HR)
    pending = [(root, root, np.full(1, np.nan))]
    full = np.uint16(0xFFFF)

    def weight(a, b):
        aa, ab = _area(tree, h, a), _area(tree, h, b)
        return np.where(a == b, 0.5 * aa * aa, aa * ab).sum()

    while pending:
        a, b, known = pending.pop()
        if len(a) > CHUNK:
            pending.append((a[CHUNK:], b[CHUNK:], known[CHUNK:]))
            a, b, known = a[:CHUNK], b[:CHUNK], known[:CHUNK]
        refiner.stats["cluster_pairs"] += len(a)
        same = a == b
        if same.any():
            s = a[same & (a < 0)]
            done_w += weight(a[same & (a >= 0)], a[same & (a >= 0)])
            if len(s):
                sa, sb = _self_pairs(tree, decode(s))
                pending.append((sa, sb, np.full(len(sa), np.nan)))
            a, b, known = a[~same], b[~same], known[~same]
        both = (a >= 0) & (b >= 0)
        if both.any():
            nodes.append((a[both], b[both], known[both]))
            done_w += weight(a[both], b[both])
            a, b, known = a[~both], b[~both], known[~both]
        if not len(a):
            continue
        ea, eb = Ends(tree, h, a), Ends(tree, h, b)
        fa, ba = faces(ea, eb)
        fb, bb = faces(eb, ea)
        f_ab, dist = estimate(ea, eb)
        f_ba, _ = estimate(eb, ea)
        fmax = np.maximum(f_ab, f_ba)
        drop = ba | bb | (fmax <= 0)
        # A cluster end whose members do not all face the other end is "partial": its kernel is
        # the SH approximation of the clamped cosine, allowed on one end of weak links only. A
        # patch node whose plane cuts the other end cannot be partial (split the other end).
        pa, pb = ~fa & ~ba & ea.cl, ~fb & ~bb & eb.cl
        facing = (fa | pa) & (fb | pb) & ~(pa & pb)
        # Small against the distance: a cluster end is seen through 4 member samples and one
        # kernel direction, so its radius counts fully; a patch node end is integrated at 2 x 2
        # Gauss points, so half its radius counts. And the link's transfer times its relative
        # variation across either end below cluster_veps: strong, uneven links (near lights) go
        # down to where the variation is resolved.
        rho_a = np.where(ea.cl, np.where(ea.theta < GRAD_CONE, 1.0, CURVED), 0.5) * ea.radius
        rho_b = np.where(eb.cl, np.where(eb.theta < GRAD_CONE, 1.0, CURVED), 0.5) * eb.radius
        size = (rho_a + rho_b) / np.maximum(dist, 1e-300)
        small = size < prm.cluster_ratio
        cand = ~drop & facing & small
        var_a, var_b = np.zeros(len(a)), np.zeros(len(a))
        if cand.any():
            var_a[cand], var_b[cand] = _variation(tree, h, a[cand], b[cand], refiner.eps)
        even = fmax * np.maximum(var_a, var_b) < prm.cluster_veps
        ok = ~drop & facing & small & even & (fmax < np.where(pa | pb, prm.partial_feps * prm.feps, prm.feps))
        vis = known.copy()
        mask = np.where(known == 1, full, np.uint16(0))
        if prm.shadow_feps > 0:
            shadow = ok & (fmax > prm.shadow_feps) & np.isnan(vis)
            if shadow.any():
                vis[shadow], mask[shadow], _ = far_visibility(refiner, tree, a[shadow], b[shadow])
                ok &= ~(shadow & (vis > 0) & (vis < 1))
        if ok.any():
            far.append((a[ok], b[ok], vis[ok], mask[ok], pa[ok], pb[ok], fmax[ok]))
        done_w += weight(a[drop | ok], b[drop | ok])
        todo = ~drop & ~ok
        # Which end to split, by the first test that failed. Facing (a node whose plane cuts the
        # other end, or two partial ends): the end whose cone, or angular radius seen from the
        # other, is larger (a node's cone is 0: its children share its plane). Size and shadow:
        # the end that looks larger. Feps: the end with the larger form factor as seen from the
        # other (as in HSA).
        a, b = a[todo], b[todo]
        th_a, th_b = ea.theta[todo], eb.theta[todo]
        phi_a = np.arcsin(np.clip(rho_a[todo] / np.maximum(dist[todo], 1e-300), 0, 1))
        phi_b = np.arcsin(np.clip(rho_b[todo] / np.maximum(dist[todo], 1e-300), 0, 1))
        fa, fb = fa[todo], fb[todo]
        face_a = np.maximum(np.where(~fa, th_a, 0), np.where(~fb, phi_a, 0))
        face_b = np.maximum(np.where(~fa, phi_b, 0), np.where(~fb, th_b, 0))
        by_face = ~facing[todo]
        by_size = ~by_face & ~small[todo]
        by_var = ~by_face & ~by_size & ~even[todo]
        prefer_a = np.where(by_face, face_a >= face_b,
                   np.where(by_size, phi_a >= phi_b,
                   np.where(by_var, phi_a >= phi_b,
                   np.where(fmax[todo] < prm.feps, phi_a >= phi_b, f_ba[todo] >= f_ab[todo]))))
        can_a = ea.cl[todo] | (ea.area[todo] > aeps)
        can_b = eb.cl[todo] | (eb.area[todo] > aeps)
        # Too strong, too uneven or half shadowed, but the end that should be split cannot be (a
        # patch node at Aeps): splitting the other end would not lower the form factor or the
        # variation on that end, so link here, as HSA does with two unsplittable nodes.
        take = ~by_face & ~by_size & np.where(prefer_a, ~can_a, ~can_b)
        if take.any():
            idx = np.flatnonzero(todo)[take]
            far.append((a[take], b[take], vis[idx], mask[idx], pa[idx], pb[idx], fmax[idx]))
            done_w += weight(a[take], b[take])
        split_a = ~take & can_a & (prefer_a | ~can_b)
        split_b = ~take & ~split_a & can_b
        # Visibility of pairs about to be split whose ends are small against their distance
        # (size < vis_inherit; the 4 x 4 segments then see most of what lies between): wholly
        # occluded pairs are dropped with all their descendants, wholly visible ones hand that
        # on; partly visible ones leave it to their children.
        kv = vis[todo]
        test = (split_a | split_b) & np.isnan(kv) & (size[todo] < prm.vis_inherit)
        if test.any():
            kv[test] = far_visibility(refiner, tree, a[test], b[test])[0]
            hidden = test & (kv == 0)
            done_w += weight(a[hidden], b[hidden])
            split_a &= ~hidden
            split_b &= ~hidden
        kv = np.where(kv == 1, 1.0, np.nan)
        new_a, new_b, new_k = [], [], []
        for sel, x, y in ((split_a, a, b), (split_b, b, a)):
            xs, ys, ks = x[sel], y[sel], kv[sel]
            cl = xs < 0
            if cl.any():
                kids, owner = tree.children(decode(xs[cl]))
                new_a.append(kids)
                new_b.append(ys[cl][owner])
                new_k.append(ks[cl][owner])
            nd = xs[~cl]
            if len(nd):
                h.subdivide(np.unique(nd[h.child0[nd] < 0]))
                new_a.append(h.children(nd).ravel())
                new_b.append(np.repeat(ys[~cl], 4))
                new_k.append(np.repeat(ks[~cl], 4))
        if new_a:
            pending.append((np.concatenate(new_a), np.concatenate(new_b), np.concatenate(new_k)))
        if progress is not None:
            progress.update("clusters", done_w, total_w)
    if far:
        fa_, fb_, fv, fm, pa_, pb_, ff_ = (np.concatenate(x) for x in zip(*far))
        fs = np.ones(len(fv))
        todo = np.flatnonzero(np.isnan(fv))
        for i in range(0, len(todo), CHUNK):
            t = todo[i:i + CHUNK]
            fv[t], fm[t], fs[t] = far_visibility(refiner, tree, fa_[t], fb_[t], ff_[t] < prm.shadow_feps)
        keep = fv > 0
        links = FarLinks(tree, fa_[keep], fb_[keep], fv[keep], fm[keep], pa_[keep], pb_[keep], refiner.eps,
                         0.1 * prm.cluster_veps, fs[keep])
    else:
        z = np.zeros(0)
        links = FarLinks(tree, z.astype(np.int64), z.astype(np.int64), z, z.astype(np.uint16))
    p, q, kv = ((np.concatenate(x) for x in zip(*nodes)) if nodes else
                (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)))
    return links, p, q, kv


def _variation(tree, h, a, b, eps):
    """(var_a, var_b): relative range, over each end's sample points, of the kernel cos cos / r^2
    summed over the other end's samples (cosines about the samples' own normals; no visibility)."""
    (pa, wa), (pb, wb) = sample_points(tree, h, a, eps), sample_points(tree, h, b, eps)
    d = pb[:, None, :, :] - pa[:, :, None, :]
    r2 = np.maximum(np.einsum("nijk,nijk->nij", d, d), 1e-300)
    na, nb = sample_normals(tree, h, a), sample_normals(tree, h, b)
    k = (np.maximum(np.einsum("nijk,nik->nij", d, na), 0) * np.maximum(-np.einsum("nijk,njk->nij", d, nb), 0)
         / (r2 * r2))
    out = []
    for ks in ((k * wb[:, None, :]).sum(2), (k * wa[:, :, None]).sum(1)):
        m = ks.mean(1)
        out.append((ks.max(1) - ks.min(1)) / np.maximum(m, 1e-300) * (m > 0))
    return out


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


def far_visibility(refiner, tree, a, b, weak=None):
    """(vis, mask, scale) of far links: the unoccluded fraction of the 4 x 4 segments between the
    ends' sample points and which of them are unoccluded (bit 4 i + j: sample i of a, j of b).
    Weak links (mask `weak`) trace only the 4 segments i -> 3 - i: their mask is full and
    `scale` holds their visibility fraction instead (1 for the others)."""
    import time
    t0 = time.perf_counter()
    h, eps = refiner.h, refiner.eps
    pa, pb = sample_points(tree, h, a, eps)[0], sample_points(tree, h, b, eps)[0]
    weak = np.zeros(len(a), bool) if weak is None else np.asarray(weak, bool)
    vis, mask, scale = np.empty(len(a)), np.empty(len(a), np.uint16), np.ones(len(a))
    st = ~weak
    if st.any():
        occ = refiner.backend.occluded(np.repeat(pa[st], 4, axis=1).reshape(-1, 3),
                                       np.tile(pb[st], (1, 4, 1)).reshape(-1, 3)).reshape(-1, 16)
        vis[st] = 1.0 - occ.mean(1)
        mask[st] = ((~occ) * (1 << np.arange(16))).sum(1)
        refiner.stats["rays"] += occ.size
    if weak.any():
        occ = refiner.backend.occluded(pa[weak], pb[weak][:, ::-1]).reshape(-1, 4)
        vis[weak] = scale[weak] = 1.0 - occ.mean(1)
        mask[weak] = 0xFFFF
        refiner.stats["rays"] += occ.size
    refiner.stats["t_vis"] += time.perf_counter() - t0
    return vis, mask, scale
