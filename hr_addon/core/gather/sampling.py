"""Random streams and sampling of the final gather: hash-rotated Hammersley patterns (a sample's
rays do not depend on batching or threads), cosine-weighted hemisphere directions, directions
uniform in solid angle over spherical triangles (Arvo 1995) and polygonal emitters."""

from dataclasses import dataclass

import numpy as np


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


def rotated_hammersley(k, seed, keys, stream):
    """(len(keys), k, 2): k Hammersley points rotated on the torus by each key's hash_uniform (a point's
    own stratified set, the same whatever batch it is in)."""
    u = hammersley(k)[None] + hash_uniform(seed, keys, stream)[:, None]
    # both terms lie in [0, 1): one subtraction wraps the sum, exact (Sterbenz) as % 1.0's fmod is,
    # so the same bits, 4x faster (the gather's 42 M hemisphere rays at 100k: ~1.2 s CPU)
    u -= u >= 1.0
    return u


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


# cosine_directions: rays per block of samples (the block's (rows, R) temporaries, ~15 of them,
# stay in the caches; a batch's 512 k rays at once cost 1.5-1.8x the CPU: the same values)
DIRECTION_BLOCK = 1 << 14


def cosine_directions(normals, index, rays, seed, stream=0):
    """(N, rays, 3) cosine-weighted unit directions about normals (N, 3): a Hammersley pattern
    rotated per sample by hash_uniform(seed, index). Computed by blocks of samples
    (DIRECTION_BLOCK rays), each sample's directions its own: the same values for any block."""
    # rotated_hammersley's two coordinates each in its own contiguous (N, R) array (its (N, R, 2)
    # read by strided views cost a third more), the same wrap, the same values
    h = hammersley(rays)
    off = hash_uniform(seed, index, stream)
    t, b = _frame(normals)
    out = np.empty((len(off), rays, 3))
    step = max(DIRECTION_BLOCK // max(rays, 1), 1)
    for s in range(0, len(off), step):
        e = s + step
        u0 = np.add(h[:, 0], off[s:e, :1])
        u0 -= u0 >= 1.0
        u1 = np.add(h[:, 1], off[s:e, 1:])
        u1 -= u1 >= 1.0
        r = np.sqrt(u0)
        phi = np.multiply(2 * np.pi, u1, out=u1)
        z = np.subtract(1, u0, out=u0)
        np.maximum(z, 0, out=z)
        np.sqrt(z, out=z)
        x = np.cos(phi)
        x *= r
        y = np.sin(phi, out=phi)
        y *= r
        # per component (x t + y b + z n, the same sums bit for bit): 3.5x faster than
        # broadcasting (N, R, 1) x (N, 1, 3); into two buffers reused per component (a fresh
        # temporary per product and sum cost a fifth of the call at 128 rays)
        A, B, o = r, np.empty_like(r), out[s:e]
        for k in range(3):
            np.multiply(x, t[s:e, k, None], out=A)
            A += np.multiply(y, b[s:e, k, None], out=B)
            A += np.multiply(z, normals[s:e, k, None], out=B)
            o[..., k] = A
    return out


# ---------------------------------------------------------------------------------------------- helpers


# ---------------------------------------------------------------------------------------------- emitters


def _unit_rows(v):
    return v / np.maximum(np.sqrt(np.einsum("...k,...k->...", v, v)), 1e-300)[..., None]


# The spherical-triangle kernels work on component-major vectors (3, ...): every operation runs over
# long contiguous rows, where numpy's broadcasting over a trailing axis of 3 costs several times
# the arithmetic (measured 0.33 ms for (29k, 3) x (29k, 1), against 0.04 ms for a row of 29k).


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross3(a, b):
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _unit3(v):
    return v / np.maximum(np.sqrt(_dot3(v, v)), 1e-300)


def _solid_angles3(A, B, C):
    num = np.abs(_dot3(A, _cross3(B, C)))
    return 2 * np.arctan2(num, 1 + _dot3(A, B) + _dot3(B, C) + _dot3(C, A))


def _setup3(A, B, C):
    # the angle at A between the great circles AB and AC
    alpha = np.arccos(np.clip(_dot3(_unit3(_cross3(A, B)), _unit3(_cross3(A, C))), -1, 1))
    return alpha, _dot3(A, B), _unit3(C - _dot3(C, A) * A)


def _arvo3(A, B, u1, u2, area, alpha, ab, c_perp, sa, ca):
    """Arvo's directions (3, N) from component-major A, B, c_perp (3, N) and per-sample rows
    (sa, ca: sin and cos of alpha, per point and triangle)."""
    ah = u1 * area - alpha
    s, t = np.sin(ah), np.cos(ah)
    u = t - ca
    v = s + sa * ab
    den = (v * s + u * t) * sa
    q = np.clip(((v * t - u * s) * ca - v) / np.where(np.abs(den) > 1e-300, den, 1e-300), -1, 1)
    ch = q * A + np.sqrt(np.maximum(1 - q * q, 0)) * c_perp
    chb = _dot3(ch, B)
    z = 1 - u2 * (1 - chb)
    return z * B + np.sqrt(np.maximum(1 - z * z, 0)) * _unit3(ch - chb * B)


def solid_angles(A, B, C):
    """Solid angles (...) of the triangles with unit vertex directions A, B, C (..., 3)
    (Van Oosterom & Strackee 1983)."""
    return _solid_angles3(*(np.moveaxis(v, -1, 0) for v in (A, B, C)))


def spherical_setup(A, B, C):
    """What Arvo's sampling of the spherical triangles A, B, C (N, 3) needs that does not depend
    on the sample: (the angle at A, A . B, the unit direction of C orthogonal to A), (N,), (N,),
    (N, 3). Computed once per point and triangle, shared by all of its shadow rays."""
    alpha, ab, c_perp = _setup3(A.T, B.T, C.T)
    return alpha, ab, c_perp.T


def sample_spherical_triangle(A, B, C, u1, u2, area=None, setup=None):
    """Directions uniform in solid angle over spherical triangles A, B, C (N, 3) unit (Arvo 1995);
    area: their solid angles if known (solid_angles); setup: spherical_setup(A, B, C) if known."""
    alpha, ab, c_perp = spherical_setup(A, B, C) if setup is None else setup
    if area is None:
        area = solid_angles(A, B, C)
    return _arvo3(A.T, B.T, u1, u2, area, alpha, ab, c_perp.T, np.sin(alpha), np.cos(alpha)).T


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
        # the triangles' normal when they share one (a planar emitter), else None
        tn = self.tri_normal
        self.normal_all = tn[0].copy() if len(tn) and (tn == tn[0]).all() else None
        self.lo, self.hi = self.verts.min(0), self.verts.max(0)

    SOLID_MIN = 1e-4  # triangles smaller than this (sr) seen from the point are sampled by area
    MAX_TRIANGLES = 256  # more: area sampling only (the per-point solid angles would cost too much)

    def sample_at(self, x, u, cm=False):
        """Points (L, S, 3) on the emitter seen from points x (L, 3), their normals and densities
        relative to solid angle: triangles are picked by their solid angle seen from x and sampled
        uniformly in solid angle (Arvo) or, when tiny, by area. Returns (y, ny, pdf_ratio) with
        pdf_ratio = (density in solid angle) x total solid angle: ~1 where sampling is exact.
        cm: where every pick was sampled exactly (the ratio is 1), (y (3, L S), ny (3, 1) or
        (3, L S), None) component-major instead (the same values)."""
        L, S = u.shape[:2]
        T = len(self.tri)
        if T > self.MAX_TRIANGLES:
            y, ny = self.sample(u)
            d = y - x[:, None]
            r2 = np.einsum("lsk,lsk->ls", d, d)
            cos_y = np.abs(np.einsum("lsk,lsk->ls", d, ny)) / np.sqrt(np.maximum(r2, 1e-300))
            # area density 1 / total -> solid-angle density r^2 / (cos_y total); normalised later
            return y, ny, np.maximum(r2, 1e-300) / np.maximum(cos_y, 1e-12) / self.total
        # unit directions to the triangles' corners, component-major: (3, L, T, 3 corners)
        V = _unit3(self.tri.transpose(2, 0, 1)[:, None] - x.T[:, :, None, None])
        A, B, C = V[..., 0], V[..., 1], V[..., 2]  # (3, L, T)
        om = _solid_angles3(A, B, C)  # (L, T)
        cdf = np.cumsum(om, axis=1)
        tot = np.maximum(cdf[:, -1:], 1e-300)
        xs = u[..., 0] * tot
        if T <= 16:  # a column at a time: no (L, S, T) temporary (the same counts)
            k = np.zeros((L, S), np.int64)
            for t in range(T - 1):
                k += cdf[:, t : t + 1] <= xs
        else:
            k = np.minimum((cdf[:, None, :] <= xs[..., None]).sum(-1), T - 1)  # (L, S)
        lo = np.where(k > 0, np.take_along_axis(cdf, np.maximum(k - 1, 0), 1), 0.0)
        ok_ = np.take_along_axis(om, k, 1)
        s1 = np.clip((xs - lo) / np.maximum(ok_, 1e-300), 0, 1)
        li = np.repeat(np.arange(L), S)
        kk = k.ravel()
        big = ok_.ravel() >= self.SOLID_MIN
        # every triangle seen large (the usual case): slices instead of masks, no copies
        allbig = bool(big.all())
        bsel = slice(None) if allbig else big
        y = np.empty((3, L * S))
        if big.any():
            # the sample-independent part of Arvo's method once per point and triangle that a
            # sample picked (with many triangles most are picked by none of a point's samples)
            kb, lb = kk[bsel], li[bsel]
            j = lb * T + kb
            A2, B2, C2 = (v.reshape(3, -1) for v in (A, B, C))
            # where a direction meets its triangle's plane: (corner 0 - x) . n per point and
            # triangle, not per sample (the same products)
            tn = self.tri_normal.T[:, None]  # (3, 1, T)
            hn = _dot3(self.tri[:, 0].T[:, None] - x.T[:, :, None], tn).reshape(-1)
            if T > 2:
                used = np.zeros(L * T, bool)
                used[j] = True
                pairs = np.flatnonzero(used)
                j = (np.cumsum(used) - 1)[j]
                A2, B2, C2 = (np.take(v, pairs, axis=1) for v in (A2, B2, C2))
                hn = np.take(hn, pairs)
            alpha, ab, c_perp = _setup3(A2, B2, C2)
            row = lambda a: np.take(a, j)
            col = lambda a: np.take(a, j, axis=1)
            w = _arvo3(
                col(A2),
                col(B2),
                s1.ravel()[bsel],
                u[..., 1].ravel()[bsel],
                ok_.ravel()[bsel],
                row(alpha),
                row(ab),
                col(c_perp),
                row(np.sin(alpha)),
                row(np.cos(alpha)),
            )
            # the point where direction w meets the triangle's plane (one normal for all: no take)
            n = self.normal_all
            n = n[:, None] if n is not None else np.take(self.tri_normal.T, kb, axis=1)
            wn = _dot3(w, n)
            tt = row(hn) / np.where(np.abs(wn) > 1e-300, wn, 1e-300)
            y[:, bsel] = np.take(x.T, lb, axis=1) + tt * w
        if cm and allbig:
            n = self.normal_all
            return y, (n[:, None] if n is not None else np.take(self.tri_normal.T, kk, axis=1)), None
        y = np.ascontiguousarray(y.T)
        small = ~big
        if not allbig and small.any():
            r1 = np.sqrt(s1.ravel()[small])
            u2 = u[..., 1].ravel()[small]
            tri = self.tri[kk[small]]
            y[small] = (
                (1 - r1)[:, None] * tri[:, 0]
                + (r1 * (1 - u2))[:, None] * tri[:, 1]
                + (r1 * u2)[:, None] * tri[:, 2]
            )
        y = y.reshape(L, S, 3)
        ny = np.take(self.tri_normal, k, axis=0)
        if allbig:  # exact solid-angle sampling everywhere: the density ratio is 1
            return y, ny, np.ones((L, S))
        d = y - x[:, None]
        r2 = np.maximum(np.einsum("lsk,lsk->ls", d, d), 1e-300)
        cos_y = np.abs(np.einsum("lsk,lsk->ls", d, ny)) / np.sqrt(r2)
        # density in solid angle: (om_k / tot) x (1 / om_k) for exact sampling, (om_k / tot) x
        # r^2 / (cos_y A_k) for area sampling; times tot
        area_k = self.tri_area[k]
        bigm = big.reshape(L, S)
        ratio = np.where(bigm, 1.0, ok_ * r2 / np.maximum(cos_y * area_k, 1e-300))
        return y, ny, ratio

    def sample_cm(self, u):
        """Area-uniform points component-major (3, N) and their normals ((3, 1) for one shared
        normal, else (3, N)) from uniforms u (N, 2), as sample(): u[:, 0] picks the triangle along
        the cumulative area. No per-point setup: the direct light's cheap shadow rays
        (DirectLight.area_sampling)."""
        T = len(self.tri)
        s = u[:, 0]
        k = None
        if T == 2:  # (a quad: a light shape's usual slab) the same picks and values by a compare
            x = s * self.total
            k = (x >= self.cdf[0]).view(np.int8)
            lo = np.array([0.0, self.cdf[0]])
            s = np.clip((x - np.take(lo, k)) / np.take(np.maximum(self.cdf - lo, 1e-300), k), 0, 1)
        elif T > 1:
            x = s * self.total
            k = np.minimum(np.searchsorted(self.cdf, x, "right"), T - 1)
            lo = np.where(k > 0, self.cdf[np.maximum(k - 1, 0)], 0.0)
            s = np.clip((x - lo) / np.maximum(self.cdf[k] - lo, 1e-300), 0, 1)
        r1 = np.sqrt(s)
        b2 = r1 * u[:, 1]
        b1 = r1 - b2
        t = self.tri.transpose(1, 2, 0)  # (corner, component, T)
        p0, e1, e2 = t[0], t[1] - t[0], t[2] - t[0]
        if k is not None:
            p0, e1, e2 = (np.take(v, k, axis=1) for v in (p0, e1, e2))
        y = p0 + b1 * e1 + b2 * e2
        n = self.normal_all
        return y, (n[:, None] if n is not None else np.take(self.tri_normal.T, k, axis=1))

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
