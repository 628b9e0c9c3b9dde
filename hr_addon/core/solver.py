"""Hierarchical radiosity solve: gather over links, push down, pull up, iterate.

Everything is in radiance units (the system L = L_e + rho sum F L is linear, so no pi appears).
State B is (3, n): every node's radiance, internal nodes holding the area-weighted mean of their
children. Emission lives on leaves; E (3, n) entries of internal nodes are ignored.
"""

import copy
from dataclasses import dataclass, field
import time
import warnings
import weakref

import numpy as np

from .hierarchy import Hierarchy
from .cluster import SLOTS
from .links import Links
from .parallel import batch_map

# GMRES ends a cycle when the recurrence's max-norm residual is below this share of the tolerance
# (the true residual is then computed and checked). The margin is the one the 2-norm test had:
# at 0.5, Live's responses (tol 1e-5, float32) moved 2.2e-6 from the batch ones, beyond the
# 1e-6 that tests/test_events.py holds them to (the tolerance bounds the residual, not the error)
RECURRENCE = 0.1

# terms per batch of a gather (a fixed cut at receiver boundaries: the sums are the same for any
# thread count; about 2^18 terms keep a batch's temporaries in cache-sized pieces)
GATHER_BLOCK = 1 << 18
# a gather whose nonzero sources are fewer than this share sums only the runs they reach (the first
# step of a light shape's response, whose emission lies on a few nodes: at 100k an FE window's
# 91 nodes reach 0.3% of the terms)
SPARSE = 0.02


class ConvergenceWarning(RuntimeWarning):
    pass


@dataclass
class SolveReport:
    iterations: int = 0
    residual: float = np.inf
    converged: bool = False
    seconds: float = 0.0
    links_per_second: float = 0.0
    emitted: float = 0.0  # total power, W (pi x radiance x area)
    absorbed: float = 0.0
    escaped: float = 0.0  # leaving surfaces towards nothing (open scenes)
    messages: list = field(default_factory=list)

    @property
    def energy_error(self):
        """Relative imbalance emitted - absorbed - escaped: a check of reciprocity and push-pull."""
        return abs(self.emitted - self.absorbed - self.escaped) / max(self.emitted, 1e-300)


class Operator:
    """The linear map B -> gathered-and-pushed irradiance term, over one hierarchy + link set."""

    def __init__(self, h: Hierarchy, links: Links, threads=1):
        """threads: core.parallel's threads for the gathers (receiver ranges; equal values for any
        count)."""
        self.h, self.links, self.version, self.threads = h, links, h.version, threads
        # Far links (with a cluster end) gather in an extended index space: the clusters' slots
        # (SH power / irradiance and its gradient) first, then the nodes (farlinks.FarLinks).
        far = links.far
        self.tree = far.tree if far is not None and len(far) else None
        ext = links.extended(h, threads)
        if self.tree is None:
            self.recv, self.src, self.f, self._corr = ext
            self.off = self.nT = 0
        else:
            (self.t_slot, self.t_src, self.t_w), (self.recv, self.src, self.f, self._corr) = ext
            self.off, self.nT = SLOTS * self.tree.C, 2 * len(far)
        sh = self._shared = _shared(links, ext)
        if not sh:
            # numpy converts other index types to intp on every fancy-indexing call: a gather's
            # take is 2.8x faster with intp sources (measured), worth their 4 extra bytes per term
            sh["src"] = self.src.astype(np.intp, copy=False)
            sh["rows"] = _blocks(_runs(self.recv), len(self.recv))
            if self.tree is not None:
                sh["t_src"] = self.t_src.astype(np.intp, copy=False)
                sh["t_rows"] = _blocks(_runs(self.t_slot), len(self.t_slot))
            # the gathers' takes skip numpy's per-index bounds error path (_sum_runs): the sources
            # checked once here (they are the HR build's nodes and the clusters' slots: below
            # every later hierarchy's size too)
            for k, m in (("src", self.nT + self.off + h.n), ("t_src", self.off + h.n)):
                if k in sh and len(sh[k]) and int(sh[k].max()) >= m:
                    raise IndexError(f"Operator: a {k} index beyond the {m} it gathers from")
        self.src, self._rows = sh["src"], sh["rows"]
        self._t_rows = None
        if self.tree is not None:
            self.t_src, self._t_rows = sh["t_src"], sh["t_rows"]
        self._f_base = self._fsum = None
        self.dtype = np.float64
        self.n = h.n
        self.levels = h.levels()
        self.leaves = h.leaves()
        self.area = h.view("area").copy()
        self.normal = h.view("normal")
        self.rho = h.node_rho()
        # Contacts (contacts.py): a leaf's radiance is its mean over the whole leaf, of which only
        # the exposed fraction emits and reflects; None where nothing is covered.
        ex = h.view("exposure").astype(np.float64)
        self.expo = ex if ex.min() < 1 else None
        if self.expo is not None:
            self.rho = self.rho * ex
        self.parent = h.view("parent")
        self.child0 = h.view("child0")
        # Per level, the internal nodes and their 4 children, for the pull.
        self.pull_levels = []
        for lv in self.levels[::-1]:
            inner = lv[self.child0[lv] >= 0]
            if len(inner):
                kids = self.child0[inner][:, None] + np.arange(4)
                self.pull_levels.append((inner, kids, self.area[kids] / self.area[inner][:, None]))
        self.push_levels = [lv[self.parent[lv] >= 0] for lv in self.levels[1:]]

    def canonical(self, nodes, fixed):
        """nodes (ids) in an order of the nodes themselves, not of the ids events gave them: those
        below `fixed` (the HR build's, the same ids in any history) by id, then the others by
        depth, their parent's place at its depth and their child index. AUTO's events number
        their nodes in the order of the edits: a Live session and a bake of its final state
        number the same nodes below the HR leaves differently."""
        got = getattr(self, "_canonical", None)
        if got is None:
            rank, depth = np.zeros(self.n, np.int64), np.zeros(self.n, np.int64)
            rank[self.levels[0]] = np.arange(len(self.levels[0]))  # the roots: the patches' order
            for d, lv in enumerate(self.levels[1:], 1):
                p = self.parent[lv]
                rank[lv[np.lexsort((lv - self.child0[p], rank[p]))]] = np.arange(len(lv))
                depth[lv] = d
            got = self._canonical = (rank, depth)
        rank, depth = got
        nodes = np.sort(nodes)
        ev = nodes[nodes >= fixed]
        return np.concatenate([nodes[nodes < fixed], ev[np.lexsort((rank[ev], depth[ev]))]])

    def float32(self):
        """This operator gathering in float32 (terms, sources and sums; results float64). About
        1e-7 relative error per gather: for solves whose tolerance is far above that."""
        if self.dtype == np.float32:
            return self
        if getattr(self, "_f32", None) is None:
            sh = self._shared
            if "f32" not in sh:
                sh["f32"] = self.f.astype(np.float32)
                if self.tree is not None:
                    sh["t_w32"] = self.t_w.astype(np.float32)
            op = copy.copy(self)
            op.dtype, op.f, op._f_base, op._fsum = np.float32, sh["f32"], None, None
            op._works = {}  # (its own work arrays: _work)
            if self.tree is not None:
                op.t_w = sh["t_w32"]
            self._f32 = op
        return self._f32

    def pull(self, B):
        """Fill internal nodes with the area-weighted mean of their children (deepest first)."""
        for inner, kids, w in self.pull_levels:
            B[:, inner] = np.einsum("cnk,nk->cn", B[:, kids], w)
        return B

    def gather(self, B, base=False):
        """G[r] = sum over links into r of F x B[src], per channel (a sum over each receiver's
        run of the receiver-sorted terms: np.add.reduceat, measured 2.8x faster than bincount).
        With clusters, the sources' SH power comes first and the clusters' gathered SH irradiance
        is handed to their member patches by orientation. base: without the push
        corrections (a node's own form factor sums)."""
        f = self.f
        if base:
            if self._f_base is None:
                self._f_base = np.where(self._corr, 0.0, self.f)
            f = self._f_base
        tree, off, dt, th = self.tree, self.off, self.dtype, self.threads
        C = B.shape[0]
        if C > 1 and all(np.array_equal(B[0], B[c]) for c in range(1, C)):
            # a grey B (an FE or AR shape's emission: the first step of its response) gathers the
            # same in every channel: one channel's sums, repeated
            return np.repeat(self.gather(B[:1], base), C, 0)
        # a B with few nonzero nodes (a light shape's emission: the first step of its response)
        # reaches few receivers: those runs only (the same sums, _sum_runs)
        sparse = np.count_nonzero(B) < SPARSE * B.size
        if tree is None:
            return _sum_runs(self._rows, f, self.src, B.astype(dt, copy=False), self.n, th, sparse=sparse)
        Z, Yw = self._work(C, dt)  # [far-link intermediates | X] per channel; the sums' output
        if sparse:  # (only the runs reached are written: the others' sums must read 0)
            Z[:, : self.nT] = 0.0
            Yw[:] = 0.0
        X = Z[:, self.nT :]
        # the clusters' power and distribution by channel and group of classes on threads (each
        # batch its own clusters and patches), the root's sums between
        parts = [(c, g) for c in range(C) for g in range(tree.groups())]
        P = np.empty((C, tree.C, SLOTS))
        batch_map(lambda c, g: tree.power_group(B[c, : tree.K], g, P[c]), parts, th)
        for c in range(C):
            X[c, :off] = tree.power_root(P[c]).ravel()
        X[:, off:] = B
        _sum_runs(self._t_rows, self.t_w, self.t_src, X, self.nT, th, out=Z[:, : self.nT], sparse=sparse)
        Y = _sum_runs(self._rows, f, self.src, Z, off + self.n, th, out=Yw, sparse=sparse)
        G = Y[:, off:].copy()  # (the caller's: push adds into it) distribute_group() reads the
        # clusters' part Y[:, :off] only
        E = Y[:, :off].reshape(C, tree.C, SLOTS)
        acc = np.empty_like(E)
        acc[:, 0] = E[:, 0]
        batch_map(lambda c, g: tree.distribute_group(E[c], acc[c], g, G[c, : tree.K]), parts, th)
        return G

    def _work(self, C, dt):
        """(Z (C, nT + off + n) dt, Y (C, off + n) float64): gather()'s work arrays, kept between
        its calls. New ones each call (34 MB at 100k) cost a response step 8k page faults, 0.03 s
        of system time (measured: an FE event's 4 steps 0.11-0.13 s of its 0.47-0.53 s CPU). A
        dense gather writes the same runs every time and every other entry stays 0."""
        work = self.__dict__.setdefault("_works", {})
        key = (C, np.dtype(dt).str)
        if key not in work:
            work[key] = (np.zeros((C, self.nT + self.off + self.n), dt), np.zeros((C, self.off + self.n)))
        return work[key]

    def release_work(self):
        """Let go of gather()'s work arrays (its float32 copy's too): 74 MB at 100k, made again by
        the next gather. A bake drops them between its solves and the final gather's stages."""
        self.__dict__.pop("_works", None)
        if getattr(self, "_f32", None) is not None:
            self._f32.__dict__.pop("_works", None)

    def push(self, G):
        """Add every ancestor's gathered radiance to its descendants (top down)."""
        for lv in self.push_levels:
            G[:, lv] += G[:, self.parent[lv]]
        return G

    def emitted(self, E):
        """Emission as node means: E (radiance of the emitting surface) x exposure."""
        return E if self.expo is None else E * self.expo

    def apply(self, B, E):
        """One Jacobi sweep: new leaf radiance E + rho G from the current B. Returns (B_new, G)."""
        G = self.push(self.gather(B))
        Bn = np.zeros_like(B)
        lf = self.leaves
        Bn[:, lf] = self.emitted(E)[:, lf] + self.rho[:, lf] * G[:, lf]
        return self.pull(Bn), G


# Links -> (its extended() terms, {name: array}): see _shared
_SHARED = weakref.WeakKeyDictionary()


def _shared(links, ext):
    """The operator's arrays that depend on a link set's terms only (intp sources, the receivers'
    runs, float32 copies), shared by the operators of every hierarchy version over those terms:
    AUTO's events add nodes below the leaves, a new Operator per event over the same
    Links.extended() (cached there: the node geometry under a link set never changes). Dropped
    with the Links, or when its extended() gives other arrays."""
    got = _SHARED.get(links)
    if got is None or got[0] is not ext:
        got = _SHARED[links] = (ext, {})
    return got[1]


def _runs(keys):
    """(first index, key) of each run of equal values in a sorted index array."""
    if not len(keys):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return first, keys[first]


def _blocks(runs, m):
    """The runs (first, key) cut into blocks of about GATHER_BLOCK terms at run boundaries:
    [(first, key, term start, term end)] (the cut depends on the terms only, never on threads)."""
    first, key = runs
    out, r0 = [], 0
    while r0 < len(first):
        r1 = int(np.searchsorted(first, first[r0] + GATHER_BLOCK, "left"))
        r1 = min(max(r1, r0 + 1), len(first))
        a, b = int(first[r0]), int(first[r1]) if r1 < len(first) else m
        out.append((first[r0:r1] - a, key[r0:r1], a, b))
        r0 = r1
    return out


def _sum_runs(blocks, f, src, X, n, threads=1, out=None, sparse=False):
    """(C, n) per channel c the sums over each run (receiver) of the terms f x X[c][src], zero where
    there is none; by blocks of runs on `threads` threads (each block writes its own receivers).
    out: a zeroed (C, n) array to write into. sparse: when few sources are nonzero (below SPARSE
    of them), only the runs with a term from one, each run whole: the same products summed in the
    same order, so the same values (the other runs' sums are of zero products: 0)."""
    out = np.zeros((len(X), n)) if out is None else out
    if sparse:
        nz = X[0] != 0
        for c in range(1, len(X)):
            nz |= X[c] != 0
        if np.count_nonzero(nz) < SPARSE * len(nz):
            cut = batch_map(lambda blk: _touched(blk, nz, src), [(blk,) for blk in blocks], threads)
            blocks = [blk for blk in cut if blk is not None]

    def block(c, k):
        first, key, a, b = blocks[k]
        # mode="clip": no per-index bounds error path (the sources are checked once, Operator),
        # the same values, 15% faster than X[c][src] (100k room)
        if isinstance(a, np.ndarray):  # _touched's: the terms' indices
            out[c, key] = np.add.reduceat(np.take(f, a) * np.take(X[c], np.take(src, a), mode="clip"), first)
        else:
            out[c, key] = np.add.reduceat(f[a:b] * np.take(X[c], src[a:b], mode="clip"), first)

    batch_map(block, [(c, k) for c in range(len(X)) for k in range(len(blocks))], threads)
    return out


def _touched(blk, nz, src):
    """A block of runs (_blocks) cut to the runs with a term whose source is nonzero (nz): (first,
    key, the terms' indices, None) with `first` into those indices; None if there is none."""
    first, key, a, b = blk
    t = np.flatnonzero(nz[src[a:b]])
    if not len(t):
        return None
    r = np.unique(np.searchsorted(first, t, "right") - 1)
    start = first[r]
    length = np.append(first[1:], b - a)[r] - start
    at = np.cumsum(length) - length  # each run's first term among the kept ones
    idx = a + np.repeat(start - at, length) + np.arange(int(length.sum()))
    return at, key[r], idx, None


def solve(
    h: Hierarchy,
    links: Links,
    E,
    B0=None,
    tol=1e-7,
    max_iter=2000,
    op: Operator = None,
    method="gmres",
    energy=True,
    verify=True,
    steps=None,
    inner=None,
):
    """Solve B = E + rho K B to a relative residual max|E + rho K B - B| / max|B| below tol.

    E: (3, n) leaf emission (radiance). B0: warm start (3, n), e.g. the previous frame's solution.
    method "gmres" (restarted, matrix-free; needs a fraction of the sweeps of "jacobi" and copes
    with reflectance near 1) or "jacobi" (the classic HR gather sweep, monotone from below).
    max_iter bounds the operator applications; a ConvergenceWarning says when it was not enough.
    energy: fill the report's power balance (two more gathers). verify: GMRES computes the true
    residual of its answer (one more gather) instead of trusting the Arnoldi recurrence's, which
    stops at RECURRENCE x tol; equal in exact arithmetic and within the gathers' rounding
    otherwise (float32: about 1e-7). steps: instead of a tolerance, exactly that many GMRES
    steps (operator applications) from zero, whatever B0 and tol: the result is then the same
    for every history of warm starts (docs/gather.md, *A fixed response solve*). inner (with
    steps): (n,) True at the splits to solve on (_gmres_steps). Returns (B, report).
    """
    t0 = time.perf_counter()
    op = op or Operator(h, links)
    E = np.asarray(E, float)
    rep = SolveReport()
    B = op.pull(np.array(B0, float, copy=True)) if B0 is not None else op.pull(_leaf_only(E, op))
    G = None  # the gathered G of the returned B where the solver computed it (the power balance's)
    if steps is not None:
        B, G = _gmres_steps(op, E, int(steps), rep, inner)
    elif method == "jacobi":
        B = _jacobi(op, E, B, tol, max_iter, rep)
    else:
        B, G = _gmres(op, E, B, tol, max_iter, rep, verify=verify)
    if not rep.converged:
        msg = (
            f"Radiosity did not converge: relative residual {rep.residual:.2e} after {rep.iterations} "
            f"iterations (max reflectance {float(op.rho.max()):.3f}; reflectance close to 1 converges "
            "slowly)."
        )
        rep.messages.append(msg)
        warnings.warn(msg, ConvergenceWarning, stacklevel=2)
    rep.seconds = time.perf_counter() - t0
    rep.links_per_second = len(op.f) * rep.iterations / max(rep.seconds, 1e-12)
    if energy:
        _energy(op, B, E, G, rep)
    return B, rep


def _jacobi(op, E, B, tol, max_iter, rep):
    lf = op.leaves
    scale = max(float(np.abs(E[:, lf]).max()) if E.size else 0.0, 1e-300)
    for it in range(1, max_iter + 1):
        Bn, _ = op.apply(B, E)
        diff = float(np.abs(Bn[:, lf] - B[:, lf]).max())
        B = Bn
        scale = max(scale, float(B[:, lf].max()))
        rep.iterations, rep.residual = it, diff / scale
        if rep.residual < tol:
            rep.converged = True
            break
    return B


def _gmres(op, E, B, tol, max_iter, rep, restart=30, verify=True):
    """Restarted GMRES on (I - rho K) x = E over the leaf unknowns of all three channels at once.
    Its vector products use einsum, not BLAS: a multithreaded BLAS spent more time waking its
    threads for these small products than the gathers took when the cores were busy (measured
    35 ms of a 90 ms solve with OpenBLAS on 2 shared cores)."""
    lf, C = op.leaves, E.shape[0]
    n = C * len(lf)
    full = np.zeros((C, op.n))
    rho = op.rho[:, lf]
    last = [None]  # G of the latest K(x)

    def K(x):  # rho K x: one gather + push, as in a Jacobi sweep without emission (op.apply)
        full[:, lf] = x.reshape(C, -1)
        last[0] = G = op.push(op.gather(op.pull(full)))
        return (rho * G[:, lf]).ravel()

    b = op.emitted(E)[:, lf].ravel()
    x = B[:, lf].ravel().copy()
    count = 0
    while True:
        r = b - x + K(x)
        count += 1
        scale = max(float(np.abs(x).max()), float(np.abs(b).max()), 1e-300)
        rep.iterations, rep.residual = count, float(np.abs(r).max()) / scale
        if rep.residual < tol:
            rep.converged = True
            break
        if count >= max_iter:
            break
        beta = _norm(r)
        m = min(restart, max_iter - count)
        V = np.zeros((m + 1, n))
        Hm = np.zeros((m + 1, m))
        cs, sn, g = np.zeros(m), np.zeros(m), np.zeros(m + 1)
        V[0], g[0] = r / beta, beta
        j_end, est = 0, np.inf
        for j in range(m):
            w = V[j] - K(V[j])
            count += 1
            for _ in range(2):  # classical Gram-Schmidt, twice: orthogonal to working precision
                hcol = np.einsum("ij,j->i", V[: j + 1], w)
                w -= np.einsum("i,ij->j", hcol, V[: j + 1])
                Hm[: j + 1, j] += hcol
            Hm[j + 1, j] = _norm(w)
            if Hm[j + 1, j] > 0:
                V[j + 1] = w / Hm[j + 1, j]
            for i in range(j):  # apply the previous Givens rotations to the new column
                Hm[i, j], Hm[i + 1, j] = (
                    cs[i] * Hm[i, j] + sn[i] * Hm[i + 1, j],
                    -sn[i] * Hm[i, j] + cs[i] * Hm[i + 1, j],
                )
            d = np.hypot(Hm[j, j], Hm[j + 1, j])
            cs[j], sn[j] = (Hm[j, j] / d, Hm[j + 1, j] / d) if d > 0 else (1.0, 0.0)
            Hm[j, j], Hm[j + 1, j] = d, 0.0
            g[j], g[j + 1] = cs[j] * g[j], -sn[j] * g[j]
            j_end = j + 1
            if Hm[j + 1, j] == 0 and d == 0:
                break
            est = _max_residual(V, cs, sn, g, j)
            if est < RECURRENCE * tol * scale:
                break
        y = np.linalg.solve(
            np.triu(Hm[:j_end, :j_end]) + np.diag(np.where(np.diag(Hm[:j_end, :j_end]) == 0, 1.0, 0.0)),
            g[:j_end],
        )
        x += np.einsum("i,ij->j", y, V[:j_end])
        if not verify and est < RECURRENCE * tol * scale:
            rep.iterations, rep.converged, rep.residual = count, True, est / scale  # the recurrence's
            last[0] = None  # no gather of this x
            break
    # Krylov iterates can undershoot by ~tol where the answer is 0; radiance is never negative.
    # The verified exits follow the residual's K(x): its gather is the solution's unless the clip
    # changes x.
    G = last[0] if x.min() >= 0 else None
    np.maximum(x, 0.0, out=x)
    full[:, lf] = x.reshape(C, -1)
    return op.pull(full.copy()), G


def _gmres_steps(op, E, steps, rep, inner=None):
    """`steps` GMRES steps on (I - rho K) x = E from x = 0: x in span(b, Kb, ..., K^(steps-1) b)
    minimising the residual's area-weighted 2-norm (one operator application per step, none for
    the start's residual, which is b), then x + r (a Richardson step on that residual, which the
    Arnoldi relation gives without an application). The area weights make the result independent of how the
    leaves are split where the splits change nothing (another shape's nodes under an HR leaf: a
    leaf's area is its children's sum): the same for a farm node and one process whatever the
    hierarchy's other splits. No residual is computed (rep.residual: the recurrence's 2-norm,
    relative to b's). That holds in exact arithmetic; bit for bit with inner = ((n,) True at the
    internal nodes of the tree to solve on, the HR build's node count), None: the hierarchy's
    tree: the tree's leaves are the unknowns, in op.canonical's order, nodes below them read
    their value (as Hierarchy.extend gives nodes added later): the same in any hierarchy with
    those splits, however its nodes are numbered."""
    C = E.shape[0]
    pull, lf = op.pull, op.leaves
    if inner is not None:
        pull, tree = tree_pull(op, inner[0], fill=False)
        lf = op.canonical(np.flatnonzero(tree & ~inner[0]), inner[1])

    full = np.zeros((C, op.n))
    rho = op.rho[:, lf]
    a = op.area[lf]
    s = np.tile(np.sqrt(a / a.mean()), C)  # x' = s x: the weighted norm is the plain one of x'

    def K(v):  # s rho K (v / s)
        full[:, lf] = (v / s).reshape(C, -1)
        return s * (rho * op.push(op.gather(pull(full)))[:, lf]).ravel()

    b = s * op.emitted(E)[:, lf].ravel()
    beta = _norm(b)
    x = np.zeros_like(b)
    if beta > 0 and steps > 0:
        V = np.zeros((steps + 1, len(b)))
        Hm = np.zeros((steps + 1, steps))
        V[0] = b / beta
        m = 0
        for j in range(steps):
            w = V[j] - K(V[j])
            m = j + 1
            for _ in range(2):  # classical Gram-Schmidt, twice, as _gmres
                hcol = np.einsum("ij,j->i", V[: j + 1], w)
                w -= np.einsum("i,ij->j", hcol, V[: j + 1])
                Hm[: j + 1, j] += hcol
            Hm[j + 1, j] = _norm(w)
            if Hm[j + 1, j] == 0:  # the Krylov space is invariant: x is exact
                break
            V[j + 1] = w / Hm[j + 1, j]
        # the least-squares problem min |beta e1 - H y| of the (m + 1) x m Hessenberg matrix
        rhs = np.zeros(m + 1)
        rhs[0] = beta
        y, *_ = np.linalg.lstsq(Hm[: m + 1, :m], rhs, rcond=None)
        x = np.einsum("i,ij->j", y, V[:m])
        # and one Richardson step on the residual, free: by the Arnoldi relation it is
        # V[: m + 1] (beta e1 - H y) without an operator application; x + r leaves the residual
        # K r, about rho times smaller (the 100k room's gathered output after 4 steps: per object
        # 0.05% -> 0.03% from 6 steps', docs/gather.md "Light events at 100k: fewer steps...")
        res = rhs - Hm[: m + 1, :m] @ y
        x += np.einsum("i,ij->j", res, V[: m + 1])
        rep.residual = float(np.linalg.norm(res)) / beta  # (the steps', before that last one)
    rep.iterations, rep.converged = steps, True
    full[:, lf] = np.maximum(x / s, 0.0).reshape(C, -1)  # radiance is never negative
    return (op.pull if inner is None else tree_pull(op, inner[0])[0])(full.copy()), None


def tree_pull(op, inner, fill=True):
    """(pull, tree): pull(B) fills the internal nodes of the tree whose internal nodes are
    `inner` ((n,) bool) with the area-weighted mean of their children, deepest first, and with
    fill the nodes below its leaves with their value, top down (as Hierarchy.extend); tree: (n,)
    True at the tree's nodes."""
    par = op.parent[: op.n]
    tree = (par < 0) | inner[np.maximum(par, 0)]

    def pull(B):
        for p, kids, w in op.pull_levels:
            k = inner[p]
            B[:, p[k]] = np.einsum("cnk,nk->cn", B[:, kids[k]], w[k])
        if fill:
            for lv in op.levels[1:]:
                out = lv[~tree[lv]]
                B[:, out] = B[:, par[out]]
        return B

    return pull, tree


def _max_residual(V, cs, sn, g, j):
    """The max norm of GMRES's residual after step j, from the Arnoldi recurrence: |g[j + 1]| is its
    2-norm, and the vector is V[: j + 2]^T q with q the last unit vector rotated back through the
    Givens rotations (one pass over V, no operator application). The 2-norm alone bounds the max
    norm, but it is up to sqrt(n) times larger: stopping on it solved the 20k room's base solution
    to 1.3e-7 for a tolerance of 1e-5 (14 operator applications)."""
    q = np.zeros(j + 2)
    q[j + 1] = 1.0
    for i in range(j, -1, -1):
        q[i], q[i + 1] = cs[i] * q[i] - sn[i] * q[i + 1], sn[i] * q[i] + cs[i] * q[i + 1]
    return abs(g[j + 1]) * float(np.abs(np.einsum("i,ij->j", q, V[: j + 2])).max())


def _norm(v):
    return float(np.sqrt(np.einsum("i,i->", v, v)))


def _leaf_only(E, op):
    B = np.zeros((E.shape[0], op.n))
    B[:, op.leaves] = op.emitted(E)[:, op.leaves]
    return B


def _energy(op, B, E, G, rep):
    """Power balance from independent sums: emitted, absorbed (1 - rho) x incident, and escaped:
    what leaves each linked node towards no surface (1 - sum of its outgoing F x V)."""
    lf, a = op.leaves, op.area
    ex = np.ones(op.n) if op.expo is None else op.expo
    rep.emitted = float(np.pi * np.sum(op.emitted(E)[:, lf] * a[lf]))
    G = op.push(op.gather(B)) if G is None else G
    rep.absorbed = float(np.pi * np.sum((ex[lf] - op.rho[:, lf]) * G[:, lf] * a[lf]))
    # Each node's outgoing form factor sum as a source, counting links held by it and by its
    # ancestors (and clusters): the gather of unit radiance, pushed down to the leaves. Push
    # corrections only reshape what a receiver gathers (they sum to zero per link), so they do
    # not count here; only the exposed part of a receiver takes what a link sends it.
    if op._fsum is None:  # depends on the operator only
        op._fsum = op.push(op.gather(ex[None], base=True))[0]
        op._f_base = None  # (its only use: 34 MB at 100k, held through the bake for nothing)
    fsum = op._fsum
    rep.escaped = float(np.pi * np.sum(B[:, lf] * a[lf] * (1 - fsum[lf])))
