"""Per-frame texel plans and the image sequences written from them (no bpy).

A TexturePlan is made once per bake (geometry is static during a bake): for every object, which
texels its UV triangles cover (raster.py), the surface point and patch of each, and the dilation
steps. Each frame the solution is evaluated at all points at once (core.texels) and every object's
image is written (io.images) into the bake's temporary cache directory, as
textures/<stem>_<frame:06d>.exr|.png. Frames whose light state is unchanged are hard links of the
previous frame's files, so the sequence has one file per frame number and Blender can play it.
"""

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..core.lights import indirect_incident
from ..core.texels import TexelLocator, solution_radiance
from ..io.cache import TEX_DIR, CacheError, CacheReader
from ..io.files import atomic_write, link_or_copy
from ..io.images import encode_exr, encode_png16, image_file_problem
from . import TextureError
from .raster import dilation_steps, rasterise, ring_sources

FORMATS = {"EXR": ".exr", "PNG": ".png"}
REP_BLOCK = 4  # texels of a REP_BLOCK x REP_BLOCK block start their leaf search from one of them


# A texture bake's peak memory (RSS) per texel its final gather gathers (TexturePlan.gathered: the
# texels an image shows their own value at) at 128 hemisphere rays, above what the process held
# before the plan, from the plan to the first frame's images (the gather at both levels, its
# precompute written, a frame evaluated): real bakes at draft, session 32 (branch texmem,
# docs/scale.md): the furnished room 2.07-2.16 kB, two_rooms 2.07-2.14 kB on main, 1.83 and 1.70 kB
# after that branch's cuts; rounded up (texels in slots gather more samples). Sessions 19-31
# counted 2-6 kB per texel of the plan, ring texels included.
GATHERED_BYTES = 2000
# what a texture bake's process holds before the plan (Blender, the scene, the hierarchy): 0.57 GB
# on the furnished room (11,645 polygons), 0.67 GB on two_rooms (13,818): 0.62 and 0.64 by these
BAKE_FIXED_BYTES = 500_000_000
POLYGON_BYTES = 10_000
# the texels a bake gathers per texel of surface at the density its lightmap is sized at: the
# surface's own and the ring texels that an image does not write from inside ones (two_rooms:
# 1.03 on lightmaps of 128 texels and more, 1.18-1.24 on the smaller ones; 1.06 in all)
RING_SHARE = 1.25


def gather_bytes(gathered, rays=128):
    """About how much memory a texture bake takes for `gathered` texels (GATHERED_BYTES each,
    the gather's weights growing with its rays) above what it held before its plan."""
    return int(gathered * GATHERED_BYTES * max(rays, 1) / 128)


def gathered_estimate(area, size, density):
    """(k,) about how many texels a bake gathers on objects of surface `area` (k,) (NaN: unknown)
    whose lightmaps are `size` (k,) texels wide, sized at `density` texels per unit: the surface at
    that density and its ring (RING_SHARE), at most the whole image (an object capped by the
    Texture Size, or whose area is unknown: its own Lightmap Size; density 0: every image)."""
    full = np.asarray(size, np.float64) ** 2
    if density <= 0:
        return full
    est = RING_SHARE * np.asarray(area, np.float64) * float(density) ** 2
    return np.where(np.isnan(est), full, np.minimum(est, full))


def bake_bytes(gathered, polygons=0, rays=128):
    """About a texture bake's peak memory: Blender, the scene and its hierarchy (BAKE_FIXED_BYTES,
    POLYGON_BYTES per polygon), then gather_bytes(gathered, rays)."""
    return int(BAKE_FIXED_BYTES + polygons * POLYGON_BYTES) + gather_bytes(gathered, rays)


def bounded_density(fit, density, budget, polygons=0, lowest=0.01, steps=8):
    """(density, fits, texels asked, texels): the highest density, about, at which a texture bake's
    estimated peak (bake_bytes of the gathered_estimate of fit(d)'s objects, and the scene's
    polygons) stays within `budget` bytes: `density` itself when it does, else lowered in a few
    steps, each from the last estimate (texels grow about as density^2), not below `lowest`.
    fit(d) -> (sizes (k,), areas (k,)) of the objects at density d; fits: fit(density found);
    texels: gathered_estimate's sum asked at `density` and at the density found."""
    got = fit(density)
    asked = total = float(gathered_estimate(got[1], got[0], density).sum())
    fixed = bake_bytes(0, polygons)
    d = density
    for _ in range(steps if density > 0 else 0):
        if bake_bytes(total, polygons) <= budget or d <= lowest:
            break
        room = max(budget - fixed, 0) / max(bake_bytes(total, polygons) - fixed, 1)
        d = max(d * float(np.sqrt(room)) * 0.995, lowest)
        got = fit(d)
        total = float(gathered_estimate(got[1], got[0], d).sum())
    return d, got, asked, total


class ObjectTexels:
    """Where one object's texels are: flat texel indices, their slice of the plan's points."""

    def __init__(self, name, res, stem, texel, inside, lo, hi, steps, uv_digest, ring=None):
        self.name, self.res, self.stem = name, res, stem
        self.texel, self.inside = texel, inside
        self.lo, self.hi = lo, hi  # slice of the concatenated points
        self.steps = steps
        self.uv_digest = uv_digest
        self.ring = ring  # raster.ring_sources: the ring texels' values from the inside ones

    def image(self, values):
        """(res, res, 3) float32 image of the values at the texels, the ring texels' from the inside
        texels next to them, dilated."""
        img = np.zeros((self.res * self.res, 3), np.float32)
        img[self.texel] = values
        if self.ring is not None and len(self.ring[0]):
            ring, i1, i2, w = self.ring
            v1, v2 = img[self.texel[i1]], img[self.texel[i2]]
            img[self.texel[ring]] = np.maximum(v1 + w[:, None].astype(np.float32) * (v1 - v2), 0)
        for dst, inv, src, w in self.steps:
            for ch in range(3):
                img[dst, ch] = np.bincount(inv, w * img[src, ch], len(dst))
        return img.reshape(self.res, self.res, 3)


def texel_axes(tri_uv, corners, res):
    """(T, 2, 3) world vectors of one texel step in u and in v on each triangle (UV tri_uv (T, 3, 2),
    corners (T, 3, 3)): the texel's footprint, which texels straddling a contact gather over."""
    uv = np.asarray(tri_uv, np.float64)
    c = np.asarray(corners, np.float64)
    U = np.stack([uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], 2)  # (T, 2, 2) columns: edges in uv
    E = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], 2)  # (T, 3, 2) the same edges in space
    det = U[:, 0, 0] * U[:, 1, 1] - U[:, 0, 1] * U[:, 1, 0]
    ok = np.abs(det) > 1e-15
    inv = np.stack([np.stack([U[:, 1, 1], -U[:, 0, 1]], 1), np.stack([-U[:, 1, 0], U[:, 0, 0]], 1)], 1)
    inv /= np.where(ok, det, 1.0)[:, None, None]
    J = np.einsum("tik,tkj->tij", E, inv) * ok[:, None, None]  # (T, 3, 2) d(world) / d(uv)
    return np.swapaxes(J, 1, 2) / res


def frame_file(stem, frame, ext):
    return f"{stem}_{frame:06d}{ext}"


def triangle_uvs(patches, oid, uv, loop_start, loop_total, loop_verts, poly0, vert0, n_verts, loops=False):
    """UVs (T, 3, 2), corners (T, 3, 3) and patch (T,) of the triangles of object `oid`'s patches
    (quads: two triangles), each corner's UV that of the same (polygon, vertex) of the object's
    mesh (loops; poly0 / vert0: the object's first polygon / vertex in the scene), and the number
    of triangles skipped because a corner has no such loop. loops: also return the corners' loops
    (T, 3) of the object's mesh (to interpolate its other UV maps), last."""
    lpoly = np.repeat(np.arange(len(loop_start)), loop_total)
    key = lpoly * (n_verts + 1) + loop_verts
    ko = np.argsort(key, kind="stable")
    sel = np.flatnonzero(patches.object_id == oid)
    nv = patches.nv[sel]
    quad = nv == 4
    tri_rows = np.concatenate([sel, sel[quad]])
    tri_c = np.concatenate([np.tile([0, 1, 2], (len(sel), 1)), np.tile([0, 2, 3], (int(quad.sum()), 1))])
    rows = np.concatenate([np.arange(len(sel)), np.flatnonzero(quad)])
    corners = patches.corners[tri_rows[:, None], tri_c]
    corner_vert = patches.vert_index[sel][rows[:, None], tri_c] - vert0
    ck = (patches.poly[tri_rows] - poly0)[:, None] * (n_verts + 1) + corner_vert
    pos = np.clip(np.searchsorted(key[ko], ck), 0, max(len(ko) - 1, 0))
    good = (key[ko][pos] == ck).all(1) if len(ko) else np.zeros(len(ck), bool)
    tri_uv = np.asarray(uv, np.float64)[ko[pos]] if len(ko) else np.zeros((len(ck), 3, 2))
    out = tri_uv[good], corners[good], tri_rows[good], int((~good).sum())
    if loops:
        out += ((ko[pos] if len(ko) else np.zeros((len(ck), 3), np.int64))[good],)
    return out


class TexturePlan:
    """Texel plans of every object of a texture bake, and the files of its frames."""

    def __init__(self, fmt="EXR"):
        fmt = fmt.upper()
        if fmt not in FORMATS:
            raise TextureError(f"Unknown texture format '{fmt}' (EXR or PNG).")
        self.fmt, self.ext = fmt, FORMATS[fmt]
        self.objects = []
        self.warnings = []
        self.tmp = None
        self.files = {}  # frame -> True once written / linked
        self._parts = []  # per object: (points, patches, representatives)
        # per object: (T, 2, 3) the texels' sides on each of its triangles, (T, 3, 3) the triangles'
        # corners in the order of Blender's loop triangles (a quad's (0, 1, 2), (0, 2, 3)), inside
        # which Cycles' bake samples a texel, and (N,) int32 each texel's triangle: per triangle,
        # not per texel (120 bytes a texel held through the bake for the gather's one read)
        self._tri = []
        self._locator = None
        self._gathered = None
        self.albedo = {}  # object index -> (N, 3) float32 texture albedo / average at its texels

    def add_object(self, name, stem, res, tri_uv, corners, tri_patch, uv_digest):
        """Plan the texels of one object's triangles (from triangle_uvs) in a res x res image.
        Returns each texel's triangle (N,) and barycentric coordinates (N, 3) (see set_albedo)."""
        texel, tri, bary, inside = rasterise(tri_uv, res)
        own = tri_patch[tri]
        # representative texel: the one at the corner of its block, if it lies in the same patch
        dense = np.full(res * res, -1, np.int64)
        dense[texel] = np.arange(len(texel))
        x, y = texel % res, texel // res
        r = dense[(y - y % REP_BLOCK) * res + (x - x % REP_BLOCK)]
        r = np.where((r >= 0) & (own[np.maximum(r, 0)] == own), r, np.arange(len(texel)))
        n = self.objects[-1].hi if self.objects else 0
        self._parts.append((np.einsum("nk,nkj->nj", bary, corners[tri]), own.astype(np.int64), r + n))
        self._tri.append((texel_axes(tri_uv, corners, res), corners, tri.astype(np.int32)))
        edge = np.einsum("nk,nkj->nj", bary, np.asarray(tri_uv, np.float64)[tri] * res - 0.5)
        steps, ring = dilation_steps(texel, res), ring_sources(texel, inside, edge, res)
        o = ObjectTexels(name, res, stem, texel, inside, n, n + len(texel), steps, uv_digest, ring)
        self.objects.append(o)
        self._locator = None
        self._gathered = None
        return tri, bary

    @property
    def texels(self):
        """Texels of all objects (the points the output evaluates)."""
        return self.objects[-1].hi if self.objects else 0

    @property
    def gathered(self):
        """(G,) indices of the texels whose own value the images show: every texel but the ring
        texels that ObjectTexels.image writes from the inside texels (ring_sources). The final
        gather gathers only these."""
        if self._gathered is None:
            own = np.ones(self.texels, bool)
            for o in self.objects:
                if o.ring is not None:
                    own[o.lo + o.ring[0]] = False
            self._gathered = np.flatnonzero(own)
        return self._gathered

    def _at_texels(self, v):
        """(N, 3) values at every texel from v (G, 3) at the gathered ones (0 at the others: the
        images write those from the inside texels)."""
        if len(v) == self.texels:
            return v
        out = np.zeros((self.texels,) + v.shape[1:], v.dtype)
        out[self.gathered] = v
        return out

    def largest(self, k=5):
        """The k objects with the most texels, most first."""
        return sorted(self.objects, key=lambda o: o.lo - o.hi)[:k]

    def set_albedo(self, index, factor):
        """Object `index`'s texels show their reflected radiance times factor (N, 3): the texture's
        albedo / the average albedo the light exchange used (lightmap.albedo), in radiance mode."""
        o = self.objects[index]
        factor = np.asarray(factor, np.float32)
        if factor.shape != (o.hi - o.lo, 3):
            raise ValueError(f"albedo factor of '{o.name}': shape {factor.shape}, {o.hi - o.lo} texels")
        self.albedo[index] = factor

    @property
    def locator(self):
        """TexelLocator of all objects' texel points (made on first use)."""
        if self._locator is None:
            pts, patch, rep = (
                [np.concatenate(z) for z in zip(*self._parts)]
                if self._parts
                else (np.zeros((0, 3)), np.zeros(0, np.int64), None)
            )
            self._locator = TexelLocator(patch, pts, rep)
        return self._locator

    def final_gather(self, system, **kw):
        """A core.gather.FinalGather at the gathered texels (`gathered`) of all objects (system:
        the DynamicRadiosity or RadiositySystem the bake uses; kw: rays, shadow_rays, seed): built
        once per geometry, handed to radiance(gather=). Each texel's samples and rays are its own,
        so the others' values are those of a gather at every texel."""
        from ..core.gather import texel_gather

        g = self.gathered
        if kw.get("rho") is not None and np.ndim(kw["rho"]) == 2:  # per texel
            kw["rho"] = np.asarray(kw["rho"])[g]
        pts, patch, axes, tris = self.texel_geometry(g)
        return texel_gather(system, patch, pts, axes=axes, tris=tris, **kw)

    def texel_geometry(self, texels=None):
        """(points (k, 3), patch (k,), sides (k, 2, 3), triangles (k, 3, 3)) of the texels (sorted
        indices into the plan's points; None: all), object by object without the locator (the
        gather locates its own samples). sides: texel_axes; triangles: the triangle of the
        texel's centre, corners in Blender's loop-triangle order."""
        if not self.objects:
            return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros((0, 2, 3)), np.zeros((0, 3, 3))
        t = np.arange(self.texels) if texels is None else np.asarray(texels)
        bounds = np.searchsorted(t, [o.lo for o in self.objects] + [self.texels])
        cut = [t[a:b] - o.lo for o, a, b in zip(self.objects, bounds[:-1], bounds[1:])]
        pts = np.concatenate([p[0][k] for p, k in zip(self._parts, cut)])
        patch = np.concatenate([p[1][k] for p, k in zip(self._parts, cut)])
        axes = np.concatenate([a[i[k]] for (a, _, i), k in zip(self._tri, cut)])
        tris = np.concatenate([c[i[k]] for (_, c, i), k in zip(self._tri, cut)])
        return pts, patch, axes, tris

    def radiance(self, solution, mode="RADIANCE", gather=None):
        """(N, 3) values of the current solution at the texel points of all objects. mode RADIANCE:
        outgoing radiance, reflected part times the albedo factor where set_albedo gave one, i.e.
        reflected x albedo / average + emission; IRRADIANCE: irradiance / pi (no emission);
        INDIRECT: irradiance / pi without the Blender lights' and the World's direct light
        (core.lights.indirect_incident; needs the gather).
        gather: final_gather() of this plan: the texels gather their own light (issue 19), 0 at
        the ring texels not gathered (`gathered`: ObjectTexels.image writes them); None: the
        solution's leaves, interpolated (today's output, unchanged)."""
        if mode == "INDIRECT":
            if gather is None:
                raise ValueError("the Indirect-only values need the final gather")
            return self._at_texels(indirect_incident(gather, solution).astype(np.float32))
        if gather is not None:
            if mode == "IRRADIANCE":
                return self._at_texels(gather.evaluate(solution, "incident").astype(np.float32))
            v = gather.evaluate_kinds(solution, ("radiance", "reflected") if self.albedo else ("radiance",))
            out = self._at_texels(v["radiance"])
            if self.albedo:
                refl = self._at_texels(v["reflected"])
                for i, f in self.albedo.items():
                    o = self.objects[i]
                    out[o.lo : o.hi] += (f - 1.0) * refl[o.lo : o.hi]
            return out.astype(np.float32)
        loc = self.locator
        if mode == "IRRADIANCE":
            return solution_radiance(solution, loc.patch, loc.points, loc, kind="incident")
        out = solution_radiance(solution, loc.patch, loc.points, loc)
        if self.albedo:
            refl = solution_radiance(solution, loc.patch, loc.points, loc, kind="reflected")
            for i, f in self.albedo.items():
                o = self.objects[i]
                out[o.lo : o.hi] += (f - 1.0) * refl[o.lo : o.hi]
        return out

    # cache manifest entries
    def objects_info(self, targets):
        mesh_of = {t.name: t.mesh_name for t in targets}
        return {
            o.name: {
                "mesh": mesh_of[o.name],
                "count": 0,
                "resolution": o.res,
                "format": self.fmt,
                "texture": f"{TEX_DIR}/{o.stem}_%06d{self.ext}",
                "uv": o.uv_digest,  # the lightmap UVs baked on: a file that lost them can check them
            }
            for o in self.objects
        }

    def signature(self, base):
        h = hashlib.sha1(base.encode())
        for o in self.objects:
            h.update(f"{o.name}|{o.res}|{self.fmt}|{o.uv_digest}".encode())
        for i in sorted(self.albedo):  # textured materials: their texels' colours
            h.update(f"albedo {i}".encode() + self.albedo[i].tobytes())
        return h.hexdigest()

    def bind(self, tmp_dir):
        self.tmp = os.path.join(str(tmp_dir), TEX_DIR)
        os.makedirs(self.tmp, exist_ok=True)

    def _path(self, o, frame, root=None):
        return os.path.join(root or self.tmp, frame_file(o.stem, frame, self.ext))

    def write(self, frame, values):
        """values (N, 3) at the plan's points (all objects); files encoded in parallel (zlib frees
        the GIL)."""

        def one(o):
            img = o.image(values[o.lo : o.hi])
            atomic_write(self._path(o, frame), encode_exr(img) if self.fmt == "EXR" else encode_png16(img))

        workers = max(1, min(len(self.objects), os.cpu_count() or 1, 8))
        if workers == 1:
            for o in self.objects:
                one(o)
        else:
            with ThreadPoolExecutor(workers) as pool:
                for fut in [pool.submit(one, o) for o in self.objects]:
                    fut.result()
        self.files[int(frame)] = True

    def reuse(self, frame, prev_frame):
        for o in self.objects:
            link_or_copy(self._path(o, prev_frame), self._path(o, frame))
        self.files[int(frame)] = True

    def damaged_frames(self, final_dir, frames):
        """{frame: problem} of `frames` of the previous bake in final_dir whose texture files are
        missing or damaged (checked as image_file_problem does: structure, not pixels)."""
        src_dir = os.path.join(str(final_dir), TEX_DIR)
        out = {}
        for f in sorted(frames):
            for o in self.objects:
                why = image_file_problem(self._path(o, f, src_dir), o.res)
                if why:
                    out[f] = f"{os.path.basename(self._path(o, f, src_dir))} {why}"
                    break
        return out

    def finish(self, writer):
        """Before writer.commit(): bring over the texture files of the previous bake's frames that the
        commit keeps, and fill every frame number of the sequence (gaps hold the frame before; the
        number before the first frame, which Blender asks for before the start, holds the first)."""
        frames = set(self.files)
        try:
            old = CacheReader(writer.final)
            m = old.manifest
            same = (
                m.get("signature") == writer.signature
                and m.get("domain") == writer.domain
                and m.get("objects") == writer.objects
            )
        except CacheError:
            same = False
        if same:
            src_dir = os.path.join(str(writer.final), TEX_DIR)
            for f in sorted(old.frames):
                if f in frames:
                    continue
                srcs = [self._path(o, f, src_dir) for o in self.objects]
                if all(os.path.isfile(s) for s in srcs):
                    for o, s in zip(self.objects, srcs):
                        link_or_copy(s, self._path(o, f))
                    frames.add(f)
        if not frames:
            return
        first, last = min(frames), max(frames)
        prev = first
        for f in range(first, last + 1):
            if f in frames:
                prev = f
                continue
            for o in self.objects:
                link_or_copy(self._path(o, prev), self._path(o, f))
        if first >= 1:
            for o in self.objects:
                link_or_copy(self._path(o, first), self._path(o, first - 1))
