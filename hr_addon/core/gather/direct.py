"""Direct light of the final gather: per emitter (the input's emissive patches, light shapes,
Blender lights) the exact form factor times a visibility ratio from shadow rays, at unit radiance,
cached so that a strength or colour change is a scale (docs/gather.md)."""

import numpy as np

from .. import formfactor as ff
from ..events.direct import clear_shafts, shape_form_factors, slab_pieces
from ..events.validation import to2d
from ..geometry import newell
from ..parallel import batch_map, ranges
from .sampling import Emitter, hammersley, hash_uniform, position_keys
from .texel_edges import edge_direct

_clipped_rings = ff.clipped_rings  # (the horizon-cut outline: formfactor.clipped_rings)


def _ratio_of(kern, vis):
    """(L,) the ratio estimator sum(kern vis) / sum(kern) over each point's rays (1 where no ray
    has weight)."""
    ks = kern.sum(1)
    return np.where(ks > 0, (kern * vis).sum(1) / np.where(ks > 0, ks, 1), 1.0)


def _in_set(ids, members):
    """np.isin(ids, members) for non-negative integer ids, by a flag per id (a look-up a sample
    instead of isin's sort of the level's samples at every event: the same answer)."""
    if not len(ids) or int(ids.min()) < 0:
        return np.isin(ids, members)
    flag = np.zeros(max(int(ids.max()), int(members.max()) if len(members) else 0) + 1, bool)
    flag[members] = True
    return flag[ids]


class DirectLight:
    """FinalGather's direct light (a mixin: it reads the gather's samples, points, normals, keys,
    dark, eps, seed, shadow_rays, system and its batching)."""

    # texture output (layouts.texel_gather): the texels gathered at their centre, whose direct light
    # (Blender lights, emitters, light shapes) is averaged over their area where an edge crosses
    # them (texel_edges)
    texel_area = None
    # light shapes too (off by default): a shape's edge pass is paid again on every event that
    # moves it (20k room, texture output: 56% of an FE window event; Cornell per frame 1.2 ->
    # 3.1 s CPU); static emitters and area lights pay it once per geometry
    edge_shapes = False
    # shadow rays to area-uniform points of the emitter, weighted cos_x cos_y / r^2, instead of
    # Arvo's solid-angle sampling: the ratio estimator gives fully lit and fully shadowed samples
    # the exact form factor either way; the density only sets the penumbrae's noise (docs/gather.md,
    # "A light shape's direct light, cheaper")
    area_sampling = True
    # samples nearer to the emitter's box centre than AREA_NEAR x its half diagonal keep Arvo's
    # rays: there the area density's 1 / r^2 spread makes the ratio noisy (docs/gather.md)
    AREA_NEAR = 2.0

    # -- direct light --------------------------------------------------------------------------------
    def direct_batch(self, em: Emitter, a, b, shafts=None):
        """(b - a,) float32: unit-radiance direct light F x V of emitter em at samples a..b-1.
        shafts: the emitter's ClearShafts (samples whose segments to it are certainly clear get
        no shadow rays: their ratio would be exactly 1)."""
        x, nx = self.points[a:b], self.normals[a:b]
        out = np.zeros(b - a)
        eps = self.eps
        # cull: a vertex of the emitter above the horizon, and (planar) the point in front of it
        ok = ~self.dark[a:b]
        if em.normal is not None:
            ok &= (x - em.point) @ em.normal > eps
        # the horizon test on the samples in front only (each sample's own products: the same
        # values; at 100k a window is behind or beside 40-55% of a level's samples)
        i = np.flatnonzero(ok)
        xi, ni = x[i], nx[i]
        top = np.full(len(i), -np.inf)
        xn = np.einsum("mk,mk->m", xi, ni)[:, None]
        for s0 in range(0, len(em.verts), 64):
            top = np.maximum(top, (ni @ em.verts[s0 : s0 + 64].T - xn).max(1))
        up = top > eps
        if not up.all():
            i, xi, ni = i[up], xi[up], ni[up]
        if len(i) == 0:
            return out.astype(np.float32)
        if self.shadow_rays <= 0:
            return self._times_form_factor(em, out, i, xi, ni)
        # the shadow rays first, then the form factor only where some ray got through (46-47% of
        # the 100k room's samples in front of its window see none of it): each sample's F and V
        # are its own, so the values are those of the form factor first, bit for bit
        lit = np.arange(len(i))
        if shafts is not None:
            e = eps * em.normal
            lit = lit[~shafts.clear(xi + eps * ni, em.lo + e, em.hi + e)]
        V = np.ones(len(i))  # (1 where the shaft is clear: F x 1 = F)
        if len(lit):
            S = self.shadow_rays
            gi = i[lit] + a
            u = hammersley(S)[None] + hash_uniform(self.seed, self.keys[gi], 1000 + em.stream)[:, None]
            u -= u >= 1.0  # = u % 1.0 (a sum of two numbers in [0, 1): exact, Sterbenz), 2x faster
            xo, no = xi[lit], ni[lit]
            if self.area_sampling:  # area-uniform rays but near the emitter (there Arvo's)
                c, rad = 0.5 * (em.lo + em.hi), 0.5 * np.linalg.norm(em.hi - em.lo)
                dc = xo - c
                near = np.einsum("lk,lk->l", dc, dc) < (self.AREA_NEAR * rad) ** 2
                for sel, area in ((near, False), (~near, True)):
                    if sel.all():  # (one kind: no copies)
                        V[lit] = self._visible(em, xo, no, u, area)
                    elif sel.any():
                        V[lit[sel]] = self._visible(em, xo[sel], no[sel], u[sel], area)
            else:
                V[lit] = self._visible(em, xo, no, u, False)
        seen = np.flatnonzero(V != 0)
        return self._times_form_factor(em, out, i[seen], xi[seen], ni[seen], V[seen])

    def _times_form_factor(self, em: Emitter, out, i, xi, ni, V=None):
        """out (float32) with the form factors of em at samples i (points xi, normals ni), times their
        visible fractions V where given (the ratio's float64 product)."""
        F = shape_form_factors(xi, ni, em.rings, em.corners, em.nv, self.eps)
        if V is not None:
            F *= V
        out[i] = F
        return out.astype(np.float32)

    def _visible(self, em: Emitter, xo, no, u, area):
        """(L,) the visible fraction of em's projected solid angle from points xo (normals no) by
        shadow rays from uniforms u (L, S, 2), a ratio estimator: Arvo's solid-angle sampling, weight
        cos_x (and only where the emitter faces the point), or area-uniform points (area) weighted
        cos_x cos_y / r^2."""
        return _ratio_of(*self._rays(em, xo, no, u, area))

    def _rays(self, em: Emitter, xo, no, u, area):
        """(kern (L, S), vis (L, S) bool) of _visible's rays: each ray's weight and whether it got
        through."""
        eps, (L, S) = self.eps, u.shape[:2]
        if area:
            y, ny = em.sample_cm(u.reshape(-1, 2))
            ratio = None
        else:
            y, ny, ratio = em.sample_at(xo, u, cm=True)
        if ratio is None:  # exact sampling everywhere: component-major (3, L, S), the same values
            y, ny = y.reshape(3, L, S), ny.reshape(3, -1, S if ny.shape[1] > 1 else 1)
            X, N = xo.T[:, :, None], no.T[:, :, None]
            d = y - X
            dot = lambda a, b: (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]  # einsum's order for rows of 3
            with np.errstate(over="ignore", invalid="ignore"):  # silent as einsum (grazing rays)
                if area:  # cos_x cos_y / r^2 over the area density: no square root
                    r2 = np.maximum(dot(d, d), 1e-150)
                    kern = np.maximum(dot(d, N), 0) * np.maximum(-dot(d, ny), 0) / (r2 * r2)
                else:
                    r = np.sqrt(np.maximum(dot(d, d), 1e-300))
                    kern = np.maximum(dot(d, N) / r, 0) * (dot(d, ny) < 0)
            o = X + eps * N
            # each point's origin once for its S rays (occluded_cm's per: the same segments)
            vis = ~self.system.backend.occluded_cm(o[:, :, 0], ((y + eps * ny) - o).reshape(3, -1), S)
        else:
            o = (xo + eps * no)[:, None]
            e = y + eps * ny
            d = y - xo[:, None]
            r = np.sqrt(np.maximum(np.einsum("lsk,lsk->ls", d, d), 1e-300))
            kern = (
                np.maximum(np.einsum("lsk,lk->ls", d, no) / r, 0)
                * (np.einsum("lsk,lsk->ls", d, ny) < 0)
                / np.maximum(ratio, 1e-300)
            )
            o = np.broadcast_to(o, d.shape).reshape(-1, 3)
            vis = ~self.system.backend.occluded(o, e.reshape(-1, 3))
        return kern, vis.reshape(kern.shape)

    @staticmethod
    def direct_cost(em: Emitter, rays):
        """A sample's work in direct_batch (its batches' size), in rays: its shadow rays, the form
        factor's edges and the sampling's triangles."""
        edges = sum(len(r) for r in em.rings) if em.rings is not None else 4 * len(em.corners)
        tri = min(len(em.tri), em.MAX_TRIANGLES)
        return max(rays, 1) * 4 + 3 * min(edges, 4 * em.MAX_TRIANGLES) + 12 * tri

    def direct_light(self, em: Emitter, edges=True):
        """(n,) float32 unit-radiance direct light of em at every sample (batches merged); edges:
        in texture output, an edge texel's value is its area's mean (texel_edges)."""
        per = self.direct_cost(em, self.shadow_rays)
        shafts = self.shafts(em)
        parts = batch_map(lambda a, b: self.direct_batch(em, a, b, shafts), self.batches(per), self.threads)
        out = np.concatenate(parts or [np.zeros(0, np.float32)])
        if edges and self.texel_area is not None:  # texture output: an edge across a texel, its area's mean
            out = edge_direct(self, em, out, self.shadow_rays, em.stream, shafts=shafts).astype(np.float32)
        return out

    # the clear-shaft cull costs about 2 us per lit sample and saves a culled sample's sampling and
    # rays, about 0.6 us per shadow ray (Cornell, medium): with a quarter to a third of the lit
    # samples culled it pays from about 16 shadow rays on, and costs more than it saves with 8
    # (a second level's at medium). Conservative either way: the values do not depend on it.
    CULL_MIN_RAYS = 16

    def shafts(self, em: Emitter):
        """ClearShafts of a planar emitter over the system's triangles (None: not planar, or too
        few shadow rays to pay for the test), shared by the levels of a gather and AUTO's first
        bounce (events.direct.clear_shafts)."""
        if em.normal is None or self.shadow_rays < self.CULL_MIN_RAYS:
            return None
        return clear_shafts(self.system, em.point, em.normal)

    def static_emitters(self):
        """The input's emissive patches, one Emitter per (object, emission)."""
        pt = self.system.patches
        em = pt.emission
        out = []
        idx = np.flatnonzero(em.max(0) > 0)
        if len(idx) == 0:
            return out
        key = np.column_stack([pt.object_id[idx], em[:, idx].T])
        _, inv = np.unique(key, axis=0, return_inverse=True)
        for g in range(inv.max() + 1):
            p = idx[inv.ravel() == g]
            _, area = ff.polygon_normal_area(pt.corners[p], pt.nv[p])
            nrm = pt.normal[p]
            planar = np.allclose(nrm, nrm[0], atol=1e-9) and np.allclose(
                (pt.corners[p].reshape(-1, 3) - pt.corners[p[0], 0]) @ nrm[0],
                0,
                atol=1e-9 * np.sqrt(area.sum()),
            )
            e = Emitter(
                pt.corners[p],
                pt.nv[p],
                area,
                nrm,
                None,
                nrm[0] if planar else None,
                pt.corners[p[0], 0] if planar else None,
                stream=int(position_keys(pt.corners[p[:1], 0], self.unit)[0] & np.uint64(0x7FFFFFFF)),
            )
            out.append((e, em[:, p[0]].copy()))
        return out

    def direct_static(self):
        if self._D_static is None:
            D = np.zeros((self.n, 3))
            for e, rad in self.static_emitters():
                D += self.direct_light(e)[:, None].astype(np.float64) * rad[None]
            self._D_static = D
        return self._D_static

    # -- light shapes ---------------------------------------------------------------------------------
    def _shape_emitter(self, dyn, rec):
        """Emitter of a light shape (its part on surfaces when it lies on one) and the samples inside
        its outline on that surface."""
        from ..events.planar import _in_rings

        got = rec.emitter
        if got is None or got[0] != self.unit:
            got = rec.emitter = (self.unit,) + self._new_shape_emitter(dyn, rec)
        _, em, nf = got
        inside = np.zeros(0, np.int64)
        if em is not None and rec.on_surface:
            on = _in_set(self.patch, rec.roots) & (self.normals @ nf > 0.999)
            on &= np.abs((self.points - rec.c) @ nf) <= max(rec.tol, 10 * self.eps)
            c = np.flatnonzero(on)
            if len(c):
                inside = c[_in_rings(dyn._to2d(rec, self.points[c]), rec.rings2d)]
        return em, inside, nf

    def _new_shape_emitter(self, dyn, rec):
        """(Emitter or None, emitting normal) of a light shape: the same for every level of a
        gather (their unit is the system's), so it is kept on the shape's record."""
        import zlib

        # the shape's own random stream, from its outline relative to the scene's box: the same
        # outline gives the same shadow rays at any scene scale or position
        stream = zlib.crc32(b"".join(position_keys(r, self.unit).tobytes() for r in rec.rings)) & 0x7FFFFFFF

        whole = rec.covered >= 1 - 1e-9 or not rec.on_surface
        if rec.on_surface and whole and len(rec.roots):
            # wholly on surfaces: the emitting region is the outline itself; its few slabs
            # instead of its pieces on every patch below it (hundreds on a finely meshed
            # wall) make the shadow rays' sampling cheap (the same region, uniform in solid
            # angle)
            nf = self.system.patches.normal[rec.roots[0]]  # as FirstBounce.pieces
            corners, nv, area = slab_pieces(rec, nf)
        elif rec.on_surface:
            # partly on surfaces: the outline's part on them, cut along the outline of the
            # covered patches' union only (AUTO's first bounce cuts along every patch's edges)
            pt = self.system.patches
            nf = pt.normal[rec.roots[0]] if len(rec.roots) else rec.n
            corners, nv, area = np.zeros((0, 4, 3)), np.zeros(0, int), np.zeros(0)
            if len(rec.roots):
                corners, nv, area = slab_pieces(rec, nf, to2d(rec, pt.corners[rec.roots]), merge=True)
        else:
            nf = rec.n
            corners, nv, area = slab_pieces(rec, nf)
        if len(corners) == 0:
            return None, nf
        rings = None
        if whole:
            rings = [r if (newell(r) @ nf > 0) == (i == 0) else r[::-1] for i, r in enumerate(rec.rings)]
        em = Emitter(corners, nv, area, np.repeat(nf[None], len(corners), 0), rings, nf, rec.c, stream=stream)
        return em, nf

    def _shape(self, dyn, rec):
        key = rec.geom_key
        got = self._shape_cache.get(key)
        if got is None:
            em, inside, _ = self._shape_emitter(dyn, rec)
            if em is None:
                D = np.zeros(self.n, np.float32)
            elif (host := self._host_store(rec, em)) is not None:  # (hostvis.ENABLED)
                D = host.light(em)
            elif getattr(self, "_leaf_nodes", None) is not None:  # (final.FinalGather's second level)
                D = self._second_shape(em)
            else:
                D = self.direct_light(em, self.edge_shapes)
            got = (D, inside)
            self._shape_cache[key] = got
        return got

    def _host_store(self, rec, em):
        """The stored visibility toward a light shape's host plane at this level (gather/hostvis.py)
        where hostvis.ENABLED and the shape moves (LightShape.moves) and lies wholly on surfaces
        (its rings known), else None (its shadow rays, as always: a still shape, whose light is
        kept per outline and would pay the store's first read at its only place; a free shape, one
        partly off its surfaces, or the texture output's edge pass for shapes)."""
        from . import hostvis

        if not (hostvis.ENABLED and rec.moves) or em.rings is None or not rec.on_surface:
            return None
        if self.shadow_rays <= 0:
            return None  # (no shadow rays: the form factor alone, as always)
        if self.texel_area is not None and self.edge_shapes:
            return None
        # the host's plane by its patch (the shape's centre may lie off it within rec.tol)
        point = self.system.patches.corners[rec.roots[0]][0] if len(rec.roots) else em.point
        return hostvis.store_for(self, em.normal, point, hostvis.points_for(self))

    # -- Blender lights (issue 20, core/lights.py) -----------------------------------------------------
    def _light(self, rec):
        """(n,) float32 unit direct light of a Blender light (DynamicRadiosity.lights record) at the
        samples, cached per light geometry: area lights through the Emitter path (solid-angle
        sampled shadow rays), the others with core.lights.unit_incident."""
        from .. import lights as lt

        if not hasattr(self, "_light_cache"):
            self._light_cache = {}
        key = rec.geom_key
        got = self._light_cache.get(key)
        if got is None:
            import zlib

            L = rec.light
            stream = zlib.crc32(repr(key).encode()) & 0x7FFFFFFF
            leaf_nodes = getattr(self, "_leaf_nodes", None)
            if leaf_nodes is not None:
                used, k2 = leaf_nodes
                v = lt.node_incident(
                    self.system.h,
                    used,
                    L,
                    self.system.backend,
                    self.eps,
                    rays=max(self.shadow_rays // 4, 4),
                    seed=self.seed,
                    unit=self.unit,
                    far=self.tmax,
                )
                got = np.repeat(v, k2).astype(np.float32)
                got[self.dark] = 0.0
            elif L.kind == "AREA":
                em = lt.area_emitter(L, stream)
                got = self.direct_light(em) * np.float32(lt.AREA_RADIANCE / max(L.area, 1e-300))
            else:
                got = np.zeros(self.n)
                ok = np.flatnonzero(~self.dark)
                rays = max(self.shadow_rays // 4, 4)
                if (L.kind in ("POINT", "SPOT") and L.radius > 0) or (L.kind == "SUN" and L.angle > 0):
                    # a light with a size: the output's own shadow rays, as a light shape's (4 rays read
                    # a penumbra's visible share in quarters: the loft's shelf item under the lamp
                    # shade's rim, exactly 0.36 / 0.19 of the bulb in sight, read 2 / 4 and 1 / 4 at its
                    # corners, +36% over its face; session 36)
                    rays = max(self.shadow_rays, rays)
                portal = None
                if L.kind == "SKY":  # where the sky gets in, from all the samples' rays: the same
                    # guiding rays for a sample in any batching
                    from ..sky import RAY_FACTOR, escape_map

                    portal = escape_map(
                        self.points[ok],
                        self.normals[ok],
                        self.system.backend,
                        self.eps,
                        rays * RAY_FACTOR,
                        self.seed,
                        self.keys[ok],
                        stream,
                        self.tmax,
                    )

                def part(a, b):  # the samples' own keys: any batching gives the same rays
                    i = ok[a:b]
                    got[i] = lt.unit_incident(
                        L,
                        self.points[i],
                        self.normals[i],
                        self.system.backend,
                        self.eps,
                        rays=rays,
                        seed=self.seed,
                        keys=self.keys[i],
                        stream=stream,
                        far=self.tmax,
                        portal=portal,
                    )

                batch_map(part, ranges(len(ok), self.batch_rays // rays), self.threads)
                if self.texel_area is not None and L.kind != "SKY":
                    got = edge_direct(self, L, got, rays, stream)
                got = got.astype(np.float32)
            self._light_cache[key] = got
            # keep the lights of the current and a few recent geometries
            for k in list(self._light_cache)[: max(len(self._light_cache) - 16, 0)]:
                del self._light_cache[k]
        return got

    def direct_and_emission(self, dyn, direct=True):
        """(D (n, 3) direct light, E (n, 3) emission at the points) of the current emitters; D None
        with direct=False (the cached responses hold it: FinalGather._incident_by_response)."""
        D = self.direct_static().copy() if direct else None
        E = self.E_static.copy()
        for rec in dyn.lights.values() if direct else ():
            D += self._light(rec)[:, None] * rec.scale[None]
        for rec in dyn.shapes.values():
            if rec.preview is not None:  # Live during a drag (FinalGather._preview_shape)
                Ds, inside = self._preview_shape(dyn, rec)
            else:
                Ds, inside = self._shape(dyn, rec)
            if direct:
                D += Ds[:, None] * rec.emission[None]
            E[inside] += rec.emission[None]
        self.forget_shapes(dyn)
        return D, E

    def forget_shapes(self, dyn):
        """Forget the direct light of shapes gone for good (a few recent ones are kept: a shape
        toggled back is instant)."""
        live = {rec.geom_key for rec in dyn.shapes.values() if rec.preview is None}
        gone = [k for k in self._shape_cache if k not in live]
        for k in gone[: max(len(gone) - 8, 0)]:
            del self._shape_cache[k]
