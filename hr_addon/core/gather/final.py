"""FinalGather: the hemisphere rays' precompute (CSR weights over the HR leaves), the run-time
values of the leaves (levels, iterations, cached responses, NAIVE) and the output (docs/gather.md)."""

import copy
import threading

import numpy as np

from .. import formfactor as ff
from ..events.records import outline_share
from ..geometry import insideness, isolated_objects
from ..visibility import first_hit_within
from ..parallel import batch_map, ranges, release_free_memory, trimming
from ..progress import Progress
from ..slots import _slot_tables, slot_mouth
from .direct import DirectLight
from .points import locate_below, onto_patch, split_lines
from .sampling import cosine_directions, position_keys

KINDS = ("radiance", "reflected", "incident")
# a sample under a covering face at a gap h (books standing side by side) is in a slot, lit through
# its open edges (contacts.Contacts.slots): it gathers no deeper than SLOT_DEPTH x h from its
# nearest mouth, where its hemisphere rays still find the mouth (view factor 0.15), and the slot's
# transfer carries that light to its own depth (docs/gather.md, "Narrow gaps"); texels within
# OPEN_EDGE x h of a mouth gather over their area (layouts.texel_samples)
OPEN_EDGE = 5.0
SLOT_DEPTH = 1.0
# a slot sample's direct light at its own point and the facing wall's bounced onto it (FinalGather's
# slot_facing=None takes this; docs/gather.md "The facing wall's direct light")
SLOT_FACING = True
# slot_facing: the depths (gap widths) over which the walls' local exchange fades out (inf: it
# counts everywhere)
SLOT_LOCAL = (np.inf, np.inf)
# slot_facing: what drives the remainder term (the light the walls nearer the mouth carry deeper):
# "mouth", the direct light crossing the mouth (a point at the mouth, mid-gap, facing out: the flux
# entering); "gather", the direct light at the gather point and its mirror over their view of the
# mouth (docs/gather.md, "The slots' remainder driven by the mouth")
SLOT_DRIVE = "mouth"
# slot_drive="mouth": the mouth's points lie at the middles of steps of about SLOT_MOUTH_STEP gap
# widths along each mouth, shared by the samples whose perpendicular meets the mouth in that step
# (0: each sample's own foot)
SLOT_MOUTH_STEP = 8.0
# the second level's fine leaves (near_points^2 samples each): their samples trace this share of
# the second level's hemisphere rays (1: all)
FINE_RAYS = 1.0
# the probe's hemisphere rays per sample (None: the second level's, rays // 2): its rows are the
# second level's on the leaves that are not fine, so this is those samples' rays too (docs/scale.md,
# session 30 "prays")
PROBE_RAYS = None
# near hits compute their nearest point only on leaves that have samples of their own (the fine
# leaves, known from the probe before the rays are traced); a hit on another leaf reads the leaf,
# as _remap_near maps it. False: every near hit computes it (session 26's rows; the same sums per
# row and column, split into more entries). docs/scale.md, session 27
NEAR_FINE_ONLY = True
# covered samples per batch of FinalGather._slots on threads (core.parallel): fixed, never by the
# thread count; every sample's slot and transfer are its own, so the batches do not change them
SLOT_BATCH = 1 << 13


# entries a thread reads at a time within a row block of _csr_matvec: its products (0.5 MB of
# float32, into a buffer the thread keeps) and columns stay in the caches across the three
# channels (100k room, with _read_cols' columns: a read's CPU 0.75-0.79x main's in steps of 2^17,
# 0.88-0.91x in whole 2^20-entry blocks; whole rows summed, so the same bits)
READ_STEP = 1 << 17
_scratch = threading.local()  # each thread's products buffer for _csr_matvec
_COLS_LOCK = threading.Lock()  # FinalGather._read_cols: its columns replaced once


def _csr_matvec(indptr, cols, w, V, chunk=1 << 20, threads=1, rays=None, used=None):
    """(n, C) float64 = W @ V for a CSR matrix (indptr, cols, w) and dense V (m, C): float32
    products summed per row by np.add.reduceat, in row blocks of about `chunk` entries (the blocks
    do not depend on `threads`, and each writes its own rows: equal for any thread count), each
    read in steps of about READ_STEP entries (whole rows: the same sums).
    w: float32 weights, or unsigned hit counts (FinalGather.w) whose weight is count / rays of the
    row (rays: one for all rows or (n,)): each row's float32 sum of V x count divided by its rays,
    for rays a power of two bit for bit the sum with float32 weights count / rays.
    used: the rows of V the columns number (_read_cols' compacted columns: cols < len(used) by
    construction), else cols index V itself."""
    n = len(indptr) - 1
    if w.dtype.kind == "u" and rays is None:
        raise ValueError("_csr_matvec: hit counts need their rows' rays")
    out = np.zeros((n, V.shape[1]))
    if len(cols) == 0:
        return out
    # the takes below skip numpy's per-index bounds error path (mode="clip": 0.125 -> 0.10 s a
    # read of the 100k room's 17.4 M weights, the same values): checked here once per read
    if (int(cols.max()) if used is None else len(used) and int(used.max())) >= len(V):
        raise IndexError(f"_csr_matvec: a column beyond V's {len(V)} rows")
    VT = _columns_f32(V, used, threads)
    rows = lambda r0, r1: _csr_rows(indptr, cols, w, VT, r0, r1, out, rays)  # noqa: E731
    batch_map(rows, _row_blocks(indptr, chunk), threads)
    return out


def _columns_f32(V, used=None, threads=1):
    """(C, m) float32 the columns a read takes: V's rows (used: those rows), channel-major (by
    ranges of rows on threads: each range its own, the same values)."""
    m = len(V) if used is None else len(used)
    VT = np.empty((V.shape[1], m), np.float32)

    def columns(a, b):
        VT[:, a:b] = (V[a:b] if used is None else V[used[a:b]]).T

    batch_map(columns, ranges(m, 1 << 16), threads)
    return VT


def _read_plan(indptr, r0, r1, rays=None):
    """[(a, b, rows, starts, per)]: _csr_rows' steps over rows r0..r1 of a CSR matrix, each about
    READ_STEP entries a..b of whole rows, with its rows that have entries, their starts within the
    step and (w hit counts: rays given) their rays. Fixed by the matrix: one read many times (the
    second level's Gauss-Seidel passes, _seidel_blocks) keeps them, ~16 bytes a row with entries."""
    steps, q0 = [], r0
    while q0 < r1:
        q1 = min(max(int(np.searchsorted(indptr, indptr[q0] + READ_STEP, "right")) - 1, q0 + 1), r1)
        a, b = int(indptr[q0]), int(indptr[q1])
        if b > a:
            nonempty = np.flatnonzero(indptr[q0 + 1 : q1 + 1] > indptr[q0:q1])
            rows, starts = q0 + nonempty, (indptr[q0:q1] - a)[nonempty]
            per = None if rays is None else rays if np.ndim(rays) == 0 else rays[rows]
            steps.append((a, b, rows, starts, per))
        q0 = q1
    return steps


def _csr_rows(indptr, cols, w, VT, r0, r1, out, rays=None, plan=None):
    """out[r0:r1] = rows r0..r1 of the CSR matrix times the columns VT (_columns_f32; cols index
    them), read in steps of about READ_STEP entries (whole rows: the same sums); rows without
    entries are left as they are (_csr_matvec's doc for w and rays). plan: _read_plan(indptr, r0,
    r1, rays) made before (the same steps: the same values)."""
    counts = w.dtype.kind == "u"
    if plan is None:
        plan = _read_plan(indptr, r0, r1, rays if counts else None)
    # channel-major: a 1-d take and reduceat per channel are 2x faster than rows of C with
    # reduceat along axis 0 (100k room, measured), and sum the same products in the same order
    for a, b, rows, starts, per in plan:
        c = np.asarray(cols[a:b], np.intp)  # once for every channel's take
        buf = getattr(_scratch, "prod", None)
        if buf is None or len(buf) < b - a:
            buf = _scratch.prod = np.empty(max(b - a, READ_STEP), np.float32)
        prod = buf[: b - a]
        for k in range(len(VT)):
            np.take(VT[k], c, mode="clip", out=prod)
            prod *= w[a:b]
            got = np.add.reduceat(prod, starts)
            out[rows, k] = got if per is None else got / per


def _row_blocks(indptr, chunk):
    """[(r0, r1), ...]: consecutive rows of a CSR matrix of about `chunk` entries each (at least
    one row; fixed by the matrix, never by the thread count)."""
    n = len(indptr) - 1
    blocks, r0 = [], 0
    while r0 < n:
        r1 = int(np.searchsorted(indptr, indptr[r0] + chunk, "right")) - 1
        r1 = min(max(r1, r0 + 1), n)
        blocks.append((r0, r1))
        r0 = r1
    return blocks


def _lit(y, D, rho, a, b):
    """y[a:b] = rho (D + y) in place over rows a..b (_levels' passes by ranges of rows on threads:
    each its own rows, the same values)."""
    y[a:b] += D[a:b] if np.ndim(D) == 2 else D
    y[a:b] *= rho[a:b]


def _column_sums(X):
    """(C,) the sums over the rows of X (n, C): einsum adds the rows in order as X.sum(0) does, the
    same bits (tests/test_gather.py pins it), 4x faster on rows of 3 (7.7 -> 1.8 ms at 514k rows:
    numpy's reduction along the first axis runs an inner loop of 3 per row)."""
    return np.einsum("ij->j", X)


def _ratio(D, F):
    """(n,) float32 the visible fraction D / F of a direct light D with unoccluded form factor F,
    NaN where F is 0 (culled: no visibility known)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(F > 0, D / F, np.nan).astype(np.float32)


def _same(V, W):
    """True when response values V are W's to 1e-6 of W's largest (a response that kept W's
    scattered light: a preview's unchecked guess)."""
    return V.shape == W.shape and np.abs(V - W).max() <= 1e-6 * np.abs(W).max()


def _leaf_frame(h, leaf):
    """(origin, e1, e2) (k, 3) of HR leaves: the first corner, the first edge's direction, and
    the normal x e1."""
    c = h.corners[leaf]
    e1 = c[:, 1] - c[:, 0]
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-300)
    return c[:, 0], e1, np.cross(h.normal[leaf], e1)


def _slope_fit(h, used, x, gw, dark):
    """(A (u, 2, k), ubar (u, 2)): for leaves `used` with gather samples x (u, k, 3) and area
    weights gw (u, k), the weighted least-squares slopes of a linear function along the leaf's
    frame (_leaf_frame) from the samples' values y (u, k, C): A @ y; ubar: the samples' weighted
    centroid in the frame (the mean's position). Leaves with a covered sample get A = 0."""
    o, e1, e2 = _leaf_frame(h, used)
    d = x - o[:, None]
    q = np.stack([np.einsum("ukj,uj->uk", d, e1), np.einsum("ukj,uj->uk", d, e2)], 2)  # (u, k, 2)
    ubar = np.einsum("uk,uka->ua", gw, q)
    r = q - ubar[:, None]
    M = np.einsum("uk,uka,ukb->uab", gw, r, r)
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    good = (np.abs(det) > 1e-12 * np.einsum("uaa->u", M) ** 2) & ~dark.any(1)
    inv = np.zeros_like(M)
    inv[good] = np.linalg.inv(M[good])
    return np.einsum("uab,ukb->uak", inv, gw[:, :, None] * r), ubar


# _exposed_quadrature: the grids (points per side) searched in turn for a leaf's uncovered part
UNCOVER_GRIDS = (8, 16, 32)


def _exposed_quadrature(g, leaves, k):
    """(points (N, k^2, 3), weights (N, k^2)): ff.quadrature's k x k Gauss points of HR leaves
    `leaves` (N,) for the second level, except on an exposed leaf whose points are all covered (a
    leaf partly under clutter with its Gauss points under it): those move to distinct uncovered
    points of the finest grid needed (UNCOVER_GRIDS), each the nearest free one to its own (as
    contacts.exposed_points moves the links' visibility points), weighted by the grid's
    uncovered area nearest to it. Such a leaf had no sample: its value in the passes was the
    response's V, so their limit depended on it (from V = 0 the 20k room's worst object was 1.1-1.7%
    off the converged gather, with the move 0.4%; docs/gather.md "Every exposed leaf sampled")."""
    s = g.system
    h, pt = s.h, s.patches
    x, w = ff.quadrature(h.corners[leaves], h.nv[leaves], k)
    ex = h.exposure[leaves]
    part = np.flatnonzero((ex > 0) & (ex < 1))
    if not len(part) or h.contacts is None:
        return x, w

    def covered(q, rows):  # as the second level's FinalGather tests its samples (h.dark)
        p = h.patch[leaves[rows]]
        q = onto_patch(pt, np.repeat(p, q.shape[1]), q, g.margin).reshape(q.shape)
        flat = q.reshape(-1, 3)
        lf = locate_below(h, np.repeat(p, q.shape[1]), flat, g.n_hr, g._lines())
        thr = 0 if g.threads is None else g.threads
        return q, h.dark(lf, flat, thr, g._leaf_boxes()).reshape(q.shape[:2])

    todo = part[covered(x[part], part)[1].all(1)]
    for kk in UNCOVER_GRIDS:
        if not len(todo):
            break
        c, cw = ff.quadrature(h.corners[leaves[todo]], h.nv[leaves[todo]], kk)
        c, cov = covered(c, todo)
        has = ~cov.all(1)
        r, c, cw, free = todo[has], c[has], cw[has], ~cov[has]
        d2 = np.where(free[:, None], ((x[r][:, :, None] - c[:, None]) ** 2).sum(-1), np.inf)
        pick = np.zeros((len(r), k * k), np.int64)
        for j in range(k * k):  # distinct points while there are enough free ones
            pick[:, j] = np.argmin(d2[:, j], 1)
            taken = np.zeros_like(free)
            np.put_along_axis(taken, pick[:, j : j + 1], True, 1)
            d2 = np.where(taken[:, None] & (free.sum(1) > j + 1)[:, None, None], np.inf, d2)
        x[r] = np.take_along_axis(c, pick[..., None], 1)
        # each free grid point's weight to the nearest picked point: the leaf's uncovered area
        near = np.argmin(((c[:, :, None] - x[r][:, None]) ** 2).sum(-1), 2)
        wr = np.zeros((len(r), k * k))
        np.add.at(wr, (np.arange(len(r))[:, None], near), cw * free)
        w[r] = wr / wr.sum(1, keepdims=True)  # (summing to 1 as quadrature's: _slope_fit's centroid)
        todo = todo[~has]
    return x, w


def _diameters(h, leaf):
    """(k,) the longest distance between two corners of nodes `leaf`."""
    c, nv = h.corners[leaf], h.nv[leaf]
    c = np.where((nv == 3)[:, None, None] & (np.arange(c.shape[1]) == 3)[None, :, None], c[:, :1], c)
    return np.sqrt(((c[:, :, None] - c[:, None]) ** 2).sum(-1).max((1, 2)))


def _near_points(h, n_hr, k):
    """(n_hr, 3 k^2) the Gauss points (ff.quadrature's k x k) of the first n_hr nodes, a node's row
    its points' x, then y, then z: _nearest_point's table, built once per gather (per batch it
    cost a sort and a quadrature of the leaves hit)."""
    x = ff.quadrature(h.corners[:n_hr], h.nv[:n_hr], k)[0]
    return np.ascontiguousarray(np.moveaxis(x, 2, 1)).reshape(n_hr, -1)


NEAREST_CHUNK = 1024  # _nearest_point's hits per step: its (chunk, k^2) temporaries stay in cache


def _nearest_point(x, leaf, hit):
    """(m,) the index of the point of x (_near_points) of node leaf[i] nearest hit[i]: the squared
    distance summed per component in the order of (d ** 2).sum(-1) (the same argmin bit for bit).
    One gather of a node's row per hit, in chunks (three gathers and whole (m, k^2) temporaries
    took 2.4x the CPU at 100k: 15.6 -> 6.5 s in a 1-thread profile of the precompute)."""
    kk = x.shape[1] // 3
    out = np.empty(len(leaf), np.intp)
    for s in range(0, len(leaf), NEAREST_CHUNK):
        # the gathered rows (a copy: take, 20% faster than indexing) as (chunk, 3, k^2), the
        # differences and squares in place over all three components at once (a third fewer
        # passes than per component)
        X = np.take(x, leaf[s : s + NEAREST_CHUNK], 0).reshape(-1, 3, kk)
        X -= hit[s : s + NEAREST_CHUNK, :, None]
        X *= X
        d2 = np.add(X[:, 0], X[:, 1])
        d2 += X[:, 2]
        out[s : s + NEAREST_CHUNK] = np.argmin(d2, 1)
    return out


def _grid_read(h, leaf, hit, k):
    """((m, 4) point indices, (m, 4) weights): the bilinear interpolation, in the leaf's own
    parameters (ff.quadrature's maps: quads bilinear, triangles collapsed), of its k x k Gauss
    points (index i k + j at parameters (x_i, x_j)) at hits (m, 3) on nodes leaf (m,); constant
    beyond the outer points (no extrapolation)."""
    c = ff._padded(h.corners[leaf], h.nv[leaf])
    a, b, cc, d = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
    tri = h.nv[leaf] == 3
    uv = np.full((len(leaf), 2), 0.5)
    for _ in range(6):  # Newton on the bilinear map (exact in one step for parallelograms)
        u, v = uv[:, :1], uv[:, 1:]
        p = (1 - u) * (1 - v) * a + u * (1 - v) * b + u * v * cc + (1 - u) * v * d
        pu = (1 - v) * (b - a) + v * (cc - d)
        pv = (1 - u) * (d - a) + u * (cc - b)
        # the collapsed map a + u (b - a) + u v (c - b)
        p = np.where(tri[:, None], a + u * (b - a) + u * v * (cc - b), p)
        pu = np.where(tri[:, None], b - a + v * (cc - b), pu)
        pv = np.where(tri[:, None], u * (cc - b), pv)
        J = np.stack([pu, pv], 2)  # (m, 3, 2): least squares in the leaf's plane
        JtJ = np.einsum("mia,mib->mab", J, J)
        r = np.einsum("mia,mi->ma", J, hit - p)
        det = JtJ[:, 0, 0] * JtJ[:, 1, 1] - JtJ[:, 0, 1] ** 2
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        du = (JtJ[:, 1, 1] * r[:, 0] - JtJ[:, 0, 1] * r[:, 1]) / det
        dv = (JtJ[:, 0, 0] * r[:, 1] - JtJ[:, 0, 1] * r[:, 0]) / det
        uv = np.clip(uv + np.column_stack([du, dv]), 0.0, 1.0)
    x = (np.polynomial.legendre.leggauss(k)[0] + 1) / 2
    i = np.clip(np.searchsorted(x, uv, "right") - 1, 0, k - 2)  # (m, 2) lower grid index
    f = np.clip((uv - x[i]) / (x[i + 1] - x[i]), 0.0, 1.0)
    fu, fv, iu, iv = f[:, 0], f[:, 1], i[:, 0], i[:, 1]
    idx = np.stack([iu * k + iv, (iu + 1) * k + iv, iu * k + iv + 1, (iu + 1) * k + iv + 1], 1)
    wts = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], 1)
    return idx, wts


_SENTINEL = np.iinfo(np.int32).max


def _row_sorted(row, col, m, span):
    """np.sort(row * span + col) (int64) for entries whose rows row (in [0, m)) each lie together
    (a sample's rays), col in [0, span), span < 2^31 - 1: each row's columns sorted in its own
    row of an (m, longest run) int32 table (sorts of 128 in place of one of ~500k int64 keys: 3x
    faster per batch of hemisphere rays)."""
    n = len(row)
    if not n:
        return np.zeros(0, np.int64)
    start = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
    run = np.diff(np.r_[start, n])
    width = int(run.max())
    T = np.full((m, width), _SENTINEL, np.int32)
    T.ravel()[row * width + (np.arange(n) - np.repeat(start, run))] = col
    T.sort(1)
    T = T.ravel()
    at = np.flatnonzero(T != _SENTINEL)
    return (at // width) * span + T[at]


# ---------------------------------------------------------------------------------------------- gather


class FinalGather(DirectLight):
    """Per-sample final gather over a RadiositySystem (see the module doc).

    FinalGather(system_or_dyn, points (n, 3), normals (n, 3) unit, facing the side the surface
    emits to, patch_ids (n,) input patches the points lie on, rho (n, 3) reflectance at the points
    (default: the patches'), rays: hemisphere rays per sample, shadow_rays: per sample and emitter,
    seed). The hemisphere rays are traced here (once per static geometry); direct light of the
    static emitters on the first evaluate(); a light shape's on its first appearance.
    `evaluate(dyn_or_system, kind)` -> (n, 3) float64.
    threads: core.parallel's batch map for the rays, the direct light and the matvecs (1: inline,
    None: every core; the values are the same for any count). progress: callable(ProgressInfo),
    called from the calling thread as batches of hemisphere rays finish; raising cancels."""

    BATCH_RAYS = 1 << 19  # rays per batch: several batches per thread even on small scenes
    ENTRY_BATCH = 1 << 21  # weights per batch of _read_cols, _reuse_rows on threads (fixed: the same values)
    MERGE_TRIM = 16 << 20  # bytes of batches merge copies between two release_free_memory
    # batches of rays between two release_free_memory (parallel.trimming; 0: none): their freed
    # temporaries not resident under the level's peak. OFF: at the 100k vertex bake every 4 batches
    # lowered the top level's peak 2.00 -> 1.93 GB for +16% of its CPU (the pages faulted in again;
    # docs/scale.md, session 36), and the bake's peak is the first frame's
    TRIM_BATCHES = 0
    # weights per batch of _remap_near (fixed): its int64 and float64 temporaries, ~60 bytes a weight,
    # were the 100k vertex bake's build peak in batches of 2^21 (session 32; its statistics' sums
    # are grouped by batch: their last bits moved then, the columns are the same)
    REMAP_BATCH = 1 << 18
    POINT_BATCH = 1 << 15  # samples per batch of their setup (onto_patch) on threads (fixed)
    ROW_BATCH = 1 << 15  # leaves or rows per batch of the passes' leaf means, near rows (fixed)
    threads = 1  # core.parallel's threads for the batches and matvecs (a class default: a gather
    # restored from stored arrays runs inline until told otherwise)
    near_points = 0  # (a class default too: a gather stored before near hits restores without it)

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
        threads=1,
        progress=None,
        groups=None,
        open_edge=OPEN_EDGE,
        sample_rays=None,
        slot_area=None,
        slopes=False,
        second_shadow_rays=None,
        slot_facing=None,
        slot_local=None,
        slot_drive=None,
        # near hits (docs/gather.md "Near hits"; 0: off): with the edge texels the furnished
        # share within 5% 75 -> 80%. near: every hit reads its leaf's nearest gather sample, not
        # the mean of the leaf (whose unseen parts are mostly unlit too: behind furniture, in a
        # shelf's corners): furnished 84 -> 87% within 5%, Cornell's worst surface 0.27 -> 0.20%,
        # for +18% weights (docs/gather.md "Near reads everywhere"); 0.5 read only hits nearer
        # than half the leaf's diameter
        near_points=4,
        near=1e9,
        near_layout=None,
        near_read="nearest",
        near_second=True,
        near_share=0.1,
        reuse=None,
        tables=None,
    ):
        self.system = s = system.system  # a DynamicRadiosity's built system, or the system itself
        h, pt = s.h, s.patches
        self.n_hr = system.n_hr
        nrm = np.asarray(normals, np.float64).reshape(-1, 3)
        self.normals = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        self.patch = np.asarray(patch_ids, np.int64).ravel()
        lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
        # twice the scene's diagonal (no absolute term: the hemisphere rays keep Embree's float32 t,
        # relative to the segment, so the segment must scale with the scene for a unit-free result)
        self.tmax = 2.0 * float(np.linalg.norm(hi - lo)) or 1.0
        # rays are traced to `reach` first, then the misses on to tmax: the ray contract's minimum
        # distance is relative to the segment, so one long segment (a stray object 50 km away
        # makes the box 100 km wide) would skip every hit within 20 cm. reach follows the surface
        # area, which a small far object hardly changes (as the refiner's eps does).
        # lengths from the main group of objects (geometry.isolated_objects): a stray object far
        # away changes neither the reach nor the samples' random streams
        # tables of the HR nodes the same for every level of one gather (_shared): the lower levels
        # (the probe's, the second's) take the top's; dropped once this level is built
        self._tables = {} if tables is None else tables
        # (the main group's area, shared too: isolated_objects once per gather, not per level)
        size = float(np.sqrt(self._shared("main_area", lambda: isolated_objects(s.mesh).main_area)))
        self.unit = 2.0 ** (np.floor(np.log2(size)) - 12)  # a power of two: exact under 2^k scaling
        self.reach = min(4.0 * size, self.tmax)
        self.eps = float(s.refiner.eps)
        self.margin = margin = max(50 * self.eps, 5e-5 * size)
        points = np.asarray(points, np.float64).reshape(-1, 3)
        onto = batch_map(  # each point its own: by batches on threads
            lambda a, b: onto_patch(pt, self.patch[a:b], points[a:b], margin),
            ranges(len(points), self.POINT_BATCH),
            threads,
        )
        self.points = np.concatenate(onto) if onto else np.zeros((0, 3))
        self.keys = position_keys(self.points, self.unit)
        n = len(self.points)
        self.n = n
        self.rho = (
            pt.reflectance[:, self.patch].T.copy()
            if rho is None
            else np.broadcast_to(np.asarray(rho, np.float64), (n, 3)).copy()
        )
        self.rays, self.shadow_rays, self.seed = int(rays), int(shadow_rays), int(seed)
        # hemisphere rays per sample where they differ (a texel's sub-samples share its rays)
        self.sample_rays = None if sample_rays is None else np.asarray(sample_rays, np.int64)
        self.batch_rays = int(batch_rays or self.BATCH_RAYS)
        # slopes (two levels; off by default, docs/gather.md "The books' fronts"): the rays read a
        # second level's leaf as the linear function its gather samples fit, at the hit, not as
        # their mean (near a shelf's front a book's rays hit the lit front of its neighbour's top,
        # whose leaf's mean takes in its dark back); per entry also the hits' summed offsets in
        # the leaf's frame (wu, wv)
        self.slopes = bool(slopes) and levels >= 2
        # near hits (two levels; docs/gather.md "Near hits"): a ray that hits an HR leaf nearer
        # than `near` x the leaf's diameter sees the leaf's light vary across it (a book's top
        # seen from its neighbour's side), so it reads the nearest of near_points^2 gather samples
        # on that leaf, not the mean of its leaf_points^2; the leaves any such ray hits get those
        # samples (the others keep leaf_points^2). The traced column of a near hit is
        # leaf + n_hr (1 + its nearest point), remapped to n_hr + that sample's index once the
        # second level's layout is known (_remap_near). near_layout (off (n_hr,) first sample of
        # each fine leaf or -1, dark (samples,)): the second level's own rays read them alike.
        two = levels >= 2 or near_layout is not None
        self.near_points = int(near_points) if two and not self.slopes else 0
        self.near = float(near)
        self.near_read = near_read  # "nearest" point, or "bilinear" between the four around the hit
        # w: where every hit weighs 1 the hits per entry (1 byte up to 255 rays, not float32 count /
        # rays: 0.17 GB at the furnished 20k room's texels), read as count / the row's rays
        # (row_rays). Only where every row's rays are a power of two (the texels', the second
        # level's; not the corners' shared rays): dividing the row's sum then gives the bits of
        # the float32 weights' sum. (A str: stored in the precompute)
        rr = np.atleast_1d(self.row_rays)
        hits = not self.slopes and not (self.near_points and near_read == "bilinear")
        hits &= bool(((rr & (rr - 1)) == 0).all())
        self._wtype = np.min_scalar_type(int(rr.max(initial=0))).name if hits else "float32"
        self._diam = None
        if covered_hits not in ("zero", "shown"):
            raise ValueError("covered_hits must be 'zero' or 'shown'")
        # "zero": rays reaching a point contacts.py calls covered read 0 (values_at); "shown": they
        # read their leaf's light on its uncovered part (the covered test's gap tolerance lets some
        # rays from exposed points reach "covered" points that a renderer sees lit)
        self.covered_hits = covered_hits
        # the rays' origins (_origins): eps along the normal unless given
        self.offsets = None if offsets is None else np.asarray(offsets, float)
        self.tri_patch = pt.triangle_patch
        # contacts: covered samples output 0 (static geometry)
        self.leaf0 = np.zeros(0, np.int64)
        if n:
            self.leaf0 = locate_below(h, self.patch, self.points, self.n_hr, self._lines())
        # threads: core.parallel's batch map (1: inline, None: every core); the same values for any
        # count. The covered tests by batches of points on threads (None there is serial)
        self.threads = threads
        cov_threads = 0 if threads is None else threads
        self.dark = (
            h.dark(self.leaf0, self.points, cov_threads, self._leaf_boxes()) if n else np.zeros(0, bool)
        )
        self.gain = None  # (n, 3) scale of the incident light of samples in a slot (None: 1)
        self._slot = None  # slot samples' direct light at their own point and the facing wall's
        self.slot_facing = SLOT_FACING if slot_facing is None else bool(slot_facing)
        self.slot_local = slot_local  # (from, to) gap widths: the local sum fades out (None: SLOT_LOCAL)
        self.slot_drive = SLOT_DRIVE if slot_drive is None else slot_drive
        if covered_samples == "gather":  # diagnostic: gather at covered samples too (contacts ignored there)
            self.dark[:] = False
        elif open_edge > 0 and h.contacts is not None and self.dark.any():
            self._slots(h.contacts, margin, slot_area)
            # the rest within open_edge x h of an open edge of a gap (a tilted block's, whose own
            # wall closes the mouth the slots test) gather where they lie (contacts.covered)
            d = np.flatnonzero(self.dark)
            self.dark[d] = h.contacts.covered(
                self.points[d], self.patch[d], open_edge=open_edge, threads=cov_threads
            )
        # groups (n,) non-decreasing: the output of row j is the mean over the samples of group j
        # (a texel's sub-samples over its area, layouts.texel_samples; covered ones count 0)
        self.group = None if groups is None else np.asarray(groups, np.int64)
        self.n_out = n if groups is None else (int(self.group[-1]) + 1 if n else 0)
        self.stats = {}
        import time

        t0 = time.process_time()
        # progress(ProgressInfo) from the calling thread, raising to cancel (core.progress)
        prog = Progress(progress, {"gather rays": 1.0})

        def report(done, total):
            prog.update("gather rays", done, total, force=done == total)

        # reuse (take (n,), indptr, cols, w): samples with take >= 0 are row `take` of those CSR
        # rows (the same sample's, traced by a probe: the fine leaves' rule below), the rest traced.
        # the batches' rows are a temporary: held on, they doubled this level's weights in memory
        # while the lower levels are precomputed
        self.second = None
        if levels >= 2:
            # two-level gather (issue 19, as Hasan et al. 2006): every HR leaf the rays hit gets
            # leaf_points^2 gather samples of its own (Gauss points) with exact direct light and a
            # gather of its own (levels - 1 levels, half the rays); the outputs' rays read those
            # instead of the leaf. The probe (below) first: its fine leaves depend on the static
            # geometry only, and this level's hits on other leaves need no nearest point
            h = s.h
            c0 = h.child0[: self.n_hr]
            leaves = np.flatnonzero((c0 < 0) | (c0 >= self.n_hr)).astype(np.int64)
            lp, r2 = int(leaf_points), int(second_rays or max(self.rays // 2, 16))
            rp = int(PROBE_RAYS or r2)
            # what a second-level sample's rays depend on (the probe's rows are the second level's)
            rays_kw = dict(
                rays=r2,
                seed=self.seed + 7919,
                batch_rays=self.batch_rays,
                covered_hits=covered_hits,
                covered_samples=covered_samples,
                threads=threads,
                progress=progress,
                open_edge=0.0,  # the leaves' values stand for their uncovered part, as exposure has it
                near=self.near,
                near_read=self.near_read,
                tables=self._tables,
            )
            fine = np.zeros(self.n_hr, bool)

            def grid(nodes, k):  # the second level's k x k samples of HR leaves `nodes`
                if covered_samples == "gather":  # (no sample is covered there)
                    return ff.quadrature(h.corners[nodes], h.nv[nodes], k)
                return _exposed_quadrature(self, nodes, k)

            if self.near_points:
                # fine leaves (near_points^2 samples, their near hits read the nearest): where the
                # near hits of one of any HR leaf's leaf_points^2 gather samples carry near_share
                # of its rays. From the static geometry and the HR leaves only, never the output's
                # rays: an output's light must not depend on what else is gathered with it (a bake
                # of all objects or of one, a farm's split, Live's re-gathers). Those samples'
                # rays are the second level's (traced anyway with iterations): it reuses them on
                # the leaves that are not fine
                # (kept: the second level's samples of the leaves that are not fine are these
                # rows, each leaf's its own, so they are not made again below)
                probe_grid = grid(leaves, lp)
                xp = probe_grid[0].reshape(-1, 3)
                nn = lp * lp
                probe = FinalGather(
                    system,
                    xp,
                    np.repeat(h.normal[leaves], nn, 0),
                    np.repeat(h.patch[leaves], nn),
                    near_points=self.near_points,
                    near_layout=(None, None),
                    **dict(rays_kw, rays=rp),
                )
                fine[probe._fine_leaves(near_share)] = True
                # only its rows are read again (the second level's reuse): its samples' arrays
                # (35 MB at the 100k room) not held through this level's rays
                probe = (probe.indptr, probe.cols, probe.w)
        # the leaves whose near hits read a sample of their own (their nearest point): a hit on
        # another leaf reads the leaf (_remap_near), so its nearest point is not computed
        # (NEAR_FINE_ONLY; its hits then merge into one entry per row and leaf)
        self._near_fine = None
        if NEAR_FINE_ONLY and self.near_points:
            if levels >= 2:
                self._near_fine = fine
            elif near_layout is not None and near_layout[0] is not None:
                self._near_fine = near_layout[0] >= 0
        self._trace = ~self.dark if reuse is None else ~self.dark & (reuse[0] < 0)
        release_free_memory()  # (the set-up's and the probe's freed temporaries: not under the rays')
        self.indptr, self.cols, self.w, self.wu, self.wv = self.merge(
            batch_map(
                trimming(self.gather_batch, self.TRIM_BATCHES),
                self.batches(self.rays),
                threads,
                report if progress else None,
            ),
            threads,
        )
        del self._trace, self._near_fine
        self.__dict__.pop("_boxes", None)  # (the batches' table: not stored)
        self._near_x = None  # (the batches' table, 28 MB at 100k: the lower levels read it from _tables)
        if reuse is not None:
            self._reuse_rows(*reuse)
        if near_layout is not None:
            self._remap_near(*near_layout)
        self.iterations = int(iterations) if levels == 2 else 0
        if levels >= 2:
            # the gather samples' own rays must find gather samples wherever they land with
            # iterations: every HR leaf gets them; else the leaves the rays hit
            used = leaves if iterations > 0 else np.unique(self.cols % self.n_hr).astype(np.int64)
            reuse = None
            k2 = np.where(fine[used], max(self.near_points, 1), lp) ** 2
            x, gw = np.zeros((k2.sum(), 3)), np.zeros(k2.sum())
            start = np.concatenate([[0], np.cumsum(k2)])
            for kk in np.unique(k2):
                sel = np.flatnonzero(k2 == kk)
                if self.near_points and kk == lp * lp:  # the probe's rows of these leaves
                    rows = np.searchsorted(leaves, used[sel])
                    xs, ws = probe_grid[0][rows], probe_grid[1][rows]
                else:
                    xs, ws = grid(used[sel], int(round(kk**0.5)))
                at = (start[sel, None] + np.arange(kk)).ravel()
                x[at], gw[at] = xs.reshape(-1, 3), ws.ravel()
            off = np.full(self.n_hr, -1, np.int64)
            off[used[fine[used]]] = start[:-1][fine[used]]
            if self.near_points:  # the probe's row of each sample of a leaf that is not fine
                at = np.repeat(np.searchsorted(leaves, used) * nn - start[:-1], k2) + np.arange(len(x))
                reuse = (np.where(np.repeat(fine[used], k2), -1, at), *probe)
                del probe, probe_grid
            self.stats["near_leaves"] = int(fine.sum())
            second_near = near_second and self.near_points and iterations and levels == 2
            self.second = FinalGather(
                system,
                x,
                np.repeat(h.normal[used], k2, 0),
                np.repeat(h.patch[used], k2),
                # the second level's direct light reaches the output only through the rays'
                # mean over many leaves, each the mean of its 2 x 2 samples: a quarter of the
                # output's shadow rays (at least 8; was a half: measured against Cycles,
                # docs/accuracy.md "Per frame, 2026-12-03")
                shadow_rays=int(second_shadow_rays or max(self.shadow_rays // 4, 8)),
                levels=levels - 1,
                second_rays=max(r2 // 2, 16),
                leaf_points=leaf_points,
                slopes=self.slopes and (levels > 2 or iterations > 0),  # its rays read a level below
                # with iterations its rays read the samples of the previous pass (_levels)
                near_points=self.near_points,
                near_layout=(off, None) if second_near else None,
                near_share=near_share,
                reuse=reuse,
                # a fine leaf's near_points^2 samples trace FINE_RAYS of the rays each; the
                # others' rows are the probe's (its rays)
                sample_rays=np.where(
                    np.repeat(fine[used], k2), max(int(r2 * FINE_RAYS), 1), rp if self.near_points else r2
                )
                if FINE_RAYS < 1 or (rp != r2 and self.near_points)
                else None,
                **rays_kw,
            )
            self._second_map = (used, gw)
            self._second_start = start
            # exposed leaves left without an uncovered sample (_exposed_quadrature found none)
            ws = np.add.reduceat(gw * ~self.second.dark, start[:-1]) if len(used) else gw
            self.stats["unsampled_leaves"] = int(((ws == 0) & (h.exposure[used] > 0)).sum())
            self._remap_near(off, self.second.dark)
            self._slope_map = (
                _slope_fit(
                    h,
                    used,
                    x.reshape(len(used), -1, 3),
                    gw.reshape(len(used), -1),
                    self.second.dark.reshape(len(used), -1),
                )
                if self.slopes
                else None
            )
            # Blender lights at the second level: the leaf's mean direct light integrated over the
            # leaf (lights.node_incident: finer where it is uneven, a spot's edge), not its 2 x 2
            # points (issue 20: the spot's bounce read 2% dark through them)
            self.second._leaf_nodes = (used, k2)
        self.stats["precompute_cpu"] = time.process_time() - t0
        del self._tables
        self.__dict__.pop("_boxes", None)  # (the covered tests' table: not stored)
        self._D_static = None
        self._shape_cache = {}  # geom_key -> (unit D (n,) float32, indices inside the outline)
        # DynamicRadiosity in "response" mode: D + I of the base solution and of each shape's
        # response at unit emission, so an emission edit is a weighted sum (_incident_by_response)
        self.cache_responses = bool(cache_responses)
        self._responses = {}
        self._responses_of = None
        self._naive_key = None
        self._naive_V = None

    def _remap_near(self, off, dark):
        """Near hits' traced columns (leaf + n_hr (1 + point)) -> n_hr + the sample's index in
        the second level (off: each leaf's first sample or -1; dark: the samples' covered flags,
        None: this level's own); the leaf itself where it has no such sample or it is covered.
        Entries of a row that land on the same column are not merged (the matvec sums them)."""
        if not self.near_points or off is None:  # (None: a probe's, read by _fine_leaves)
            return
        m = self.n_hr
        dark = self.dark if dark is None else dark
        # in place: each batch rewrites its own entries only (a copy, and the near entries' indices
        # gathered for the statistics, took 1 GB at the furnished 20k room's texels)
        cols = self.cols if self.cols.dtype == np.int32 else self.cols.astype(np.int32)

        def part(a, b):  # entries a..b, each its own: on threads (batch_map)
            c = cols[a:b].astype(np.int64)
            j = np.flatnonzero(c >= m)
            pnt, leaf = np.divmod(c[j], m)  # (one pass for both: the same quotient and remainder)
            s = off[leaf] + pnt - 1
            ok = off[leaf] >= 0  # (s of a leaf without samples is no index: a tiny level has fewer)
            ok[ok] = ~dark[s[ok]]
            cols[a + j] = np.where(ok, m + s, leaf)
            w = self.entry_weights(a, b).astype(np.float64)
            return len(j), int(ok.sum()), float(w[j[ok]].sum()), float(w.sum())

        parts = batch_map(part, ranges(len(cols), self.REMAP_BATCH), self.threads)
        if not sum(p[0] for p in parts):
            return
        self.cols = cols
        self.stats["near_entries"] = sum(p[1] for p in parts) / max(len(cols), 1)
        total = sum(p[3] for p in parts)
        self.stats["near_weight"] = sum(p[2] for p in parts) / max(total, 1e-300)

    def _fine_leaves(self, share):
        """HR leaves on which one sample's near hits (traced columns, before _remap_near) carry
        `share` of its rays."""
        m, ip = self.n_hr, self.indptr

        def rows(r0, r1):  # each row's sums its own: by blocks of rows on threads
            c, w = self.cols[ip[r0] : ip[r1]], self.entry_weights(ip[r0], ip[r1])
            j = np.flatnonzero(c >= m)
            row = np.repeat(np.arange(r0, r1), np.diff(ip[r0 : r1 + 1]))[j]
            key = row * m + c[j] % m
            # a (row, leaf)'s weights summed in entry order (a stable sort of the keys, already
            # by row: 4x faster than np.unique's inverse, the same sums)
            o = np.argsort(key, kind="stable")
            key = key[o]
            new = np.r_[True, key[1:] != key[:-1]] if len(key) else np.zeros(0, bool)
            got = np.bincount(np.cumsum(new) - 1, w[j][o], int(new.sum()))
            return np.unique(key[new][got >= max(share, 1e-30)] % m)

        parts = batch_map(rows, _row_blocks(ip, self.ENTRY_BATCH), self.threads)
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def _reuse_rows(self, take, indptr, cols, w):
        """Rows `take` (>= 0) of CSR (indptr, cols, w) in place of this gather's (untraced) rows
        there; near hits' traced columns read as their leaf where this level reads none."""
        old = take >= 0
        cnt = np.diff(self.indptr)
        cnt[old] = np.diff(indptr)[take[old]]
        ip = np.zeros(len(cnt) + 1, np.int64)
        np.cumsum(cnt, out=ip[1:])
        n0 = len(self.cols)
        first = np.where(old, n0 + indptr[:-1][np.maximum(take, 0)], self.indptr[:-1]) - ip[:-1]
        # entries below n0 are this level's, the rest the given rows' (taken from each, not from a
        # concatenated copy of both: 0.1 GB less at the 100k room's second level, the same entries);
        # one field at a time, the old one let go before the next is made (-40 MB at its peak)

        def taken(x, y):
            out = np.empty(ip[-1], np.result_type(x, y))

            def rows(r0, r1):  # each block of rows copies its own entries: on threads (batch_map)
                a, b = ip[r0], ip[r1]
                src = np.repeat(first[r0:r1], cnt[r0:r1]) + np.arange(a, b)
                mine = src < n0
                out[a:b][mine] = x[src[mine]]
                out[a:b][~mine] = y[src[~mine] - n0]

            batch_map(rows, _row_blocks(ip, self.ENTRY_BATCH), self.threads)
            return out

        self.cols = taken(self.cols, cols)
        self.w = taken(self.w, w)
        self.indptr = ip
        if not self.near_points:
            self.cols %= self.n_hr

    def _slots(self, con, margin, area=None):
        """Covered samples in a slot (contacts.Contacts.slots: under a face or solid a gap h in
        front, lit through open edges) gather: from SLOT_DEPTH x h inside their nearest mouth,
        towards their own position (or where they lie, if nearer), and their incident light is
        scaled by the slot's transfer to their own position through all its mouths, with every
        bounce between the walls, over what the gather finds through its nearest mouth
        (slots.slot_transfer / Contacts.through_mouth: the light outside uniform over the
        mouths). Rays from deep in a slot would find its mouth too rarely (view factor
        about (h / 2x)^2). area: (rows, points (r, k, 3)[, chains (r, k), patches (r, k)]): the
        transfer of sample rows[j] is the mean over points[j] (a texel's area, layouts.texel_samples);
        chains: the slot chain Contacts.slots found at each point on patches (layouts.slot_split's),
        reused where that patch's plane and piece are the sample's (slots() reads only those)."""
        s = self.system
        pt = s.patches
        con.close_mouths(s.backend.occluded)  # (and the mouths built: once, before the batches)
        _slot_tables()  # (built once, before the batches)
        dark = np.flatnonzero(self.dark)

        def batch(a, b):  # the slot samples among covered samples dark[a:b], each its own answer
            d = dark[a:b]
            x, hg, foot, chain, mouth = con.slots(self.points[d], self.patch[d])
            ok = (hg > 0) & (x > 0)
            d, x, hg, foot, chain, mouth = d[ok], x[ok], hg[ok], foot[ok], chain[ok], mouth[ok]
            if area is not None:  # the area's points and their chains (slots()), once for both transfers
                rows, ap = area[:2]
                j = np.flatnonzero(np.isin(d, rows))
                r = np.searchsorted(rows, d[j])  # rows ascending (texel_samples' order)
                k = ap.shape[1]
                pa, qa = ap[r].reshape(-1, 3), np.repeat(self.patch[d[j]], k)
                if len(area) > 2:  # known where found on a patch of the sample's plane and piece
                    ca, kp = area[2][r].ravel(), area[3][r].ravel()
                    redo = np.flatnonzero((con.plane[kp] != con.plane[qa]) | (con.piece[kp] != con.piece[qa]))
                    ca[redo] = con.slots(pa[redo], qa[redo])[3]
                else:
                    ca = con.slots(pa, qa)[3]

            # slot_transfer with the samples' own walls and, with slot_facing, black ones (the mouths'
            # view factor: the first bounce of an even outside, every mouth); a texel's the mean
            # over its area's points (area). The mouths' geometry found once for both
            walls = [(self.rho[d], pt.reflectance)]
            if self.slot_facing:
                walls.append((np.zeros((len(d), 3)), np.zeros_like(pt.reflectance)))
            Es = con.slot_transfers(self.points[d], self.patch[d], chain, walls)
            if area is not None:
                Ea = con.slot_transfers(pa, qa, ca, [(np.repeat(rho[j], k, 0), refl) for rho, refl in walls])
                for E, A in zip(Es, Ea):
                    E[j] = A.reshape(len(j), k, 3).mean(1)
            return d, x, hg, foot, mouth, Es[0], Es[-1]

        parts = batch_map(batch, ranges(len(dark), SLOT_BATCH), self.threads)
        d, x, hg, foot, mouth, E, fm = (np.concatenate(p) for p in zip(*parts))
        del parts
        if not len(d):
            return
        xg = np.minimum(x, SLOT_DEPTH * hg)
        q = foot + (xg / x)[:, None] * (self.points[d] - foot)
        stay = np.zeros(len(d), bool)  # off its patch; by rows (each its own: the test's temporaries
        for a, b in ranges(len(d), SLOT_BATCH):  # are 24 x (rows, 4, 3) floats)
            p = self.patch[d[a:b]]
            stay[a:b] = insideness(pt.corners[p][:, None], pt.normal[p][:, None], q[a:b])[:, 0] < margin
        q[stay], xg[stay] = self.points[d[stay]], x[stay]
        x0 = self.points[d].copy()
        if not self.slot_facing:
            self.points[d] = q  # (the rays start there: _origins)
        self.dark[d] = False
        self.gain = np.ones((self.n, 3))
        self.gain[d] = E / con.through_mouth(mouth, xg / hg, self.rho[d], pt.reflectance)
        if self.slot_facing:
            self._slot_facing(con, d, x0, q, x / hg, xg / hg, hg, mouth, E, fm, foot)

    def _slot_facing(self, con, d, x0, q, xi, xq, hg, mouth, E, fm, foot):
        """slot_facing (docs/gather.md, "The facing wall's direct light"): a slot sample's direct
        light is read at its own point x0 (xi gap widths behind its nearest mouth), not at its
        gather point q (xq) through the transfer, which spreads it as an outside even over the
        mouth (a lamp's light entering at a slant is not), and the facing wall's own direct light,
        at the mirrored point x0 + h n, bounces onto it: the walls' exchange with the light taken
        as even along the slot about the point, T_a = D_a + rho_b F T_b, T_b = D_b + rho_a F T_a
        (F: the facing wall's view factor inside the slot, 1 - the mouths'), so
        T_a = (D_a + rho_b F D_b) / (1 - rho_a rho_b F^2). What that local sum misses (the walls
        nearer the mouth carry light deeper) is the transfer's share of the outside's direct
        light less the same local sum for an even outside (>= 0), driven by the outside's
        radiance as the direct light read at the mouth's point (slot_drive="mouth": mid-gap on
        the mouth, facing out, shared along the mouth by steps, _mouth_points) or at q and at its
        mirrored point ("gather"). The gathered (indirect) light keeps the transfer's gain. fm:
        the mouths' view factor (an even outside's first bounce) at x0. Per emitter as the other
        direct light: _slot holds a copy of this gather on the points x0 + h n and the mouth's
        points (or q, q + h n) (their direct light only) and the mix's per-channel weights, over
        the gain that scaled() applies to the sum."""
        pt = self.system.patches
        rho = self.rho[d]
        rb = con._other_wall(mouth, pt.reflectance)
        # the local sum's weight: 1 to slot_local[0] gap widths deep, 0 from slot_local[1] on (there
        # the transfer of what the gather point and its mirror read carries the direct light too).
        # Default everywhere: deep, a point's own shadow rays rarely find the mouths (the furnace
        # slot's deep part scattered 0.75-1.13 over three seeds), but the books' slots see the
        # lamp straight up through their top (faded from 2 to 5: the room's 83% -> 81%)
        lo, hi = SLOT_LOCAL if self.slot_local is None else self.slot_local
        w = np.ones((len(d), 1))
        if np.isfinite(hi):
            w[:, 0] = np.clip((hi - xi) / max(hi - lo, 1e-9), 0.0, 1.0)
        # a mouth at the receiver's own edge (a shorter book's top) with the facing wall going on
        # beyond it: the outside is seen past that extension (fm), the facing wall inside the slot
        # ends at the mouth, and its mirrored points see the outside beyond the receiver's edge
        own = (con.slot_mouths()["own"][mouth] & (con.slot_mouths()["ext"][mouth] > 0))[:, None]
        F = 1.0 - np.maximum(fm, slot_mouth(xi)[:, None])
        a = w / (1.0 - rho * rb * F * F)
        fmb = np.where(own, slot_mouth(xi)[:, None], fm)
        zero = np.zeros_like(pt.reflectance)
        t1 = con.through_mouth(mouth, xq, rho, zero)  # the outside's part of what q finds
        t2 = np.where(own, slot_mouth(xq)[:, None], t1)  # what its mirrored point finds
        tm = con.through_mouth(mouth, xq, rho, pt.reflectance)
        local = a * (fm + rb * F * fmb)  # the local sum for an even outside
        far = np.maximum(E * t1 / tm - local, 0.0)
        # beyond a mouth at the receiver's own edge the gather reads the facing wall's extension
        # (its light: tm - t1), whose share of the transfer took in the facing wall's light inside
        # the slot in proportion: the part of it the local sum now carries is taken out
        # (an even outside's total stays the transfer)
        ext = np.maximum(E * (1.0 - t1 / tm), 1e-300)
        self.gain[d] *= np.where(own, np.clip((E - np.maximum(local, E * t1 / tm)) / ext, 1e-3, 1.0), 1.0)
        del local, ext, fmb, tm  # (rows x 3 floats each: let go before the points below are made)
        near = w[:, 0] > 0
        loc = np.flatnonzero(near)
        nl, nf = len(loc), len(d)
        nrm = self.normals[d]
        mouth_drive = self.slot_drive == "mouth"
        if mouth_drive:
            # the extra direct-light points: x0 + h n where the local sum counts, and the mouth's
            # point (mid-gap on the perpendicular from x0, facing out): its direct light is the
            # flux entering the slot there, an even outside's times the part of its hemisphere
            # that sees the outside (tm2: past the facing wall's extension at an own-edge mouth,
            # 2D). Steadier than the gather point's (its shadow rays find the mouth in 15% of its
            # hemisphere) and unlike it, blind to which wall a slanting lamp lights
            e = np.where(own[:, 0], con.slot_mouths()["ext"][mouth] / hg, 0.0)
            tm2 = 0.5 * (1.0 + 0.5 / np.sqrt(0.25 + e * e))
            mp, mn, inv = self._mouth_points(con, d, x0, foot, hg, mouth)
            fp = np.concatenate([x0[loc] + hg[loc, None] * nrm[loc], mp])
            fn = np.concatenate([-nrm[loc], mn])
            fpatch = np.concatenate([self.patch[d[loc]], self.patch[d[np.unique(inv, return_index=True)[1]]]])
            del mp, mn, t2
        else:
            # the extra direct-light points: x0 + h n where the local sum counts, q there (elsewhere
            # the sample's own point moves to q, as without slot_facing), q + h n everywhere
            self.points[d[~near]] = q[~near]
            fp = np.concatenate([x0[loc] + hg[loc, None] * nrm[loc], q[loc], q + hg[:, None] * nrm])
            fn = np.concatenate([-nrm[loc], nrm[loc], -nrm])
            fpatch = np.concatenate([self.patch[d[loc]], self.patch[d[loc]], self.patch[d]])
        f = copy.copy(self)
        f.points, f.normals, f.patch = fp, fn, fpatch
        f.keys = position_keys(fp, self.unit)
        m = len(fp)
        f.dark, f.n, f.E_static = np.zeros(m, bool), m, np.zeros((m, 3))
        f.texel_area, f.gain, f._slot, f.second, f.group = None, None, None, None, None
        f._D_static, f._shape_cache = None, {}
        for k in (
            "_light_cache",
            "_leaf_nodes",
            "_preview_cache",
            "_bounce_cache",
            "_tables",
            "_host_stores",
            "_boxes",
        ):
            f.__dict__.pop(k, None)
        for k in ("indptr", "cols", "w", "wu", "wv", "offsets", "rho", "leaf0", "sample_rays"):
            setattr(f, k, None)
        g = self.gain[d]
        tiny = 1e-300
        at = np.full(nf, m, np.int64)  # each row's x0 + h n and q in f (m: none, a zero row)
        at[loc] = np.arange(nl)
        self._slot = dict(
            rows=d,
            f=f,
            at=at,
            at_q=q,
            near=near,
            own=a / g,
            facing=rb * F * a / g,
        )
        if mouth_drive:
            self._slot.update(m=far / np.maximum(tm2[:, None] * g, tiny), m_at=nl + inv)
        else:
            self._slot.update(q=far / np.maximum(2 * t1 * g, tiny), qf=far / np.maximum(2 * t2 * g, tiny))

    def _mouth_points(self, con, d, x0, foot, hg, mouth):
        """The mouth's points of slot samples d (slot_drive="mouth"): mid-gap on the mouth, facing
        out of the slot, at the middle of the step of about SLOT_MOUTH_STEP gap widths along the
        mouth that the sample's foot lies in (its foot itself with step 0). Returns (points (k, 3),
        normals (k, 3), inv (len(d),): each sample's point); a point is made from the mouth's own
        geometry and its step only, so it is the same whichever other samples share it."""
        M = con.slot_mouths()
        gi = con.plane[self.patch[d]]
        ng = con.n_g[gi]
        side = np.where(np.einsum("ij,ij->i", self.normals[d], ng) >= 0, 1.0, -1.0)  # the gap's side
        A, B = M["a"][mouth], M["b"][mouth]
        L = np.linalg.norm(B - A, axis=1)
        e = (B - A) / np.maximum(L, 1e-300)[:, None]
        f2, x2 = con._to2d(gi, np.stack([foot, x0], 1)).transpose(1, 0, 2)
        perp = np.column_stack([-e[:, 1], e[:, 0]])
        out = np.where((np.einsum("ij,ij->i", f2 - x2, perp) >= 0)[:, None], perp, -perp)
        if SLOT_MOUTH_STEP > 0:
            nc = np.maximum(np.ceil(L / (SLOT_MOUTH_STEP * hg)), 1.0)
            k = np.clip(np.floor(np.einsum("ij,ij->i", f2 - A, e) * nc / np.maximum(L, 1e-300)), 0, nc - 1)
            m2 = A + ((k + 0.5) * L / nc)[:, None] * e
            key = np.column_stack([mouth, k, out[:, 0] > 0, out[:, 1] > 0, side > 0]).astype(np.int64)
        else:
            m2 = f2
            key = np.arange(len(d))[:, None]
        _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inv = inv.ravel()
        m2, out, gi, hs, sd = m2[first], out[first], gi[first], hg[first], side[first]
        to3 = lambda p2: p2[:, :1] * con.u_g[gi] + p2[:, 1:] * con.v_g[gi]  # noqa: E731
        pts = con.o_g[gi] + to3(m2) + (0.5 * hs * sd)[:, None] * con.n_g[gi]
        return pts, to3(out), inv

    def _facing_part(self, unit):
        """unit(g) at the slot's mirrored points (_slot_facing), or None."""
        S = getattr(self, "_slot", None)
        return None if S is None else unit(S["f"])

    def _dmix(self, D, Df):
        """(n, 3) direct light D with the slot samples' rows mixed (_slot_facing) from their own and
        Df, the same light at _slot's copy's points (x0 + h n of the rows near a mouth, q of
        those, q + h n of all); D itself without slot_facing."""
        if getattr(self, "_slot", None) is None:
            return D
        S = self._slot
        r = S["rows"]
        out = np.array(D, np.float64)
        Df = np.vstack([np.asarray(Df, np.float64), np.zeros((1, np.shape(Df)[1]))])
        nl, nf = int(S["near"].sum()), len(r)
        at = S["at"]
        if "m" in S:  # driven by the mouth's point (slot_drive="mouth")
            out[r] = out[r] * S["own"] + Df[at] * S["facing"] + Df[S["m_at"]] * S["m"]
            return out
        Dq = np.where(S["near"][:, None], Df[np.where(at < nl, at + nl, len(Df) - 1)], out[r])
        out[r] = out[r] * S["own"] + Df[at] * S["facing"] + Dq * S["q"] + Df[2 * nl + np.arange(nf)] * S["qf"]
        return out

    def direct_static(self):
        S = getattr(self, "_slot", None)
        if S is not None:  # (computed with the rest: the precompute captures it)
            S["f"].threads = self.threads
            S["f"].direct_static()
        return super().direct_static()

    def direct_and_emission(self, dyn, direct=True):
        D, E = super().direct_and_emission(dyn, direct)
        if direct and getattr(self, "_slot", None) is not None:
            self._slot["f"].threads = self.threads
            D = self._dmix(D, self._slot["f"].direct_and_emission(dyn)[0])
        return D, E

    def scaled(self, v):
        """Incident light at the samples (n, 3) with the slot samples' transfer applied."""
        return v if self.gain is None else v * self.gain

    # -- batching ------------------------------------------------------------------------------------
    def batches(self, per_sample):
        """Sample ranges of about batch_rays rays each (independent: any order, any thread; their
        bounds do not depend on the thread count)."""
        return ranges(self.n, self.batch_rays // max(per_sample, 1))

    @staticmethod
    def merge(parts, threads=1):
        """Concatenate the partial CSR rows of consecutive batches (one array per thread)."""
        if not parts:
            z = np.zeros(0, np.int64)
            return np.zeros(1, np.int64), z.astype(np.int32), z.astype(np.float32), None, None
        k = 3 if parts[0][3] is None else 5
        # one field at a time, each batch's part of it let go once copied (the caller's list
        # loses its tuples): the batches and the whole never both held (+0.5 GB at the furnished
        # 20k room's texels)
        for j in range(len(parts)):
            parts[j] = list(parts[j])
        out = []
        for i in range(k):
            # copied batch by batch, each let go once copied and the heap's freed pages given back
            # every MERGE_TRIM bytes: the whole and its batches not both resident (the 100k vertex
            # bake's top level: its 70 MB of columns were +0.1 GB at the build's peak; session 34)
            o = np.empty(sum(len(p[i]) for p in parts), np.result_type(*[p[i] for p in parts]))
            a = done = 0
            for p in parts:
                o[a : a + len(p[i])] = p[i]
                a, done = a + len(p[i]), done + p[i].nbytes
                p[i] = None
                if done >= FinalGather.MERGE_TRIM:
                    release_free_memory()
                    done = 0
            out.append(o)
        indptr = np.zeros(len(out[0]) + 1, np.int64)
        np.cumsum(out[0], out=indptr[1:])
        return (indptr, *out[1:], None, None) if k == 3 else (indptr, *out[1:])

    @property
    def E_static(self):
        """(n, 3) the static emission at the samples: their patches' (made where asked, not held: 14
        MB a level at the 100k room's vertex bake, docs/scale.md session 33), or the array set."""
        E = self.__dict__.get("_E_static")
        return self.system.patches.emission[:, self.patch].T.copy() if E is None else E

    @E_static.setter
    def E_static(self, value):
        self.__dict__["_E_static"] = value

    @property
    def row_rays(self):
        """The hemisphere rays of each row (n,), or of every row (an int): w's hit counts over
        them are the weights."""
        return self.rays if self.sample_rays is None else self.sample_rays

    def entry_weights(self, a=0, b=None):
        """(b - a,) float32 the weights of entries a..b-1 (w itself, or its hit counts over their
        rows' rays: equal to the float32 weights a gather stored before counts holds)."""
        b = len(self.w) if b is None else b
        if self.w.dtype.kind != "u":
            return self.w[a:b]
        rr = self.row_rays
        if np.ndim(rr) and b > a:  # each entry's row's rays: the rows a..b spans, repeated over
            # their entries there (a search per row, not per entry: the same rays)
            r0, r1 = np.searchsorted(self.indptr, [a, b - 1], "right") - 1
            ip = np.clip(self.indptr[r0 : r1 + 2], a, b)
            rr = np.repeat(rr[r0 : r1 + 1], np.diff(ip))
        elif np.ndim(rr):
            rr = rr[:0]
        return (self.w[a:b] / rr).astype(np.float32)

    @property
    def weights_bytes(self):
        """Bytes of the CSR weights, the lower levels' included."""
        own = self.indptr.nbytes + self.cols.nbytes + self.w.nbytes
        own += sum(a.nbytes for a in (getattr(self, "wu", None), getattr(self, "wv", None)) if a is not None)
        return own + (self.second.weights_bytes if self.second is not None else 0)

    # -- precompute: hemisphere rays -> CSR rows over HR leaves -------------------------------------
    def _shared(self, name, make):
        """make(), a table of the HR nodes, made once for every level of a gather under
        construction (the split lines, the leaves' diameters, the near points: the same for the
        probe and the second level, each 0.1-0.5 s CPU at 100k), else once here."""
        tables = getattr(self, "_tables", None)
        got = None if tables is None else tables.get(name)
        if got is None:
            got = make()
            if tables is not None:
                tables[name] = got  # (one assignment: threads may race, never half)
        return got

    def _leaf_boxes(self):
        """Hierarchy.leaf_boxes of the partly covered HR leaves, once per gather (not stored): the
        covered test of the rays' hits searches each leaf's chains, not the grid's cells per hit
        (the same answers)."""
        if getattr(self, "_boxes", None) is None:  # one assignment: threads may race, never half
            h, m = self.system.h, self.n_hr

            def make():
                c0, ex = h.child0[:m], h.exposure[:m]
                return h.leaf_boxes(np.flatnonzero(((c0 < 0) | (c0 >= m)) & (ex > 0) & (ex < 1)))

            self._boxes = self._shared("leaf_boxes", make)
        return self._boxes

    def _lines(self):
        """The HR nodes' split lines for locate_below, once per gather (not stored: rebuilt)."""
        if getattr(self, "_split", None) is None:  # one assignment: threads may race, never half
            self._split = self._shared("split", lambda: split_lines(self.system.h, self.n_hr))
        return self._split

    def gather_batch(self, a, b):
        """Samples a..b-1: (hits per row (m,), HR leaf per entry int32, weight per entry float32, and
        with slopes the hits' summed offsets in their leaf's frame per entry (wu, wv) float32, else
        None, None)."""
        s = self.system
        h, pt = s.h, s.patches
        m = b - a
        rr = np.full(m, self.rays) if self.sample_rays is None else self.sample_rays[a:b]
        sels, dirs = [], []
        for R in np.unique(rr):  # covered samples trace nothing
            sel = np.flatnonzero((rr == R) & self._trace[a:b])
            if len(sel):
                d = cosine_directions(self.normals[a + sel], self.keys[a + sel], int(R), self.seed, stream=0)
                sels.append(sel)
                dirs.append(d.reshape(-1, 3))
        if not sels:
            e = np.zeros(0, np.float32) if self.slopes else None
            return np.zeros(m, np.int64), np.zeros(0, np.int32), np.zeros(0, self._wtype), e, e
        sel = np.concatenate(sels)
        row = np.repeat(sel, rr[sel])
        dirs = dirs[0] if len(dirs) == 1 else np.concatenate(dirs)
        org = self._origins(np.arange(a, b))  # (a sample's origin made once, not per ray)
        prim, t = self.first_hit(org[sel], dirs, rr[sel])
        ok = prim >= 0
        patch = np.where(ok, self.tri_patch[np.maximum(prim, 0)], 0)
        # (rows of 3 by take: fancy indexing of (n, 3) rows costs 3x at 100k)
        ok &= np.einsum("ij,ij->i", dirs, np.take(pt.normal, patch, 0)) < 0  # back faces reflect nothing
        i = np.flatnonzero(ok)
        hit = np.take(dirs, i, 0)  # org + t d of the hits only (the hits' rows of 3 by take)
        hit *= t[i, None]
        hit += np.take(org, row[i], 0)
        leaf = locate_below(h, patch[i], hit, self.n_hr, self._lines())
        if self.covered_hits == "zero":
            lit = ~h.dark(leaf, hit, boxes=self._leaf_boxes())  # covered points read 0
        else:
            lit = h.exposure[leaf] > 0
        keep = np.flatnonzero(lit)
        if len(keep) < len(lit):  # (the hits' rows of 3 by take)
            i, leaf, hit = i[keep], leaf[keep], np.take(hit, keep, 0)
        col, er, ew = leaf.copy(), row[i], None  # ew: weights per hit where they are not all 1
        if self.near_points:
            if self._diam is None:  # one assignment: threads may race, never half
                # (a copy: each level stores its own, as before)
                self._diam = self._shared("diam", lambda: _diameters(h, np.arange(self.n_hr))).copy()
            near = t[i] < self.near * self._diam[leaf]
            nf = getattr(self, "_near_fine", None)  # (a restored gather has none: every leaf)
            if nf is not None:
                near &= nf[leaf]
            nr = np.flatnonzero(near)
            k = self.near_points
            if self.near_read == "bilinear":
                pnt, pw = _grid_read(h, leaf[nr], hit[nr], k)
                far = np.setdiff1d(np.arange(len(i)), nr)
                col = np.concatenate([col[far], (leaf[nr, None] + self.n_hr * (1 + pnt)).ravel()])
                er = np.concatenate([er[far], np.repeat(er[nr], 4)])
                ew = np.concatenate([np.ones(len(far)), pw.ravel()])
            else:
                if getattr(self, "_near_x", None) is None:  # one assignment: threads may race, never half
                    self._near_x = self._shared(("near", k), lambda: _near_points(h, self.n_hr, k))
                if len(nr) == len(i):  # (every hit near: no copies)
                    col += self.n_hr * (1 + _nearest_point(self._near_x, leaf, hit))
                else:  # (the near hits' rows of 3 by take)
                    ln = leaf[nr]
                    col[nr] = ln + self.n_hr * (1 + _nearest_point(self._near_x, ln, np.take(hit, nr, 0)))
        span = self.n_hr * (1 + self.near_points**2)
        if self.slopes or (self.near_points and self.near_read == "bilinear"):  # (weights per hit)
            u, inv = np.unique(er.astype(np.int64) * span + col, return_inverse=True)
            cnt = np.bincount(inv, np.ones(len(inv)) if ew is None else ew, len(u))
        else:  # every hit weighs 1: the counts of equal keys, exact (no argsort)
            if span < _SENTINEL:
                key = _row_sorted(er, col, m, span)
            else:
                key = np.sort(er.astype(np.int64) * span + col)
            new = np.ones(len(key), bool)
            new[1:] = key[1:] != key[:-1]
            first = np.flatnonzero(new)
            u, cnt = key[first], np.diff(np.r_[first, len(key)])
        r = u // span
        counts = np.bincount(r, minlength=m).astype(np.int64)
        wu = wv = None
        if self.slopes:
            o, e1, e2 = _leaf_frame(h, leaf)
            d = hit - o
            wu, wv = (
                (np.bincount(inv, np.einsum("ij,ij->i", d, e), len(u)) / rr[r]).astype(np.float32)
                for e in (e1, e2)
            )
        w = (cnt / rr[r]).astype(np.float32) if self._wtype == "float32" else cnt.astype(self._wtype)
        return counts, (u % span).astype(np.int32), w, wu, wv

    @property
    def origins(self):
        """(n, 3) every sample's ray origin (_origins, made on each call)."""
        return self._origins(np.arange(self.n))

    def _origins(self, idx):
        """Ray origins of samples idx: eps along the normal off the point, a slot
        sample's off its gather point (_slots: _slot's at_q, or its point without slot_facing).
        Made per batch, not held: 72 MB at the furnished 20k room's 3 M texel samples."""
        if getattr(self, "offsets", None) is not None:
            return self.offsets[idx]
        org = self.points[idx] + self.eps * self.normals[idx]
        S = getattr(self, "_slot", None)
        if S is not None and len(idx):
            rows = S["rows"]
            pos = np.minimum(np.searchsorted(rows, idx), len(rows) - 1)
            j = np.flatnonzero(rows[pos] == idx)
            org[j] = S["at_q"][pos[j]] + self.eps * self.normals[idx[j]]
        return org

    # hits farther than this x reach (~1 cm at 100k) keep Embree's float32 t, no float64 re-test
    # (visibility's _first): 87% of the hits at 100k; with refine.FF_TARGET 4 the gathered output
    # per object within 0.02% (20k) / 0.16% (100k) of before (docs/scale.md "inexact cuts")
    SURE_HITS = 1e-4

    def first_hit(self, org, dirs, per=None):
        """Nearest hits of unit rays (visibility.first_hit_within: near hits to self.reach first);
        per: rays per origin (first_hit's: org one row per origin)."""
        return first_hit_within(self.system.backend, org, dirs, self.reach, self.tmax, self.SURE_HITS, per)

    # -- run time: values at the HR leaves -----------------------------------------------------------
    def _state(self, dyn):
        """(h, B, E) of the solution in effect on self.system's hierarchy, or None under NAIVE."""
        if dyn.naive_active:
            return None
        return dyn.current()[:3]

    def leaf_values(self, dyn):
        """(n_hr, 3) reflected radiance on the uncovered part of every HR leaf (0 elsewhere); with
        a second level, of the leaves the rays hit: the mean of their gather samples (exact direct
        light + the solution one bounce further) over the uncovered ones."""
        return self._leaf_levels(dyn)[0]

    def _leaf_levels(self, dyn):
        """_levels of the solution in effect and the current direct light (with the tail where a
        shape's scattered light is left to the passes, _Rec.gathered, or a Blender light's:
        _lights_tail)."""
        lit = not dyn.naive_active and self._lights_tail(dyn) and bool(dyn.lights)
        tail = lit or (not dyn.naive_active and any(r.gathered for r in dyn.shapes.values()))
        hot = [self._hot_second(rec, rec.scale[None]) for rec in dyn.lights.values()]
        direct = lambda g: g.direct_and_emission(dyn)[0]  # noqa: E731
        return self._levels(self.solution_values(dyn), direct, tail, lit, hot)

    @staticmethod
    def _lights_tail(dyn):
        """Whether a Blender light's passes over its response go on until their tail is at most
        TAIL_SHARE of the light and take that tail (as a gathered shape's, "zero" or "tail":
        DynamicRadiosity.gather_responses), not the 1 + iterations passes alone. Those stop short
        of the passes' limit by what V's error keeps after them (issue 19, session 32, branch
        indirect, docs/accuracy.md): the two rooms' indirect light at frame 1 (a point and an
        area light) -1.05% from that limit at draft (the response 3 GMRES steps on the draft
        transport: dark there), -0.16% with the tail; the furnace with clutter (rho 0.8 / 0.7 /
        0.5) -2.6 / +1.4 / +0.4% of rho / (1 - rho), with the tail after 5 passes +1.5% in red,
        until the tail is at most 2% (7 passes) within 0.1%."""
        return bool(getattr(dyn, "gather_responses", ""))

    # the tail's largest ratio: a pass's change over the one before tends to rho where light
    # bounces around a closed room (a furnace: B = E / (1 - rho)); above it the tail, r / (1 - r)
    # times the last change, would amplify the passes' noise more than it adds light
    TAIL_MAX = 0.95
    # from V = 0 the passes go on (at most TAIL_PASSES) while the tail is more than TAIL_SHARE of
    # the light: the first changes' ratio overshoots rho (a closed room at rho 0.85: 0.857 after 5
    # passes, +2.3% of light; 0.850 after 13, +0.02%). The furnished 100k room (ratio about 0.59,
    # the gathered output per object against the converged gather after the FE window's event):
    # 0.1 stopped at 5 passes, 4.5% worst object; 0.03 at 7, 2.0%; 0.02 at 8, 1.6% (the tail from
    # a 4-step response: FE 2.3%, AUTO 1.8%); 12 passes and more 1.1% (docs/gather.md, "Every
    # exposed leaf sampled")
    TAIL_PASSES, TAIL_SHARE = 16, 0.02

    def _levels(self, V, direct, tail=False, until=False, hot=(), warm=None):
        """The leaf values the top level's rays read, from the solution's V (n_hr, 3) and
        direct(g) -> (g.n, 3) direct light at a level's samples: V itself with one level; with
        more, the lower levels' gathers (linear in V and the direct light). tail: the passes'
        limit instead of the last pass (the bounces after it: a geometric series of the last
        change, per channel; a shape's passes from V = 0, DynamicRadiosity.gather_responses).
        until (with tail): the passes go on, as from V = 0, while the tail is more than TAIL_SHARE
        of the light (a Blender light's: _lights_tail). hot: [(leaves, their first bounce, its light
        at the second level's samples)] (_hot_second) taken out of the Jacobi passes' reads and
        added to D2 exactly. warm: a key under which the Gauss-Seidel passes from V = 0 keep their
        limit and start from the one kept last (_seidel_warm)."""
        if self.second is None:
            return (V, None, None, None)
        g2 = self.second
        fit = getattr(self, "_slope_map", None)  # None: the rays read the means (slopes off)
        D2 = direct(g2)
        hot = [x for x in hot if x is not None]
        if hot:  # (hot.py: a lamp shade's inside integrated, not hit or missed by the rays)
            D2 = D2 + sum(x[2] for x in hot)
        zero = tail and not V.any()
        # the first pass from V = 0 on the last level reads 0: zeros instead of the read (what it
        # gives, 0 x count summed over the rays; one read of a "zero" event's 8)
        nothing = zero and g2.second is None
        L = g2._levels(V, direct)  # levels > 2: its own levels
        if g2.near_points and len(L[0]) == self.n_hr and not nothing:  # its near hits first read
            L = (self._near_rows(L[0]), None, None, None)  # their leaf's value
        # iterations: the gather samples gather from each other (Jacobi on the HR leaves with exact
        # direct light): every pass moves the solution one bounce further away
        last, sums = [], []
        until = zero or (tail and until)
        gs = self._seidel_blocks() if zero and fit is None and g2.second is None else None
        least, share = max(self.iterations, 2), self.TAIL_SHARE  # (the passes' minimum is least + 1)
        if gs is not None:
            least = max(self.SEIDEL_MIN_PASSES - 1, 2) if self.SEIDEL_MIN_PASSES else least
            share = self.TAIL_SHARE if self.SEIDEL_TAIL_SHARE is None else self.SEIDEL_TAIL_SHARE
        self.stats["warm_passes"] = 0
        if gs is not None and warm is not None:
            got = self._seidel_warm(gs, warm, V, D2)
            if got is not None:
                return got
        for k in range(self.TAIL_PASSES if until else 1 + self.iterations):
            if until and k > least and self._tail_share(sums) <= share:
                k -= 1
                break
            if gs is not None and not (nothing and k == 0):
                Y = self._seidel_pass(gs, L[0], V, D2)
            else:
                Lr = L if not hot or nothing and k == 0 else self._hot_read(L, hot)
                y = g2._read(None if nothing and k == 0 else Lr)  # rho (D2 + read), in place: no (n, 3)
                # temporaries a pass
                batch_map(
                    lambda a, b: _lit(y, D2, g2.rho, a, b), ranges(len(y), self.ROW_BATCH), self.threads
                )
                Y = self._leaf_means(y, V)
                if zero:  # (from nothing: the leaves without samples too)
                    self._fill_dark_leaves(Y)
            if tail:
                last = (last + [Y])[-3:]
                sums = (sums + [_column_sums(Y)])[-3:]
            if fit is None:
                L = (Y, None, None, None)
                continue
            # the linear function the leaf's samples fit: its slopes along the leaf's frame, and
            # S, the slopes times the mean's position (the mean minus S: its value at the frame's
            # origin; 0 where a sample is covered: the mean alone)
            used = self._second_map[0]
            A, ubar = fit
            G = np.einsum("uak,ukc->uac", A, y.reshape(len(used), -1, 3))
            S, Gu, Gv = np.zeros_like(V), np.zeros_like(V), np.zeros_like(V)
            S[used] = np.einsum("ua,uac->uc", ubar, G)
            Gu[used], Gv[used] = G[:, 0], G[:, 1]
            L = (Y, S, Gu, Gv)
        if len(last) == 3:  # the passes are a Jacobi (or Seidel) solve: its limit, whatever V it began at
            Yt, _ = self._tail(last, not zero or (gs is not None and self.SEIDEL_TAIL_LOCAL))
            self.stats["tail_passes"] = k + 1
            L = (Yt,) + tuple(L[1:])
        if gs is not None and warm is not None:
            self._warm[warm] = L[0]
        return L

    # a gathered shape's Gauss-Seidel passes from nothing started from the limit its passes reached at its
    # last event instead (_levels' warm, where WARM_TOL is set and DynamicRadiosity.warm_moves: never a
    # bake's, whose frames must not depend on the frames before them, docs/farm.md): the same fixed point,
    # and a sweep's steps are close, so fewer passes reach it. OFF by default (0): a shape's values would
    # then depend on where it was before, and Live's refine would no longer equal a bake's frame bit for bit
    # (test_live_preview, test_blender_moving): the lead's call. They go on (at least WARM_MIN_PASSES, at
    # most TAIL_PASSES) while a pass changes the leaf values by more than WARM_TOL of their L1 norm (the
    # largest channel's); the change left after the last pass, about r / (1 - r) of that pass's (r the
    # passes' ratio), is not extrapolated (a warm start's change has either sign, so its sums give no
    # ratio). The furnished 100k room's FE window swept by 2.2 cm steps at draft: 2 passes (changes ~8e-3,
    # then ~1.5e-3) instead of 5 from nothing, per object from the passes' limit median 0.007-0.008%, p95
    # 0.03-0.04%, worst 0.19-0.30% (from nothing 0.015 / 0.13 / 0.77%); a 0.5 m move 4 passes, 0.019 / 0.045
    # / 0.70%, bias +0.018% (docs/events.md, session 35, branch ev05), at WARM_TOL 3e-3.
    WARM_TOL, WARM_MIN_PASSES = 0.0, 1

    def _seidel_warm(self, gs, key, V, D2):
        """_levels' leaf values from the limit kept under key (None where there is none, of these
        rows, or WARM_TOL is 0: the passes from nothing)."""
        Y = self.__dict__.setdefault("_warm", {}).get(key)
        if not self.WARM_TOL or Y is None or len(Y) != len(gs["pos"]):
            return None
        changes = self.stats["warm_changes"] = []
        for k in range(self.TAIL_PASSES):
            Yn = self._seidel_pass(gs, Y, V, D2)
            d, s = np.empty(3), np.empty(3)
            for c in range(3):  # (per channel: no (rows, 3) temporaries)
                d[c] = np.abs(Yn[:, c] - Y[:, c]).sum()
                s[c] = np.abs(Yn[:, c]).sum()
            Y = Yn
            changes.append(float((d / np.maximum(s, 1e-300)).max()))
            if k + 1 >= self.WARM_MIN_PASSES and changes[-1] <= self.WARM_TOL:
                break
        self.stats["tail_passes"] = self.stats["warm_passes"] = k + 1
        self._warm[key] = Y
        return (Y, None, None, None)

    # a gathered shape's passes from nothing to their limit (_levels' zero) as Gauss-Seidel: each
    # block of rows (about SEIDEL_BLOCK weights, whole leaves, fixed by the matrix) reads the leaf
    # values the blocks before it in the pass made. The same limit as the Jacobi passes (the fixed
    # point of the same operator) in fewer passes: the furnished 100k room's FE window stops at 5
    # passes (4 reads) instead of 8 (7), per object 0.015-0.018% from the limit at the median,
    # p95 0.13-0.15%, worst 0.71-0.77% (the Jacobi passes 0.009-0.011 / 0.074-0.087 / 0.43-0.49%;
    # the draft's seed floor 0.045-0.058 / 0.71-0.81 / 6-8%; docs/events.md, session 33, branch
    # ev100k). 0: the Jacobi passes. (A Blender light's passes to their limit stay Jacobi: not
    # measured.)
    SEIDEL_BLOCK = 1 << 20
    # the Gauss-Seidel passes' own stopping rule (0 / None: the Jacobi passes' minimum, 1 +
    # max(iterations, 2), and TAIL_SHARE): at least SEIDEL_MIN_PASSES passes (3 or more: the tail
    # takes the last three), then on while the tail is more than SEIDEL_TAIL_SHARE of the light
    SEIDEL_MIN_PASSES, SEIDEL_TAIL_SHARE = 0, None
    # the Gauss-Seidel passes' tail with each object's own ratio where lower than the room's (_tail's
    # local), not the room's alone. OFF by default (the lead's call): with SEIDEL_MIN_PASSES 4 and
    # SEIDEL_TAIL_SHARE 0.05 (one read fewer: a sweep step x0.75-0.93 at draft) the furnished 100k
    # room's FE window stops 0.044% (median) / 0.31% (p95) / 1.87% (worst) per object from the passes'
    # limit, bias +0.012-0.014%, where the room's ratio alone leaves 0.070 / 0.29 / 1.85%, bias +0.052%
    # (main's 5 passes: 0.015 / 0.13 / 0.77%, -0.002%; with this at 5 passes 0.015 / 0.15 / 0.82%,
    # -0.013%: it is for the 4 passes; docs/events.md, session 37, branch ev37). Kept off in session 38
    # (ev38): with every shape tried at 100k (draft, medium) the 4 passes leave 8 small objects 1.5-2.3%
    # from the limit with either ratio (main's 5: 2-5 at 0.5-0.85%), and where the share stops later (6
    # passes: the 20k room, Cornell) each object's ratio is farther from the limit than the room's
    SEIDEL_TAIL_LOCAL = False
    SEIDEL_STEP = 1 << 18  # weights per batch of a block's rows on threads (fixed: the same values)

    def _seidel_blocks(self):
        """The second level's Gauss-Seidel blocks ([(first leaf, end leaf, row ranges, the value
        rows it writes that a read takes, their columns)]) and the arrays its passes read: the
        compacted columns, each value row's column (-1: not read), the leaf means' sample weights
        and sums; None where SEIDEL_BLOCK is 0 or a leaf of _second_map has no sample (the Jacobi
        passes)."""
        if not self.SEIDEL_BLOCK:
            return None
        g2 = self.second
        cols, used = g2._read_cols()
        got = self.__dict__.get("_seidel")
        key = (self.SEIDEL_BLOCK, self.SEIDEL_STEP, READ_STEP)
        if got is not None and got["cols"] is cols and got["block"] == key:
            return got
        start = self._second_start
        if len(start) < 2 or not (np.diff(start) > 0).all():
            return None
        w = self._second_map[1] * ~g2.dark
        ws = np.add.reduceat(w, start[:-1])
        pos = np.full(self.n_hr + (g2.n if self.near_points else 0), -1, np.int32)
        pos[used] = np.arange(len(used))
        cuts = [0]
        for _, r1 in _row_blocks(g2.indptr, self.SEIDEL_BLOCK):
            a = int(np.searchsorted(start, r1))  # (the block ends at a leaf's first row)
            if a > cuts[-1]:
                cuts.append(a)
        if cuts[-1] != len(start) - 1:
            cuts.append(len(start) - 1)
        ok, m, leaves = ws > 0, self.n_hr, self._second_map[0]
        blocks = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            s0, s1 = int(start[a]), int(start[b])
            # each range's read steps made once (every pass of every event reads them: x0.91 of a
            # read's CPU on the 100k room, the same steps, docs/events.md session 36)
            rays = g2.row_rays if g2.w.dtype.kind == "u" else None
            sub = [
                (s0 + r0, s0 + r1, _read_plan(g2.indptr, s0 + r0, s0 + r1, rays))
                for r0, r1 in _row_blocks(g2.indptr[s0 : s1 + 1] - g2.indptr[s0], self.SEIDEL_STEP)
            ]
            # the rows of leaf values the block writes (its leaves with weight, then with near hits
            # its samples') that a read takes, and their columns
            at = leaves[a:b][ok[a:b]]
            if len(pos) > m:
                at = np.concatenate([at, np.arange(m + s0, m + s1)])
            at = at[pos[at] >= 0].astype(np.int32)  # (int32: with pos ~3.6 MB at 100k, half int64)
            blocks.append((a, b, sub, at, pos[at]))
        got = dict(
            cols=cols,
            used=used,
            pos=pos,
            w=w,
            ws=ws,
            ok=ok,
            blocks=blocks,
            block=key,
        )
        self._seidel = got  # (the static geometry's: one assignment, threads may race to make it)
        return got

    def _seidel_pass(self, gs, L, V, D2):
        """One Gauss-Seidel pass of _levels from nothing (_seidel_blocks) from leaf values L (full
        rows, as _leaf_means gives them): the new leaf values (the leaves without samples V's, but
        _fill_dark_leaves'; with near hits the samples' values below)."""
        g2, m = self.second, self.n_hr
        leaves, start = self._second_map[0], self._second_start
        pos, w, ws, ok = gs["pos"], gs["w"], gs["ws"], gs["ok"]
        VT = _columns_f32(L, gs["used"], self.threads)
        Y = np.empty((len(pos), 3))
        Y[:m] = V[:m]
        y = np.zeros((g2.n, 3))
        for a, b, sub, at, cols in gs["blocks"]:
            s0, s1 = int(start[a]), int(start[b])

            def rows(r0, r1, plan):  # each range its own rows
                _csr_rows(g2.indptr, gs["cols"], g2.w, VT, r0, r1, y, g2.row_rays, plan)
                _lit(y, D2, g2.rho, r0, r1)

            batch_map(rows, sub, self.threads)
            k = ok[a:b]
            sums = np.add.reduceat(w[s0:s1, None] * y[s0:s1], start[a:b] - s0, 0)
            Y[leaves[a:b][k]] = sums[k] / ws[a:b][k, None]
            if len(pos) > m:
                Y[m + s0 : m + s1] = y[s0:s1]
            VT[:, cols] = Y[at].T
        self._fill_dark_leaves(Y)
        return Y

    def _tail(self, last, local=True):
        """(the limit of the passes whose last three leaf values are `last`: the last plus the
        geometric series of its change, the ratio of the last two changes' sums per channel, the
        room's or the row's object's where lower; the largest share of the light that series is
        over the channels; local False: the room's alone, as from V = 0, where the objects' ratios
        made single objects worse: 5.0 -> 5.2%)."""
        # (the elementwise steps by ranges of rows and the objects' sums by channel on threads:
        # each range or channel its own, the same values; session 22, docs/threads.md)
        rows = ranges(len(last[2]), self.ROW_BATCH)
        d1, d0 = np.empty_like(last[2]), np.empty_like(last[2])

        def changes(a, b):
            np.subtract(last[2][a:b], last[1][a:b], out=d1[a:b])
            np.subtract(last[1][a:b], last[0][a:b], out=d0[a:b])

        batch_map(changes, rows, self.threads)
        r = self.stats["tail_ratio"] = self._tail_ratio(_column_sums(d1), _column_sums(d0))
        if local:
            # each object's own ratio where it is lower (its light converging faster than the
            # room's; opposite changes: none): one ratio left single objects of the 100k room 3.8%
            # off the passes' limit, the lower of the two 1.8%; each object's alone (uncapped) 9%
            grp = self._tail_groups(len(d1))
            k = grp.max() + 1
            g = np.empty((2, k, 3))

            def sums(i, c):
                g[i, :, c] = np.bincount(grp, (d1, d0)[i][:, c], k)

            batch_map(sums, [(i, c) for i in range(2) for c in range(3)], self.threads)
            g1, g0 = g
            r = np.clip(np.divide(g1, g0, out=np.zeros_like(g1), where=g0 != 0), 0.0, r)
            f = r / (1 - r)

            def series(a, b):  # (per object, then its rows: the same values)
                np.multiply(d1[a:b], np.take(f, grp[a:b], 0), out=d1[a:b])

        else:
            f = r / (1 - r)

            def series(a, b):
                np.multiply(d1[a:b], f, out=d1[a:b])

        batch_map(series, rows, self.threads)
        t, out = d1, np.empty_like(d1)

        def add(a, b):
            np.add(last[2][a:b], t[a:b], out=out[a:b])

        batch_map(add, rows, self.threads)
        return out, float((np.abs(_column_sums(t)) / (np.abs(_column_sums(last[2])) + 1e-300)).max())

    def _tail_share(self, sums):
        """_tail(last, False)'s share from the channel sums of the last three passes' leaf values
        alone (its series sums to the change's sum times r / (1 - r)): the stopping rule after each
        pass, where _tail's full arrays cost 0.04 s a pass on the 100k room."""
        s1 = sums[2] - sums[1]
        r = self._tail_ratio(s1, sums[1] - sums[0])
        return float((np.abs(s1 * (r / (1 - r))) / (np.abs(sums[2]) + 1e-300)).max())

    def _tail_ratio(self, s1, s0):
        """(3,) the passes' ratio per channel: the last change's sum s1 over the one before's s0,
        clipped to [0, TAIL_MAX] (0 where s0 is)."""
        return np.clip(np.divide(s1, s0, out=np.zeros(3), where=s0 != 0), 0.0, self.TAIL_MAX)

    def _tail_groups(self, rows):
        """(rows,) the object of each row of _levels' leaf values (the HR leaves, then with near
        hits the second level's samples: their leaf's)."""
        got = getattr(self, "_tgroups", None)
        if got is None or len(got) != rows:
            h, m = self.system.h, self.n_hr
            leaf = np.arange(m)
            if rows > m:
                leaf = np.concatenate([leaf, np.repeat(self._second_map[0], np.diff(self._second_start))])
            got = self._tgroups = np.asarray(self.system.patches.object_id)[h.patch[leaf]].astype(np.int64)
        return got

    def _fill_dark_leaves(self, Y):
        """Y (n_hr(+), 3) of a pass from V = 0 (tail): the exposed HR leaves whose gather samples
        are all covered (a leaf partly under clutter, its Gauss points under it) keep V in the
        passes, the solution's value, which a shape without a response lacks: they take the
        area mean (uncovered) of the leaves with samples under their lowest ancestor that has
        some (in place). On the 20k room those 417 of 17,774 leaves alone took 5.7% off an
        object's light at 0 (docs/gather.md, "Light events without a response solve"); their
        samples now move onto their uncovered part (_exposed_quadrature): this is for a leaf
        whose uncovered part none of UNCOVER_GRIDS' points finds (none on the 20k and 100k rooms)."""
        got = getattr(self, "_dark_fill", None)
        if got is None:  # from the static geometry once (one assignment: threads may race)
            h, m = self.system.h, self.n_hr
            used, gw = self._second_map
            ws = np.add.reduceat(gw * ~self.second.dark, self._second_start[:-1]) if len(used) else gw
            good, bad = used[ws > 0], used[(ws == 0) & (h.exposure[used] > 0)]
            par = h.parent[:m]
            anc, leaf = [], []
            a, lf = good, good
            while len(a):  # (ancestor, good leaf) pairs, the leaf its own first
                anc.append(a)
                leaf.append(lf)
                keep = par[a] >= 0
                a, lf = par[a[keep]], lf[keep]
            anc, leaf = np.concatenate(anc), np.concatenate(leaf)
            has = np.zeros(m, bool)
            has[anc] = True
            t = par[bad]
            while ((t >= 0) & ~has[np.maximum(t, 0)]).any():
                t = np.where((t >= 0) & ~has[np.maximum(t, 0)], par[np.maximum(t, 0)], t)
            ok = t >= 0
            bad, t = bad[ok], t[ok]
            order = np.argsort(anc, kind="stable")
            anc, leaf = anc[order], leaf[order]
            lo, hi = np.searchsorted(anc, t), np.searchsorted(anc, t, "right")
            row = np.repeat(np.arange(len(bad)), hi - lo)
            col = leaf[np.concatenate([np.arange(x, y) for x, y in zip(lo, hi)] + [[]]).astype(np.int64)]
            w = h.area[col] * h.exposure[col]
            w /= np.bincount(row, w, len(bad))[row]
            got = self._dark_fill = (bad, row, col, w)
        bad, row, col, w = got
        if len(bad):
            Y[bad] = np.stack([np.bincount(row, w * Y[col, c], len(bad)) for c in range(3)], 1)

    def _near_rows(self, V):
        """V (n_hr, 3) leaf values as this level's rays read them when no second level was
        evaluated: with near hits, the rows n_hr + sample their reads point at hold the sample's
        leaf's value."""
        if not self.near_points or self.second is None:
            return V
        own = self.__dict__.get("_near_own")
        if own is None:  # the static geometry's (one assignment: threads may race to make it)
            own = self._near_own = np.repeat(self._second_map[0], np.diff(self._second_start))
        m = self.n_hr
        out = np.empty((m + len(own),) + V.shape[1:], V.dtype)
        out[:m] = V[:m]
        # rows by take (3x faster than fancy indexing), by ranges on threads: each row its own
        part = lambda a, b: np.take(V, own[a:b], 0, out=out[m + a : m + b], mode="clip")  # noqa: E731
        batch_map(part, ranges(len(own), self.ROW_BATCH), self.threads)
        return out

    def _read(self, L, cols=None):
        """(n, 3) what the rays read of leaf values L = (means Y, S, slopes along e1 and e2;
        _levels): the means, or with slopes the linear function at the hits (Y - S at the frame's
        origin; Y may be changed in place after _levels, _light_bounce); None: all 0 (no read).
        cols: columns indexing Y's rows, else _read_cols' compacted ones (the same values)."""
        if L is None:  # leaf values all 0: what the read gives (0 x count summed, over the rays)
            return np.zeros((len(self.indptr) - 1, 3))
        Y, S, Gu, Gv = L
        cols, used = self._read_cols() if cols is None else (cols, None)
        kw = dict(threads=self.threads, rays=self.row_rays, used=used)
        if getattr(self, "wu", None) is None or Gu is None:
            return _csr_matvec(self.indptr, cols, self.w, Y, **kw)
        parts = ((self.w, Y - S), (self.wu, Gu), (self.wv, Gv))
        return sum(_csr_matvec(self.indptr, cols, w, v, **kw) for w, v in parts)

    # a light shape's direct light at the second level's samples (that level's light reaches the
    # output only as indirect light, through the reads): the samples farther from the shape's box
    # centre than FAR_NEAR x its half diagonal take FAR_RAYS shadow rays instead of the level's
    # (100k room, docs/events.md sessions 24 and 26: per object below that level's own seed noise,
    # unbiased, x0.75-0.8 of its shape light; most of its light comes from near the shape)
    FAR_NEAR, FAR_RAYS = 6.0, 4

    def _second_shape(self, em):
        """(n,) float32 a light shape's (Emitter em) unit direct light at this (second) level's
        samples: the level's shadow rays within FAR_NEAR of it, FAR_RAYS beyond (fewer rays than
        the level's only; each sample's own stratified set, so the near samples' values are those
        of the level's rays everywhere, bit for bit)."""
        if not 0 < self.FAR_RAYS < self.shadow_rays:
            return self.direct_light(em, self.edge_shapes)
        c, rad = 0.5 * (em.lo + em.hi), 0.5 * np.linalg.norm(em.hi - em.lo)
        dc = self.points - c
        close = np.einsum("lk,lk->l", dc, dc) < (self.FAR_NEAR * rad) ** 2
        D = np.zeros(self.n, np.float32)
        for idx, rays in ((np.flatnonzero(close), self.shadow_rays), (np.flatnonzero(~close), self.FAR_RAYS)):
            if len(idx):
                D[idx] = self._unoccluded(em, idx, rays)
        return D

    def _read_cols(self):
        """(columns, used): the level's columns renumbered over the leaf values they read (used,
        ascending: the rows of the value array a read takes, _csr_matvec), int32. The 100k room's
        second level reads 187k of its 514k rows: their 0.75 MB a channel stays in a core's cache
        where the whole 2 MB did not (the same products in the same order; docs/threads.md,
        session 21). Made on the first read, they replace self.cols (kept beside them they were a
        second copy, 153 MB at the 100k room's vertex bake; docs/scale.md, session 32): the leaf
        value an entry reads is then used[cols] (leaf_columns); columns set anew are compacted
        again on the next read. Made by batches of ENTRY_BATCH weights on threads: 0.15 s of CPU
        at 100k."""
        got = self.__dict__.get("_cols_read")
        if got is not None and got[0] is self.cols:
            return got
        with _COLS_LOCK:  # (reads on threads: compacted once, and never compacted twice)
            got = self.__dict__.get("_cols_read")
            if got is not None and got[0] is self.cols:
                return got
            cols = self.cols
            seen = np.zeros(int(cols.max()) + 1 if len(cols) else 0, bool)
            parts = ranges(len(cols), self.ENTRY_BATCH)

            def mark(a, b):  # (batches on threads may set the same flags: all to True)
                seen[cols[a:b]] = True

            batch_map(mark, parts, self.threads)
            rank = np.cumsum(seen, dtype=np.int32) - 1
            out = np.empty(len(cols), np.int32)

            def renumber(a, b):  # each range its own
                np.take(rank, cols[a:b], out=out[a:b])

            batch_map(renumber, parts, self.threads)
            got = self._cols_read = (out, np.flatnonzero(seen))
            self.cols = out  # (after _cols_read: whenever self.cols is compacted, it says so)
        return got

    def leaf_columns(self):
        """(entries,) the row of the leaf values each entry reads (the traced columns, remapped):
        self.cols, or used[cols] once a read has compacted them (_read_cols)."""
        got, cols = self.__dict__.get("_cols_read"), self.cols
        return got[1][cols].astype(cols.dtype) if got is not None and got[0] is cols else cols

    def _leaf_means(self, y, V):
        """V (n_hr, 3) with the leaves that have second-level samples set to the mean of those
        samples' values y (second.n, 3) over their uncovered ones; with near hits (near_points)
        y appended below (the rows n_hr + sample the near hits read)."""
        used, gw = self._second_map
        start = self._second_start
        m = self.n_hr
        full = None
        if self.near_points:  # (V's rows, then y: filled by ranges on threads, each its own rows)
            full = np.empty((m + len(y),) + y.shape[1:], np.result_type(V, y))
            out = full[:m]

            def fill(a, b):
                if a < m:
                    out[a : min(b, m)] = V[a : min(b, m)]
                if b > m:
                    full[max(a, m) : b] = y[max(a, m) - m : b - m]

            batch_map(fill, ranges(len(full), self.ROW_BATCH), self.threads)
        else:
            out = V[:m].copy()
        if len(used) and (start[1] - start[0]) * len(used) == start[-1]:  # k^2 samples on every leaf
            got = self.__dict__.get("_mean_weights")
            if got is None:  # the static geometry's (every pass of every event reads them)
                w = gw.reshape(len(used), -1) * ~self.second.dark.reshape(len(used), -1)
                ws = w.sum(1)
                ok = ws > 0
                got = self._mean_weights = (used[ok], w[ok] / ws[ok, None], None if ok.all() else ok)
            rows, wn, ok = got
            yk = y.reshape(len(used), -1, 3)
            out[rows] = np.einsum("uk,ukc->uc", wn, yk if ok is None else yk[ok])
        elif len(used):
            got = self.__dict__.get("_mean_runs")
            if got is None:  # the static geometry's (every pass of every event reads them)
                w = gw * ~self.second.dark
                ws = np.add.reduceat(w, start[:-1])
                got = self._mean_runs = (w, ws, ws > 0, bool((np.diff(start) > 0).all()))
            w, ws, ok, every = got

            def part(a, b):  # leaves a..b: each its own samples' sum (the same segments as one sum)
                s0, s1 = start[a], start[b]
                k = ok[a:b]
                sums = np.add.reduceat(w[s0:s1, None] * y[s0:s1], start[a:b] - s0, 0)
                out[used[a:b][k]] = sums[k] / ws[a:b][k, None]

            # by ranges of leaves on threads, where every leaf has samples (an empty one's
            # reduceat would read past its range's end)
            batch_map(part, ranges(len(used), self.ROW_BATCH) if every else [(0, len(used))], self.threads)
        return out if full is None else full

    def _light_bounce(self, rec, Y, scale=1.0):
        """A Blender light's first bounce off the few HR leaves that hold it (a sun through a small
        opening: lights.bright_leaves) or off its hot ones (a lamp shade's inside: hot.py),
        integrated at the samples explicitly (lights.leaf_bounce) and taken out of the leaf values
        Y (n_hr, 3) the hemisphere rays read (in place, Y holding the light at `scale`). -> (n, 3)
        incident light at that scale, or 0.0. The rays found such a patch a few times per texel: a
        surface's mean scattered by +-2.5% with the gather's seed. Per unit scale, cached per light
        geometry; the second level's samples likewise (_hot_second, in _levels' passes)."""
        got = self._bounce_leaves(rec)
        if got is None or len(got[0]) == 0:
            return 0.0
        idx, Y1, B = got[:3]
        self._take_out(Y, idx, scale * Y1)
        return B * scale

    def _bounce_leaves(self, rec):
        """(idx, Y1 (len(idx), 3), B (n, 3), cache entry) of a Blender light (_light_bounce): the
        leaves hot.bounce_leaves picks, their first bounce at unit scale and its exact incident light
        at this level's samples; None without a second level."""
        if self.second is None:
            return None
        from .hot import bounce_leaves

        cache = self.__dict__.setdefault("_bounce_cache", {})
        got = cache.get(rec.geom_key)
        if got is None:
            h = self.system.h
            g2 = self.second
            # the leaves' first bounce as the rays read it: the second level's samples' mean where
            # a leaf has them, else the hierarchy's (rec.D: the same direct light, a leaf's mean)
            Y1 = np.zeros((self.n_hr, 3))
            if getattr(rec, "D", None) is not None:
                Y1 = rec.D[:, : self.n_hr].T.copy()
            Y1 = self._leaf_means(g2.rho * g2._light(rec)[:, None], Y1)[: self.n_hr]
            ex = h.exposure[: self.n_hr].astype(np.float64)
            idx = bounce_leaves(Y1.mean(1), h.area[: self.n_hr] * ex)  # (hot.py: and the hot leaves)
            B = self._bounce_at(self, idx, Y1[idx] * ex[idx, None])
            got = cache[rec.geom_key] = [idx, Y1[idx], B, {}]  # ({}: the second level's, _hot_second)
            for k in list(cache)[: max(len(cache) - 16, 0)]:
                del cache[k]
        return got

    def _bounce_at(self, g, idx, radiance):
        """(g.n, 3) incident light at level g's uncovered samples from the leaves idx of uniform
        radiance (their value is their uncovered part's mean: spread over the whole polygon)."""
        from .. import lights as lt

        B = np.zeros((g.n, 3))
        ok = np.flatnonzero(~g.dark)
        if len(idx) and len(ok):
            pts = g.points
            if getattr(g, "_slot", None) is not None:  # slot samples: at their gather point,
                pts = pts.copy()  # as the rest of the light their gain scales
                pts[g._slot["rows"]] = g._slot["at_q"]
            h = self.system.h
            B[ok] = lt.leaf_bounce(
                pts[ok], g.normals[ok], g.keys[ok], h.corners[idx], h.nv[idx], radiance,
                self.system.backend, self.eps, rays=g.shadow_rays, seed=g.seed,
            )  # fmt: skip
        return B

    def _hot_second(self, rec, scale=1.0):
        """(idx, Y1, B2) at `scale` of a Blender light's picked leaves (_bounce_leaves) for the
        second level's passes (_levels' hot): their first bounce taken out of what that level's
        rays read, its exact incident light B2 at the level's samples added to their direct light.
        Deep in a room the second level's 64 rays found a lamp shade's hot inside or not, and the
        walls' leaf values the top level reads scattered with them. None: nothing picked."""
        from . import hot

        got = self._bounce_leaves(rec)
        if got is None or len(got[0]) == 0 or not hot.SECOND:
            return None
        idx, Y1, _, more = got
        if "B2" not in more:
            ex = self.system.h.exposure[idx].astype(np.float64)
            more["B2"] = self._bounce_at(self.second, idx, Y1 * ex[:, None])
        return idx, scale * Y1, scale * more["B2"]

    def _hot_read(self, L, hot):
        """L (_levels' leaf values) with the hot leaves' first bounce taken out of its means (a copy)."""
        Y = np.array(L[0])
        for idx, Y1, _ in hot:
            self._take_out(Y, idx, Y1)
        return (Y,) + tuple(L[1:])

    def _take_out(self, Y, idx, Y1):
        """Y (rows, 3) leaf values a level's rays read, in place: rows idx less Y1 (their first
        bounce, integrated apart), at least 0; near hits' rows (n_hr + sample) read those leaves'
        samples: the leaf's mean out of them too (exact on average over the leaf, not per sample)."""
        Y[idx] = np.maximum(Y[idx] - Y1, 0.0)
        if len(Y) > self.n_hr:
            used = self._second_map[0]
            pos = np.minimum(np.searchsorted(used, idx), len(used) - 1)
            a, b = self._second_start[pos], self._second_start[pos + 1]
            b = np.where(used[pos] == idx, b, a)  # (a leaf without samples: none)
            rows = self.n_hr + np.concatenate([np.arange(p, q) for p, q in zip(a, b)] + [[]]).astype(np.int64)
            Yr = np.repeat(np.broadcast_to(Y1, (len(idx), 3)), b - a, 0)
            Y[rows] = np.maximum(Y[rows] - Yr, 0.0)

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
        parts = self._response_parts(dyn)
        if parts is None:
            return None
        total = parts[0][2].copy()
        for _, wt, part, _ in parts[1:]:
            total += wt[None] * part
        return total

    def _response_parts(self, dyn):
        """[(key, weight (3,), part (n, 3), shape record or None)]: the cached parts whose weighted
        sum is _incident_by_response's D + I, the base solution's first (weight None), then the
        light shapes' (weight: their emission) and the Blender lights' (their scale), in that order.
        None where that does not apply."""
        if not self.cache_responses or dyn.incremental != "response" or dyn.naive_active:
            return None
        recs = list(dyn.shapes.values())
        if any(r.U is None or r.used == "NAIVE" or not r.on_surface for r in recs):
            return None
        if any(rec.U is None for rec in dyn.lights.values()):
            return None
        warm = self.__dict__.setdefault("_warm", {})
        if self._responses_of is not dyn:  # parts of another DynamicRadiosity (ids may be reused)
            self._responses.clear()
            warm.clear()
            self._responses_of = dyn
        for k in [k for k in warm if k[1] not in dyn.shapes]:  # (shapes gone: their limits)
            del warm[k]
        dyn._sync()
        h = dyn.system.h
        n = h.n
        ex = h.exposure[:n].astype(np.float64)
        key0 = ("base",)
        if key0 not in self._responses:
            X = dyn._Bbase[:, :n] - dyn.system.base_emission()[:, :n] * ex
            V = self._values_from(h, X)
            Y = self._levels(V, lambda g: g.direct_static())
            D0 = self._dmix(self.direct_static(), self._facing_part(lambda g: g.direct_static()))
            self._responses[key0] = D0 + self._read(Y)
            del X, V, Y, D0
            release_free_memory()  # (each new part's freed temporaries: not resident under the next's)
        out = [(key0, None, self._responses[key0], None)]
        for rec in recs:
            if rec.preview is not None:
                out.append((("preview", rec.geom_key), rec.emission, self._preview_part(dyn, rec), rec))
                continue
            k = ("shape", rec.geom_key, rec.used, rec.gathered)
            if k not in self._responses:
                X = rec.U[:, :n] - dyn._coverage(rec)[None, :n] * ex

                def unit(g, rec=rec):
                    return np.repeat(g._shape(dyn, rec)[0][:, None].astype(np.float64), 3, 1)

                V = self._values_from(h, X)
                warm = None
                if rec.gathered == "zero":  # no response: the passes from nothing and their tail
                    V = np.zeros_like(V)
                    warm = ("shape", rec.key) if dyn.warm_moves and self.WARM_TOL else None  # (_seidel_warm)
                Y = self._levels(V, unit, bool(rec.gathered), warm=warm)
                part = self._dmix(unit(self), self._facing_part(unit)) + self._read(Y)
                self._responses[k] = part.astype(np.float32)
                del X, V, Y, part
                release_free_memory()
            out.append((k, rec.emission, self._responses[k], rec))
        for rec in dyn.lights.values():
            k = ("light", rec.geom_key)
            if k not in self._responses:
                X = rec.U[:, :n]  # a light emits nothing at nodes: all of U is reflected light

                def unit(g, rec=rec):
                    return np.repeat(g._light(rec)[:, None].astype(np.float64), 3, 1)

                tail = self._lights_tail(dyn)
                Y = self._levels(self._values_from(h, X), unit, tail, tail, [self._hot_second(rec)])
                part = self._dmix(unit(self), self._facing_part(unit)) + self._light_bounce(rec, Y[0])
                part += self._read(Y)
                self._responses[k] = part.astype(np.float32)
                del X, Y, part
                release_free_memory()
            out.append((k, rec.scale, self._responses[k], None))
        live = {p[0] for p in out}
        gone = [k for k in self._responses if k not in live]
        for k in gone[: max(len(gone) - 8, 0)]:
            del self._responses[k]
        return out

    # -- Live's preview of a dragged shape (events.records.Preview, docs/live.md) ---------------------
    def _preview_shape(self, dyn, rec):
        """(unit D (n,) float32, indices inside the outline) of a previewed shape: _shape's estimator
        with the preview's shadow rays (the top level's, or the second level's), the same fixed
        stratified set per sample (Hammersley, rotated by the sample's hash), so unbiased in
        expectation; kept for the last few outlines."""
        P = rec.preview
        second = getattr(self, "_leaf_nodes", None) is not None  # (set on the second level only)
        S = P.second_shadow_rays if second else P.shadow_rays
        if S >= self.shadow_rays:
            return self._shape(dyn, rec)
        cache = self.__dict__.setdefault("_preview_cache", {})
        got = cache.get((rec.geom_key, S))
        if got is None:
            em, inside, _ = self._shape_emitter(dyn, rec)
            D = self._preview_direct(dyn, rec, em, S) if em is not None else np.zeros(self.n, np.float32)
            got = cache[(rec.geom_key, S)] = (D, inside)
            for k in list(cache)[: max(len(cache) - 4, 0)]:
                del cache[k]
        return got

    def _unoccluded(self, em, idx=None, rays=0):
        """(n,) float32 em's unit direct light at the samples (idx: at those only) with `rays`
        shadow rays per sample; rays 0: its exact unoccluded form factor, with direct_batch's culls
        (this level copied, the arrays shared or sliced)."""
        g = copy.copy(self)
        g.shadow_rays, g.texel_area = rays, None
        if idx is not None:
            g.points, g.normals, g.keys, g.dark = (
                a[idx] for a in (self.points, self.normals, self.keys, self.dark)
            )
            g.n = len(idx)
        return g.direct_light(em, edges=False)

    def _preview_direct(self, dyn, rec, em, rays):
        """(n,) float32 a previewed shape's unit direct light (Preview.reuse_visibility): its exact
        unoccluded form factor times the visible fraction its reference had at each sample, while
        the outline shares at least Preview.reuse_share of its area with the reference's (rays
        where the reference was culled: behind it or below its horizon). The reference: the shape's
        last exact state (its direct light with all the level's shadow rays), else the last preview
        that took `rays` shadow rays; a preview sharing less takes them and becomes the reference.
        Exact where nothing or everything between a sample and both outlines is occluded; elsewhere
        off by at most the form factor of the two outlines' symmetric difference (the part both
        share keeps its visibility; docs/live.md). Texture output and reuse_visibility off: rays."""
        if not rec.preview.reuse_visibility or self.texel_area is not None:
            g = copy.copy(self)  # this level with fewer shadow rays (the arrays shared)
            g.shadow_rays = rays
            return g.direct_light(em)
        refs = self.__dict__.setdefault("_preview_refs", {})  # shape key -> (exact origin, Emitter, V)
        got, ref = refs.get(rec.key), rec.ref
        origin = None if ref is None else ref.geom_key
        if origin is not None and (got is None or got[0] != origin) and origin in self._shape_cache:
            rem = ref.emitter[1] if ref.emitter is not None and ref.emitter[0] == self.unit else None
            if rem is not None:
                V = _ratio(self._shape_cache[origin][0], self._unoccluded(rem))
                got = refs[rec.key] = (origin, rem, V)
        if got is not None and outline_share(rec, got[1]) >= rec.preview.reuse_share:
            V = got[2]
            D = np.zeros(self.n, np.float32)
            see = np.flatnonzero(V != 0)  # the samples the reference lit or culled (0 x F elsewhere)
            F, Vs = self._unoccluded(em, see), V[see]
            D[see] = F * np.nan_to_num(Vs, nan=0.0)
            new = see[np.isnan(Vs) & (F > 0)]
            if len(new):
                D[new] = self._unoccluded(em, new, rays)
            return D
        D = self._unoccluded(em, rays=rays)
        refs[rec.key] = (origin, em, _ratio(D, self._unoccluded(em)))
        for k in list(refs)[: max(len(refs) - 8, 0)]:
            del refs[k]
        return D

    def _preview_part(self, dyn, rec):
        """(n, 3) float32 a previewed shape's D + I at unit emission: its preview direct light, and
        the rays reading the HR leaves (levels 1) or a second level without iterations (levels 2)
        of its preview response, plus what that read misses of its last exact state
        (_preview_reference). Kept on the record (a colour edit during a drag is a scale)."""
        got = getattr(rec, "_part", None)
        if got is not None and got[0] is self:
            return got[1]
        levels = rec.preview.levels
        V = self._preview_values(dyn, rec)
        ref = self._preview_reference(dyn, rec)
        D = np.repeat(self._preview_shape(dyn, rec)[0][:, None].astype(np.float64), 3, 1)
        last = self.__dict__.get("_preview_last")  # (dyn, exact reference, V, I) of the last read
        if ref is not None and levels < 2 and _same(V, ref[0]):
            # the response kept the exact state's scattered light (the preview's solve took its
            # guess: the 100k room's drags): that state's own indirect light, without the read (of
            # a gathered preview near a gathered state: both V 0, scaled by the power ratio)
            part = D + rec.ratio * ref[1]
        elif levels < 2 and last is not None and last[0] is dyn and last[1] is ref and _same(V, last[2]):
            part = D + last[3]  # it kept the last read preview's (an unchecked guess after a solve)
        else:
            Ie = self._preview_read(dyn, V, levels, lambda g: g._preview_shape(dyn, rec)[0])
            if ref is not None:
                Ie += ref[2]
            self._preview_last = (dyn, ref, V, Ie) if levels < 2 else None  # (levels 2: its outline's)
            part = D + Ie
        part = part.astype(np.float32)
        rec._part = (self, part)
        return part

    def _preview_values(self, dyn, rec):
        """(n_hr, 3) the HR leaves' values of rec's response (its reflected light; 0 unsolved,
        _Rec.gathered)."""
        h = dyn.system.h
        n = h.n
        X = rec.U[:, :n] - dyn._coverage(rec)[None, :n] * h.exposure[:n].astype(np.float64)
        V = self._values_from(h, X)
        return np.zeros_like(V) if rec.gathered == "zero" else V

    def _preview_read(self, dyn, V, levels, direct):
        """(n, 3) float64 the indirect light at unit emission of a response with HR leaf values V
        read as a preview reads it: the HR leaves (levels 1) or a second level without iterations
        (levels 2, whose samples take direct(g), the (g.n,) unit direct light at that level)."""
        if levels >= 2 and self.second is not None:
            g = copy.copy(self)
            g.iterations = 0
            return self._read(g._levels(V, lambda g: np.repeat(direct(g)[:, None].astype(np.float64), 3, 1)))
        return self._read((self._near_rows(V), None, None, None))

    def _preview_reference(self, dyn, rec):
        """(V (n_hr, 3), I (n, 3), C (n, 3)) of the previewed shape's last exact state (Preview.correct):
        its HR leaf values, its exact indirect light (the final gather's, all levels and iterations)
        and what a preview's read of V misses of it (the second level and its iterations: on the
        furnished 100k room the one-level read is 8% darker on average), added to every preview of
        the drag: a preview of that very state is then exact. None: no exact state, its part no
        longer kept, or its response solved on splits since gone (AR, AUTO)."""
        ref = rec.ref
        if ref is None or not rec.preview.correct or ref.gathered == "zero" != rec.gathered:  # (a
            # solved preview of an unsolved state: that state's V, 0, is not what its gather read)
            return None
        key = ("shape", ref.geom_key, ref.used, ref.gathered)
        exact = self._responses.get(key) if self._responses_of is dyn else None
        if exact is None or ref.U is None or ref.U.shape[1] != dyn.system.h.n or len(ref.owned):
            return None
        got = self.__dict__.get("_preview_ref")
        if got is not None and got[0] == (key, rec.preview.levels) and got[2] is dyn:
            return got[1]
        V = self._preview_values(dyn, ref)
        Ie = exact - np.repeat(self._shape(dyn, ref)[0][:, None].astype(np.float64), 3, 1)
        C = Ie - self._preview_read(dyn, V, rec.preview.levels, lambda g: g._shape(dyn, ref)[0])
        self._preview_ref = ((key, rec.preview.levels), (V, Ie, C), dyn)
        return V, Ie, C

    def _naive_values(self, dyn):
        """NAIVE: each used HR leaf reads the rebuilt solution (reflected, shown) at its 2 x 2 Gauss
        points (cached per rebuild)."""
        nv = dyn._naive
        if self._naive_key is nv:
            return self._naive_V
        h = self.system.h
        m = self.n_hr
        c1 = self.leaf_columns()
        used = np.unique(c1[c1 < m]).astype(np.int64)
        if self.second is not None:  # the gather samples' rays land on other leaves too (near
            # hits read samples of leaves in _second_map)
            c2 = self.second.leaf_columns()
            used = np.union1d(np.union1d(used, c2[c2 < m]), self._second_map[0]).astype(np.int64)
        x, gw = ff.quadrature(h.corners[used], h.nv[used], 2)
        pts = x.reshape(-1, 3)
        roots, p2 = nv.remap(pts, np.repeat(h.patch[used], 4))
        from ..output import locate

        hs = nv.system.h
        leaf = locate(hs, roots, p2)
        R = hs.shown(nv.system.B - nv.system.base_emission() * hs.exposure[: hs.n])
        val = R[:, leaf].T.reshape(-1, 4, 3)
        V = np.zeros((self.n_hr, 3))
        V[used] = np.maximum((val * gw[..., None]).sum(1), 0.0)
        self._naive_key, self._naive_V = nv, V
        return V

    def indirect(self, dyn):
        """(n, 3) I = W @ leaf_values: the solution's reflected radiance seen by the hemisphere (a
        Blender light's first bounce off a few bright leaves integrated apart: _light_bounce)."""
        L = self._leaf_levels(dyn)
        own = sum(self._light_bounce(rec, L[0], rec.scale[None]) for rec in dyn.lights.values())
        return own + self._read(L)

    # -- output ----------------------------------------------------------------------------------------
    def evaluate(self, dyn, kind="radiance"):
        """(n, 3) at the samples: "radiance" E + rho (D + I), "reflected" rho (D + I), "incident"
        D + I (irradiance / pi). dyn: the solution (a DynamicRadiosity, or a RadiositySystem: static
        emission only). Covered samples read 0."""
        return self.evaluate_kinds(dyn, (kind,))[kind]

    def evaluate_kinds(self, dyn, kinds=KINDS):
        """{kind: (n, 3)} for several kinds from one gather (see evaluate)."""
        for k in kinds:
            if k not in KINDS:
                raise ValueError(f"unknown kind {k!r} ({', '.join(KINDS)})")
        inc = self._incident_by_response(dyn)
        D, E = self.direct_and_emission(dyn, direct=inc is None)
        if inc is None:
            inc = D + self.indirect(dyn)
        inc[self.dark] = 0.0
        inc = self.scaled(np.maximum(inc, 0.0))  # (the slopes' linear read can dip below 0 at a hit)
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
        return {k: self.outputs(v) for k, v in out.items()}

    def outputs(self, v):
        """Sample values (n, C) -> output values (n_out, C): the means over the groups."""
        if self.group is None:
            return v
        cnt = np.bincount(self.group, minlength=self.n_out)
        return (
            np.stack([np.bincount(self.group, v[:, c], self.n_out) for c in range(v.shape[1])], 1)
            / np.maximum(cnt, 1)[:, None]
        )

    @property
    def out_dark(self):
        """(n_out,) True where every sample of the output is covered."""
        return self.dark if self.group is None else self.outputs(self.dark[:, None].astype(float))[:, 0] == 1
