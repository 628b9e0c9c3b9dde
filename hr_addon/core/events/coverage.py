"""FE and AR (and AUTO's outline): the clipped coverage of a shape on the hierarchy, AR subdivision,
and the per-node state below the HR leaves (reference-counted splits, arrays kept the length of
the hierarchy)."""

import numpy as np

from ..parallel import batch_map
from .validation import classify


class NodeState:
    """Per-node state of a DynamicRadiosity on its growing hierarchy h: which nodes the HR build
    made (n_hr; internal ones are never collapsed), how many shapes need each split below the HR
    leaves (ref), and the solutions: base (no shapes), warm (warm mode's state), current (B),
    guess (a reshaped shape's first guess), guess0 (a preview's: the guess a move without
    previews would start from). sync() extends them and the records' U, D and G to new nodes,
    gc() drops the splits no shape needs and renumbers them."""

    def __init__(self, h, base, threads=1):
        self.h = h
        self.n_hr = h.n
        self.hr_mask = h.child0[: h.n] >= 0
        self.ref = np.zeros(h.n, np.int64)
        self.base, self.warm, self.current = base, base.copy(), base.copy()
        self.guess = self.guess0 = None
        self.threads = threads  # gc()'s compaction (core.parallel)

    def hr_internal(self, nodes):
        """True for nodes the HR build split (never collapsed by events)."""
        nodes = np.asarray(nodes, np.int64)
        out = np.zeros(len(nodes), bool)
        m = nodes < self.n_hr
        out[m] = self.hr_mask[nodes[m]]
        return out

    def owned_ancestors(self, nodes):
        """Nodes below the HR leaves (and split HR leaves) on the path to `nodes`: the splits they need."""
        h = self.h
        res = []
        cur = np.unique(h.parent[np.asarray(nodes, np.int64)])
        cur = cur[cur >= 0]
        while len(cur):
            cur = cur[~self.hr_internal(cur)]
            res.append(cur)
            cur = np.unique(h.parent[cur])
            cur = cur[cur >= 0]
        return np.unique(np.concatenate(res)) if res else np.zeros(0, np.int64)

    def gc(self, recs):
        """Delete the children of owned splits no shape needs; recs: every record holding node
        arrays (shapes, cached shapes, lights, one being added). Returns the nodes deleted."""
        h = self.h
        self.sync(recs)
        n = h.n
        idx = np.arange(n)
        collapse = (h.child0[:n] >= 0) & ~self.hr_internal(idx) & (self.ref[:n] == 0)
        if not collapse.any():
            return 0
        dead = np.zeros(n, bool)
        for lv in h.levels()[1:]:
            par = h.parent[lv]
            dead[lv] = collapse[par] | dead[par]
        keep = ~dead
        remap = h.compact(keep, self.threads)
        assert (remap[: self.n_hr] == np.arange(self.n_hr)).all()
        self.ref = self.ref[:n][keep]
        # the node arrays of this state and of the records, each its own: by a batch map
        arrays = [(self, "base"), (self, "warm")]
        arrays += [(self, "current")] if self.current.shape[1] == n else []
        arrays += [(self, k) for k in ("guess", "guess0") if getattr(self, k) is not None]
        arrays += [(r, k) for r in recs for k in ("U", "D", "G") if getattr(r, k, None) is not None]

        def kept(obj, name):
            setattr(obj, name, getattr(obj, name)[:, keep])

        batch_map(kept, arrays, self.threads)
        for rec in recs:
            for name in ("cov_nodes", "owned"):
                a = getattr(rec, name, None)
                if a is not None and len(a):
                    a = remap[a]
                    assert (a >= 0).all(), "a live shape lost a node it needs"
                    setattr(rec, name, a)
        return int(dead.sum())

    def sync(self, recs):
        """Extend per-node arrays to nodes created since: solutions by copy from the parent (new nodes
        carry no links, so this is exact), first-bounce terms and reference counts with zeros."""
        h = self.h
        n = h.n
        if len(self.ref) < n:
            self.ref = np.concatenate([self.ref, np.zeros(n - len(self.ref), np.int64)])
        self.base = h.extend(self.base)
        self.warm = h.extend(self.warm)
        self.current = h.extend(self.current)
        if self.guess is not None:
            self.guess = h.extend(self.guess)
        if self.guess0 is not None:
            self.guess0 = h.extend(self.guess0)
        for rec in recs:
            if rec.U is not None:
                rec.U = h.extend(rec.U)
            if getattr(rec, "G", None) is not None:  # (light records have none)
                rec.G = h.extend(rec.G)
            if rec.D is not None and rec.D.shape[1] < n:
                rec.D = np.concatenate([rec.D, np.zeros((3, n - rec.D.shape[1]))], 1)


class Coverage:
    """A shape's coverage of the hierarchy (FE, AR, AUTO's outline): which nodes it covers and by
    how much, AR's splits (min_area, AUTO: direct_min_area; node_budget; AUTO stops at
    emission_tol x the shape's area of L1 error). pull(x): the solver's pull (node means)."""

    def __init__(self, nodes: NodeState, min_area, direct_min_area, emission_tol, node_budget, pull):
        self.nodes, self.h = nodes, nodes.h
        self.min_area, self.direct_min_area = min_area, direct_min_area
        self.emission_tol, self.node_budget = emission_tol, node_budget
        self.pull = pull

    def cover(self, rec):
        """Coverage of the shape on the hierarchy: cov_nodes get cov_vals (1 inside, else the overlap
        fraction), inherited by their descendants. Splits by the method's rule (see module doc)."""
        h = self.h
        # AUTO resolves the outline as finely as the light it casts (direct_min_area)
        min_area = self.direct_min_area if rec.method == "AUTO" else self.min_area
        inside, part, pfrac = [], [], []
        frontier = rec.roots
        while len(frontier):
            frac, ins, out = classify(rec, h, frontier)
            frontier, frac, ins = frontier[~out], frac[~out], ins[~out]
            inside.append(frontier[ins])
            p, f = frontier[~ins], frac[~ins]
            hr = self.nodes.hr_internal(p)
            part.append(p[~hr])
            pfrac.append(f[~hr])
            frontier = (h.child0[p[hr]][:, None] + np.arange(4)).ravel()
        inside = np.concatenate(inside) if inside else np.zeros(0, np.int64)
        part = np.concatenate(part) if part else np.zeros(0, np.int64)
        pfrac = np.concatenate(pfrac) if pfrac else np.zeros(0)
        n_split = 0
        target = self.emission_tol * rec.area
        while len(part) and rec.method in ("AR", "AUTO"):
            area = h.area[part]
            err = np.round(2 * pfrac * (1 - pfrac) * area / rec.area, 12)
            can = area > min_area
            if rec.method == "AUTO":
                if err.sum() <= target / rec.area:
                    break
            if not can.any():
                break
            idx = np.flatnonzero(can)
            cen = h.centre[part[idx]]
            order = idx[np.lexsort((cen[:, 2], cen[:, 1], cen[:, 0], -err[idx]))]
            if rec.method == "AUTO":
                cum = np.cumsum(err[order])
                order = order[: int(np.searchsorted(cum, 0.5 * cum[-1])) + 1]
            room = (self.node_budget - 4 * n_split) // 4
            if len(order) > room:
                order = order[: max(room, 0)]
                rec.budget_hit = True
            if len(order) == 0:
                break
            sel = part[order]
            n_split += len(sel)
            h.subdivide(sel[h.child0[sel] < 0])
            keep = np.ones(len(part), bool)
            keep[order] = False
            part, pfrac = part[keep], pfrac[keep]
            kids = (h.child0[sel][:, None] + np.arange(4)).ravel()
            frac, ins, out = classify(rec, h, kids)
            inside = np.concatenate([inside, kids[ins]])
            m = ~ins & ~out
            part = np.concatenate([part, kids[m]])
            pfrac = np.concatenate([pfrac, frac[m]])
        rec.cov_nodes = np.concatenate([inside, part]).astype(np.int64)
        rec.cov_vals = np.concatenate([np.ones(len(inside)), pfrac])
        rec.emission_l1 = float(np.sum(2 * pfrac * (1 - pfrac) * h.area[part])) / rec.area
        if rec.budget_hit:
            rec.used = rec.method + "+FE"
            rec.msgs.append(
                f"shape '{rec.name}': {rec.method} reached the node budget "
                f"({self.node_budget} nodes); {len(part)} boundary nodes use FE "
                f"(emission L1 error {100 * rec.emission_l1:.2f}%)"
            )

    def coverage(self, rec, mean=False, pull=None):
        """(n,) coverage fraction of every leaf (internal nodes: area-weighted mean). mean: as
        node means, the solver's convention (x the leaf's exposure: covered parts emit nothing).
        pull: instead of self.pull (Solves.tree_pull: the tree a response is solved on)."""
        h = self.h
        n = h.n
        c = np.zeros(n)
        s = np.zeros(n, bool)
        if rec.cov_nodes is None or len(rec.cov_nodes) == 0:
            return c
        c[rec.cov_nodes] = rec.cov_vals
        s[rec.cov_nodes] = True
        par = h.parent[:n]
        for lv in h.levels()[1:]:
            m = lv[~s[lv] & s[par[lv]]]
            c[m] = c[par[m]]
            s[m] = True
        if mean:
            c *= h.exposure[:n]
        return (pull or self.pull)(c[None].copy())[0]
