"""Radiance of the current solution at many fixed surface points (texel centres), per leaf.

A lightmap holds up to millions of texels; evaluating output.radiance_at at each of them every
frame would repeat the same work per leaf. radiance_per_leaf probes each leaf holding points once
(four corner values) and interpolates; TexelLocator remembers the points' leaves between frames,
since light events change the hierarchy only a little. Used by lightmap.plan for texture bakes.
"""

import numpy as np

from .output import corner_weights, locate, radiance_at

_NUDGE = 0.05  # corner probes: this fraction of the way from each corner to the leaf centre


def radiance_per_leaf(h, B, patch, points, leaf=None, locator=None, chunk=200_000):
    """The values of core.output.radiance_at(h, B, patch, points, smooth=True), computed per leaf.

    radiance_at interpolates four values per leaf (one per corner) linearly on the leaf's triangles:
    it is called at one point just inside each corner of every leaf holding points, the corner
    values are solved for, and applied to the points. Same result; the costly corner probes run
    once per leaf instead of once per point. leaf: the points' leaves if known; locator: the
    TexelLocator that found them (keeps the interpolation weights of unchanged leaves)."""
    patch = np.asarray(patch, np.int64)
    pts = np.asarray(points, float)
    if len(pts) == 0:
        return np.zeros((0, 3))
    if locator is not None and locator.h is h:
        U, inv = locator.leaf_u, locator.inv
    else:
        if leaf is None:
            leaf = np.concatenate(
                [locate(h, patch[a : a + chunk], pts[a : a + chunk]) for a in range(0, len(pts), chunk)]
            )
        U, inv = np.unique(leaf, return_inverse=True)
        inv = inv.ravel()
        locator = None
    c = h.corners[U]  # (u, 4, 3)
    nv = h.nv[U].astype(np.int64)
    nrm = h.normal[U]
    g = np.where((nv == 4)[:, None], c.mean(1), c[:, :3].mean(1))
    q = c + _NUDGE * (g[:, None] - c)  # just inside each corner
    quad = nv == 4
    rows = np.concatenate([np.repeat(np.arange(len(U)), 3), np.flatnonzero(quad)])
    ks = np.concatenate([np.tile([0, 1, 2], len(U)), np.full(int(quad.sum()), 3)])
    sp = q[rows, ks]
    roots = h.patch[U][rows].astype(np.int64)
    s = np.concatenate(
        [
            radiance_at(h, B, roots[a : a + chunk], sp[a : a + chunk], smooth=True, mask=False)
            for a in range(0, len(sp), chunk)
        ]
    )
    M = np.zeros((len(U), 4, 4))
    rhs = np.zeros((len(U), 4, 3))
    M[rows, ks] = corner_weights(c[rows], nv[rows], nrm[rows], sp)
    rhs[rows, ks] = s
    tri = ~quad  # triangles: corner 3 repeats corner 2
    M[tri, 3] = [0.0, 0.0, -1.0, 1.0]
    try:
        val = np.linalg.solve(M, rhs)  # (u, 4, 3) corner values
    except np.linalg.LinAlgError:  # a degenerate leaf: evaluate every point instead
        if locator is not None:
            locator.valid[:] = False
        return np.concatenate(
            [
                radiance_at(h, B, patch[a : a + chunk], pts[a : a + chunk], smooth=True)
                for a in range(0, len(pts), chunk)
            ]
        )
    if locator is not None:
        w = locator.weights
        todo = np.flatnonzero(~locator.valid)
    else:
        w = np.empty((len(pts), 4))
        todo = np.arange(len(pts))
    for a in range(0, len(todo), chunk):
        i = todo[a : a + chunk]
        w[i] = corner_weights(c[inv[i]], nv[inv[i]], nrm[inv[i]], pts[i])
    if locator is not None:
        locator.valid[:] = True
    out = np.empty((len(pts), 3))
    for a in range(0, len(pts), chunk):
        out[a : a + chunk] = np.einsum("mk,mkc->mc", w[a : a + chunk], val[inv[a : a + chunk]])
    out[h.dark(U[inv], pts)] = 0.0  # covered points (contacts.py), as radiance_at
    return out


class TexelLocator:
    """Leaves of fixed points (texel centres) in a hierarchy that changes a little every frame.

    Remembers the points' leaves and a few of their ancestors with their corners; next frame the
    descent starts from the deepest remembered node that still has the same corners in the same
    patch (then it is the same cell of the same quadtree, so descending from it reaches the leaf a
    descent from the patch reaches), else from the patch. Per point it keeps 4-byte indices only."""

    DEPTH = 4

    def __init__(self, patch, points, rep=None):
        """rep: for each point, a nearby point of the same patch (itself for some): the first descent
        locates only those, and the others start from the deepest ancestor of their
        representative's leaf that holds them strictly inside (the descent from the patch passes
        through it), which is exact and much cheaper for dense texels."""
        self.patch = np.asarray(patch, np.int64)
        self.points = np.asarray(points, float)
        self.rep = None if rep is None else np.asarray(rep, np.int64)
        self.h = None
        self.leaf_u = None  # unique leaves of the last call
        self.inv = None  # (N,) int32: each point's entry in leaf_u
        self.anc = self.anc_corners = self.anc_patch = None
        self.weights = np.zeros((len(self.patch), 4), np.float32)  # see radiance_per_leaf
        self.valid = np.zeros(len(self.patch), bool)  # weights computed for the current leaf

    def leaves(self, h, chunk=200_000):
        start = self.patch.copy()
        prev = None
        if self.h is h and self.leaf_u is not None:
            best = np.full(len(self.leaf_u), -1, np.int64)
            for d in range(self.DEPTH):
                nodes = self.anc[:, d]
                i = np.flatnonzero((best < 0) & (nodes >= 0) & (nodes < h.n))
                good = (h.corners[nodes[i]] == self.anc_corners[i, d]).all((1, 2)) & (
                    h.patch[nodes[i]] == self.anc_patch[i]
                )
                best[i[good]] = nodes[i[good]]
            sel = best[self.inv]
            start = np.where(sel >= 0, sel, start)
            prev = self.leaf_u[self.inv]
        elif self.rep is not None and len(start):
            start = self._from_representatives(h, chunk)
        leaf = (
            np.concatenate(
                [
                    locate(h, start[a : a + chunk], self.points[a : a + chunk])
                    for a in range(0, len(start), chunk)
                ]
            )
            if len(start)
            else start
        )
        same = (start == leaf) & (leaf == prev) if prev is not None else np.zeros(len(leaf), bool)
        self.valid &= same
        U, inv = np.unique(leaf, return_inverse=True)
        anc = np.empty((len(U), self.DEPTH), np.int64)
        node = U.astype(np.int64)
        for d in range(self.DEPTH):
            anc[:, d] = node
            node = np.where(node >= 0, h.parent[np.maximum(node, 0)], -1).astype(np.int64)
        self.h, self.leaf_u, self.inv = h, U, inv.ravel().astype(np.int32)
        self.anc, self.anc_patch = anc, h.patch[U].copy()
        self.anc_corners = h.corners[np.maximum(anc, 0)].copy()
        return leaf

    def _from_representatives(self, h, chunk):
        start = self.patch.copy()
        samp = np.flatnonzero(self.rep == np.arange(len(self.rep)))
        start[samp] = np.concatenate(
            [
                locate(h, self.patch[samp[a : a + chunk]], self.points[samp[a : a + chunk]])
                for a in range(0, len(samp), chunk)
            ]
        )
        others = np.flatnonzero(self.rep != np.arange(len(self.rep)))
        for a in range(0, len(others), chunk):
            o = others[a : a + chunk]
            cand = start[self.rep[o]]
            todo = np.ones(len(o), bool)
            for _ in range(64):
                i = np.flatnonzero(todo & (cand >= 0))
                if len(i) == 0:
                    break
                i = i[h.patch[cand[i]] == self.patch[o[i]]]
                ins = i[_strictly_inside(h, cand[i], self.points[o[i]])]
                start[o[ins]] = cand[ins]
                todo[ins] = False
                cand = np.where(cand >= 0, h.parent[np.maximum(cand, 0)], -1).astype(np.int64)
        return start


def _strictly_inside(h, nodes, pts, rel=1e-7):
    """Points inside the cells of nodes by more than rel x the cell size."""
    c = h.corners[nodes]
    e = np.roll(c, -1, axis=1) - c
    el = np.linalg.norm(e, axis=-1)
    d = np.einsum("mvj,mj->mv", np.cross(e, pts[:, None] - c), h.normal[nodes]) / np.maximum(el, 1e-300)
    d = np.where(el > 0, d, np.inf)
    return d.min(1) > rel * np.sqrt(h.area[nodes])


def incident_radiance(h, B, E, links):
    """(3, n) irradiance / pi at every leaf (other nodes 0): the light a white diffuse surface
    would reflect there, what a game-engine lightmap or Cycles' Diffuse bake without Color holds.

    B - E is the reflected radiance rho H / pi (this holds whatever the solver folded into it,
    e.g. AUTO's first bounce), so where rho > 0 it is divided by rho. Channels with rho = 0 reflect
    nothing and keep no trace of H: for them the links are gathered from B once (solver.Operator,
    gather + push), which misses only light a method added to E premultiplied by rho (AUTO's first
    bounce from light shapes), i.e. nothing on black surfaces except that."""
    from .solver import Operator

    rho = h.node_rho()
    out = np.zeros_like(B)
    lf = h.leaves()
    r = rho[:, lf]
    out[:, lf] = np.where(r > 0, (h.shown(B) - E)[:, lf] / np.where(r > 0, r, 1.0), 0.0)
    if (r <= 0).any():
        op = Operator(h, links)
        G = op.push(op.gather(B))[:, lf]
        out[:, lf] = np.where(r > 0, out[:, lf], G)
    # node means, as B: covered parts (contacts.py) receive nothing
    return np.maximum(out, 0.0) * h.exposure[: B.shape[1]]


KINDS = ("radiance", "reflected", "incident")


def solution_radiance(solution, patch, points, locator=None, kind="radiance"):
    """Radiance (N, 3) float32 of the current solution at surface points of the given input patches.
    solution: a DynamicRadiosity or a RadiositySystem (solved if it is not); locator: a
    TexelLocator of these points, to find their leaves faster (not used while NAIVE's rebuilt
    system is current: the points then lie on its patches, not the input's).
    kind: "radiance" (outgoing, emission included), "reflected" (without emission) or "incident"
    (irradiance / pi, see incident_radiance)."""
    if kind not in KINDS:
        raise ValueError(f"unknown kind {kind!r} ({', '.join(KINDS)})")
    _, _, patch, points = solution.solution_at(points, patch)
    if solution.naive_active:
        locator = None
    h, B, E, links = solution.current()
    if kind == "reflected":
        B = B - E * h.exposure[: B.shape[1]]  # B holds node means (contacts.py)
    elif kind == "incident":
        B = incident_radiance(h, B, E, links)
    leaf = locator.leaves(h) if locator is not None else None
    return radiance_per_leaf(h, B, patch, points, leaf=leaf, locator=locator).astype(np.float32)


def loop_incident(solution, domain="CORNER", smooth_angle=30.0):
    """Irradiance / pi per input loop (or vertex), as loop_radiance() gives radiance: the same
    interpolation run on the incident field (solution.loop_field)."""
    h, B, E, links = solution.current()
    return solution.loop_field(incident_radiance(h, B, E, links), domain, smooth_angle)
