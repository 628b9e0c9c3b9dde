"""Final gather: the output stage of issue 19 (numpy only; rays through the visibility backends).

Every output sample (a welded vertex / corner, or a texel centre) computes its own incident light
instead of reading the hierarchy leaf it lies in:

    out = E_point + rho_point x (D + I)          radiance, linear RGB, per channel

- D, direct light, exact: for every emitter (the input's emissive patches, the current light
  shapes) the point-to-polygon form factor (formfactor.py's contour integral; light shapes as
  their outline with holes, or their convex pieces with horizon clipping) times a visibility ratio
  from shadow rays toward stratified points on the emitter (kernel-weighted, as AUTO's first
  bounce in events/direct.py), times the emitter's radiance. Cached per emitter and sample at unit
  radiance, so a strength or colour change is a scale; a shape's D is computed only at samples in
  front of its plane that face it.
- I, indirect light: R cosine-weighted hemisphere rays per sample, traced once per static
  geometry (first_hit), each hit recorded on the hierarchy leaf holding it; per sample a sparse CSR
  row of weights over those leaves (hits / R, duplicates merged; rays that escape, hit a back face
  or a covered point contribute nothing). At run time I = W @ (reflected radiance of the solution
  at the leaves): B - E (the node's own, possibly fractional, emission is taken out: the exact
  direct term carries all emission), shown on the node's uncovered part (Hierarchy.shown).
- E_point: the emitter's own radiance exactly at the point: the input patch's emission, plus a
  light shape's radiance inside its outline (point in polygon with holes, on the surface it lies
  on); outside the outline 0, whatever fraction of it the coarse nodes carry for transport.
- Points Hierarchy.dark() calls covered (contacts) output exactly 0.

Where the hits are recorded. Weights are kept on the leaves of the hierarchy as built (the HR
leaves, node ids below DynamicRadiosity.n_hr). Light events add nodes only below those leaves and
delete only nodes they added, so the HR ids never move (DynamicRadiosity._gc asserts it) and the
weights stay valid for the system's lifetime with no re-location per frame. When an event has split
an HR leaf, the leaf's value is the area mean of its current sub-leaves' reflected radiance. What
that gives up: detail of the reflected light below an HR leaf (AR/FE sub-nodes carry no links, so
their reflected radiance is the parent's anyway; AUTO's first bounce on split receivers is
averaged over the HR leaf). Each gather reads hundreds of leaves, so this averaging is far below the
ray noise. Under NAIVE (a rebuilt system, other patches) each HR leaf reads the rebuilt solution at
its 2 x 2 Gauss points.

Randomness is a fixed pattern per sample: Hammersley points rotated (Cranley-Patterson) by a hash
of (seed, sample index, stream), so results do not depend on batching or thread count. The
precompute and the direct light work in independent batches over sample ranges
(`gather_batch`, `direct_batch`) whose partial results are merged; ~1 M rays per batch.
"""

from dataclasses import dataclass

import numpy as np

from . import formfactor as ff
from .geometry import isolated_objects, newell
from .events.direct import _contour
from .visibility import first_hit_within
from .output import _insideness

KINDS = ("radiance", "reflected", "incident")
_GOLD = np.uint64(0x9E3779B97F4A7C15)


# ---------------------------------------------------------------------------------------------- random


def _mix(x):
    """splitmix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    x = x ^ (x >> np.uint64(30))
    x = x * np.uint64(0xBF58476D1CE4E5B9)
    x = x ^ (x >> np.uint64(27))
    x = x * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def hash_uniform(seed, index, stream, k=2):
    """(len(index), k) uniforms in [0, 1) from (seed, index, stream): the same for a sample whatever
    batch it is computed in."""
    with np.errstate(over="ignore"):
        base = _mix(np.uint64(seed & 0xFFFFFFFF) * _GOLD + np.uint64(stream & 0xFFFFFFFF))
        x = np.asarray(index, np.uint64)[:, None] * _GOLD + base + np.arange(k, dtype=np.uint64)[None] * _GOLD
        x = _mix(_mix(x))
    return (x >> np.uint64(11)).astype(np.float64) * 2.0**-53


def position_keys(points, unit):
    """uint64 keys of points (n, 3) quantised to `unit`: a sample's random stream follows where it
    is, not its index, so adding or reordering objects elsewhere leaves its rays alone."""
    q = np.floor(np.asarray(points, np.float64) / unit).astype(np.int64).view(np.uint64)
    with np.errstate(over="ignore"):
        return _mix(_mix(_mix(q[:, 0]) + q[:, 1]) + q[:, 2])


def hammersley(n):
    """(n, 2) Hammersley points: ((i + 0.5) / n, radical inverse base 2 of i)."""
    i = np.arange(n, dtype=np.uint64)
    r = np.zeros(n)
    f, b = 0.5, i.copy()
    while b.any():
        r += f * (b & np.uint64(1))
        b >>= np.uint64(1)
        f /= 2
    return np.column_stack([(np.arange(n) + 0.5) / n, r])


def _frame(n):
    """Orthonormal tangents (t, b) of unit normals n (N, 3) (Duff et al. 2017, branchless)."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.column_stack([1 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]])
    bb = np.column_stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]])
    return t, bb


def cosine_directions(normals, index, rays, seed, stream=0):
    """(N, rays, 3) cosine-weighted unit directions about normals (N, 3): a Hammersley pattern
    rotated per sample by hash_uniform(seed, index)."""
    u = (hammersley(rays)[None] + hash_uniform(seed, index, stream)[:, None]) % 1.0  # (N, R, 2)
    r = np.sqrt(u[..., 0])
    phi = 2 * np.pi * u[..., 1]
    z = np.sqrt(np.maximum(1 - u[..., 0], 0))
    t, b = _frame(normals)
    return (
        (r * np.cos(phi))[..., None] * t[:, None]
        + (r * np.sin(phi))[..., None] * b[:, None]
        + z[..., None] * normals[:, None]
    )


# ---------------------------------------------------------------------------------------------- helpers


def _triple(e, w, n):
    """det[e, w, n] = (e x w) . n, rows (m, 3)."""
    return (
        (e[:, 1] * w[:, 2] - e[:, 2] * w[:, 1]) * n[:, 0]
        + (e[:, 2] * w[:, 0] - e[:, 0] * w[:, 2]) * n[:, 1]
        + (e[:, 0] * w[:, 1] - e[:, 1] * w[:, 0]) * n[:, 2]
    )


def locate_below(h, patch, points, n_hr):
    """The HR leaf holding each point (M,) <- patch (M,), points (M, 3): the leaf of the first
    n_hr nodes (nodes whose children were added later, by light events, count as leaves).

    Children of a quad are the bilinear images of the parameter square's quarters, split by the
    straight lines from edge midpoint to edge midpoint; children of a triangle are its corner
    triangles and the middle one. So one level costs two (quads) or three (triangles) side tests
    against those lines instead of output.locate's test against every child's edges; ties on a
    line go to either side, as locate's."""
    node = np.asarray(patch, np.int64).copy()
    pts = np.asarray(points, float)
    while True:
        c0 = h.child0[node]
        inner = np.flatnonzero((c0 >= 0) & (c0 < n_hr))
        if len(inner) == 0:
            return node
        nd = node[inner]
        c = h.corners[nd]
        n = h.normal[nd]
        p = pts[inner]
        a, b, cc, d = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
        ab, bc, cd, da, ca = (a + b) / 2, (b + cc) / 2, (cc + d) / 2, (d + a) / 2, (cc + a) / 2
        k = np.zeros(len(nd), np.int64)
        quad = h.nv[nd] == 4
        q = np.flatnonzero(quad)
        if len(q):
            # line ab -> cd separates u < 1/2 (a's side) from u > 1/2; line da -> bc: v
            e1 = cd[q] - ab[q]
            right = _triple(e1, p[q] - ab[q], n[q]) * _triple(e1, a[q] - ab[q], n[q]) < 0
            e2 = bc[q] - da[q]
            top = _triple(e2, p[q] - da[q], n[q]) * _triple(e2, a[q] - da[q], n[q]) < 0
            k[q] = np.where(top, np.where(right, 2, 3), np.where(right, 1, 0))
        t = np.flatnonzero(~quad)
        if len(t):
            nn = n[t]
            pt_ = p[t]

            def corner_side(m0, m1, corner):
                e = m1 - m0
                return _triple(e, pt_ - m0, nn) * _triple(e, corner - m0, nn) > 0

            in_a = corner_side(ab[t], ca[t], a[t])
            in_b = corner_side(ab[t], bc[t], b[t])
            in_c = corner_side(ca[t], bc[t], cc[t])
            k[t] = np.where(in_a, 0, np.where(in_b, 1, np.where(in_c, 2, 3)))
        node[inner] = c0[inner] + k


def _into_patch(pt, patch, p, margin):
    """Points (M, 3) in their patches' planes moved to at least `margin` inside their patch: points
    beyond its outline (a lightmap's dilation ring) to the nearest point of it, then those closer
    than margin to it (texels and vertices on an edge where two surfaces meet: rays from there
    would start on the other surface and pass through it) towards the patch's centre."""
    c = pt.corners[patch]
    d = _insideness(c[:, None], pt.normal[patch][:, None], p)[:, 0]
    size = np.sqrt(pt.area[patch])
    p = p.copy()
    out = np.flatnonzero(d < 0)
    if len(out):
        q, cc = p[out], c[out]
        a, b = cc, np.roll(cc, -1, axis=1)
        ab = b - a
        t = np.einsum("mkj,mkj->mk", q[:, None] - a, ab) / np.maximum(
            np.einsum("mkj,mkj->mk", ab, ab), 1e-300
        )
        near = a + np.clip(t, 0, 1)[..., None] * ab
        k = np.argmin(np.linalg.norm(near - q[:, None], axis=-1), axis=1)
        p[out] = near[np.arange(len(out)), k]
        d[out] = 0.0
    close = np.flatnonzero(d < margin)
    if len(close):
        nv = pt.nv[patch[close]]
        cc = c[close]
        centre = np.where((nv == 4)[:, None], cc.mean(1), cc[:, :3].mean(1))
        to = centre - p[close]
        # the inradius-like distance of the centre bounds how far moving towards it can go
        dc = _insideness(cc[:, None], pt.normal[patch[close]][:, None], centre)[:, 0]
        f = np.clip((margin - d[close]) / np.maximum(dc - d[close], 1e-300), 0, 0.5)
        f = np.where(margin < 0.25 * size[close], f, np.minimum(f, 1e-3))
        p[close] += f[:, None] * to
    return p


def _csr_matvec(indptr, cols, w, V, chunk=1 << 22):
    """(n, C) float64 = W @ V for a CSR matrix (indptr, cols, w float32) and dense V (m, C): float32
    products summed per row by np.add.reduceat, in blocks of about `chunk` entries."""
    n = len(indptr) - 1
    out = np.zeros((n, V.shape[1]))
    if len(cols) == 0:
        return out
    V32 = np.ascontiguousarray(V, dtype=np.float32)
    r0 = 0
    while r0 < n:
        r1 = int(np.searchsorted(indptr, indptr[r0] + chunk, "right")) - 1
        r1 = min(max(r1, r0 + 1), n)
        a, b = indptr[r0], indptr[r1]
        if b > a:
            prod = V32[cols[a:b]]
            prod *= w[a:b, None]
            starts = indptr[r0:r1] - a
            nonempty = np.flatnonzero(indptr[r0 + 1 : r1 + 1] > indptr[r0:r1])
            out[r0 + nonempty] = np.add.reduceat(prod, starts[nonempty], axis=0)
        r0 = r1
    return out


def _unit_rows(v):
    return v / np.maximum(np.sqrt(np.einsum("...k,...k->...", v, v)), 1e-300)[..., None]


def solid_angles(A, B, C):
    """Solid angles (...) of the triangles with unit vertex directions A, B, C (..., 3)
    (Van Oosterom & Strackee 1983)."""
    num = np.abs(np.einsum("...k,...k->...", A, ff._cross(B, C)))
    den = 1 + np.einsum("...k,...k->...", A, B) + np.einsum("...k,...k->...", B, C)
    den += np.einsum("...k,...k->...", C, A)
    return 2 * np.arctan2(num, den)


def spherical_setup(A, B, C):
    """What Arvo's sampling of the spherical triangles A, B, C (N, 3) needs that does not depend
    on the sample: (the angle at A, A . B, the unit direction of C orthogonal to A), (N,), (N,),
    (N, 3). Computed once per point and triangle, shared by all of its shadow rays."""
    dot = lambda x, y: np.einsum("nk,nk->n", x, y)
    # the angle at A between the great circles AB and AC
    alpha = np.arccos(np.clip(dot(_unit_rows(ff._cross(A, B)), _unit_rows(ff._cross(A, C))), -1, 1))
    return alpha, dot(A, B), _unit_rows(C - dot(C, A)[:, None] * A)


def sample_spherical_triangle(A, B, C, u1, u2, area=None, setup=None):
    """Directions uniform in solid angle over spherical triangles A, B, C (N, 3) unit (Arvo 1995);
    area: their solid angles if known (solid_angles); setup: spherical_setup(A, B, C) if known."""
    dot = lambda x, y: np.einsum("nk,nk->n", x, y)
    alpha, ab, c_perp = spherical_setup(A, B, C) if setup is None else setup
    if area is None:
        area = solid_angles(A, B, C)
    ah = u1 * area
    s, t = np.sin(ah - alpha), np.cos(ah - alpha)
    sa, ca = np.sin(alpha), np.cos(alpha)
    u = t - ca
    v = s + sa * ab
    den = (v * s + u * t) * sa
    q = np.clip(((v * t - u * s) * ca - v) / np.where(np.abs(den) > 1e-300, den, 1e-300), -1, 1)
    ch = q[:, None] * A + np.sqrt(np.maximum(1 - q * q, 0))[:, None] * c_perp
    z = 1 - u2 * (1 - dot(ch, B))
    return z[:, None] * B + np.sqrt(np.maximum(1 - z * z, 0))[:, None] * _unit_rows(
        ch - dot(ch, B)[:, None] * B
    )


@dataclass
class Emitter:
    """A polygonal emitter: convex pieces (T, 4, 3) CCW about their own emitting normals, nv (T,),
    areas (T,), normals (T, 3); rings (outer CCW about `normal`, holes CW) when the whole emitter is
    one planar polygon with holes (the contour fast path), else None; `normal`/`point` its plane
    when planar (None otherwise)."""

    corners: np.ndarray
    nv: np.ndarray
    area: np.ndarray
    normals: np.ndarray
    rings: list = None
    normal: np.ndarray = None
    point: np.ndarray = None
    stream: int = 0  # random stream of its shadow rays

    def __post_init__(self):
        # triangles for area-uniform sampling: (0, 1, 2) and, for quads, (0, 2, 3)
        c, nv = self.corners, self.nv
        tri = [c[:, [0, 1, 2]]]
        tn = [self.normals]
        q = np.flatnonzero(nv == 4)
        tri.append(c[q][:, [0, 2, 3]])
        tn.append(self.normals[q])
        self.tri = np.concatenate(tri)
        self.tri_normal = np.concatenate(tn)
        a = 0.5 * np.linalg.norm(
            np.cross(self.tri[:, 1] - self.tri[:, 0], self.tri[:, 2] - self.tri[:, 0]), axis=1
        )
        self.tri_area = a
        self.cdf = np.cumsum(a)
        self.total = float(self.cdf[-1]) if len(a) else 0.0
        self.verts = c.reshape(-1, 3)
        self.lo, self.hi = self.verts.min(0), self.verts.max(0)

    SOLID_MIN = 1e-4  # triangles smaller than this (sr) seen from the point are sampled by area
    MAX_TRIANGLES = 256  # more: area sampling only (the per-point solid angles would cost too much)

    def sample_at(self, x, u):
        """Points (L, S, 3) on the emitter seen from points x (L, 3), their normals and densities
        relative to solid angle: triangles are picked by their solid angle seen from x and sampled
        uniformly in solid angle (Arvo) or, when tiny, by area. Returns (y, ny, pdf_ratio) with
        pdf_ratio = (density in solid angle) x total solid angle: ~1 where sampling is exact."""
        L, S = u.shape[:2]
        T = len(self.tri)
        if T > self.MAX_TRIANGLES:
            y, ny = self.sample(u)
            d = y - x[:, None]
            r2 = np.einsum("lsk,lsk->ls", d, d)
            cos_y = np.abs(np.einsum("lsk,lsk->ls", d, ny)) / np.sqrt(np.maximum(r2, 1e-300))
            # area density 1 / total -> solid-angle density r^2 / (cos_y total); normalised later
            return y, ny, np.maximum(r2, 1e-300) / np.maximum(cos_y, 1e-12) / self.total
        V = _unit_rows(self.tri[None] - x[:, None, None])  # (L, T, 3, 3)
        om = solid_angles(V[..., 0, :], V[..., 1, :], V[..., 2, :])  # (L, T)
        cdf = np.cumsum(om, axis=1)
        tot = np.maximum(cdf[:, -1:], 1e-300)
        xs = u[..., 0] * tot
        k = np.minimum((cdf[:, None, :] <= xs[..., None]).sum(-1), T - 1)  # (L, S)
        lo = np.where(k > 0, np.take_along_axis(cdf, np.maximum(k - 1, 0), 1), 0.0)
        ok_ = np.take_along_axis(om, k, 1)
        s1 = np.clip((xs - lo) / np.maximum(ok_, 1e-300), 0, 1)
        li = np.repeat(np.arange(L), S)
        kk = k.ravel()
        t3 = self.tri[kk]
        big = ok_.ravel() >= self.SOLID_MIN
        y = np.empty((L * S, 3))
        if big.any():
            # the sample-independent part of Arvo's method once per point and triangle
            Vf = V.reshape(L * T, 3, 3)
            alpha, ab, c_perp = spherical_setup(Vf[:, 0], Vf[:, 1], Vf[:, 2])
            j = li[big] * T + kk[big]
            Vb = Vf[j]
            w = sample_spherical_triangle(
                Vb[:, 0],
                Vb[:, 1],
                Vb[:, 2],
                s1.ravel()[big],
                u[..., 1].ravel()[big],
                ok_.ravel()[big],
                setup=(alpha[j], ab[j], c_perp[j]),
            )
            # the point where direction w meets the triangle's plane
            n = self.tri_normal[kk[big]]
            xo = x[li[big]]
            tt = np.einsum("nk,nk->n", t3[big, 0] - xo, n) / np.where(
                np.abs(np.einsum("nk,nk->n", w, n)) > 1e-300, np.einsum("nk,nk->n", w, n), 1e-300
            )
            y[big] = xo + tt[:, None] * w
        small = ~big
        if small.any():
            r1 = np.sqrt(s1.ravel()[small])
            u2 = u[..., 1].ravel()[small]
            tri = t3[small]
            y[small] = (
                (1 - r1)[:, None] * tri[:, 0]
                + (r1 * (1 - u2))[:, None] * tri[:, 1]
                + (r1 * u2)[:, None] * tri[:, 2]
            )
        y = y.reshape(L, S, 3)
        ny = self.tri_normal[k]
        d = y - x[:, None]
        r2 = np.maximum(np.einsum("lsk,lsk->ls", d, d), 1e-300)
        cos_y = np.abs(np.einsum("lsk,lsk->ls", d, ny)) / np.sqrt(r2)
        # density in solid angle: (om_k / tot) x (1 / om_k) for exact sampling, (om_k / tot) x
        # r^2 / (cos_y A_k) for area sampling; times tot
        area_k = self.tri_area[k]
        bigm = big.reshape(L, S)
        ratio = np.where(bigm, 1.0, ok_ * r2 / np.maximum(cos_y * area_k, 1e-300))
        return y, ny, ratio

    def sample(self, u):
        """Points (..., 3) and their normals on the emitter, area-uniform, from uniforms u (..., 2):
        u[..., 0] picks the triangle along the cumulative area (stratification carries over)."""
        x = u[..., 0] * self.total
        k = np.minimum(np.searchsorted(self.cdf, x, "right"), len(self.cdf) - 1)
        lo = np.where(k > 0, self.cdf[np.maximum(k - 1, 0)], 0.0)
        s = np.clip((x - lo) / np.maximum(self.cdf[k] - lo, 1e-300), 0, 1)  # reused within the triangle
        r1 = np.sqrt(s)
        t = self.tri[k]
        p = (1 - r1)[..., None] * t[..., 0, :] + (r1 * (1 - u[..., 1]))[..., None] * t[..., 1, :]
        p += (r1 * u[..., 1])[..., None] * t[..., 2, :]
        return p, self.tri_normal[k]


_clipped_rings = ff.clipped_rings  # (the horizon-cut outline: formfactor.clipped_rings)


# ---------------------------------------------------------------------------------------------- gather


class FinalGather:
    """Per-sample final gather over a RadiositySystem (see the module doc).

    FinalGather(system_or_dyn, points (n, 3), normals (n, 3) unit, facing the side the surface
    emits to, patch_ids (n,) input patches the points lie on, rho (n, 3) reflectance at the points
    (default: the patches'), rays: hemisphere rays per sample, shadow_rays: per sample and emitter,
    seed). The hemisphere rays are traced here (once per static geometry); direct light of the
    static emitters on the first evaluate(); a light shape's on its first appearance.
    `evaluate(dyn_or_system, kind)` -> (n, 3) float64."""

    BATCH_RAYS = 1 << 20

    def __init__(
        self,
        system,
        points,
        normals,
        patch_ids,
        rho=None,
        rays=128,
        shadow_rays=32,
        seed=0,
        offsets=None,
        batch_rays=None,
        levels=1,
        second_rays=None,
        leaf_points=2,
        covered_hits="zero",
        covered_samples="zero",
        iterations=0,
        cache_responses=True,
    ):
        dyn = system if hasattr(system, "n_hr") else None
        self.system = dyn.system if dyn is not None else system
        s = self.system
        h, pt = s.h, s.patches
        self.n_hr = dyn.n_hr if dyn is not None else h.n
        nrm = np.asarray(normals, np.float64).reshape(-1, 3)
        self.normals = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        self.patch = np.asarray(patch_ids, np.int64).ravel()
        # onto the plane of their patch: points on a renderer's triangulation of a slightly warped
        # polygon lie off the patch (behind it by more than eps, every ray would hit its back)
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        pn = pt.normal[self.patch]
        p = p - np.einsum("ij,ij->i", p - pt.corners[self.patch, 0], pn)[:, None] * pn
        # and into it: texels of a lightmap's dilation ring lie beyond their polygon's edge
        lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
        self.tmax = 2.0 * float(np.linalg.norm(hi - lo)) + 1.0
        # rays are traced to `reach` first, then the misses on to tmax: the ray contract's minimum
        # distance is relative to the segment, so one long segment (a stray object 50 km away
        # makes the box 100 km wide) would skip every hit within 20 cm. reach follows the surface
        # area, which a small far object hardly changes (as the refiner's eps does).
        # lengths from the main group of objects (geometry.isolated_objects): a stray object far
        # away changes neither the reach nor the samples' random streams
        size = float(np.sqrt(isolated_objects(s.mesh).main_area))
        self.unit = 2.0 ** (np.floor(np.log2(size)) - 12)  # a power of two: exact under 2^k scaling
        self.reach = min(4.0 * size, self.tmax)
        self.eps = float(s.refiner.eps)
        margin = max(50 * self.eps, 5e-5 * size)
        self.points = np.ascontiguousarray(_into_patch(pt, self.patch, p, margin))
        self.keys = position_keys(self.points, self.unit)
        n = len(self.points)
        self.n = n
        self.rho = (
            pt.reflectance[:, self.patch].T.copy()
            if rho is None
            else np.broadcast_to(np.asarray(rho, np.float64), (n, 3)).copy()
        )
        self.rays, self.shadow_rays, self.seed = int(rays), int(shadow_rays), int(seed)
        self.batch_rays = int(batch_rays or self.BATCH_RAYS)
        if covered_hits not in ("zero", "shown"):
            raise ValueError("covered_hits must be 'zero' or 'shown'")
        # "zero": rays reaching a point contacts.py calls covered read 0 (values_at); "shown": they
        # read their leaf's light on its uncovered part (the covered test's gap tolerance lets some
        # rays from exposed points reach "covered" points that a renderer sees lit)
        self.covered_hits = covered_hits
        self.origins = (
            self.points + self.eps * self.normals if offsets is None else np.asarray(offsets, float)
        )
        self.tri_patch = pt.triangle_patch
        # contacts: covered samples output 0 (static geometry)
        self.leaf0 = locate_below(h, self.patch, self.points, self.n_hr) if n else np.zeros(0, np.int64)
        self.dark = h.dark(self.leaf0, self.points) if n else np.zeros(0, bool)
        if covered_samples == "gather":  # diagnostic: gather at covered samples too (contacts ignored there)
            self.dark[:] = False
        self.E_static = pt.emission[:, self.patch].T.copy()
        self.stats = {}
        import time

        t0 = time.process_time()
        parts = [self.gather_batch(a, b) for a, b in self.batches(self.rays)]
        self.indptr, self.cols, self.w = self.merge(parts)
        self.second = None
        self.iterations = int(iterations) if levels == 2 else 0
        if levels >= 2:
            # two-level gather (issue 19, as Hasan et al. 2006): every HR leaf the rays hit gets
            # leaf_points^2 gather samples of its own (Gauss points) with exact direct light and a
            # gather of its own (levels - 1 levels, half the rays); the outputs' rays read those
            # instead of the leaf
            h = s.h
            used = np.unique(self.cols).astype(np.int64)
            if iterations > 0:
                # the gather samples' own rays must find gather samples wherever they land: every
                # HR leaf gets them
                c0 = h.child0[: self.n_hr]
                used = np.flatnonzero((c0 < 0) | (c0 >= self.n_hr)).astype(np.int64)
            x, gw = ff.quadrature(h.corners[used], h.nv[used], int(leaf_points))
            k2 = x.shape[1]
            self.second = FinalGather(
                system,
                x.reshape(-1, 3),
                np.repeat(h.normal[used], k2, 0),
                np.repeat(h.patch[used], k2),
                rays=int(second_rays or max(self.rays // 2, 16)),
                shadow_rays=max(self.shadow_rays // 2, 8),
                seed=self.seed + 7919,
                batch_rays=self.batch_rays,
                levels=levels - 1,
                second_rays=max(int(second_rays or max(self.rays // 2, 16)) // 2, 16),
                leaf_points=leaf_points,
                covered_hits=covered_hits,
                covered_samples=covered_samples,
            )
            self._second_map = (used, gw)
            # Blender lights at the second level: the leaf's mean direct light integrated over the
            # leaf (lights.node_incident: finer where it is uneven, a spot's edge), not its 2 x 2
            # points (issue 20: the spot's bounce read 2% dark through them)
            self.second._leaf_nodes = (used, k2)
        self.stats["precompute_cpu"] = time.process_time() - t0
        self._D_static = None
        self._shape_cache = {}  # geom_key -> (unit D (n,) float32, indices inside the outline)
        # DynamicRadiosity in "response" mode: D + I of the base solution and of each shape's
        # response at unit emission, so an emission edit is a weighted sum (_incident_by_response)
        self.cache_responses = bool(cache_responses)
        self._responses = {}
        self._responses_of = None
        self._naive_key = None
        self._naive_V = None

    # -- batching ------------------------------------------------------------------------------------
    def batches(self, per_sample):
        """Sample ranges of about batch_rays rays each (independent: any order, any thread)."""
        step = max(1, self.batch_rays // max(per_sample, 1))
        return [(a, min(a + step, self.n)) for a in range(0, self.n, step)]

    @staticmethod
    def merge(parts):
        """Concatenate the partial CSR rows of consecutive batches."""
        counts = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
        indptr = np.zeros(len(counts) + 1, np.int64)
        np.cumsum(counts, out=indptr[1:])
        cols = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, np.int32)
        w = np.concatenate([p[2] for p in parts]) if parts else np.zeros(0, np.float32)
        return indptr, cols, w

    @property
    def weights_bytes(self):
        """Bytes of the CSR weights, the lower levels' included."""
        own = self.indptr.nbytes + self.cols.nbytes + self.w.nbytes
        return own + (self.second.weights_bytes if self.second is not None else 0)

    # -- precompute: hemisphere rays -> CSR rows over HR leaves -------------------------------------
    def gather_batch(self, a, b):
        """Samples a..b-1: (hits per row (m,), HR leaf per entry int32, weight per entry float32)."""
        s = self.system
        h, pt = s.h, s.patches
        R = self.rays
        m = b - a
        keep = ~self.dark[a:b]
        dirs = cosine_directions(self.normals[a:b], self.keys[a:b], R, self.seed, stream=0).reshape(-1, 3)
        org = np.repeat(self.origins[a:b], R, 0)
        prim, t = self.first_hit(org, dirs)
        row = np.repeat(np.arange(m), R)
        ok = (prim >= 0) & np.repeat(keep, R)
        patch = np.where(ok, self.tri_patch[np.maximum(prim, 0)], 0)
        ok &= np.einsum("ij,ij->i", dirs, pt.normal[patch]) < 0  # back faces reflect nothing
        i = np.flatnonzero(ok)
        hit = org[i] + t[i, None] * dirs[i]
        leaf = locate_below(h, patch[i], hit, self.n_hr)
        if self.covered_hits == "zero":
            lit = ~h.dark(leaf, hit)  # covered points read 0
        else:
            lit = h.exposure[leaf] > 0
        i, leaf = i[lit], leaf[lit]
        key = row[i].astype(np.int64) * self.n_hr + leaf
        u, cnt = np.unique(key, return_counts=True)
        r = u // self.n_hr
        counts = np.bincount(r, minlength=m).astype(np.int64)
        return counts, (u % self.n_hr).astype(np.int32), (cnt / R).astype(np.float32)

    def first_hit(self, org, dirs):
        """Nearest hits of unit rays (visibility.first_hit_within: near hits to self.reach first)."""
        return first_hit_within(self.system.backend, org, dirs, self.reach, self.tmax)

    # -- run time: values at the HR leaves -----------------------------------------------------------
    def _state(self, dyn):
        """(h, B, E) of the solution in effect on self.system's hierarchy, or None under NAIVE."""
        if dyn is None or not hasattr(dyn, "n_hr"):
            s = dyn if dyn is not None else self.system
            if s.B is None:
                s.solve()
            return s.h, s.B, s.base_emission()
        if dyn.naive_active:
            return None
        return dyn.system.h, dyn.B, dyn.emission()

    def leaf_values(self, dyn):
        """(n_hr, 3) reflected radiance on the uncovered part of every HR leaf (0 elsewhere); with
        a second level, of the leaves the rays hit: the mean of their gather samples (exact direct
        light + the solution one bounce further) over the uncovered ones."""
        return self._levels(self.solution_values(dyn), lambda g: g.direct_and_emission(dyn)[0])

    def _levels(self, V, direct):
        """The leaf values the top level's rays read, from the solution's V (n_hr, 3) and
        direct(g) -> (g.n, 3) direct light at a level's samples: V itself with one level; with
        more, the lower levels' gathers (linear in V and the direct light)."""
        if self.second is None:
            return V
        used, gw = self._second_map
        g2 = self.second
        w = gw * ~g2.dark.reshape(len(used), -1)
        ws = w.sum(1)
        ok = ws > 0
        w = w[ok] / ws[ok, None]
        D2 = direct(g2)
        Y = g2._levels(V, direct) if g2.second is not None else V  # levels > 2: its own levels
        # iterations: the gather samples gather from each other (Jacobi on the HR leaves with exact
        # direct light): every pass moves the solution one bounce further away
        for _ in range(1 + self.iterations):
            y = (g2.rho * (D2 + _csr_matvec(g2.indptr, g2.cols, g2.w, Y))).reshape(len(used), -1, 3)
            Ynew = V.copy()
            Ynew[used[ok]] = np.einsum("uk,ukc->uc", w, y[ok])
            Y = Ynew
        return Y

    def solution_values(self, dyn):
        """(n_hr, 3) the solution's reflected radiance on the uncovered part of every HR leaf."""
        st = self._state(dyn)
        if st is None:
            return self._naive_values(dyn)
        h, B, E = st
        n = h.n
        X = B[:, :n] - E[:, :n] * h.exposure[:n].astype(np.float64)
        return np.maximum(self._values_from(h, X), 0.0)

    def _values_from(self, h, X):
        """(n_hr, 3) shown values of the HR leaves from reflected node means X (3, n) (linear)."""
        n, m = h.n, self.n_hr
        ex = h.exposure[:n].astype(np.float64)
        X = X[:, :n] * h.area[:n]  # reflected power-like: node means x area
        if n > m:  # HR leaves split by light events: the area mean of their current leaves
            leaf = h.child0[:n] < 0
            Y = np.where(leaf, X, 0.0)
            par = h.parent[:n]
            for lv in reversed(h.levels()[1:]):
                sel = lv[lv >= m]
                if len(sel):
                    for c in range(3):
                        Y[c] += np.bincount(par[sel], weights=Y[c, sel], minlength=n)
            X = np.where((np.arange(n) < m) & ~leaf & (h.child0[:n] >= m), Y, X)
        V = X[:, :m] / np.maximum(h.area[:m], 1e-300)
        exm = ex[:m]
        return np.where(exm > 0, V / np.maximum(exm, 1e-30), 0.0).T

    def _incident_by_response(self, dyn):
        """(n, 3) D + I of a DynamicRadiosity in "response" mode as a sum of cached parts: the
        base solution's, and per light shape its response's at unit emission times the shape's
        emission (a colour or strength edit: one weighted sum). None where that does not apply
        (NAIVE, warm mode, a static system)."""
        if not self.cache_responses or dyn is None or not hasattr(dyn, "n_hr"):
            return None
        if dyn.incremental != "response" or dyn.naive_active:
            return None
        recs = list(dyn.shapes.values())
        if any(r.U is None or r.used == "NAIVE" or not r.on_surface for r in recs):
            return None
        if self._responses_of is not dyn:  # parts of another DynamicRadiosity (ids may be reused)
            self._responses.clear()
            self._responses_of = dyn
        dyn._sync()
        h = dyn.system.h
        n = h.n
        ex = h.exposure[:n].astype(np.float64)
        key0 = ("base",)
        if key0 not in self._responses:
            X = dyn._Bbase[:, :n] - dyn.system.base_emission()[:, :n] * ex
            V = self._values_from(h, X)
            Y = self._levels(V, lambda g: g.direct_static())
            self._responses[key0] = self.direct_static() + _csr_matvec(self.indptr, self.cols, self.w, Y)
        total = self._responses[key0].copy()
        live = {key0}
        for rec in recs:
            k = ("shape", rec.geom_key, rec.used)
            live.add(k)
            if k not in self._responses:
                X = rec.U[:, :n] - dyn._coverage(rec)[None, :n] * ex

                def unit(g, rec=rec):
                    return np.repeat(g._shape(dyn, rec)[0][:, None].astype(np.float64), 3, 1)

                Y = self._levels(self._values_from(h, X), unit)
                part = unit(self) + _csr_matvec(self.indptr, self.cols, self.w, Y)
                self._responses[k] = part.astype(np.float32)
            total += rec.emission[None] * self._responses[k]
        for rec in dyn.lights.values():
            if rec.U is None:
                return None
            k = ("light", rec.geom_key)
            live.add(k)
            if k not in self._responses:
                X = rec.U[:, :n]  # a light emits nothing at nodes: all of U is reflected light

                def unit(g, rec=rec):
                    return np.repeat(g._light(rec)[:, None].astype(np.float64), 3, 1)

                Y = self._levels(self._values_from(h, X), unit)
                part = unit(self) + _csr_matvec(self.indptr, self.cols, self.w, Y)
                self._responses[k] = part.astype(np.float32)
            total += rec.scale[None] * self._responses[k]
        gone = [k for k in self._responses if k not in live]
        for k in gone[: max(len(gone) - 8, 0)]:
            del self._responses[k]
        return total

    def _naive_values(self, dyn):
        """NAIVE: each used HR leaf reads the rebuilt solution (reflected, shown) at its 2 x 2 Gauss
        points (cached per rebuild)."""
        nv = dyn._naive
        if self._naive_key is nv:
            return self._naive_V
        h = self.system.h
        used = np.unique(self.cols).astype(np.int64)
        if self.second is not None:  # the gather samples' rays land on other leaves too
            used = np.union1d(used, self.second.cols).astype(np.int64)
        x, gw = ff.quadrature(h.corners[used], h.nv[used], 2)
        pts = x.reshape(-1, 3)
        roots, p2 = nv.remap(pts, np.repeat(h.patch[used], 4))
        from .output import locate

        hs = nv.system.h
        leaf = locate(hs, roots, p2)
        R = hs.shown(nv.system.B - nv.system.base_emission() * hs.exposure[: hs.n])
        val = R[:, leaf].T.reshape(-1, 4, 3)
        V = np.zeros((self.n_hr, 3))
        V[used] = np.maximum((val * gw[..., None]).sum(1), 0.0)
        self._naive_key, self._naive_V = nv, V
        return V

    def indirect(self, dyn=None):
        """(n, 3) I = W @ leaf_values: the solution's reflected radiance seen by the hemisphere."""
        return _csr_matvec(self.indptr, self.cols, self.w, self.leaf_values(dyn))

    # -- direct light --------------------------------------------------------------------------------
    def direct_batch(self, em: Emitter, a, b):
        """(b - a,) float32: unit-radiance direct light F x V of emitter em at samples a..b-1."""
        x, nx = self.points[a:b], self.normals[a:b]
        out = np.zeros(b - a)
        eps = self.eps
        # cull: a vertex of the emitter above the horizon, and (planar) the point in front of it
        ok = ~self.dark[a:b]
        if em.normal is not None:
            ok &= (x - em.point) @ em.normal > eps
        top = np.full(len(x), -np.inf)
        for s0 in range(0, len(em.verts), 64):
            v = em.verts[s0 : s0 + 64]
            top = np.maximum(top, (nx @ v.T - np.einsum("mk,mk->m", x, nx)[:, None]).max(1))
        ok &= top > eps
        i = np.flatnonzero(ok)
        if len(i) == 0:
            return out.astype(np.float32)
        xi, ni = x[i], nx[i]
        F = np.zeros(len(i))
        whole = np.zeros(len(i), bool)
        if em.rings is not None:
            allv = np.concatenate(em.rings)
            whole = ((allv[None] - xi[:, None]) * ni[:, None]).sum(-1).min(1) > eps
            if whole.any():
                F[whole] = _contour(xi[whole], ni[whole], em.rings)
        rest = np.flatnonzero(~whole)
        if em.rings is not None and len(rest):
            # the horizon cuts the outline: its rings clipped to the point's upper half-space
            # (exact, as the pieces' sum, for a handful of edges instead of every piece's)
            F[rest] = _clipped_rings(xi[rest], ni[rest], em.rings)
            rest = rest[:0]
        T = len(em.corners)
        step = max(1, (1 << 18) // max(T, 1))
        for s0 in range(0, len(rest), step):
            r = rest[s0 : s0 + step]
            F[r] = (
                ff.point_to_polygon(
                    np.repeat(xi[r], T, 0),
                    np.repeat(ni[r], T, 0),
                    np.tile(em.corners, (len(r), 1, 1)),
                    np.tile(em.nv, len(r)),
                )
                .reshape(-1, T)
                .sum(1)
            )
        lit = np.flatnonzero(F > 0)
        if len(lit) and self.shadow_rays > 0:
            S = self.shadow_rays
            gi = i[lit] + a
            u = (
                hammersley(S)[None] + hash_uniform(self.seed, self.keys[gi], 1000 + em.stream)[:, None]
            ) % 1.0
            xo = xi[lit]
            y, ny, ratio = em.sample_at(xo, u)  # (L, S, 3)
            o = (xo + eps * ni[lit])[:, None]
            e = y + eps * ny
            d = y - xo[:, None]
            r = np.sqrt(np.maximum(np.einsum("lsk,lsk->ls", d, d), 1e-300))
            # ratio estimator of the visible fraction of the projected solid angle: weight cos_x
            # over the samples' solid-angle density (and only where the emitter faces the point)
            kern = (
                np.maximum(np.einsum("lsk,lk->ls", d, ni[lit]) / r, 0)
                * (np.einsum("lsk,lsk->ls", d, ny) < 0)
                / np.maximum(ratio, 1e-300)
            )
            vis = ~self.system.backend.occluded(np.broadcast_to(o, d.shape).reshape(-1, 3), e.reshape(-1, 3))
            vis = vis.reshape(kern.shape)
            ks = kern.sum(1)
            F[lit] *= np.where(ks > 0, (kern * vis).sum(1) / np.where(ks > 0, ks, 1), 1.0)
        out[i] = F
        return out.astype(np.float32)

    def direct_light(self, em: Emitter):
        """(n,) float32 unit-radiance direct light of em at every sample (batches merged)."""
        edges = sum(len(r) for r in em.rings) if em.rings is not None else 4 * len(em.corners)
        per = (
            max(self.shadow_rays, 1) * 4
            + 3 * min(edges, 4 * em.MAX_TRIANGLES)
            + 12 * min(len(em.tri), em.MAX_TRIANGLES)
        )
        return np.concatenate([self.direct_batch(em, a, b) for a, b in self.batches(per)] or [np.zeros(0)])

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
        from .events.planar import _in_rings, slab_decomposition

        import zlib

        # the shape's own random stream, from its outline relative to the scene's box: the same
        # outline gives the same shadow rays at any scene scale or position
        stream = zlib.crc32(b"".join(position_keys(r, self.unit).tobytes() for r in rec.rings)) & 0x7FFFFFFF

        def outline_pieces(nf):
            """The outline's own convex pieces (slabs of its rings)."""
            edges = np.concatenate([np.stack([x, np.roll(x, -1, 0)], 1) for x in rec.rings2d])
            traps = slab_decomposition(edges, 1e-9 * (float(np.abs(edges).max()) or 1.0))
            out, nvs = [], []
            for q, mid in traps:
                if not _in_rings(mid[None], rec.rings2d)[0]:
                    continue
                p3 = rec.c + q[:, :1] * rec.u + q[:, 1:2] * rec.v
                if newell(p3) @ nf < 0:
                    p3 = p3[::-1]
                nvs.append(len(p3))
                out.append(np.concatenate([p3, p3[-1:]]) if len(p3) == 3 else p3)
            corners = np.array(out).reshape(-1, 4, 3)
            nv = np.array(nvs, int)
            _, area = ff.polygon_normal_area(corners, nv)
            return corners, nv, area

        whole = rec.covered >= 1 - 1e-9 or not rec.on_surface
        if rec.on_surface:
            corners, nv, area, nf = dyn._pieces(rec)
            if whole and len(corners):
                # wholly on surfaces: the emitting region is the outline itself; its few slabs
                # instead of its pieces on every patch below it (hundreds on a finely meshed
                # wall) make the shadow rays' sampling cheap (the same region, uniform in solid
                # angle)
                corners, nv, area = outline_pieces(nf)
        else:
            nf = rec.n
            corners, nv, area = outline_pieces(nf)
        inside = np.zeros(0, np.int64)
        if len(corners) == 0:
            return None, inside, nf
        rings = None
        if whole:
            rings = [r if (newell(r) @ nf > 0) == (i == 0) else r[::-1] for i, r in enumerate(rec.rings)]
        em = Emitter(corners, nv, area, np.repeat(nf[None], len(corners), 0), rings, nf, rec.c, stream=stream)
        if rec.on_surface:
            on = np.isin(self.patch, rec.roots) & (self.normals @ nf > 0.999)
            on &= np.abs((self.points - rec.c) @ nf) <= max(rec.tol, 10 * self.eps)
            c = np.flatnonzero(on)
            if len(c):
                inside = c[_in_rings(dyn._to2d(rec, self.points[c]), rec.rings2d)]
        return em, inside, nf

    def _shape(self, dyn, rec):
        key = rec.geom_key
        got = self._shape_cache.get(key)
        if got is None:
            em, inside, _ = self._shape_emitter(dyn, rec)
            D = self.direct_light(em) if em is not None else np.zeros(self.n, np.float32)
            got = (D, inside)
            self._shape_cache[key] = got
        return got

    # -- Blender lights (issue 20, core/lights.py) -----------------------------------------------------
    def _light(self, rec):
        """(n,) float32 unit direct light of a Blender light (DynamicRadiosity.lights record) at the
        samples, cached per light geometry: area lights through the Emitter path (solid-angle
        sampled shadow rays), the others with core.lights.unit_incident."""
        from . import lights as lt

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
                got[ok] = lt.unit_incident(
                    L,
                    self.points[ok],
                    self.normals[ok],
                    self.system.backend,
                    self.eps,
                    rays=max(self.shadow_rays // 4, 4),
                    seed=self.seed,
                    keys=self.keys[ok],
                    stream=stream,
                    far=self.tmax,
                )
                got = got.astype(np.float32)
            self._light_cache[key] = got
            # keep the lights of the current and a few recent geometries
            for k in list(self._light_cache)[: max(len(self._light_cache) - 16, 0)]:
                del self._light_cache[k]
        return got

    def direct_and_emission(self, dyn=None):
        """(D (n, 3) direct light, E (n, 3) emission at the points) of the current emitters."""
        D = self.direct_static().copy()
        E = self.E_static.copy()
        for rec in getattr(dyn, "lights", {}).values() if dyn is not None and hasattr(dyn, "n_hr") else ():
            D += self._light(rec)[:, None] * rec.scale[None]
        shapes = getattr(dyn, "shapes", None) if dyn is not None and hasattr(dyn, "n_hr") else None
        live = set()
        for rec in (shapes or {}).values():
            Ds, inside = self._shape(dyn, rec)
            live.add(rec.geom_key)
            D += Ds[:, None] * rec.emission[None]
            E[inside] += rec.emission[None]
        # forget shapes gone for good (keep a few recent ones: a shape toggled back is instant)
        gone = [k for k in self._shape_cache if k not in live]
        for k in gone[: max(len(gone) - 8, 0)]:
            del self._shape_cache[k]
        return D, E

    # -- output ----------------------------------------------------------------------------------------
    def evaluate(self, dyn=None, kind="radiance"):
        """(n, 3) at the samples: "radiance" E + rho (D + I), "reflected" rho (D + I), "incident"
        D + I (irradiance / pi). dyn: a DynamicRadiosity, or a RadiositySystem (static emission
        only), or None (self.system). Covered samples read 0."""
        return self.evaluate_kinds(dyn, (kind,))[kind]

    def evaluate_kinds(self, dyn=None, kinds=KINDS):
        """{kind: (n, 3)} for several kinds from one gather (see evaluate)."""
        for k in kinds:
            if k not in KINDS:
                raise ValueError(f"unknown kind {k!r} ({', '.join(KINDS)})")
        D, E = self.direct_and_emission(dyn)
        inc = self._incident_by_response(dyn)
        if inc is None:
            inc = D + self.indirect(dyn)
        inc[self.dark] = 0.0
        out = {}
        for k in kinds:
            if k == "incident":
                out[k] = inc
            elif k == "reflected":
                out[k] = self.rho * inc
            else:
                v = E + self.rho * inc
                v[self.dark] = 0.0
                out[k] = v
        return out


# ---------------------------------------------------------------------------------------------- layouts


def loop_samples(system, smooth_angle=30.0, inset=0.5, nudge=1e-3):
    """Gather samples for the input mesh's corners, the layout of core.output.loop_radiance.

    inset > 0 (default): one sample per loop, inside the corner's own region of its patch: `inset`
    of the way from the corner to the patch's centre (0.5: the centre of a quad's corner quarter).
    A corner's value is then the area-weighted mean over the loops at the same position of the same
    object whose polygons lie within smooth_angle (uncovered samples only), like output.loop_plan's
    leaves: interpolated over a face, the corner values give the face's mean even on coarse meshes,
    where values at the corners themselves would stand for the corners only (contacts, concave
    corners).
    inset = 0: samples at the corners themselves, one per welded vertex and smooth normal (the area
    mean of the polygons' normals within smooth_angle) and material, moved `nudge` of the way
    towards the patch's centre.
    Returns (points (S, 3), normals (S, 3), patch ids (S,), loop -> sample index (L,), -1 for loops
    of polygons dropped as degenerate, and (li, lj, w): loop li averages sample loop_index[lj] with
    weight w (None for inset = 0))."""
    from .output import _weld_ids

    mesh, pt = system.mesh, system.patches
    P = len(mesh.loop_start)
    loop_poly = np.repeat(np.arange(P), mesh.loop_total)
    loop_obj = np.asarray(mesh.object_id)[loop_poly]
    weld = _weld_ids(mesh, loop_obj)
    # the patch of each loop: the patch of its polygon holding its vertex
    jj, kk = np.nonzero(pt.vert_index >= 0)
    key_p = pt.poly[jj].astype(np.int64) * (len(mesh.verts) + 1) + pt.vert_index[jj, kk]
    order = np.argsort(key_p, kind="stable")
    key_l = loop_poly.astype(np.int64) * (len(mesh.verts) + 1) + np.asarray(mesh.loop_verts, np.int64)
    pos = np.minimum(np.searchsorted(key_p[order], key_l), len(order) - 1)
    found = key_p[order][pos] == key_l
    lpatch = np.where(found, jj[order][pos], -1)
    # polygon normal and area (from their patches)
    pn = np.zeros((P, 3))
    np.add.at(pn, pt.poly, pt.normal * pt.area[:, None])
    parea = np.linalg.norm(pn, axis=1)
    pn = pn / np.maximum(parea, 1e-300)[:, None]
    # pairs of loops at the same weld whose polygons lie within smooth_angle
    L = len(weld)
    o = np.argsort(weld, kind="stable")
    ws = weld[o]
    start = np.searchsorted(ws, weld, "left")
    count = np.searchsorted(ws, weld, "right") - start
    li = np.repeat(np.arange(L), count)
    offs = np.arange(len(li)) - np.repeat(np.cumsum(count) - count, count)
    lj = o[np.repeat(start, count) + offs]
    a, b = loop_poly[li], loop_poly[lj]
    ok = np.einsum("ij,ij->i", pn[a], pn[b]) >= np.cos(np.radians(smooth_angle))
    valid = lpatch >= 0
    vl = np.flatnonzero(valid)
    p = np.asarray(mesh.verts, float)[np.asarray(mesh.loop_verts)]
    if inset > 0:
        loop_index = np.full(L, -1, np.int64)
        loop_index[vl] = np.arange(len(vl))
        patch = lpatch[vl]
        c = pt.corners[patch]
        centre = np.where((pt.nv[patch] == 4)[:, None], c.mean(1), c[:, :3].mean(1))
        pts = p[vl] + inset * (centre - p[vl])
        keep = ok & valid[lj]
        lpj = lpatch[lj[keep]]
        w = pt.area[lpj] / pt.nv[lpj]  # the corner's share of its patch
        return pts, pt.normal[patch], patch, loop_index, (li[keep], lj[keep], w)
    sn = np.zeros((L, 3))
    for c in range(3):
        sn[:, c] = np.bincount(li, weights=ok * pn[b, c] * parea[b], minlength=L)
    nl = np.linalg.norm(sn, axis=1)
    sn = np.where(nl[:, None] > 0, sn / np.maximum(nl, 1e-300)[:, None], pn[loop_poly])
    mat = np.column_stack(
        [pt.reflectance[:, np.maximum(lpatch, 0)].T, pt.emission[:, np.maximum(lpatch, 0)].T]
    )
    key = np.column_stack([weld, np.round(sn * 1e4).astype(np.int64), np.round(mat * 1e6).astype(np.int64)])
    _, first, inv = np.unique(key[valid], axis=0, return_index=True, return_inverse=True)
    rep = vl[first]
    loop_index = np.full(L, -1, np.int64)
    loop_index[vl] = inv.ravel()
    patch = lpatch[rep]
    q = p[rep]
    towards = pt.corners[patch].mean(1) - q  # the patch's centre (padded triangles: close enough)
    dist = np.linalg.norm(towards, axis=1)
    f = np.minimum(nudge, 50 * system.refiner.eps / np.maximum(dist, 1e-300))
    pts = q + f[:, None] * towards
    nrm = sn[rep]
    flip = np.einsum("ij,ij->i", nrm, pt.normal[patch]) <= 0  # turned to the patch's side
    nrm[flip] = pt.normal[patch[flip]]
    return pts, nrm, patch, loop_index, None


class LoopGather(FinalGather):
    """FinalGather for the input mesh's corners: loop_radiance() in the layout of
    DynamicRadiosity.loop_radiance (CORNER: (L, 3) per loop; POINT: (V, 3) per vertex), float32.
    inset: see loop_samples (0.5: samples in the corners' regions, averaged; 0: at the corners)."""

    def __init__(self, system, smooth_angle=30.0, inset=0.5, **kw):
        s = system.system if hasattr(system, "n_hr") else system
        pts, nrm, patch, self.loop_index, self.average = loop_samples(s, smooth_angle, inset)
        self.smooth_angle = smooth_angle
        super().__init__(system, pts, nrm, patch, **kw)

    def loop_radiance(self, dyn=None, domain="CORNER", kind="radiance"):
        v = self.evaluate(dyn, kind)
        if self.average is not None:
            li, lj, w = self.average
            sj = self.loop_index[lj]
            w = w * ~self.dark[sj]
            den = np.bincount(li, w, len(self.loop_index))
            out = np.zeros((len(self.loop_index), 3))
            for c in range(3):
                out[:, c] = np.bincount(li, w * v[sj, c], len(self.loop_index))
            out = np.where(den[:, None] > 0, out / np.maximum(den, 1e-300)[:, None], 0.0)
        else:
            out = np.where((self.loop_index >= 0)[:, None], v[np.maximum(self.loop_index, 0)], 0.0)
        if domain == "POINT":
            mesh = self.system.mesh
            res = np.zeros((len(mesh.verts), 3))
            res[mesh.loop_verts] = out
            return res.astype(np.float32)
        return out.astype(np.float32)


def texel_gather(system, patch, points, **kw):
    """FinalGather at texel centres (lightmap.plan's points on input patches), normals from the
    patches: evaluate(dyn, kind) replaces core.texels.solution_radiance(dyn, system, patch, points,
    kind=kind) (same kinds; float64, cast as needed)."""
    s = system.system if hasattr(system, "n_hr") else system
    patch = np.asarray(patch, np.int64)
    return FinalGather(system, points, s.patches.normal[patch], patch, **kw)
