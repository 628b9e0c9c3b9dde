"""Quadtrees over the patches, stored as flat growable arrays (structure of arrays).

Node i: corners[i] (4, 3) convex planar CCW (triangles repeat corner 2), nv[i], parent[i] (-1 for
roots), child0[i] (-1 for leaves; the four children are child0 .. child0+3), level[i], patch[i].
Roots are nodes 0 .. K-1, one per patch, in patch order.

Quads split at edge midpoints and the centroid of the corners (the bilinear centre), so children of
a planar convex quad stay planar and convex. Triangles split at edge midpoints; child 3 is the
middle triangle. Child k (k < nv) holds the parent's corner k, which output.py relies on.
"""

import numpy as np

from .geometry import Patches


class Hierarchy:
    def __init__(self, patches: Patches):
        k = len(patches.nv)
        self.patches = patches
        self.n = 0
        self._cap = 0
        self._grow(max(4 * k, 64))
        self.n = k
        self.corners[:k] = patches.corners
        self.nv[:k] = patches.nv
        self.parent[:k] = -1
        self.child0[:k] = -1
        self.level[:k] = 0
        self.patch[:k] = np.arange(k)
        self.exposure[:k] = 1.0
        self._set_derived(np.arange(k))
        self.version = 0  # bumped on every structural change (caches key on it)
        self.contacts = None  # contacts.Contacts: which points of partly covered leaves are covered
        self._levels = None

    # -- storage -------------------------------------------------------------------------------------
    _fields = (
        ("corners", (4, 3), np.float64),
        ("nv", (), np.int8),
        ("parent", (), np.int32),
        ("child0", (), np.int32),
        ("level", (), np.int16),
        ("patch", (), np.int32),
        ("area", (), np.float64),
        ("centre", (3,), np.float64),
        ("normal", (3,), np.float64),
        ("exposure", (), np.float32),
    )

    def _grow(self, need):
        if need <= self._cap:
            return
        cap = max(need, 2 * self._cap)
        for name, shape, dt in self._fields:
            new = np.zeros((cap,) + shape, dt)
            if self._cap:
                new[: self.n] = getattr(self, name)[: self.n]
            setattr(self, name, new)
        self._cap = cap

    def _set_derived(self, ids):
        c = self.corners[ids]
        self.normal[ids] = self.patches.normal[self.patch[ids]]
        # Area from the two triangles (0,1,2) and (0,2,3); the second vanishes for a padded triangle.
        a = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]) + np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 0])
        self.area[ids] = 0.5 * np.linalg.norm(a, axis=1)
        nv = self.nv[ids].astype(float)
        self.centre[ids] = (c[:, 0] + c[:, 1] + c[:, 2] + np.where(nv[:, None] == 4, c[:, 3], 0)) / nv[
            :, None
        ]

    def view(self, name):
        """The live part of a field, e.g. h.view('area')."""
        return getattr(self, name)[: self.n]

    # -- structure -----------------------------------------------------------------------------------
    @property
    def is_leaf(self):
        return self.child0[: self.n] < 0

    def leaves(self):
        return np.flatnonzero(self.is_leaf)

    def subdivide(self, ids):
        """Give each of the leaf nodes `ids` four children; returns the children as (len(ids), 4)."""
        ids = np.asarray(ids, np.int64)
        ids = ids[self.child0[ids] < 0]
        m = len(ids)
        if m == 0:
            return np.zeros((0, 4), np.int64)
        start = self.n
        self._grow(self.n + 4 * m)
        c = self.corners[ids]
        tri = self.nv[ids] == 3
        a, b, cc, d = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
        ab, bc, cd, da = (a + b) / 2, (b + cc) / 2, (cc + d) / 2, (d + a) / 2
        ca = (cc + a) / 2
        m_q = (a + b + cc + d) / 4
        quads = ((a, ab, m_q, da), (ab, b, bc, m_q), (m_q, bc, cc, cd), (da, m_q, cd, d))
        tris = ((a, ab, ca, ca), (ab, b, bc, bc), (ca, bc, cc, cc), (bc, ca, ab, ab))
        quad_children, tri_children = (np.stack([np.stack(k, 1) for k in four], 1) for four in (quads, tris))
        kids = np.where(tri[:, None, None, None], tri_children, quad_children)  # (m, 4, 4, 3)
        new = start + np.arange(4 * m)
        self.corners[new] = kids.reshape(-1, 4, 3)
        self.nv[new] = np.repeat(self.nv[ids], 4)
        self.parent[new] = np.repeat(ids, 4)
        self.child0[new] = -1
        self.level[new] = np.repeat(self.level[ids] + 1, 4)
        self.patch[new] = np.repeat(self.patch[ids], 4)
        self.exposure[new] = np.repeat(self.exposure[ids], 4)  # refined again where it matters
        self.child0[ids] = start + 4 * np.arange(m)
        self.n += 4 * m
        self._set_derived(new)
        self._changed()
        return new.reshape(m, 4)

    def children(self, ids):
        """(len(ids), 4) children of internal nodes ids."""
        return self.child0[np.asarray(ids)][:, None] + np.arange(4)

    def compact(self, keep, threads=1):
        """Delete nodes where keep is False (whole subtrees: a kept node's parent must be kept and
        a parent keeps all four children or none). Returns remap old -> new index (-1 deleted).
        threads: the fields by a batch map (core.parallel: each field its own array)."""
        from .parallel import batch_map

        keep = np.asarray(keep, bool)[: self.n]
        remap = np.full(self.n, -1, np.int64)
        remap[keep] = np.arange(int(keep.sum()))

        def field(name):
            arr = getattr(self, name)
            kept = arr[: self.n][keep]
            arr[: len(kept)] = kept

        batch_map(field, [(name,) for name, _, _ in self._fields], threads)
        self.n = int(keep.sum())
        p = self.parent[: self.n]
        p[p >= 0] = remap[p[p >= 0]]
        c0 = self.child0[: self.n]
        has = c0 >= 0
        c0[has] = remap[c0[has]]
        self._changed()
        return remap

    def renumber(self, new, start):
        """Give the nodes from `start` on the ids new[id] (a permutation of them that keeps each
        node's four children together and in order): their rows moved, parents and children
        renumbered (farlinks.link_clusters: the ids its depth-first order gave)."""
        n = self.n
        old = np.empty(n - start, np.int64)
        old[new[start:n] - start] = np.arange(start, n)
        for name, _, _ in self._fields:
            arr = getattr(self, name)
            arr[start:n] = arr[old]
        for ref in (self.parent[:n], self.child0[:n]):
            m = ref >= start
            ref[m] = new[ref[m]]
        self._changed()

    def _changed(self):
        self.version += 1
        self._levels = None

    def levels(self):
        """Node ids grouped by depth: list over levels of index arrays (for push-pull)."""
        if self._levels is None:
            lv = self.level[: self.n]
            order = np.argsort(lv, kind="stable")
            bounds = np.searchsorted(lv[order], np.arange(int(lv.max()) + 2))
            self._levels = [order[bounds[i] : bounds[i + 1]] for i in range(len(bounds) - 1)]
        return self._levels

    def node_rho(self):
        """(3, n) reflectance of every node (inherited from its patch)."""
        return self.patches.reflectance[:, self.patch[: self.n]]

    def shown(self, B):
        """Radiance of the uncovered part of each node: B holds node means over the whole node
        (covered parts contribute nothing), so divide by the exposure; fully covered nodes show 0."""
        ex = self.exposure[: B.shape[-1]]
        if ex.min() >= 1:
            return B
        return np.where(ex > 0, B / np.maximum(ex, 1e-30), 0.0)

    def values_at(self, B, leaf, points):
        """(N, 3) radiance at points (N, 3) lying in nodes `leaf` (N,): shown() of their node,
        0 where the point is covered (dark())."""
        ex = self.exposure[leaf].astype(np.float64)
        out = np.where(ex > 0, B[:, leaf] / np.maximum(ex, 1e-30), 0.0).T
        out[self.dark(leaf, np.asarray(points, float))] = 0.0
        return out

    def dark(self, leaf, points, threads=None):
        """True where points (N, 3) in leaves `leaf` (N,) are covered: the whole leaf when its
        exposure is 0, by the contact test when it is partly covered. threads: the contact test
        by batches of points on threads (Contacts.covered; None: serial)."""
        ex = self.exposure[leaf]
        out = ex == 0
        part = np.flatnonzero((ex > 0) & (ex < 1))
        if len(part) and self.contacts is not None:
            out[part] = self.contacts.covered(
                np.take(points, part, 0), self.patch[leaf[part]], threads=threads
            )
        return out

    def leaf_at_corner(self, roots, k):
        """Descend from roots to the leaf holding corner k of each root (vectorised)."""
        node = np.asarray(roots, np.int64).copy()
        while True:
            inner = self.child0[node] >= 0
            if not inner.any():
                return node
            node[inner] = self.child0[node[inner]] + np.broadcast_to(k, node.shape)[inner]

    def extend(self, B):
        """Per-node values B (C, m) on the first m nodes, extended to all nodes by copying from
        parents: nodes added below the old leaves carry no links, so their solution is the parent's."""
        m = B.shape[1]
        if m >= self.n:
            return B
        out = np.empty((B.shape[0], self.n))
        out[:, :m] = B
        for lv in self.levels():
            new = lv[lv >= m]
            out[:, new] = out[:, self.parent[new]]
        return out

    @classmethod
    def node_bytes(cls):
        """Bytes of storage per node (all per-node arrays, solver state excluded)."""
        return sum(
            int(np.prod(shape, dtype=np.int64)) * np.dtype(dt).itemsize for _, shape, dt in cls._fields
        )


class DepthFirstRounds:
    """The order of a depth-first refinement loop, replayed by one that runs breadth-first (issue
    23: a level's pairs in a few large batch maps; farlinks.link_clusters, Refiner.refine). The
    depth-first loop popped the last pending set of pairs, took `chunk` of them (pushing the rest
    back) as a round, pushed the sets that round made (in an order of its own) and subdivided the
    nodes it split as it went. Every pair's decision is its own, so the levels decide what the loop
    decided; with each pair's round (sets(), next_level()) and the nodes each round split,
    renumber() gives the loop's order of the rounds and its ids for those nodes, so the results
    are the loop's bit for bit."""

    def __init__(self, chunk):
        self.chunk = chunk
        self.first, self.count = [], []  # per set: its first round, its number of rounds
        self.made = []  # per round: the sets it made, in the order the loop pushed them

    def sets(self, sizes):
        """New sets of `sizes` pairs, in order: the round of each of their pairs."""
        sizes = np.asarray(sizes, np.int64)
        pieces = -(-sizes // self.chunk)
        first = len(self.made) + np.cumsum(pieces) - pieces
        self.first += first.tolist()
        self.count += pieces.tolist()
        self.made += [[] for _ in range(int(pieces.sum()))]
        rid = np.repeat(first, sizes)
        start = np.cumsum(sizes) - sizes
        for k in np.flatnonzero(pieces > 1).tolist():  # (sets of more than one round: few)
            rid[start[k] : start[k] + sizes[k]] += np.arange(sizes[k]) // self.chunk
        return rid

    def next_level(self, kinds, width):
        """The next level's (`width` columns, round of each pair) from the sets a level's rounds
        made: kinds, in the loop's push order, each a list of parts [columns..., the round that
        made each row, a place], every part's rows in round order: a round's rows of one kind
        are one set, ordered by place, then as given. Each row's place in the next level is
        counted (no sort), and the parts' columns are let go as they are copied."""
        total = sum(len(p[0]) for parts in kinds for p in parts)
        out, rid, at = [np.zeros(0, np.int64)] * width, np.empty(total, np.int64), 0
        for parts in kinds:
            parts = sorted((p for p in parts if len(p[0])), key=lambda p: p[-1])  # (stable)
            if not parts:
                continue
            r0 = min(int(p[-2][0]) for p in parts)  # a level's rounds: r0 ...
            cnt = [np.bincount(p[-2] - r0) for p in parts]
            cnt = np.array([np.pad(c, (0, max(map(len, cnt)) - len(c))) for c in cnt])  # (part, round)
            # where each round's rows of each part start: rounds in order, parts in order in one
            start = at + (np.cumsum(cnt.T) - cnt.T.ravel()).reshape(cnt.shape[::-1]).T
            size = cnt.sum(0)
            made = np.flatnonzero(size)
            rid[at : at + int(size.sum())] = self.sets(size[made])
            for k, r in enumerate(made.tolist()):
                self.made[r0 + r].append(len(self.first) - len(made) + k)
            dest = []
            for k, p in enumerate(parts):
                r = p[-2] - r0
                dest.append(np.take(start[k] - (np.cumsum(cnt[k]) - cnt[k]), r) + np.arange(len(r)))
            for c in range(width):
                for k, p in enumerate(parts):
                    if not len(out[c]):
                        out[c] = np.empty(total, p[c].dtype)
                    out[c][dest[k]] = p[c]
                    p[c] = None
            at += int(size.sum())
        return out, rid

    def order(self):
        """pos[round]: the rounds in the loop's order."""
        pos, k = np.empty(len(self.made), np.int64), 0
        stack = [(0, 0)]  # (set, round of it)
        while stack:
            s, i = stack.pop()
            r = self.first[s] + i
            pos[r], k = k, k + 1
            if i + 1 < self.count[s]:
                stack.append((s, i + 1))
            stack += [(m, 0) for m in self.made[r]]
        return pos

    def renumber(self, h: Hierarchy, n0, splits):
        """The loop's order of the rounds (pos[round]) and its ids for the nodes made since node n0
        (new[id]; h's rows moved to them: Hierarchy.renumber). splits: (nodes, their rounds, a
        place: the loop's subdivide() calls of a round, in order) as the levels split them."""
        pos = self.order()
        new = np.arange(h.n)
        if h.n == n0:
            return new, pos
        node = np.concatenate([s[0] for s in splits])
        key = np.concatenate([2 * pos[s[1]] + s[2] for s in splits])
        o = np.argsort(key, kind="stable")
        node, key = node[o], key[o]
        made = h.child0[node] >= n0  # (a node subdivided before keeps its children)
        node, key = node[made], key[made]
        first = np.sort(np.unique(node, return_index=True)[1])  # where the loop subdivided each
        node, key = node[first], key[first]
        cut = np.flatnonzero(np.r_[True, key[1:] != key[:-1], True])
        at = n0
        for i, j in zip(cut[:-1], cut[1:]):  # one subdivide() of the loop: in its id order
            blk = node[i:j][np.argsort(new[node[i:j]])]
            new[h.child0[blk][:, None] + np.arange(4)] = at + np.arange(4 * len(blk)).reshape(-1, 4)
            at += 4 * len(blk)
        if at != h.n:
            raise AssertionError("DepthFirstRounds.renumber: the replayed subdivisions miss nodes")
        h.renumber(new, n0)
        return new, pos
