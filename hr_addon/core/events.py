"""Dynamic light shapes on a hierarchical radiosity solution (numpy only; see docs/events.md).

A light shape is a planar polygon (outer ring + holes, concave allowed) with RGB emitted radiance lying on
existing surfaces. Shapes appear, change colour/intensity, move/reshape and disappear; overlapping
shapes add. Four methods:

- NAIVE: the shapes become new input patches, laid over the surface (offset by `naive_offset` x the
  size of the shapes and their surfaces along the surface normal, so the covered surface is hidden
  behind them); parts of a shape off every surface do not emit, as in the other methods. Overlaps, holes and
  concavity are resolved by a slab (trapezoid) decomposition of all shape and patch edges of a plane, so
  each light patch has one summed emission and the reflectance of the one surface patch under it. A new
  RadiositySystem is built (links from scratch) and solved cold. Baseline and accuracy reference.
- AR (adaptive refinement): nodes wholly inside the shape are marked, partly covered nodes are
  descended (HR leaves subdivided) down to `min_area_rel` x scene area, where the overlap fraction is
  used. At most `node_budget` nodes per shape; beyond it the remaining boundary nodes use FE.
- FE (fractional emissivity): no refinement; each overlapped HR leaf emits overlap fraction x emission
  (clip.classify, exact for concave shapes with holes against convex nodes).
- AUTO (ours): the outline per node by FE or AR from an exact error bound (FE's L1 emission error on a
  node is 2 f (1 - f) A |E|): the worst nodes are split until the shape's relative emission error is
  below `emission_tol`. Transport: the existing links were refined for the old, dark walls and average a
  source node's radiance over the whole node, which smears a small bright shape; so the shape's first
  bounce is gathered separately at the receivers: exact point-to-shape form factor (contour integral
  over the rings) x ray-cast visibility at 2 x 2 Gauss points, receivers split below the HR leaves where
  rho x (range of F V) > bf_rel (the B x F criterion: only where the light is strong and uneven),
  shadow edges included. The existing links then carry the further bounces. The link set is not
  changed, so every cached response stays valid. Error at or below NAIVE's at a few times FE's cost.

Incremental solution (AR/FE/AUTO), `incremental=`:
- "response" (default): the system is linear, so B = B_base + sum_s E_s * U_s with U_s the solution for
  shape s at unit emission (per channel). Adding a shape is one cold solve of its own response; a colour
  or intensity change is a scale, a removal drops a term: no solve, history independent (the sum is
  recomputed, nothing is subtracted), radiance never negative. A moved or reshaped shape's solve
  starts from its old response's scattered light (equal to a fresh add to the tolerance). Responses
  stay valid when other shapes add or remove nodes below HR leaves (such nodes carry no links: their
  solution is the parent's, extended by copy).
- "warm": one state, re-solved with the total emission, warm-started from the previous solution
  (solver.solve(B0=...)), as in the paper.
Nodes below the HR leaves are reference-counted by the shapes that need them and deleted (Hierarchy.compact)
when none does, so node and link counts return to the baseline.

A shape on no surface is handled by NAIVE (for the whole configuration while it is active), and the
report says so. Invalid shapes (NaN, not planar, degenerate, an outline that crosses itself, holes outside the outline
or overlapping) raise InputError naming the shape.
"""
from collections import OrderedDict
from dataclasses import dataclass, field
import time

import numpy as np

from . import clip
from . import formfactor as ff
from .geometry import InputError, MeshInput, _newell
from .output import locate, radiance_at
from .output import loop_plan as _loop_plan
from .output import loop_radiance as _loop_radiance
from .radiosity import RadiositySystem
from .refine import link_form_factors
from .solver import Operator, solve

METHODS = ("NAIVE", "AR", "FE", "AUTO")


@dataclass
class LightShape:
    rings: list            # world-space rings (M_i, 3): outer first, then holes; planar
    emission: np.ndarray   # (3,) radiance (Cycles strength x colour)
    name: str = ""


@dataclass
class EventReport:
    kind: str                  # "add", "remove", "emission", "reshape"
    key: object = None
    name: str = ""
    method: str = ""           # method actually used: NAIVE, AR, FE, AUTO, "AR+FE" (AR stopped at the budget)
    seconds: float = 0.0
    iterations: int = 0        # solver iterations
    nodes_added: int = 0
    nodes_removed: int = 0
    nodes: int = 0             # after the event
    links: int = 0             # after the event (the solver's links)
    direct_links: int = 0      # AUTO: links from the shape computed for its first bounce (not kept)
    memory_bytes: int = 0      # nodes + links + cached responses
    emission_l1: float = 0.0   # relative L1 error of the shape's emission field (exact for FE/AR/AUTO)
    covered: float = 1.0       # fraction of the shape's area lying on surfaces
    messages: list = field(default_factory=list)


@dataclass
class FrameReport:
    events: list = field(default_factory=list)
    seconds: float = 0.0
    iterations: int = 0
    nodes_added: int = 0
    nodes_removed: int = 0
    nodes: int = 0
    links: int = 0
    memory_bytes: int = 0
    messages: list = field(default_factory=list)

    @property
    def changed(self):
        return bool(self.events)

    @property
    def method(self):
        return "+".join(sorted({e.method for e in self.events})) if self.events else ""


@dataclass
class _Rec:
    key: object
    name: str
    rings: list                # validated world rings
    emission: np.ndarray       # (3,)
    method: str                # requested
    used: str = ""
    c: np.ndarray = None       # plane: point, normal, in-plane basis
    n: np.ndarray = None
    u: np.ndarray = None
    v: np.ndarray = None
    tol: float = 0.0           # distance tolerance of its plane (plane_tol x its own size)
    rings2d: list = None
    area: float = 0.0
    group: np.ndarray = None   # coplanar root patches (emitting side)
    roots: np.ndarray = None   # coplanar root patches the shape overlaps
    covered: float = 0.0
    on_surface: bool = False
    cov_nodes: np.ndarray = None
    cov_vals: np.ndarray = None
    owned: np.ndarray = None   # nodes whose split this shape needs (reference counted)
    U: np.ndarray = None       # (3, n) response at unit emission
    D: np.ndarray = None       # (3, n) AUTO: first-bounce radiance per unit emission, at link receivers
    emission_l1: float = 0.0
    budget_hit: bool = False
    direct_links: int = 0
    msgs: list = field(default_factory=list)

    @property
    def geom_key(self):
        return tuple(r.tobytes() for r in self.rings)


class DynamicRadiosity:
    def __init__(self, system: RadiositySystem, method="AUTO", min_area_rel=1e-5, node_budget=20000,
                 plane_tol=1e-3, incremental="response", emission_tol=0.05, bf_rel=3e-3,
                 naive_params=None, naive_offset=1e-4, cache_size=8,
                 direct_min_area_rel=None, response_tol=None, response_float32=False):
        """system: a built RadiositySystem (its hierarchy is extended in place below the HR leaves).
        min_area_rel: smallest AR node, fraction of the total scene area. node_budget: most nodes one shape
        may add (AR/AUTO). plane_tol: distance tolerance of "planar" and "on a surface", fraction of
        the shape's own bounding-box diagonal (never the scene's). emission_tol: AUTO's target relative L1 error of the emission field.
        bf_rel: AUTO's first bounce: a receiver node is kept when rho x the range of F x V over it is
        below bf_rel (radiance per unit emitted radiance). direct_min_area_rel: smallest such receiver
        (and AUTO outline) node, default 4 x min_area_rel. incremental: "response" or "warm" (module
        doc). naive_params: RefineParams for NAIVE rebuilds (default: the system's). cache_size: removed
        shapes whose responses need no extra nodes are kept for instant re-adding (0: off).
        response_tol: solver tolerance of the shapes' responses (default: the system's, as the
        base solution); response_float32: those solves gather in float32 (Live Relight, whose
        output is float32, uses both: see docs/events.md)."""
        method = method.upper()
        if method not in METHODS:
            raise ValueError(f"Unknown method '{method}' (choose from {', '.join(METHODS)})")
        if incremental not in ("response", "warm"):
            raise ValueError("incremental must be 'response' or 'warm'")
        self.system = system
        self.method = method
        self.incremental = incremental
        self.min_area_rel, self.node_budget, self.plane_tol = min_area_rel, int(node_budget), plane_tol
        self.emission_tol, self.bf_rel = emission_tol, bf_rel
        self.direct_min_area_rel = direct_min_area_rel if direct_min_area_rel is not None else 4 * min_area_rel
        self.naive_params, self.naive_offset, self.cache_size = naive_params, naive_offset, cache_size
        self.tol = system.tol
        self.response_tol = response_tol if response_tol is not None else system.tol
        self.response_float32 = response_float32
        self.links = system.links
        h = system.h
        self.n_hr = h.n
        self.hr_internal = h.child0[:h.n] >= 0
        pt = system.patches
        self.total_area = float(pt.area.sum())
        lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
        self.diag = float(np.linalg.norm(hi - lo)) or 1.0
        # occluder triangles (bounds, plane ids) for the first-bounce shaft test
        tris = pt.triangles
        tri_patch = np.concatenate([np.arange(len(pt.nv)), np.flatnonzero(pt.nv == 4)])
        self._tri_lo, self._tri_hi = tris.min(1), tris.max(1)
        scale = 1e-6 * np.sqrt(self.total_area)
        key = np.column_stack([np.round(pt.normal * 1e6), np.round(np.einsum("ij,ij->i", pt.normal, pt.corners[:, 0]) / scale)])
        self._patch_plane = np.unique(key, axis=0, return_inverse=True)[1].ravel()
        self._tri_plane = self._patch_plane[tri_patch]
        self.shapes = OrderedDict()          # key -> _Rec
        self._cache = OrderedDict()          # (geom_key, method) -> _Rec
        self._ref = np.zeros(h.n, np.int64)  # shapes needing each node's split
        self._op = None
        self._op_version = None
        self._naive = None                   # active NAIVE rebuild (_NaiveState) or None
        self._guess = None                   # (3, n) first guess of a reshaped shape's response
        self._plan = None                    # (key, output.loop_plan) of loop_radiance
        E0 = system.base_emission()
        self._Bbase, rep = self._solve(E0)
        self._X = self._Bbase.copy()          # warm mode state
        self._B = self._Bbase.copy()
        self.base_iterations = rep.iterations

    # -- public API ---------------------------------------------------------------------------------
    @property
    def h(self):
        """The hierarchy B lives on (the NAIVE rebuild's while one is active)."""
        return self._naive.system.h if self._naive is not None else self.system.h

    @property
    def B(self):
        """(3, n) current node radiance on self.h."""
        return self._naive.system.B if self._naive is not None else self._B

    @property
    def naive_active(self):
        return self._naive is not None

    def loop_radiance(self, domain="CORNER", smooth_angle=30.0):
        """(L, 3) float32 per input loop (or (V, 3) per vertex for domain='POINT') of the input mesh."""
        if self._naive is not None:
            return self._naive.loop_radiance(self.system.mesh, domain, smooth_angle)
        h = self.system.h
        key = (id(h), h.version, h.n, domain, smooth_angle)     # the plan depends on geometry only
        if self._plan is None or self._plan[0] != key:
            self._plan = (key, _loop_plan(h, self.system.mesh, smooth_angle, domain))
        return _loop_radiance(h, self._B, self.system.mesh, smooth_angle, domain, plan=self._plan[1])

    def add(self, key, shape):
        t0 = time.perf_counter()
        rep = self._add(key, shape)
        rep.iterations += self._finish([rep])
        return self._stamp(rep, t0)

    def remove(self, key):
        t0 = time.perf_counter()
        rep = self._remove(key)
        rep.iterations += self._finish([rep])
        return self._stamp(rep, t0)

    def set_emission(self, key, emission):
        t0 = time.perf_counter()
        rep = self._set_emission(key, emission)
        rep.iterations += self._finish([rep])
        return self._stamp(rep, t0)

    def apply(self, shapes: dict) -> FrameReport:
        """Make `shapes` (key -> LightShape, the full active set) current with as little work as possible."""
        t0 = time.perf_counter()
        fr = FrameReport()
        valid = {k: self._validate(k, s) for k, s in shapes.items()}   # raise before changing anything
        evs = []
        for k in [k for k in self.shapes if k not in valid]:
            evs.append(self._remove(k))
        for k, (rings, em, name) in valid.items():
            rec = self.shapes.get(k)
            if rec is None:
                continue
            same_geom = len(rec.rings) == len(rings) and all(np.array_equal(a, b) for a, b in zip(rec.rings, rings))
            if not same_geom:
                # the new response is solved from the new emission plus the old one's scattered
                # light: a moved shape lights the room much as before (fewer iterations)
                self._guess = self._scattered(rec)
                try:
                    r1 = self._remove(k)
                    r2 = self._add(k, LightShape(rings, em, name), validated=(rings, em, name))
                finally:
                    self._guess = None
                r2.kind = "reshape"
                r2.nodes_removed += r1.nodes_removed
                r2.seconds += r1.seconds
                evs.append(r2)
            elif not np.array_equal(rec.emission, em):
                evs.append(self._set_emission(k, em))
        for k, (rings, em, name) in valid.items():
            if k not in self.shapes:
                evs.append(self._add(k, LightShape(rings, em, name), validated=(rings, em, name)))
        if evs:
            fr.iterations += self._finish(evs)
        fr.events = evs
        for e in evs:
            fr.iterations += e.iterations
            fr.messages += e.messages
        fr.nodes_added = sum(e.nodes_added for e in evs)
        fr.nodes_removed = sum(e.nodes_removed for e in evs)
        fr.seconds = time.perf_counter() - t0
        self._counts(fr)
        return fr

    def emission(self):
        """(3, n) leaf emission currently in effect on system.h (base + shapes' coverage fields)."""
        self._sync()
        E = self.system.base_emission()
        for rec in self.shapes.values():
            if rec.on_surface and rec.cov_nodes is not None:
                E += rec.emission[:, None] * self._coverage(rec)[None]
        return E

    def memory_bytes(self):
        from .hierarchy import Hierarchy
        h = self.h
        links = len(self._naive.system.links) if self._naive is not None else len(self.links)
        cached = sum(sum(a.nbytes for a in (r.U, r.D) if a is not None)
                     for r in list(self.shapes.values()) + list(self._cache.values()))
        return h.n * Hierarchy.node_bytes() + links * 32 + cached

    def evaluate(self, points, patch_ids):
        """Radiance at surface points (N, 3) lying on input patches patch_ids (N,): returns
        (B (N, 3), E (N, 3)), total and emitted radiance of the leaf holding each point."""
        if self._naive is not None:
            return self._naive.evaluate(points, patch_ids)
        self._sync()
        h = self.system.h
        leaf = locate(h, patch_ids, points)
        return self._B[:, leaf].T.copy(), self.emission()[:, leaf].T.copy()

    def radiance_at(self, points, patch_ids, smooth=True):
        """Radiance (N, 3) at surface points lying on input patches (output.radiance_at on the current
        solution; under NAIVE, points covered by a light patch read that patch)."""
        if self._naive is not None:
            roots, pts = self._naive.remap(points, patch_ids)
            return radiance_at(self._naive.system.h, self._naive.system.B, roots, pts, smooth)
        self._sync()
        return radiance_at(self.system.h, self._B, patch_ids, points, smooth)

    # -- events -------------------------------------------------------------------------------------
    def _stamp(self, rep, t0):
        rep.seconds = time.perf_counter() - t0
        self._counts(rep)
        return rep

    def _counts(self, rep):
        rep.nodes = self.h.n
        rep.links = len(self._naive.system.links) if self._naive is not None else len(self.links)
        rep.memory_bytes = self.memory_bytes()

    def _add(self, key, shape, validated=None):
        t0 = time.perf_counter()
        if key in self.shapes:
            raise KeyError(f"A light shape with key {key!r} is already active (use apply() or remove it first).")
        rings, em, name = validated or self._validate(key, shape)
        rep = EventReport("add", key, name)
        n0 = self.system.h.n
        rec = _Rec(key, name, rings, em, self.method)
        cached = self._cache.pop((rec.geom_key, rec.method), None) if self.method != "NAIVE" else None
        if cached is not None:
            cached.emission, cached.key, cached.name = em, key, name
            rec = cached
            rep.messages.append(f"shape '{name}': response reused from the cache")
        else:
            self._plane(rec)
            self._find_surface(rec)
            if not rec.on_surface:
                rec.used = "NAIVE"
                rec.msgs.append(f"shape '{name}' lies on no surface: handled by NAIVE")
            elif self.method == "NAIVE":
                rec.used = "NAIVE"
            else:
                rep.iterations += self._incremental_add(rec)
        self.shapes[key] = rec
        rep.method, rep.covered, rep.emission_l1 = rec.used, rec.covered, rec.emission_l1
        rep.direct_links = rec.direct_links
        rep.messages += rec.msgs
        rep.nodes_added = self.system.h.n - n0
        rep.seconds = time.perf_counter() - t0
        return rep

    def _remove(self, key):
        t0 = time.perf_counter()
        if key not in self.shapes:
            raise KeyError(f"No active light shape with key {key!r}.")
        rec = self.shapes.pop(key)
        rep = EventReport("remove", key, rec.name, rec.used)
        if rec.owned is not None and len(rec.owned):
            self._ref[rec.owned] -= 1
            rep.nodes_removed = self._gc()
        elif rec.U is not None and self.cache_size > 0 and rec.used != "NAIVE":
            self._cache[(rec.geom_key, rec.method)] = rec
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
        rep.seconds = time.perf_counter() - t0
        return rep

    def _set_emission(self, key, emission):
        t0 = time.perf_counter()
        if key not in self.shapes:
            raise KeyError(f"No active light shape with key {key!r}.")
        rec = self.shapes[key]
        em = self._check_emission(emission, rec.name)
        rec.emission = em
        rep = EventReport("emission", key, rec.name, rec.used)
        rep.seconds = time.perf_counter() - t0
        return rep

    def _finish(self, reps):
        """Bring B up to date after a batch of events; returns solver iterations spent here."""
        its = 0
        naive = [r for r in self.shapes.values() if r.used == "NAIVE"]
        if naive:
            t0 = time.perf_counter()
            self._naive = _NaiveState(self, list(self.shapes.values()))
            its += self._naive.iterations
            names = ", ".join(f"'{r.name}'" for r in naive if not r.on_surface)
            if self.method != "NAIVE" and names:
                reps[-1].messages.append(f"NAIVE rebuild of all {len(self.shapes)} active shape(s) because {names} "
                                         f"lie(s) on no surface ({time.perf_counter() - t0:.2f} s)")
            return its
        self._naive = None
        self._sync()
        if self.incremental == "response":
            B = self._Bbase.copy()
            for rec in self.shapes.values():
                B += rec.emission[:, None] * rec.U
            self._B = B
        else:
            E = self.system.base_emission()
            extra = np.zeros_like(E)
            for rec in self.shapes.values():
                cov = self._coverage(rec)[None] * rec.emission[:, None]
                if rec.used == "AUTO":
                    E += rec.emission[:, None] * self._push(rec.D)
                    extra += cov
                else:
                    E += cov
            self._X, rep = self._solve(E, B0=self._X)
            its += rep.iterations
            self._B = self._X + self._operator().pull(extra)
        return its

    # -- validation and geometry ---------------------------------------------------------------------
    @staticmethod
    def _check_emission(emission, name):
        em = np.asarray(emission, float).reshape(-1)
        if em.shape != (3,):
            raise InputError(f"Light shape '{name}': emission must be 3 values (RGB), got shape {em.shape}.")
        if not np.isfinite(em).all():
            raise InputError(f"Light shape '{name}': emission {tuple(em)} is not finite.")
        if (em < 0).any():
            raise InputError(f"Light shape '{name}': negative emission {tuple(em)}.")
        return em

    def _validate(self, key, shape):
        name = (getattr(shape, "name", "") or str(key))
        rings = getattr(shape, "rings", None)
        if rings is None or len(rings) == 0:
            raise InputError(f"Light shape '{name}' has no rings.")
        out = []
        for i, r in enumerate(rings):
            try:
                r = np.array(r, dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"Light shape '{name}': ring {i} is not an array of 3D points.") from None
            if r.ndim != 2 or r.shape[1] != 3 or len(r) < 3:
                raise InputError(f"Light shape '{name}': ring {i} must be (M >= 3, 3) points, got {r.shape}.")
            if not np.isfinite(r).all():
                raise InputError(f"Light shape '{name}': ring {i} has NaN or infinite coordinates.")
            out.append(r)
        em = self._check_emission(shape.emission, name)
        size = _size(out)
        nrm = _newell(out[0])
        if np.linalg.norm(nrm) <= 1e-9 * size ** 2:
            # No net area (e.g. a bowtie whose two lobes cancel): the plane from the points instead
            pts = out[0]
            sv, vt = np.linalg.svd(pts - pts.mean(0), full_matrices=False)[1:]
            if len(sv) < 3 or sv[1] <= 1e-9 * max(sv[0], 1e-300):
                raise InputError(f"Light shape '{name}': the outer ring has zero area (its points lie on a line).")
            nrm = vt[2]
        n = nrm / np.linalg.norm(nrm)
        c = out[0].mean(0)
        off = max(float(np.abs((r - c) @ n).max()) for r in out)
        tol = _plane_tolerance(out, self.plane_tol)
        if off > tol:
            raise InputError(f"Light shape '{name}' is not planar: a point is {off:.3g} off its plane "
                             f"(tolerance {tol:.3g}, {self.plane_tol:.2%} of its size).")
        key = tuple(r.tobytes() for r in out)
        problem = self._outline_ok.get(key) if hasattr(self, "_outline_ok") else None
        if problem is None:
            axis = np.eye(3)[int(np.argmin(np.abs(n)))]
            u = np.cross(n, axis)
            u /= np.linalg.norm(u)
            v = np.cross(n, u)
            problem = outline_problem([np.stack([(r - c) @ u, (r - c) @ v], -1) for r in out])
            cache = self.__dict__.setdefault("_outline_ok", OrderedDict())
            cache[key] = problem
            while len(cache) > 256:
                cache.popitem(last=False)
        if problem:
            raise InputError(f"Light shape '{name}': {problem}. A light shape must be a simple outline "
                             "(no crossings; holes inside it and apart): redraw it, e.g. as faces that "
                             "do not overlap.")
        if np.linalg.norm(_newell(out[0])) <= 1e-9 * size ** 2:
            raise InputError(f"Light shape '{name}': the outer ring has zero area.")
        return out, em, name

    def _plane(self, rec):
        nrm = _newell(rec.rings[0])
        rec.n = nrm / np.linalg.norm(nrm)
        rec.c = rec.rings[0].mean(0)
        axis = np.eye(3)[int(np.argmin(np.abs(rec.n)))]
        rec.u = np.cross(rec.n, axis)
        rec.u /= np.linalg.norm(rec.u)
        rec.v = np.cross(rec.n, rec.u)
        rec.rings2d = [self._to2d(rec, r) for r in rec.rings]
        rec.tol = _plane_tolerance(rec.rings, self.plane_tol)
        a = [abs(clip.polygon_area_2d(r)) for r in rec.rings2d]
        rec.area = a[0] - sum(a[1:])
        if rec.area <= 0:
            raise InputError(f"Light shape '{rec.name}': its holes cover its whole area.")

    @staticmethod
    def _to2d(rec, p):
        d = np.asarray(p, float) - rec.c
        return np.stack([d @ rec.u, d @ rec.v], -1)

    def _find_surface(self, rec):
        pt = self.system.patches
        tol = rec.tol
        dist = np.abs((pt.corners - rec.c) @ rec.n).max(1)
        al = pt.normal @ rec.n
        cand = (dist <= tol) & (np.abs(al) >= 0.999)
        if (cand & (al > 0)).any():
            cand &= al > 0   # surfaces on both sides of the plane: the shape emits on its front side
        rec.group = np.flatnonzero(cand)
        rec.roots = np.zeros(0, np.int64)
        rec.covered = 0.0
        if len(rec.group):
            frac, _, out = self._classify(rec, rec.group)
            rec.roots = rec.group[~out]
            rec.covered = float(np.sum(frac[~out] * self.system.h.area[rec.roots])) / rec.area
        rec.on_surface = rec.covered > 1e-6
        if rec.on_surface and rec.covered < 0.999:
            rec.msgs.append(f"shape '{rec.name}': only {100 * rec.covered:.1f}% of its area lies on surfaces; "
                            "the rest does not emit")

    def _classify(self, rec, nodes):
        h = self.system.h
        return clip.classify(rec.rings2d, self._to2d(rec, h.corners[nodes]), h.nv[nodes])

    # -- incremental methods -------------------------------------------------------------------------
    def _incremental_add(self, rec):
        h = self.system.h
        rec.used = rec.method
        self._event_n0 = h.n      # the node budget covers the outline and the first bounce together
        self._cover(rec)
        required = [rec.cov_nodes]
        if rec.method == "AUTO":
            rec.D, req = self._direct(rec)
            required.append(req)
        rec.owned = self._owned_ancestors(np.concatenate(required))
        self._sync(extra=[rec])
        self._ref[rec.owned] += 1
        self._gc(extra=[rec])       # splits made on the way that turned out unnecessary
        self._sync(extra=[rec])
        cov = self._coverage(rec)
        if rec.method == "AUTO":
            E = np.broadcast_to(self._push(rec.D), (3, h.n)).copy() if rec.D is not None else np.zeros((3, h.n))
        else:
            E = np.repeat(cov[None], 3, 0)
        if self.incremental == "warm":
            return 0
        U, rep = self._solve(E, B0=None if self._guess is None else E + self._guess, response=True)
        if rec.method == "AUTO":
            U = U + self._operator().pull(np.repeat(cov[None], 3, 0))
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
                order = order[:int(np.searchsorted(cum, 0.5 * cum[-1])) + 1]
            room = (self.node_budget - 4 * n_split) // 4
            if len(order) > room:
                order = order[:max(room, 0)]
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
            rec.msgs.append(f"shape '{rec.name}': {rec.method} reached the node budget ({self.node_budget} nodes); "
                            f"{len(part)} boundary nodes use FE (emission L1 error {100 * rec.emission_l1:.2f}%)")

    def _direct(self, rec):
        """AUTO: the shape's first bounce, per unit emission, at receiver nodes (3, n, not pushed) and
        the nodes it needs.

        Receivers are evaluated at 2 x 2 Gauss points: exact unoccluded point-to-shape form factor
        (contour integral over the rings; convex pieces with horizon clipping where the receiver's
        plane cuts the shape) times a kernel-weighted visibility ratio (rays to points on the shape).
        Starting at the roots, a node takes the value if the light on it is weak (HR internal nodes:
        rho F < bf_rel) or even (own leaves: rho x range of F V < bf_rel); otherwise it is split
        (below the HR leaves down to direct_min_area_rel x scene area, node budget permitting).
        """
        h, pt = self.system.h, self.system.patches
        rho, rho_max = pt.reflectance, pt.reflectance.max(0)
        min_area, thr = self.direct_min_area_rel * self.total_area, self.bf_rel
        corners, nv, area, nf = self._pieces(rec)
        if len(corners) == 0:
            return np.zeros((3, h.n)), np.zeros(0, np.int64)
        # points on the shape for the visibility ratio: 2 x 2 Gauss points of the pieces, thinned to
        # at most 16 by systematic sampling along their cumulative area (deterministic)
        sp, sw = ff.quadrature(corners, nv, 2)
        sp, sw = sp.reshape(-1, 3), (sw * area[:, None]).ravel()
        if len(sp) > 16:
            cum = np.cumsum(sw)
            pick = np.minimum(np.searchsorted(cum, (np.arange(16) + 0.5) / 16 * cum[-1]), len(sp) - 1)
            sp, sw = sp[pick], np.full(16, cum[-1] / 16)
        eps = self.system.refiner.eps
        rings = None
        if rec.covered >= 1 - 1e-9:          # contour over the rings: outer CCW about nf, holes CW
            rings = [r if (_newell(r) @ nf > 0) == (i == 0) else r[::-1] for i, r in enumerate(rec.rings)]
        allv = np.concatenate(rec.rings)
        shape_lo, shape_hi = corners.reshape(-1, 3).min(0), corners.reshape(-1, 3).max(0)
        shape_plane = self._plane_id(rec.roots[0])

        def unoccluded(nodes):
            """(m, 4) unoccluded point-to-shape form factors at the nodes' Gauss points, points, weights."""
            x, gw = ff.quadrature(h.corners[nodes], h.nv[nodes], 2)
            xn = np.repeat(h.normal[nodes], 4, 0)
            x = x.reshape(-1, 3)
            F = np.zeros(len(x))
            front = (x - rec.c) @ nf > eps
            above = ((allv[None] - x[:, None]) * xn[:, None]).sum(-1).min(1) > eps
            ok = front & above & (rings is not None)
            if ok.any():
                F[ok] = _contour(x[ok], xn[ok], rings)
            rest = np.flatnonzero(front & ~ok)
            if len(rest):
                T = len(corners)
                F[rest] = ff.point_to_polygon(np.repeat(x[rest], T, 0), np.repeat(xn[rest], T, 0),
                                              np.tile(corners, (len(rest), 1, 1)),
                                              np.tile(nv, len(rest))).reshape(-1, T).sum(1)
            return F.reshape(-1, 4), x, xn, gw

        def visible(nodes, F, x, xn):
            """F x kernel-weighted visibility ratio; rays only where an occluder may be in the way."""
            FV = F.ravel().copy()
            may = self._maybe_occluded(nodes, shape_lo, shape_hi, shape_plane)
            lit = np.flatnonzero((FV > 0) & np.repeat(may, 4))
            if len(lit):
                K = len(sp)
                a = np.repeat(x[lit] + eps * xn[lit], K, 0)
                b = np.tile(sp + eps * nf, (len(lit), 1))
                d = b - a
                r2 = np.einsum("ij,ij->i", d, d)
                kern = (np.maximum(np.einsum("ij,ij->i", d, np.repeat(xn[lit], K, 0)), 0)
                        * np.maximum(-(d @ nf), 0) / np.maximum(r2, 1e-300) ** 2 * np.tile(sw, len(lit)))
                vis = ~self.system.backend.occluded(a, b)
                kern, vis = kern.reshape(-1, K), vis.reshape(-1, K)
                ks = kern.sum(1)
                FV[lit] *= np.where(ks > 0, (kern * vis).sum(1) / np.where(ks > 0, ks, 1), 1.0)
            return FV.reshape(-1, 4)

        in_group = np.zeros(len(pt.nv), bool)
        in_group[rec.group] = True
        roots = np.flatnonzero(~in_group)
        # cull receivers wholly behind the shape or facing away from all of it
        rc = pt.corners[roots]
        front = ((rc - rec.c) @ nf > eps).any(1)
        sees = ((allv[None] - pt.corners[roots][:, :1]) * pt.normal[roots][:, None]).sum(-1).max(1) > eps
        frontier = roots[front & sees]
        n_start = getattr(self, "_event_n0", h.n)
        acc_nodes, acc_vals = [], []
        budget_msg = False
        while len(frontier):
            F, x, xn, gw = unoccluded(frontier)
            rm = rho_max[h.patch[frontier]]
            hr = self._hr_internal(frontier)
            # HR internal nodes keep the light if it is weak on them, else they are descended
            acc = hr & (rm * F.max(1) < thr) & (F.max(1) > 0)
            leaf = ~hr & (F.max(1) > 0)
            ev = np.flatnonzero(acc | leaf)
            FV = np.zeros_like(F)
            if len(ev):
                sel = (ev[:, None] * 4 + np.arange(4)).ravel()
                FV[ev] = visible(frontier[ev], F[ev], x[sel], xn[sel])
            val = (FV * gw).sum(1)
            var = rm * (FV.max(1) - FV.min(1))
            split = leaf & (h.area[frontier] > min_area) & (var >= thr)
            room = max((self.node_budget - (h.n - n_start)) // 4, 0)
            if split.sum() > room:       # over budget: split the most uneven nodes only
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
            rec.msgs.append(f"shape '{rec.name}': first-bounce refinement reached the node budget "
                            f"({self.node_budget} nodes)")
        nodes = np.concatenate(acc_nodes)
        vals = np.concatenate(acc_vals)
        rec.direct_links = len(nodes)
        D = np.zeros((3, h.n))
        D[:, nodes] = rho[:, h.patch[nodes]] * vals
        return D, nodes

    def _pieces(self, rec):
        """Convex pieces (trapezoids) of the shape on its covered patches: corners (T, 4, 3) CCW about
        the emitting side's normal, nv, areas, and that normal."""
        pt = self.system.patches
        roots = rec.roots
        nf = pt.normal[roots[0]] if len(roots) else rec.n
        if len(roots) == 0:
            return np.zeros((0, 4, 3)), np.zeros(0, int), np.zeros(0), nf
        p2 = self._to2d(rec, pt.corners[roots])
        edges = [np.stack([x, np.roll(x, -1, 0)], 1) for x in rec.rings2d]
        edges += [np.stack([q, np.roll(q, -1, 0)], 1) for q in p2]
        edges = np.concatenate(edges)
        traps = slab_decomposition(edges, 1e-9 * (float(np.abs(edges).max()) or 1.0))
        if not traps:
            return np.zeros((0, 4, 3)), np.zeros(0, int), np.zeros(0), nf
        mids = np.array([m for _, m in traps])
        keep = _in_rings(mids, rec.rings2d) & _in_convex(mids, p2).any(1)
        out, nvs = [], []
        for t in np.flatnonzero(keep):
            q = traps[t][0]
            p3 = rec.c + q[:, :1] * rec.u + q[:, 1:2] * rec.v
            if _newell(p3) @ nf < 0:
                p3 = p3[::-1]
            nvs.append(len(p3))
            out.append(np.concatenate([p3, p3[-1:]]) if len(p3) == 3 else p3)
        c = np.array(out)
        _, a = ff.polygon_normal_area(c, np.array(nvs))
        return c, np.array(nvs), a, nf

    def _plane_id(self, patch):
        return int(self._patch_plane[patch])

    def _maybe_occluded(self, nodes, lo, hi, shape_plane, budget=4_000_000):
        """Conservative shaft test between nodes and the shape's box: False where no occluder
        triangle (outside both planes) meets the joint bounding box, so no rays are needed."""
        h = self.system.h
        T = len(self._tri_lo)
        if T > 1024 or len(nodes) == 0:
            return np.ones(len(nodes), bool)
        c = h.corners[nodes]
        e = self.system.refiner.eps
        nlo = np.minimum(c.min(1), lo) - e
        nhi = np.maximum(c.max(1), hi) + e
        pp = self._patch_plane[h.patch[nodes]]
        out = np.ones(len(nodes), bool)
        step = max(1, budget // max(T, 1))
        tlo, thi = self._tri_lo, self._tri_hi
        for s0 in range(0, len(nodes), step):
            sl = slice(s0, s0 + step)
            # one axis at a time on (nodes, triangles): 4.5x faster than np.all over a last axis of 3
            hit = (self._tri_plane[None] != pp[sl, None]) & (self._tri_plane != shape_plane)[None]
            for k in range(3):
                hit &= tlo[None, :, k] <= nhi[sl, k, None]
                hit &= thi[None, :, k] >= nlo[sl, k, None]
            out[sl] = hit.any(1)
        return out

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
        assert (remap[:self.n_hr] == np.arange(self.n_hr)).all()
        self._ref = self._ref[:n][keep]
        self._Bbase = self._Bbase[:, keep]
        self._X = self._X[:, keep]
        self._B = self._B[:, keep] if self._B.shape[1] == n else self._B
        if self._guess is not None:
            self._guess = self._guess[:, keep]
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
        for rec in list(self.shapes.values()) + list(self._cache.values()) + list(extra):
            if rec.U is not None:
                rec.U = h.extend(rec.U)
            if rec.D is not None and rec.D.shape[1] < n:
                rec.D = np.concatenate([rec.D, np.zeros((3, n - rec.D.shape[1]))], 1)

    def _coverage(self, rec):
        """(n,) coverage fraction of every leaf (internal nodes: area-weighted mean)."""
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
        return self._operator().pull(c[None].copy())[0]

    def _scattered(self, rec):
        """The part of rec's response carried by the links (its solve minus its emission), pulled:
        a reshaped or moved shape's new response is solved from its new emission plus this."""
        if rec.U is None or rec.used == "NAIVE" or self.incremental != "response":
            return None
        self._sync()
        cov = self._coverage(rec)[None]
        if rec.method == "AUTO":     # U = solve(push(D)) + pull(coverage)
            return self._operator().pull(rec.U - cov - (self._push(rec.D) if rec.D is not None else 0.0))
        return rec.U - cov

    def _push(self, D):
        h = self.system.h
        D = D.copy()
        par = h.parent[:h.n]
        for lv in h.levels()[1:]:
            D[:, lv] += D[:, par[lv]]
        return D

    def _operator(self):
        h = self.system.h
        if self._op is None or self._op_version != h.version or self._op.n != h.n:
            self._op = Operator(h, self.links)
            self._op_version = h.version
        return self._op

    def _solve(self, E, B0=None, response=False):
        """Solve with non-negative emission; the exact solution is non-negative, so the solver's
        tiny negative excursions (GMRES is not monotone) are clipped. response: a shape's response
        (response_tol, response_float32; its power balance is not reported)."""
        op = self._operator()
        if response and self.response_float32:
            op = op.float32()
        B, rep = solve(self.system.h, self.links, E, B0=B0, tol=self.response_tol if response else self.tol, op=op,
                       energy=not response)
        return np.maximum(B, 0.0), rep

    def solution_at(self, points, patch_ids):
        """(h, B (3, h.n), patch_ids, points) of the current solution, the points on input patches
        mapped into h (NAIVE: onto the rebuilt system's patches, under a light patch onto it)."""
        if self._naive is not None:
            return (self._naive.system.h, self._naive.system.B) + self._naive.remap(points, patch_ids)
        self._sync()
        return self.system.h, self._B, patch_ids, points


# -- helpers --------------------------------------------------------------------------------------------
def _size(rings):
    """Bounding-box diagonal of a shape's rings (its own size)."""
    pts = np.concatenate(rings)
    return float(np.linalg.norm(pts.max(0) - pts.min(0)))


def _plane_tolerance(rings, plane_tol):
    """Distance tolerance of "in the shape's plane" / "on a surface": plane_tol x the shape's own
    size, never the scene's (a far-away object must not change it), plus a floor for float32
    coordinates (Blender's) far from the origin."""
    pts = np.concatenate(rings)
    return plane_tol * _size(rings) + 1e-6 * float(np.abs(pts).max())


def _winding(pts, ring):
    """Signed winding number of ring (M, 2) about points (N, 2)."""
    a, b = ring[None], np.roll(ring, -1, 0)[None]
    x, y = pts[:, :1], pts[:, 1:2]
    side = (b[..., 0] - a[..., 0]) * (y - a[..., 1]) - (b[..., 1] - a[..., 1]) * (x - a[..., 0])
    up = (a[..., 1] <= y) & (b[..., 1] > y) & (side > 0)
    down = (b[..., 1] <= y) & (a[..., 1] > y) & (side < 0)
    return up.sum(1) - down.sum(1)


def outline_problem(rings2d, chunk=200_000):
    """'' if the rings (outer first, then holes; 2D) bound one well-defined region, else what is wrong.

    Well defined: no ring crosses itself or another ring, holes lie inside the outline and apart.
    Only then do the even-odd rule (NAIVE), signed clipped areas (FE, AR, AUTO) and the nonzero
    rule agree, so every method emits the same power. A self-intersecting outline (a pentagram,
    a bowtie) is refused rather than given a meaning that would differ from Blender's own."""
    rings = [np.asarray(r, float) for r in rings2d]
    size = max(float(np.linalg.norm(np.concatenate(rings).max(0) - np.concatenate(rings).min(0))), 1e-300)
    a = np.concatenate([r for r in rings])
    b = np.concatenate([np.roll(r, -1, 0) for r in rings])
    ring = np.concatenate([np.full(len(r), k) for k, r in enumerate(rings)])
    idx = np.concatenate([np.arange(len(r)) for r in rings])
    m = np.array([len(r) for r in rings])[ring]
    tol = 1e-9 * size * size
    E = len(a)
    touch = False
    # candidate pairs: edges whose bounding boxes overlap (sweep along x, then y), in chunks
    pad = 1e-9 * size
    lo, hi = np.minimum(a, b) - pad, np.maximum(a, b) + pad
    order = np.argsort(lo[:, 0], kind="stable")
    end = np.searchsorted(lo[order, 0], hi[order, 0], side="right")
    first = np.arange(E) + 1
    counts = np.maximum(end - first, 0)
    cum = np.cumsum(counts)
    r0 = 0
    while r0 < E:
        r1 = max(int(np.searchsorted(cum, (cum[r0 - 1] if r0 else 0) + chunk, side="right")), r0 + 1)
        r1 = min(r1, E)
        rws = np.arange(r0, r1)
        n = counts[rws]
        base = np.repeat(first[rws], n)
        k = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
        p1, p2 = order[np.repeat(rws, n)], order[base + k]
        r0 = r1
        ii, jj = np.minimum(p1, p2), np.maximum(p1, p2)
        ov = (lo[ii, 1] <= hi[jj, 1]) & (lo[jj, 1] <= hi[ii, 1])
        ii, jj = ii[ov], jj[ov]
        same = ring[ii] == ring[jj]
        adj = same & ((jj - ii == 1) | ((idx[ii] == 0) & (idx[jj] == m[jj] - 1)))
        ii, jj = ii[~adj], jj[~adj]

        def orient(p, q, r):
            return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])
        o1, o2 = orient(a[ii], b[ii], a[jj]), orient(a[ii], b[ii], b[jj])
        o3, o4 = orient(a[jj], b[jj], a[ii]), orient(a[jj], b[jj], b[ii])
        cross = (o1 * o2 < 0) & (o3 * o4 < 0) & (np.minimum.reduce([abs(o1), abs(o2), abs(o3), abs(o4)]) > tol)
        if cross.any():
            k = np.flatnonzero(cross)[0]
            r1, r2 = sorted((int(ring[ii[k]]), int(ring[jj[k]])))
            if r1 == r2:
                return "its outline crosses itself" if r1 == 0 else f"hole {r1} crosses itself"
            return f"hole {r2} crosses its outline" if r1 == 0 else f"holes {r1} and {r2} cross"
        # a corner on another edge (or on another corner): weakly simple, checked below
        for o, p in ((o1, a[jj]), (o2, b[jj])):
            near = np.abs(o) <= tol * 1e3
            if near.any():
                t = np.einsum("ij,ij->i", (p - a[ii])[near], (b[ii] - a[ii])[near])
                L2 = np.einsum("ij,ij->i", (b[ii] - a[ii])[near], (b[ii] - a[ii])[near])
                touch |= bool(np.any((t >= 0) & (t <= L2) & (L2 > 0)))
    for k in range(1, len(rings)):
        if _in_rings(rings[k], rings[:1]).mean() < 0.5:
            return f"hole {k} lies outside its outline"
        for j in range(1, k):
            if _in_rings(rings[k], [rings[j]]).mean() >= 0.5 or _in_rings(rings[j], [rings[k]]).mean() >= 0.5:
                return f"holes {j} and {k} overlap"
    if touch:
        if E > 2000:
            return "its outline touches itself"
        edges = np.stack([a, b], 1)
        traps = slab_decomposition(edges, 1e-9 * size)
        if traps:
            mids = np.array([mid for _, mid in traps])
            w = np.stack([_winding(mids, r) for r in rings])          # (R, T)
            s = [np.sign(clip.polygon_area_2d(r)) or 1 for r in rings]
            for k in range(len(rings)):
                if not np.isin(w[k], (0, s[k])).all():
                    return "its outline crosses itself" if k == 0 else f"hole {k} crosses itself"
            inner = w[1:] != 0
            if (inner & (w[:1] == 0)).any():
                return "a hole lies outside its outline"
            if (inner.sum(0) > 1).any():
                return "holes overlap"
    return ""


def _facing(h, p, q, tol):
    """Some corner of q is in front of p's plane and vice versa (as refine._facing)."""
    def front(x, y):
        d = np.einsum("nkj,nj->nk", h.corners[y] - h.centre[x][:, None], h.normal[x])
        return (d > tol).any(1)
    return front(p, q) & front(q, p)


def _variation(h, x, y):
    """Range of the point form factor to polygon y over x's (slightly shrunk) corners and centre."""
    pts = np.concatenate([h.corners[x], h.centre[x][:, None]], 1)
    pts += 0.01 * (h.centre[x][:, None] - pts)
    f = ff.point_to_polygon(pts.reshape(-1, 3), np.repeat(h.normal[x], 5, 0),
                            np.repeat(h.corners[y], 5, 0), np.repeat(h.nv[y], 5)).reshape(-1, 5)
    return f.max(1) - f.min(1)


def _contour(x, n, rings):
    """Unoccluded form factor from points x (N, 3) with normals n to a polygon with holes lying wholly
    above their horizons: Lambert's contour integral over all rings (outer CCW about the polygon's
    normal, holes CW)."""
    f = np.zeros(len(x))
    for r in rings:
        R = r[None] - x[:, None]                                      # (N, M, 3)
        Rn = np.roll(R, -1, axis=1)
        cr = np.cross(R, Rn)
        cl = np.linalg.norm(cr, axis=-1)
        g = np.arctan2(cl, np.einsum("nmk,nmk->nm", R, Rn))
        t = np.where(cl > 0, g * np.einsum("nmk,nk->nm", cr, n) / np.where(cl > 0, cl, 1), 0.0)
        f -= t.sum(1) / (2 * np.pi)
    return np.clip(f, 0.0, 1.0)


def surface_samples(patches, per_area, min_k=2):
    """Stratified points on every input patch: k x k per patch with k ~ sqrt(area x per_area).
    Returns points (N, 3), patch ids (N,), area weights (N,)."""
    k = np.maximum(np.ceil(np.sqrt(patches.area * per_area)).astype(int), min_k)
    pts, ids, wts = [], [], []
    for kk in np.unique(k):
        m = np.flatnonzero(k == kk)
        p = ff.sample_points(patches.corners[m], patches.nv[m], kk)
        pts.append(p.reshape(-1, 3))
        ids.append(np.repeat(m, kk * kk))
        wts.append(np.repeat(patches.area[m] / (kk * kk), kk * kk))
    return np.concatenate(pts), np.concatenate(ids), np.concatenate(wts)


def _in_rings(pts, rings):
    """Even-odd point-in-polygon over all rings (outer + holes), pts (N, 2)."""
    inside = np.zeros(len(pts), bool)
    for r in rings:
        a, b = r, np.roll(r, -1, 0)
        ay, by = a[:, 1][None], b[:, 1][None]
        y = pts[:, 1:2]
        crosses = (ay > y) != (by > y)
        t = (y - ay) / np.where(by != ay, by - ay, 1)
        x = a[:, 0][None] + t * (b[:, 0] - a[:, 0])[None]
        inside ^= (crosses & (pts[:, :1] < x)).sum(1) % 2 == 1
    return inside


def _in_convex(pts, poly):
    """pts (N, 2) inside convex polygons poly (T, M, 2) of either orientation (zero edges ignored): (N, T)."""
    e = np.roll(poly, -1, 1) - poly                                    # (T, M, 2)
    w = pts[:, None, None, :] - poly[None]                             # (N, T, M, 2)
    cr = e[None, ..., 0] * w[..., 1] - e[None, ..., 1] * w[..., 0]
    zero = (np.abs(e).sum(-1) == 0)[None]
    return (np.where(zero, 0, cr) >= 0).all(-1) | (np.where(zero, 0, cr) <= 0).all(-1)


def slab_decomposition(edges, eps):
    """Trapezoids (and triangles) between consecutive non-crossing edges in horizontal slabs.

    edges (E, 2, 2). Slab boundaries are all endpoint heights and pairwise crossing heights, so inside a
    slab no edges cross. Returns a list of (polygon (3 or 4, 2) counter-clockwise, midpoint (2,))."""
    a, b = edges[:, 0].copy(), edges[:, 1].copy()
    keep = np.abs(a[:, 1] - b[:, 1]) > eps
    a, b = a[keep], b[keep]
    sw = a[:, 1] > b[:, 1]
    a[sw], b[sw] = b[sw].copy(), a[sw].copy()
    ys = [a[:, 1], b[:, 1]]
    i, j = np.triu_indices(len(a), 1)
    d1, d2 = b[i] - a[i], b[j] - a[j]
    den = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    ok = np.abs(den) > 1e-30
    r = a[j] - a[i]
    t = np.where(ok, (r[:, 0] * d2[:, 1] - r[:, 1] * d2[:, 0]) / np.where(ok, den, 1), -1)
    s = np.where(ok, (r[:, 0] * d1[:, 1] - r[:, 1] * d1[:, 0]) / np.where(ok, den, 1), -1)
    hit = ok & (t > 0) & (t < 1) & (s > 0) & (s < 1)
    ys.append((a[i] + t[:, None] * d1)[hit, 1])
    ys = np.sort(np.concatenate(ys))
    ys = ys[np.concatenate([[True], np.diff(ys) > eps])]
    out = []
    for y0, y1 in zip(ys[:-1], ys[1:]):
        ym = 0.5 * (y0 + y1)
        act = np.flatnonzero((a[:, 1] < ym) & (b[:, 1] > ym))
        if len(act) < 2:
            continue
        aa, bb = a[act], b[act]
        dx = (bb[:, 0] - aa[:, 0]) / (bb[:, 1] - aa[:, 1])
        x0 = aa[:, 0] + (y0 - aa[:, 1]) * dx
        x1 = aa[:, 0] + (y1 - aa[:, 1]) * dx
        xm = 0.5 * (x0 + x1)
        o = np.argsort(xm)
        x0, x1, xm = x0[o], x1[o], xm[o]
        for k in range(len(o) - 1):
            if xm[k + 1] - xm[k] <= eps:
                continue
            mid = np.array([0.5 * (xm[k] + xm[k + 1]), ym])
            bot, top = x0[k + 1] - x0[k] > eps, x1[k + 1] - x1[k] > eps
            if bot and top:
                poly = [(x0[k], y0), (x0[k + 1], y0), (x1[k + 1], y1), (x1[k], y1)]
            elif bot:
                poly = [(x0[k], y0), (x0[k + 1], y0), (0.5 * (x1[k] + x1[k + 1]), y1)]
            elif top:
                poly = [(0.5 * (x0[k] + x0[k + 1]), y0), (x1[k + 1], y1), (x1[k], y1)]
            else:
                continue
            out.append((np.array(poly), mid))
    return out


class _NaiveState:
    """NAIVE: the active shapes as offset input patches, a new RadiositySystem, solved cold."""

    def __init__(self, dyn: DynamicRadiosity, recs):
        t0 = time.perf_counter()
        sysm = dyn.system
        mesh, pt = sysm.mesh, sysm.patches
        self.groups = []
        verts, polys, rhos, ems, oids = [], [], [], [], []
        replaced = set()     # input polygons replaced by their pieces around / under the light patches
        P0 = len(mesh.loop_start)
        todo = [r for r in recs]
        for r in todo:
            if r.n is None:
                dyn._plane(r)
                dyn._find_surface(r)
        # Offset of the light patches off their surface: naive_offset x the size of what the shapes
        # light (the shapes and their surfaces), not of the scene (a far-away object must not lift
        # them off the wall); well above the rays' offset.
        local = [np.concatenate(r.rings) for r in todo] + [pt.corners[r.group].reshape(-1, 3) for r in todo
                                                           if r.group is not None and len(r.group)]
        local = np.concatenate(local) if local else np.zeros((1, 3))
        delta = max(dyn.naive_offset * float(np.linalg.norm(local.max(0) - local.min(0))),
                    20 * sysm.refiner.eps)
        while todo:
            r0 = todo[0]
            tol = max(r.tol for r in todo)
            grp = [r for r in todo if abs(r.n @ r0.n) > 0.999 and abs((r.c - r0.c) @ r0.n) <= tol]
            todo = [r for r in todo if r not in grp]
            pats = np.unique(np.concatenate([r.group for r in grp]).astype(np.int64))
            rings = [[dyn._to2d(r0, x) for x in r.rings] for r in grp]
            lo = np.min([x.min(0) for rr in rings for x in rr], 0)
            hi = np.max([x.max(0) for rr in rings for x in rr], 0)
            p2 = dyn._to2d(r0, pt.corners[pats]) if len(pats) else np.zeros((0, 4, 2))
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
            p2 = dyn._to2d(r0, pt.corners[pats]) if len(pats) else np.zeros((0, 4, 2))
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
            for t in np.flatnonzero(~lit & repl):    # uncovered pieces of a replaced host polygon
                poly2 = traps[t][0]
                hn = pt.normal[under[t]]
                p3 = r0.c + poly2[:, :1] * r0.u + poly2[:, 1:2] * r0.v
                p3 = p3 - (((p3 - pt.corners[under[t], 0]) @ hn) / (r0.n @ hn))[:, None] * r0.n[None]
                if _newell(p3) @ hn < 0:
                    p3, poly2 = p3[::-1], poly2[::-1]
                base = len(np.concatenate(verts)) if verts else 0
                verts.append(p3)
                polys.append(list(range(base, base + len(p3))))
                rhos.append(pt.reflectance[:, under[t]])
                ems.append(pt.emission[:, under[t]])
                oids.append(int(pt.object_id[under[t]]))
                g_quads.append(np.concatenate([poly2, poly2[-1:]]) if len(poly2) == 3 else poly2)
                g_patch.append(P0 + len(polys) - 1)
                g_front.append(np.zeros(3))
            for t in np.flatnonzero(lit):
                poly2 = traps[t][0]
                front = pt.normal[under[t]] if under[t] >= 0 else next(
                    r.n for r, rr in zip(grp, rings) if _in_rings(mids[t:t + 1], rr)[0])
                p3 = r0.c + poly2[:, :1] * r0.u + poly2[:, 1:2] * r0.v + delta * front
                if _newell(p3) @ front < 0:
                    p3, poly2 = p3[::-1], poly2[::-1]
                base = len(np.concatenate(verts)) if verts else 0
                verts.append(p3)
                polys.append(list(range(base, base + len(p3))))
                rhos.append(pt.reflectance[:, under[t]] if under[t] >= 0 else np.zeros(3))
                ems.append(em[t] + (pt.emission[:, under[t]] if under[t] >= 0 else 0))
                oids.append(-1)
                q4 = np.concatenate([poly2, poly2[-1:]]) if len(poly2) == 3 else poly2
                g_quads.append(q4)
                g_patch.append(P0 + len(polys) - 1)
                g_front.append(front)
            if g_quads:
                self.groups.append((r0, set(pats.tolist()), np.array(g_quads), np.array(g_patch), np.array(g_front)))
        self.P0, self.L0, self.V0 = P0, len(mesh.loop_verts), len(mesh.verts)
        self.delta = delta
        self.replaced = np.array(sorted(replaced), np.int64)
        if polys:
            light = MeshInput.from_polygons(np.concatenate(verts), polys, np.array(rhos), np.array(ems),
                                            np.zeros(len(polys), np.int64), ["light shapes (NAIVE)"])
            nm = mesh.concat(light)
            oids = np.array(oids, np.int64)
            nm.object_id[P0:][oids >= 0] = oids[oids >= 0]    # pieces weld with their host object
            if len(self.replaced):   # collapse the replaced polygons (dropped as degenerate)
                nm.loop_verts = nm.loop_verts.copy()
                for q in self.replaced:
                    a, k = mesh.loop_start[q], mesh.loop_total[q]
                    nm.loop_verts[a:a + k] = nm.loop_verts[a]
        else:
            nm = mesh
        # original patch -> patch of the same polygon in the NAIVE system (-1: polygon replaced)
        kept = ~np.isin(pt.poly, self.replaced)
        self.patch_map = np.where(kept, np.cumsum(kept) - 1, -1)
        self.orig_poly = pt.poly
        self.system = RadiositySystem(nm, dyn.naive_params or sysm.params, backend=sysm.backend.name, tol=sysm.tol)
        self.system.solve()
        self.iterations = self.system.report.iterations
        poly = self.system.patches.poly
        for g in self.groups:   # input polygon -> patch index (-1 if dropped as degenerate)
            pi = np.searchsorted(poly, g[3])
            pi = np.minimum(pi, len(poly) - 1)
            g[3][:] = np.where(poly[pi] == g[3], pi, -1)
        self.seconds = time.perf_counter() - t0

    def evaluate(self, points, patch_ids):
        roots, pts = self.remap(points, patch_ids)
        h = self.system.h
        leaf = locate(h, roots, pts)
        E = self.system.base_emission()
        return self.system.B[:, leaf].T.copy(), E[:, leaf].T.copy()

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
            p2 = DynamicRadiosity._to2d(r0, pts[m])
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
        out = self.system.loop_radiance("CORNER", smooth_angle)[:self.L0].astype(np.float64)
        # corners under a light patch show the light, not the hidden surface behind it
        loop_poly = np.repeat(np.arange(self.P0), mesh.loop_total)
        first = np.searchsorted(self.orig_poly, loop_poly)   # a patch of the ORIGINAL system
        pos = mesh.verts[mesh.loop_verts]
        covered = np.zeros(len(pos), bool)
        for r0, pats, quads, pidx, front in self.groups:
            m = np.flatnonzero(np.isin(first, list(pats)))
            if len(m):
                lit = front.any(1)   # unlit pieces (zero offset) are handled below
                covered[m] = _in_convex(DynamicRadiosity._to2d(r0, pos[m]), quads[lit]).any(1)
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
