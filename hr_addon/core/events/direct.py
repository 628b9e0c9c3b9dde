"""AUTO's first bounce: exact point-to-shape form factors x visibility at receivers split by the
B x F criterion."""

import weakref

import numpy as np

from .. import formfactor as ff
from ..geometry import newell
from ..parallel import batch_map, ranges
from ..planes import ClearShafts
from .planar import _in_convex, _in_rings, slab_decomposition
from .validation import to2d


# receiver nodes per batch on threads (fixed: equal values for any thread count, and for any batch
# size: every node's light is its own). 1024: a refinement round of a few thousand nodes still
# feeds both cores (20k room, AUTO event: 1.39x modelled on 2 cores against 1.31x with 4096)
NODE_BATCH = 1024
# patches per batch of the first bounce's cull of the receivers (fixed; each patch its own test)
ROOT_BATCH = 1 << 14
_SHAFTS = []  # (weak reference to the patches' corners, emitter plane, ClearShafts): the last few


def clear_shafts(system, point, normal):
    """planes.ClearShafts of an emitter plane over a system's triangles, shared by AUTO's first
    bounce and every level of the final gather (the same patches and plane: the same grid;
    copies of a system share their patches). Keyed by the plane, not the point: a shape moved in
    its plane (Live's drags) reuses the grid. The grid depends on the point only through which
    triangles lie behind the plane, and a plane within the margin (1e-3 eps) of the one it was
    built for leaves out only triangles within that margin of it, which no segment from a sample
    in front (by eps) to the emitter (eps in front of it) can meet: still conservative, so the
    values do not change (a clear shaft's ratio is exactly 1 either way)."""
    pt = system.patches
    margin = 1e-3 * system.refiner.eps
    key = ((np.round(normal, 12) + 0.0).tobytes(), round(float(point @ normal) / margin))  # + 0.0: no -0.0
    for ref, k, sh in _SHAFTS:
        if ref() is pt.corners and k == key:
            return sh
    sh = ClearShafts(
        pt.triangles, system.refiner.occluders.plane, point, normal, margin, system.backend.threads
    )
    _SHAFTS.append((weakref.ref(pt.corners), key, sh))
    del _SHAFTS[:-4]
    return sh


def _by_nodes(fn, m, threads, *rows):
    """fn over fixed ranges of m nodes on threads, each range's results concatenated per output;
    rows: per node arrays (first axis m) or per Gauss point arrays (4 m), cut with the nodes."""

    def part(a, b):
        return fn(*(r[a * (len(r) // m) : b * (len(r) // m)] for r in rows))

    parts = batch_map(part, ranges(m, NODE_BATCH), threads)
    return tuple(np.concatenate(p) for p in zip(*parts))


class FirstBounce:
    """AUTO's first bounce of a shape on a system's hierarchy. nodes: the events' NodeState (which
    nodes the HR build split); occluders: planes.Occluders of the system's patches; min_area: the
    smallest receiver; bf_rel, node_budget as in DynamicRadiosity."""

    def __init__(self, system, nodes, occluders, min_area, bf_rel, node_budget, points=16):
        self.system, self.nodes, self.occluders = system, nodes, occluders
        self.min_area, self.bf_rel, self.node_budget = min_area, bf_rel, node_budget
        self.points = int(points)  # points on the shape for the visibility ratio (at most)

    # the clear-shaft cull pays from this many rays per receiver point on (as the gather's direct
    # light, DirectLight.CULL_MIN_RAYS): with the gather's 4 points its test cost more than the
    # rays it saved (100k room, AUTO window added and moved: first bounces 1.76 -> 1.48 s CPU
    # without it, bitwise equal). Conservative either way: the values do not depend on it
    CULL_MIN_POINTS = 16

    def direct(self, rec, n_start):
        """AUTO: the shape's first bounce, per unit emission, at receiver nodes (3, n, not pushed) and
        the nodes it needs.

        Receivers are evaluated at 2 x 2 Gauss points: exact unoccluded point-to-shape form factor
        (contour integral over the rings; convex pieces with horizon clipping where the receiver's
        plane cuts the shape) times a kernel-weighted visibility ratio (rays to points on the shape).
        Starting at the roots, a node takes the value if the light on it is weak (HR internal nodes:
        rho F < bf_rel) or even (own leaves: rho x range of F V < bf_rel); otherwise it is split
        (below the HR leaves down to min_area, node budget permitting: the nodes made since
        n_start count, with the outline's).
        """
        h, pt = self.system.h, self.system.patches
        rho, rho_max = pt.reflectance, pt.reflectance.max(0)
        min_area, thr = self.min_area, self.bf_rel
        corners, nv, area, nf = self.pieces(rec)
        if len(corners) == 0:
            return np.zeros((3, h.n)), np.zeros(0, np.int64)
        # points on the shape for the visibility ratio: 2 x 2 Gauss points of the pieces, thinned to
        # at most self.points by systematic sampling along their cumulative area (deterministic)
        sp, sw = ff.quadrature(corners, nv, 2)
        sp, sw = sp.reshape(-1, 3), (sw * area[:, None]).ravel()
        P = self.points
        if len(sp) > P:
            cum = np.cumsum(sw)
            pick = np.minimum(np.searchsorted(cum, (np.arange(P) + 0.5) / P * cum[-1]), len(sp) - 1)
            sp, sw = sp[pick], np.full(P, cum[-1] / P)
        eps = self.system.refiner.eps
        rings = None
        fc, fnv = corners, nv  # the region whose form factor the receivers take
        if rec.covered >= 1 - 1e-9:  # contour over the rings: outer CCW about nf, holes CW
            rings = [r if (newell(r) @ nf > 0) == (i == 0) else r[::-1] for i, r in enumerate(rec.rings)]
        else:  # the same region cut along the covered patches' union only: a few pieces, not one per patch
            fc, fnv = slab_pieces(rec, nf, to2d(rec, pt.corners[rec.roots]), merge=True)[:2]
        allv = np.concatenate(rec.rings)
        shape_lo, shape_hi = corners.reshape(-1, 3).min(0), corners.reshape(-1, 3).max(0)

        threads = self.system.backend.threads
        # the clear-shaft grid at any scene size: per Gauss point, cheaper than Occluders' test
        # of every node's box against every triangle (Cornell: 1.8 s -> 0.4 s over the 56 recorded
        # Live edits), and the values are the same (a clear shaft's ratio is exactly 1 either way)
        shafts = clear_shafts(self.system, rec.c, nf)

        def unoccluded(nodes):
            """(m, 4) unoccluded point-to-shape form factors at the nodes' Gauss points, points, normals,
            weights (by node ranges on threads)."""
            if len(nodes) == 0:
                return unoccluded_part(nodes)
            return _by_nodes(unoccluded_part, len(nodes), threads, nodes)

        def unoccluded_part(nodes):
            x, gw = ff.quadrature(h.corners[nodes], h.nv[nodes], 2)
            xn = np.repeat(h.normal[nodes], 4, 0)
            x = x.reshape(-1, 3)
            F = np.zeros(len(x))
            front = (x - rec.c) @ nf > eps
            F[front] = shape_form_factors(x[front], xn[front], rings, fc, fnv, eps)
            return F.reshape(-1, 4), x, xn, gw

        def visible(nodes, F, x, xn):
            """(F x kernel-weighted visibility ratio; rays only where an occluder may be in the way,
            (m, 4) True at the Gauss points not covered (contacts.py) of the partly covered nodes,
            True elsewhere), by node ranges on threads."""
            return _by_nodes(visible_part, len(nodes), threads, nodes, F, x, xn)

        def visible_part(nodes, F, x, xn):
            FV = F.ravel().copy()
            # every ray of a clear shaft is unoccluded: the ratio is 1 without them
            lit = np.flatnonzero(FV > 0)
            if len(sp) >= self.CULL_MIN_POINTS:
                o = x[lit] + eps * xn[lit]
                lit = lit[~shafts.clear(o, shape_lo + eps * nf, shape_hi + eps * nf)]
            if len(lit):
                K = len(sp)
                a = np.repeat(x[lit] + eps * xn[lit], K, 0)
                b = np.tile(sp + eps * nf, (len(lit), 1))
                d = b - a
                r2 = np.einsum("ij,ij->i", d, d)
                kern = (
                    np.maximum(np.einsum("ij,ij->i", d, np.repeat(xn[lit], K, 0)), 0)
                    * np.maximum(-(d @ nf), 0)
                    / np.maximum(r2, 1e-300) ** 2
                    * np.tile(sw, len(lit))
                )
                vis = ~self.system.backend.occluded(a, b)
                kern, vis = kern.reshape(-1, K), vis.reshape(-1, K)
                ks = kern.sum(1)
                FV[lit] *= np.where(ks > 0, (kern * vis).sum(1) / np.where(ks > 0, ks, 1), 1.0)
            # the partly covered nodes' Gauss points: the covered test (each point its own: here,
            # on threads, rather than after the map; session 22)
            shown = np.ones(len(FV), bool)
            if h.contacts is not None:
                ex = h.exposure[nodes]
                part = np.flatnonzero((ex > 0) & (ex < 1))
                if len(part):
                    sel = (part[:, None] * 4 + np.arange(4)).ravel()
                    shown[sel] = ~h.dark(np.repeat(nodes[part], 4), x[sel])
            return FV.reshape(-1, 4), shown.reshape(-1, 4)

        in_group = np.zeros(len(pt.nv), bool)
        in_group[rec.group] = True
        roots = np.flatnonzero(~in_group)

        # cull receivers wholly behind the shape or facing away from all of it (by ranges of
        # roots on threads: each root its own test; the stacked products of (4, 3) corners by nf
        # are each their own too, the same bits however the roots are cut)
        def cull(a, b):
            r = roots[a:b]
            rc = pt.corners[r]
            front = ((rc - rec.c) @ nf > eps).any(1)
            sees = ((allv[None] - rc[:, :1]) * pt.normal[r][:, None]).sum(-1).max(1) > eps
            return r[front & sees]

        frontier = np.concatenate(batch_map(cull, ranges(len(roots), ROOT_BATCH), threads) or [roots[:0]])
        acc_nodes, acc_vals = [], []
        budget_msg = False
        while len(frontier):
            F, x, xn, gw = unoccluded(frontier)
            rm = rho_max[h.patch[frontier]]
            hr = self.nodes.hr_internal(frontier)
            # HR internal nodes keep the light if it is weak on them, else they are descended
            acc = hr & (rm * F.max(1) < thr) & (F.max(1) > 0)
            leaf = ~hr & (F.max(1) > 0)
            ev = np.flatnonzero(acc | leaf)
            FV = np.zeros_like(F)
            if len(ev):
                sel = (ev[:, None] * 4 + np.arange(4)).ravel()
                FV[ev], shown = visible(frontier[ev], F[ev], x[sel], xn[sel])
            val = (FV * gw).sum(1)
            if h.contacts is not None and len(ev):
                # partly covered nodes (contacts.py): the light on their exposed part; the solve
                # counts the exposure itself
                ex = h.exposure[frontier[ev]]
                part = np.flatnonzero((ex > 0) & (ex < 1))
                if len(part):
                    rows = ev[part]
                    lit = shown[part]
                    w = gw[rows] * lit
                    ws = w.sum(1)
                    val[rows] = np.where(
                        ws > 0, (FV[rows] * w).sum(1) / np.where(ws > 0, ws, 1) * gw[rows].sum(1), val[rows]
                    )
            var = rm * (FV.max(1) - FV.min(1))
            split = leaf & (h.area[frontier] > min_area) & (var >= thr)
            room = max((self.node_budget - (h.n - n_start)) // 4, 0)
            if split.sum() > room:  # over budget: split the most uneven nodes only
                budget_msg = True
                idx = np.flatnonzero(split)
                cen = h.centre[frontier[idx]]
                keep = idx[np.lexsort((cen[:, 2], cen[:, 1], cen[:, 0], -np.round(var[idx], 12)))[:room]]
                split[:] = False
                split[keep] = True
            take = (acc | (leaf & ~split)) & (val > 0)
            acc_nodes.append(frontier[take])
            acc_vals.append(val[take])
            down = frontier[(hr & ~acc & (F.max(1) > 0)) | split]
            h.subdivide(down[h.child0[down] < 0])
            frontier = (h.child0[down][:, None] + np.arange(4)).ravel()
        if budget_msg:
            rec.msgs.append(
                f"shape '{rec.name}': first-bounce refinement reached the node budget "
                f"({self.node_budget} nodes)"
            )
        nodes = np.concatenate(acc_nodes)
        vals = np.concatenate(acc_vals)
        rec.direct_links = len(nodes)
        D = np.zeros((3, h.n))
        D[:, nodes] = rho[:, h.patch[nodes]] * vals
        return D, nodes

    def pieces(self, rec):
        """Convex pieces (trapezoids) of the shape on its covered patches: corners (T, 4, 3) CCW about
        the emitting side's normal, nv, areas, and that normal."""
        pt = self.system.patches
        roots = rec.roots
        nf = pt.normal[roots[0]] if len(roots) else rec.n
        if len(roots) == 0:
            return np.zeros((0, 4, 3)), np.zeros(0, int), np.zeros(0), nf
        return slab_pieces(rec, nf, to2d(rec, pt.corners[roots])) + (nf,)


def slab_pieces(rec, nf, cells=None, merge=False):
    """Convex pieces (slabs) of a shape's outline: corners (T, 4, 3) CCW about nf, nv, areas.
    cells: convex polygons (P, 4, 2) in the shape's plane (its covered patches): the outline is cut
    along their edges too and only the pieces inside one of them are kept. merge: cut only along
    the outline of their union (edges two cells share are left out): the same region in a few
    pieces instead of one per cell and slab (a shape reaching past the edge of a finely meshed
    wall)."""
    edges = [np.stack([x, np.roll(x, -1, 0)], 1) for x in rec.rings2d]
    if cells is not None and merge:
        # only edges reaching into the outline's box can cut it (the others' heights would only
        # cut its slabs into more pieces)
        e, lo, hi = _union_edges(cells), np.min(edges[0], (0, 1)), np.max(edges[0], (0, 1))
        edges.append(e[((e.max(1) >= lo) & (e.min(1) <= hi)).all(1)])
    elif cells is not None:
        edges.append(np.stack([cells, np.roll(cells, -1, 1)], 2).reshape(-1, 2, 2))
    edges = np.concatenate(edges)
    scale = float(np.abs(edges).max()) or 1.0
    traps = slab_decomposition(edges, 1e-9 * scale)
    mids = np.array([m for _, m in traps]).reshape(-1, 2)
    keep = _in_rings(mids, rec.rings2d)
    if cells is not None:
        # merged: a piece lies wholly inside the union or wholly outside it, but its midpoint may
        # lie on an edge two cells share, so it counts within a rounding tolerance of a cell
        keep &= _in_convex(mids, cells, 1e-9 * scale if merge else None).any(1)
    # the kept pieces' corners in 3-d, turned CCW about nf, triangles padded with their last
    # corner: the triangles and the quads each as one array (the same arithmetic per piece as
    # one at a time: the same corners; session 22)
    idx = np.flatnonzero(keep)
    nv = np.array([len(traps[t][0]) for t in idx], int)
    c = np.zeros((len(idx), 4, 3))
    for k in (3, 4):
        at = np.flatnonzero(nv == k)
        if not len(at):
            continue
        q = np.stack([traps[t][0] for t in idx[at]])  # (m, k, 2)
        p3 = rec.c + q[..., :1] * rec.u + q[..., 1:2] * rec.v
        flip = np.array([v @ nf < 0 for v in newell(p3)], bool)  # (each piece's dot, as before)
        p3[flip] = p3[flip][:, ::-1]
        c[at, :k] = p3
        if k == 3:
            c[at, 3] = p3[:, 2]
    return c, nv, ff.polygon_normal_area(c, nv)[1]


def _union_edges(cells):
    """Edges (E, 2, 2) of convex cells (P, M, 2) that no other cell shares (the outline of their
    union where they meet edge to edge, as a mesh's patches do; cells meeting at a T-junction keep
    both edges: more pieces, the same region). Zero-length edges are dropped."""
    e = np.stack([cells, np.roll(cells, -1, 1)], 2).reshape(-1, 2, 2)
    e = e[(e[:, 0] != e[:, 1]).any(1)]
    a, b = e[:, 0], e[:, 1]
    swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
    key = np.where(swap[:, None], np.concatenate([b, a], 1), np.concatenate([a, b], 1))
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return e[cnt[inv.ravel()] == 1]


def shape_form_factors(x, n, rings, corners, nv, eps):
    """Unoccluded form factors (N,) from points x (N, 3) with normals n in front of a shape: over
    its rings (outer CCW about its normal, holes CW; None: unknown) by the contour integral where
    the shape lies wholly above a point's horizon, else the rings clipped to it; without rings the
    sum over its convex pieces (corners (T, 4, 3), nv)."""
    F = np.zeros(len(x))
    if rings is not None:
        X, N = np.ascontiguousarray(x.T), np.ascontiguousarray(n.T)  # component-major: rows of N
        v = np.concatenate(rings)[:, :, None]
        # (the sum's order as .sum(-1) of rows of 3 had it)
        whole = (((v[:, 0] - X[0]) * N[0] + (v[:, 1] - X[1]) * N[1]) + (v[:, 2] - X[2]) * N[2]).min(0) > eps
        if whole.any():
            F[whole] = _contour(X[:, whole], N[:, whole], rings)
        cut = ~whole
        if cut.any():
            # the horizon cuts the outline: its rings clipped to the point's upper half-space
            # (exact, as the pieces' sum, for a handful of edges instead of every piece's)
            F[cut] = ff.clipped_rings(x[cut], n[cut], rings)
        return F
    T = len(corners)
    step = max(1, (1 << 18) // max(T, 1))  # bounded temporaries
    for s0 in range(0, len(x), step):
        r = slice(s0, s0 + step)
        m = len(x[r])
        F[r] = (
            ff.point_to_polygon(
                np.repeat(x[r], T, 0), np.repeat(n[r], T, 0), np.tile(corners, (m, 1, 1)), np.tile(nv, m)
            )
            .reshape(-1, T)
            .sum(1)
        )
    return F


def _contour(X, N, rings):
    """Unoccluded form factor from points X (3, P) (component-major) with normals N to a polygon
    with holes lying wholly above their horizons: Lambert's contour integral over all rings (outer
    CCW about the polygon's normal, holes CW). Rows of P per component and vertex (numpy is slow
    on a last axis of 3: 1.4-1.8x faster on the 100k room's events); the sums in the order np.cross,
    norm and einsum gave them (the same bits)."""
    f = np.zeros(X.shape[1])
    for r in rings:
        R = r.T[:, :, None] - X[:, None]  # (3, M, P)
        Rn = np.roll(R, -1, axis=1)
        c0 = R[1] * Rn[2] - R[2] * Rn[1]
        c1 = R[2] * Rn[0] - R[0] * Rn[2]
        c2 = R[0] * Rn[1] - R[1] * Rn[0]
        cl = np.sqrt((c0 * c0 + c1 * c1) + c2 * c2)
        g = np.arctan2(cl, (R[0] * Rn[0] + R[2] * Rn[2]) + R[1] * Rn[1])
        on = cl > 0
        t = np.where(on, g * ((c0 * N[0] + c2 * N[2]) + c1 * N[1]) / np.where(on, cl, 1), 0.0)
        f -= t.sum(0) / (2 * np.pi)
    return np.clip(f, 0.0, 1.0)
