"""NAIVE: the active shapes as offset input patches over their surfaces, a new RadiositySystem."""

import time
import numpy as np

from ..geometry import MeshInput, newell
from ..output import locate, radiance_at
from ..radiosity import RadiositySystem
from .planar import _in_convex, _in_rings, slab_decomposition
from .lightsrc import LIGHT_RAYS
from .validation import find_surface, shape_plane, to2d


class _NaiveState:
    """NAIVE: the active shapes as offset input patches, a new RadiositySystem, solved cold."""

    def __init__(self, sysm, recs, lights=(), params=None, offset=1e-4, plane_tol=1e-3, far=None):
        """sysm: the base RadiositySystem; recs: the active shapes' records; lights: the Blender
        lights' records (lightsrc._LightRec); params: RefineParams of the rebuild (default the
        system's); offset: naive_offset; plane_tol: as DynamicRadiosity's; far: the lights'
        distance beyond the scene."""
        t0 = time.perf_counter()
        mesh, pt = sysm.mesh, sysm.patches
        self.groups = []
        verts, polys, rhos, ems, oids = [], [], [], [], []
        replaced = set()  # input polygons replaced by their pieces around / under the light patches
        P0 = len(mesh.loop_start)
        todo = [r for r in recs]
        for r in todo:
            if r.n is None:
                shape_plane(r, plane_tol)
                find_surface(r, sysm)
        # Offset of the light patches off their surface: naive_offset x the size of what the shapes
        # light (the shapes and their surfaces), not of the scene (a far-away object must not lift
        # them off the wall); well above the rays' offset.
        local = [np.concatenate(r.rings) for r in todo] + [
            pt.corners[r.group].reshape(-1, 3) for r in todo if r.group is not None and len(r.group)
        ]
        local = np.concatenate(local) if local else np.zeros((1, 3))
        delta = max(offset * float(np.linalg.norm(local.max(0) - local.min(0))), 20 * sysm.refiner.eps)
        while todo:
            r0 = todo[0]
            tol = max(r.tol for r in todo)
            grp = [r for r in todo if abs(r.n @ r0.n) > 0.999 and abs((r.c - r0.c) @ r0.n) <= tol]
            todo = [r for r in todo if r not in grp]
            pats = np.unique(np.concatenate([r.group for r in grp]).astype(np.int64))
            rings = [[to2d(r0, x) for x in r.rings] for r in grp]
            lo = np.min([x.min(0) for rr in rings for x in rr], 0)
            hi = np.max([x.max(0) for rr in rings for x in rr], 0)
            p2 = to2d(r0, pt.corners[pats]) if len(pats) else np.zeros((0, 4, 2))
            near = (p2.min(1) <= hi).all(1) & (p2.max(1) >= lo).all(1) if len(pats) else np.zeros(0, bool)
            pats = pats[near]
            # Host polygons touched by the shapes are replaced by their pieces (below), so no host leaf
            # straddles a light patch outline: take all the patches of those polygons, if all coplanar.
            if len(pats):
                hp = np.unique(pt.poly[pats])
                allp = np.flatnonzero(np.isin(pt.poly, hp))
                off = np.abs((pt.corners[allp] - r0.c) @ r0.n).max(1) > tol
                bad = np.unique(pt.poly[allp[off]])
                hp = np.setdiff1d(hp, np.union1d(bad, list(replaced)))
                pats = np.union1d(pats, allp[np.isin(pt.poly[allp], hp)])
                replaced.update(hp.tolist())
                grp_repl = np.isin(pt.poly[pats], hp)
            else:
                grp_repl = np.zeros(0, bool)
            p2 = to2d(r0, pt.corners[pats]) if len(pats) else np.zeros((0, 4, 2))
            edges = [np.stack([x, np.roll(x, -1, 0)], 1) for rr in rings for x in rr]
            edges += [np.stack([q, np.roll(q, -1, 0)], 1) for q in p2]
            edges = np.concatenate(edges)
            scale = float(np.abs(edges).max()) or 1.0
            traps = slab_decomposition(edges, 1e-9 * scale)
            if not traps:
                continue
            mids = np.array([m for _, m in traps])
            under = np.full(len(mids), -1)
            repl = np.zeros(len(mids), bool)
            if len(pats):
                inc = _in_convex(mids, p2)
                has = inc.any(1)
                k = np.argmax(inc[has], 1)
                under[has] = pats[k]
                repl[has] = grp_repl[k]
            em = np.zeros((len(mids), 3))
            for r, rr in zip(grp, rings):
                # a shape on a surface emits only where it lies on it (as AR, FE and AUTO); a shape
                # on no surface is a floating emitter
                emits = (under >= 0) | (not r.on_surface)
                em += (_in_rings(mids, rr) & emits)[:, None] * r.emission[None]
            lit = em.max(1) > 0
            g_quads, g_patch, g_front = [], [], []

            def add(p3, poly2, facing, rho, e, oid, front):
                """One new input polygon p3 (its 2D outline poly2), wound to face `facing`; front:
                the offset direction of a light patch (0 for pieces left on the surface)."""
                if newell(p3) @ facing < 0:
                    p3, poly2 = p3[::-1], poly2[::-1]
                base = len(np.concatenate(verts)) if verts else 0
                verts.append(p3)
                polys.append(list(range(base, base + len(p3))))
                rhos.append(rho)
                ems.append(e)
                oids.append(oid)
                g_quads.append(np.concatenate([poly2, poly2[-1:]]) if len(poly2) == 3 else poly2)
                g_patch.append(P0 + len(polys) - 1)
                g_front.append(front)

            for t in np.flatnonzero(~lit & repl):  # uncovered pieces of a replaced host polygon
                poly2 = traps[t][0]
                hn = pt.normal[under[t]]
                p3 = r0.c + poly2[:, :1] * r0.u + poly2[:, 1:2] * r0.v
                p3 = p3 - (((p3 - pt.corners[under[t], 0]) @ hn) / (r0.n @ hn))[:, None] * r0.n[None]
                add(
                    p3,
                    poly2,
                    hn,
                    pt.reflectance[:, under[t]],
                    pt.emission[:, under[t]],
                    int(pt.object_id[under[t]]),
                    np.zeros(3),
                )
            for t in np.flatnonzero(lit):
                poly2 = traps[t][0]
                front = (
                    pt.normal[under[t]]
                    if under[t] >= 0
                    else next(r.n for r, rr in zip(grp, rings) if _in_rings(mids[t : t + 1], rr)[0])
                )
                p3 = r0.c + poly2[:, :1] * r0.u + poly2[:, 1:2] * r0.v + delta * front
                rho = pt.reflectance[:, under[t]] if under[t] >= 0 else np.zeros(3)
                e = em[t] + (pt.emission[:, under[t]] if under[t] >= 0 else 0)
                add(p3, poly2, front, rho, e, -1, front)
            if g_quads:
                self.groups.append(
                    (r0, set(pats.tolist()), np.array(g_quads), np.array(g_patch), np.array(g_front))
                )
        self.P0, self.L0, self.V0 = P0, len(mesh.loop_verts), len(mesh.verts)
        self.delta = delta
        self.replaced = np.array(sorted(replaced), np.int64)
        if polys:
            light = MeshInput.from_polygons(
                np.concatenate(verts),
                polys,
                np.array(rhos),
                np.array(ems),
                np.zeros(len(polys), np.int64),
                ["light shapes (NAIVE)"],
            )
            nm = mesh.concat(light)
            oids = np.array(oids, np.int64)
            nm.object_id[P0:][oids >= 0] = oids[oids >= 0]  # pieces weld with their host object
            if len(self.replaced):  # collapse the replaced polygons (dropped as degenerate)
                nm.loop_verts = nm.loop_verts.copy()
                for q in self.replaced:
                    a, k = mesh.loop_start[q], mesh.loop_total[q]
                    nm.loop_verts[a : a + k] = nm.loop_verts[a]
        else:
            nm = mesh
        # original patch -> patch of the same polygon in the NAIVE system (-1: polygon replaced)
        kept = ~np.isin(pt.poly, self.replaced)
        self.patch_map = np.where(kept, np.cumsum(kept) - 1, -1)
        self.orig_poly = pt.poly
        self.system = RadiositySystem(
            nm, params or sysm.params, backend=sysm.backend.name, tol=sysm.tol, threads=sysm.backend.threads
        )
        E = self.system.base_emission()
        if lights:
            # Blender lights (issue 20): their first bounce on the rebuilt system's leaves
            from ..lights import node_incident

            h2, pt2 = self.system.h, self.system.patches
            leaves = np.flatnonzero(h2.child0[: h2.n] < 0)
            rho = pt2.reflectance[:, h2.patch[leaves]]
            for rec in lights:
                v = node_incident(
                    h2,
                    leaves,
                    rec.light,
                    self.system.backend,
                    self.system.refiner.eps,
                    LIGHT_RAYS,
                    far=far,
                )
                E[:, leaves] += rec.scale[:, None] * rho * v
        self.system.solve(E)
        self.iterations = self.system.report.iterations
        poly = self.system.patches.poly
        for g in self.groups:  # input polygon -> patch index (-1 if dropped as degenerate)
            pi = np.searchsorted(poly, g[3])
            pi = np.minimum(pi, len(poly) - 1)
            g[3][:] = np.where(poly[pi] == g[3], pi, -1)
        self.seconds = time.perf_counter() - t0

    def evaluate(self, points, patch_ids):
        roots, pts = self.remap(points, patch_ids)
        h = self.system.h
        leaf = locate(h, roots, pts)
        E = self.system.base_emission()
        return h.values_at(self.system.B, leaf, pts), E[:, leaf].T.copy()

    def remap(self, points, patch_ids):
        """Points on input patches -> (root patch, point) in the NAIVE system: points under a light
        patch move onto it."""
        pts = np.asarray(points, float).copy()
        orig = np.asarray(patch_ids, np.int64)
        roots = self.patch_map[orig]
        for r0, pats, quads, pidx, front in self.groups:
            m = np.flatnonzero(np.isin(orig, list(pats)))
            if len(m) == 0:
                continue
            p2 = to2d(r0, pts[m])
            inc = _in_convex(p2, quads) & (pidx >= 0)[None]
            has = inc.any(1)
            # a point of a replaced polygon just outside every piece (rounding): the nearest piece
            lost = ~has & (roots[m] < 0)
            if lost.any():
                cen = quads.mean(1)
                d = ((p2[lost][:, None] - cen[None]) ** 2).sum(-1) + np.where(pidx >= 0, 0, np.inf)[None]
                inc[np.flatnonzero(lost), np.argmin(d, 1)] = True
                has = inc.any(1)
            t = np.argmax(inc[has], 1)
            mm = m[has]
            roots[mm] = pidx[t]
            pts[mm] = pts[mm] + self.delta * front[t]
        return roots, pts

    def loop_radiance(self, mesh, domain, smooth_angle):
        out = self.system.loop_radiance("CORNER", smooth_angle)[: self.L0].astype(np.float64)
        # corners under a light patch show the light, not the hidden surface behind it
        loop_poly = np.repeat(np.arange(self.P0), mesh.loop_total)
        first = np.searchsorted(self.orig_poly, loop_poly)  # a patch of the ORIGINAL system
        pos = mesh.verts[mesh.loop_verts]
        covered = np.zeros(len(pos), bool)
        for r0, pats, quads, pidx, front in self.groups:
            m = np.flatnonzero(np.isin(first, list(pats)))
            if len(m):
                lit = front.any(1)  # unlit pieces (zero offset) are handled below
                covered[m] = _in_convex(to2d(r0, pos[m]), quads[lit]).any(1)
        if covered.any():
            out[covered] = self.evaluate(pos[covered], first[covered])[0]
        # corners of replaced polygons: the pieces' smooth radiance, probed just inside the polygon
        rl = np.flatnonzero(np.isin(loop_poly, self.replaced) & ~covered)
        if len(rl):
            cen = np.zeros((self.P0, 3))
            np.add.at(cen, loop_poly, pos)
            cen /= np.maximum(mesh.loop_total, 1)[:, None]
            p = pos[rl] + 1e-6 * (cen[loop_poly[rl]] - pos[rl])
            roots, p = self.remap(p, first[rl])
            out[rl] = radiance_at(self.system.h, self.system.B, roots, p, True)
        if domain == "POINT":
            res = np.zeros((self.V0, 3))
            res[mesh.loop_verts] = out
            return res.astype(np.float32)
        return out.astype(np.float32)
