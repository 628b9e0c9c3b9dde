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

    def dark(self, leaf, points, threads=None, boxes=None):
        """True where points (N, 3) in leaves `leaf` (N,) are covered: the whole leaf when its
        exposure is 0, by the contact test when it is partly covered. threads: the contact test
        by batches of points on threads (Contacts.covered; None: serial). boxes: (row per node,
        table) of leaf_boxes(): the contact test searches each leaf's chains (the same answers)."""
        ex = self.exposure[leaf]
        out = ex == 0
        part = np.flatnonzero((ex > 0) & (ex < 1))
        if len(part) and self.contacts is not None:
            lp = leaf[part]
            out[part] = self.contacts.covered(
                np.take(points, part, 0),
                self.patch[lp],
                threads=threads,
                boxes=None if boxes is None else (np.take(boxes[0], lp), boxes[1]),
            )
        return out

    def leaf_boxes(self, nodes):
        """(row (n,) per node: its row of the table or -1, table): Contacts.box_chains of nodes
        `nodes`' boxes in their planes, for dark(..., boxes=); None without contacts."""
        con = self.contacts
        if con is None:
            return None
        nodes = np.asarray(nodes, np.int64)
        c = self.corners[nodes].copy()
        tri = self.nv[nodes] == 3
        c[tri, 3] = c[tri, 2]  # (a triangle's padding corner: its own third)
        patch = self.patch[nodes].astype(np.int64)
        gi = con.plane[patch]
        p2 = con._to2d(gi, c)
        row = np.full(self.n, -1, np.int64)
        row[nodes] = np.arange(len(nodes))
        return row, con.box_chains(gi, p2.min(1), p2.max(1), con.piece[patch])

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
