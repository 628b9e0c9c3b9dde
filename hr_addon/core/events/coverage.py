"""FE and AR (and AUTO's outline): the clipped coverage of a shape on the hierarchy, AR subdivision,
and the reference-counted nodes below the HR leaves."""

import numpy as np


class _CoverageMixin:
    """DynamicRadiosity's coverage of a shape and node bookkeeping."""

    def _incremental_add(self, rec):
        h = self.system.h
        rec.used = rec.method
        self._event_n0 = h.n  # the node budget covers the outline and the first bounce together
        self._cover(rec)
        required = [rec.cov_nodes]
        if rec.method == "AUTO":
            rec.D, req = self._direct(rec)
            required.append(req)
        rec.owned = self._owned_ancestors(np.concatenate(required))
        self._sync(extra=[rec])
        self._ref[rec.owned] += 1
        self._gc(extra=[rec])  # splits made on the way that turned out unnecessary
        self._sync(extra=[rec])
        cov = self._coverage(rec)
        if rec.method == "AUTO":
            E = (
                np.broadcast_to(self._push(rec.D), (3, h.n)).copy()
                if rec.D is not None
                else np.zeros((3, h.n))
            )
        else:
            E = np.repeat(cov[None], 3, 0)
        if self.incremental == "warm":
            return 0
        U, rep = self._solve(E, B0=None if self._guess is None else E + self._guess, response=True)
        if rec.method == "AUTO":
            U = U + np.repeat(self._coverage(rec, mean=True)[None], 3, 0)
        rec.U = U
        return rep.iterations

    def _cover(self, rec):
        """Coverage of the shape on the hierarchy: cov_nodes get cov_vals (1 inside, else the overlap
        fraction), inherited by their descendants. Splits by the method's rule (see module doc)."""
        h = self.system.h
        # AUTO resolves the outline as finely as the light it casts (direct_min_area_rel)
        min_area = (self.direct_min_area_rel if rec.method == "AUTO" else self.min_area_rel) * self.total_area
        inside, part, pfrac = [], [], []
        frontier = rec.roots
        while len(frontier):
            frac, ins, out = self._classify(rec, frontier)
            frontier, frac, ins = frontier[~out], frac[~out], ins[~out]
            inside.append(frontier[ins])
            p, f = frontier[~ins], frac[~ins]
            hr = self._hr_internal(p)
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
            frac, ins, out = self._classify(rec, kids)
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

    # -- node bookkeeping ----------------------------------------------------------------------------
    def _hr_internal(self, nodes):
        nodes = np.asarray(nodes, np.int64)
        out = np.zeros(len(nodes), bool)
        m = nodes < self.n_hr
        out[m] = self.hr_internal[nodes[m]]
        return out

    def _owned_ancestors(self, nodes):
        """Nodes below the HR leaves (and split HR leaves) on the path to `nodes`: the splits they need."""
        h = self.system.h
        res = []
        cur = np.unique(h.parent[np.asarray(nodes, np.int64)])
        cur = cur[cur >= 0]
        while len(cur):
            cur = cur[~self._hr_internal(cur)]
            res.append(cur)
            cur = np.unique(h.parent[cur])
            cur = cur[cur >= 0]
        return np.unique(np.concatenate(res)) if res else np.zeros(0, np.int64)

    def _gc(self, extra=()):
        """Delete the children of owned splits no shape needs. Returns the number of nodes deleted."""
        h = self.system.h
        self._sync(extra)
        n = h.n
        idx = np.arange(n)
        collapse = (h.child0[:n] >= 0) & ~self._hr_internal(idx) & (self._ref[:n] == 0)
        if not collapse.any():
            return 0
        dead = np.zeros(n, bool)
        for lv in h.levels()[1:]:
            par = h.parent[lv]
            dead[lv] = collapse[par] | dead[par]
        keep = ~dead
        remap = h.compact(keep)
        assert (remap[: self.n_hr] == np.arange(self.n_hr)).all()
        self._ref = self._ref[:n][keep]
        self._Bbase = self._Bbase[:, keep]
        self._X = self._X[:, keep]
        self._B = self._B[:, keep] if self._B.shape[1] == n else self._B
        if self._guess is not None:
            self._guess = self._guess[:, keep]
        for rec in list(getattr(self, "lights", {}).values()):
            rec.U = rec.U[:, keep] if rec.U is not None else None
            rec.D = rec.D[:, keep] if rec.D is not None else None
        for rec in list(self.shapes.values()) + list(self._cache.values()) + list(extra):
            for name in ("U", "D"):
                a = getattr(rec, name)
                if a is not None:
                    setattr(rec, name, a[:, keep])
            for name in ("cov_nodes", "owned"):
                a = getattr(rec, name)
                if a is not None and len(a):
                    a = remap[a]
                    assert (a >= 0).all(), "a live shape lost a node it needs"
                    setattr(rec, name, a)
        return int(dead.sum())

    def _sync(self, extra=()):
        """Extend per-node arrays to nodes created since: solutions by copy from the parent (new nodes
        carry no links, so this is exact), first-bounce terms and reference counts with zeros."""
        h = self.system.h
        n = h.n
        if len(self._ref) < n:
            self._ref = np.concatenate([self._ref, np.zeros(n - len(self._ref), np.int64)])
        self._Bbase = h.extend(self._Bbase)
        self._X = h.extend(self._X)
        self._B = h.extend(self._B)
        if self._guess is not None:
            self._guess = h.extend(self._guess)
        for rec in list(getattr(self, "lights", {}).values()):
            if rec.U is not None:
                rec.U = h.extend(rec.U)
            if rec.D is not None and rec.D.shape[1] < n:
                rec.D = np.concatenate([rec.D, np.zeros((3, n - rec.D.shape[1]))], 1)
        for rec in list(self.shapes.values()) + list(self._cache.values()) + list(extra):
            if rec.U is not None:
                rec.U = h.extend(rec.U)
            if rec.D is not None and rec.D.shape[1] < n:
                rec.D = np.concatenate([rec.D, np.zeros((3, n - rec.D.shape[1]))], 1)

    def _coverage(self, rec, mean=False):
        """(n,) coverage fraction of every leaf (internal nodes: area-weighted mean). mean: as
        node means, the solver's convention (x the leaf's exposure: covered parts emit nothing)."""
        h = self.system.h
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
        return self._operator().pull(c[None].copy())[0]
