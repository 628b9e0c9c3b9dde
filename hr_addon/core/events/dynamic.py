"""DynamicRadiosity: add, remove, apply and re-colour light shapes, the cached responses and the
solves (the methods' work is in validation.py, coverage.py, direct.py and naive.py)."""

from collections import OrderedDict
import hashlib
import time

import numpy as np

from ..output import locate, radiance_at
from ..output import loop_plan as _loop_plan
from ..output import loop_radiance as _loop_radiance
from ..radiosity import RadiositySystem
from .coverage import Coverage, NodeState
from .direct import FirstBounce
from .lightsrc import LIGHT_RAYS, Lights
from .naive import _NaiveState
from .records import METHODS, EventReport, FrameReport, LightShape, Preview, _Rec, outline_share
from .solves import Solves
from .validation import ShapeValidator, check_emission, find_surface, off_surface_message, shape_plane, to2d


# DynamicRadiosity.gather_options: the solves' settings when the final gather is on. A response
# reaches the output only after the gather's two levels and iterations (each a bounce, rho < 1), so
# it is a fixed number of GMRES steps from zero (response_steps), not a solve to a tolerance: the
# same for Live (warm starts), a bake and a farm node whatever came before (a tolerance left them
# apart by its share: 1e-3 gave Live against a bake 5e-4). 6 steps instead of the 9-12 operator
# applications of 1e-4 change the 20k room's gathered output by at most 0.026% per object, 1.5e-5
# of the brightest value per corner; 5 steps 0.08% (docs/gather.md, "A fixed response solve").
# Draft took 4: on the furnished 100k room the gathered output moves from 6 steps' by 0.05% per
# object (median), 0.75% at worst, bias -0.04% (3 steps: 0.26%, 2.3%, -0.21%); with the solver's
# free residual step after them (solver._gmres_steps) 0.03%, 0.37%, -0.02% (docs/gather.md,
# "Light events at 100k: fewer steps, fewer first-bounce rays"). Since session 24 draft takes 3: the
# 100k room's gathered output per object against 4 steps' (the window added / moved), FE median
# 0.004 / 0.005%, p95 0.28 / 0.27%, worst 0.81 / 0.92%, bias -0.005 / -0.007%; AUTO 0.001 /
# 0.002%, 0.08 / 0.05%, 0.24 / 0.19%; one operator application fewer, x0.76-0.97 of the event
# with its output (docs/events.md, "Light events at 100k, session 24"). bounce_points: AUTO's first
# bounce (the response's emission) with 4 visibility rays per receiver point instead of 16: the
# gathered output moves by 0.02% per object (median), 0.2% at worst (docs/gather.md, the section above).
# response_tol stays for previews' and callers' explicit tolerances. gather_responses "tail": the
# gather's passes over an AR, FE or AUTO shape's response are a Jacobi solve whose limit does not
# depend on the response they start from: the gathered part takes their geometric tail
# (FinalGather._levels), closer to that limit than the 5 passes (furnished 100k room, per object
# against a converged gather, FE: median 0.54 -> 0.23%, worst 3.6 -> 2.1%, bias -0.49 -> -0.20%;
# AUTO 0.35 -> 0.18%, 2.2 -> 1.6%, -0.31 -> -0.16%). "zero" (draft's since session 29) solves no response
# at all, nor AUTO's first bounce: events of about 0.01 s, the passes from nothing (8 there); since
# every exposed leaf has second-level samples, closer to that limit than "tail" there (worst object
# 1.2-1.6% against FE's 1.9-2.3% and AUTO's 1.4-1.8%; on Cornell too), a hair farther from Cycles
# on Cornell's FE (worst surface 0.165 against 0.137%: the converged gather is, 0.19%); AUTO's
# events about 0.55 s cheaper, FE's not (its 3 more
# passes cost what the response saved) (docs/gather.md, "Light events without a response solve",
# "Every exposed leaf sampled"). Since session 29 draft takes "zero": on the 100k room the
# response cost 0.46-0.70 s (FE) and the 3 more passes 0.26-0.51 s (their first reads nothing),
# FE event + output x0.95, AUTO x0.68-0.80; per object against a converged gather median 0.03-0.04%,
# p95 0.21-0.38%, worst 0.77-1.58% where "tail" read 0.04-0.09%, 0.58-0.95%, 1.37-3.20%
# (docs/events.md, "the gathered output's reads and the response, session 29"); response_steps
# and bounce_points stay for previews and callers who ask for "tail". Draft's base solution to
# 1e-3 since session 31 (issue 19, build60; 1e-5 before): with "zero" the gathered output reads it
# only after its two levels' passes, per object 3e-6 from 1e-5's (20k room), 14 -> 9 GMRES steps at
# 100k. 1e-2 (7 steps, the output 2e-5) left the leaves 3.3e-3 from a tight solve, over
# test_events' 2.5e-3 for draft's options; 1e-1 (one step) moved the output by 1.5%
# (docs/scale.md, session 31). Medium takes "zero" too since session 34 (branch evmed2): on the 100k
# room per object against the passes' limit median 0.015-0.017%, p95 0.12-0.14%, worst 0.76-0.82%
# where "tail" read FE 0.017-0.022%, 0.39-0.45%, 2.2-2.4% (AUTO up to 6.1%); Cornell's worst surface
# against Cycles 0.15% (FE "tail" 0.12%, AUTO 0.15%), every surface within 0.31%; a sweep step's
# event 1.3 s (FE) / 1.8-2.9 s (AUTO) -> 0.02 s (docs/events.md, session 34).
GATHER_SOLVE = {
    "draft": dict(
        tol=1e-3,
        response_tol=1e-4,
        response_float32=True,
        response_steps=3,
        bounce_points=4,
        gather_responses="zero",
    ),
    "medium": dict(
        tol=1e-5,
        response_tol=1e-4,
        response_float32=True,
        response_steps=6,
        bounce_points=4,
        gather_responses="zero",
    ),
    "high": dict(
        tol=1e-6, response_tol=1e-5, response_float32=True, response_steps=8, gather_responses="tail"
    ),
}


class DynamicRadiosity:
    """Light shapes (and Blender lights) on a built RadiositySystem, made of parts with explicit
    state: the validator (validation.py), the per-node state on the growing hierarchy and the
    coverage (coverage.py), AUTO's first bounce (direct.py), the lights (lightsrc.py), the solves
    (solves.py); NAIVE rebuilds in naive.py."""

    LIGHT_RAYS = LIGHT_RAYS

    def __init__(
        self,
        system: RadiositySystem,
        method="AUTO",
        min_area_rel=1e-5,
        node_budget=20000,
        plane_tol=1e-3,
        incremental="response",
        emission_tol=0.05,
        bf_rel=3e-3,
        naive_params=None,
        naive_offset=1e-4,
        cache_size=8,
        direct_min_area_rel=None,
        response_tol=None,
        response_float32=False,
        tol=None,
        warm_moves=True,
        response_steps=None,
        bounce_points=16,
        gather_responses=False,
    ):
        """system: a built RadiositySystem (its hierarchy is extended in place below the HR leaves).
        min_area_rel: smallest AR node, fraction of the total scene area. node_budget: most nodes one shape
        may add (AR/AUTO). plane_tol: distance tolerance of "planar" and "on a surface", fraction of
        the shape's own bounding-box diagonal (never the scene's). emission_tol: AUTO's target relative
        L1 error of the emission field.
        bf_rel: AUTO's first bounce: a receiver node is kept when rho x the range of F x V over it is
        below bf_rel (radiance per unit emitted radiance). direct_min_area_rel: smallest such receiver
        (and AUTO outline) node, default 4 x min_area_rel. incremental: "response" or "warm" (module
        doc). naive_params: RefineParams for NAIVE rebuilds (default: the system's). cache_size: removed
        shapes whose responses need no extra nodes are kept for instant re-adding (0: off).
        response_tol: solver tolerance of the shapes' responses (default: the system's, as the
        base solution); response_float32: those solves gather in float32 (Live Relight, whose
        output is float32, uses both: see docs/events.md). tol: solver tolerance of the base
        solution and of warm mode (default: the system's). With the final gather on, see
        gather_options(). warm_moves: a moved shape's or light's response is solved starting from
        the old one's scattered light (fewer iterations); False: from its emission alone, as when
        it is added, and the shapes and lights are summed in apply()'s order, so that a frame's
        values do not depend on the frames solved before it (FE and one AR/AUTO shape: a farm
        node's first frame equals one process's, docs/farm.md). response_steps: each response is
        that many GMRES steps from zero instead of a solve to response_tol (the final gather's
        setting, gather_options): the same for Live, a bake and a farm node whatever the order
        of events, warm starts unused. bounce_points: AUTO's first bounce, points on the shape
        (at most) for the visibility ratio at each receiver point (one ray each; gather_options
        takes fewer: the gather reads the response only after its own bounces). gather_responses
        (for the final gather, gather_options): AR, FE and AUTO shapes (_Rec.gathered) have the
        gather's passes over their response extrapolated to the passes' limit ("tail"), or
        ("zero") when added or moved without a preview no response solve and no first bounce at
        all: U is their emission alone, the passes start from nothing (the classic output, which
        shows U, would miss their scattered light)."""
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
        self.direct_min_area_rel = (
            direct_min_area_rel if direct_min_area_rel is not None else 4 * min_area_rel
        )
        self.naive_params, self.naive_offset, self.cache_size = naive_params, naive_offset, cache_size
        self.tol = tol if tol is not None else system.tol
        self.response_tol = response_tol if response_tol is not None else system.tol
        self.response_float32 = response_float32
        self.warm_moves = warm_moves
        if gather_responses not in (False, None, "tail", "zero"):
            raise ValueError(f"gather_responses must be False, 'tail' or 'zero', not {gather_responses!r}")
        self.gather_responses = gather_responses or ""
        self.links = system.links
        h = system.h
        pt = system.patches
        self.total_area = float(pt.area.sum())
        lo, hi = pt.corners.reshape(-1, 3).min(0), pt.corners.reshape(-1, 3).max(0)
        self.diag = float(np.linalg.norm(hi - lo)) or 1.0
        self.occluders = system.refiner.occluders  # the first bounce's shaft test
        self.shapes = OrderedDict()  # key -> _Rec
        self._cache = OrderedDict()  # (geom_key, method) -> _Rec
        self._naive = None  # active NAIVE rebuild (_NaiveState) or None
        self._plan = None  # (key, output.loop_plan) of loop_radiance
        self.validator = ShapeValidator(plane_tol)
        threads = system.backend.threads
        self.solves = Solves(
            h, self.links, self.tol, self.response_tol, response_float32, threads, response_steps
        )
        base, self.base_iterations = self._base_solution()
        self.nodes = NodeState(h, base, threads)
        self.coverage = Coverage(
            self.nodes,
            min_area_rel * self.total_area,
            self.direct_min_area_rel * self.total_area,
            emission_tol,
            self.node_budget,
            lambda x: self.solves.operator().pull(x),
        )
        self.bounce = FirstBounce(
            system,
            self.nodes,
            self.occluders,
            self.direct_min_area_rel * self.total_area,
            bf_rel,
            self.node_budget,
            bounce_points,
        )
        self.light_part = Lights(
            system, self.nodes, self.solves, 2 * self.diag + 1, incremental, self._records, warm_moves
        )
        self.lights = self.light_part.recs  # key -> lightsrc._LightRec (Blender lights, issue 20)

    def _base_solution(self):
        """(B (3, n), solver iterations) of the static emission alone. Kept on the system per
        tolerance and emission (system.bases) while its hierarchy is the build's: the scene
        precompute stores it (io/precompute.py), and a copy of the system reuses it."""
        s = self.system
        E0 = s.base_emission()
        if s.h.version != getattr(s, "build_version", None):  # light events changed the hierarchy
            B, rep = self.solves.solve(E0)
            return B, rep.iterations
        key = (float(self.tol), hashlib.sha256(np.ascontiguousarray(E0).tobytes()).hexdigest()[:16])
        if key not in s.bases:
            B, rep = self.solves.solve(E0)
            s.bases[key] = (B, rep.iterations)
        B, iterations = s.bases[key]
        return B.copy(), iterations

    @staticmethod
    def gather_options(quality="draft"):
        """Solver options when the final gather is on (docs/gather.md, Transport): the gather
        reads the solution only after its exact direct light and its iterations, so it is solved
        to a tolerance matched to the output, not to 1e-7."""
        return dict(GATHER_SOLVE[quality.lower()])

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
        key = (id(h), h.version, h.n, domain, smooth_angle)  # the plan depends on geometry only
        if self._plan is None or self._plan[0] != key:
            self._plan = (key, _loop_plan(h, self.system.mesh, smooth_angle, domain))
        return _loop_radiance(h, self._B, self.system.mesh, smooth_angle, domain, plan=self._plan[1])

    def current(self):
        """(h, B, E, links) of the solution in effect (NAIVE: its rebuilt system's)."""
        if self._naive is not None:
            s = self._naive.system
            return s.h, s.B, s.base_emission(), s.links
        return self.h, self.B, self.emission(), self.links

    def loop_field(self, X, domain="CORNER", smooth_angle=30.0):
        """A node field X (3, n) on current()'s hierarchy other than B, per input loop (or
        vertex) as loop_radiance interpolates B (NAIVE's special cases included)."""
        holder, attr = (self._naive.system, "B") if self._naive is not None else (self.nodes, "current")
        saved = getattr(holder, attr)
        setattr(holder, attr, X)
        try:
            return self.loop_radiance(domain, smooth_angle)
        finally:
            setattr(holder, attr, saved)

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

    def apply(self, shapes: dict, lights: dict = None, preview: Preview = None) -> FrameReport:
        """Make `shapes` (key -> LightShape, the full active set) current with as little work as possible.
        lights: key -> core.lights.Light, the full set of Blender lights (None: leave them as they are);
        a moved or re-aimed light is one response solve, a colour or strength change a scale.
        preview: the shapes moved, reshaped or added get a Preview's cheaper response (Live during a
        drag); refine() solves them as this apply() without it would have."""
        t0 = time.perf_counter()
        fr = FrameReport()
        valid = {
            k: self.validator.validate(k, s) for k, s in shapes.items()
        }  # raise before changing anything
        moves = {k: bool(getattr(s, "moves", False)) for k, s in shapes.items()}
        evs = []
        for k in [k for k in self.shapes if k not in valid]:
            evs.append(self._remove(k))
        for k, (rings, em, name) in valid.items():
            rec = self.shapes.get(k)
            if rec is None:
                continue
            same_geom = (
                len(rec.rings) == len(rings)
                and all(np.array_equal(a, b) for a, b in zip(rec.rings, rings))
                and rec.moves == moves[k]  # (its direct light is another estimator's: a reshape)
            )
            if not same_geom:
                # the new response is solved from the new emission plus the old one's scattered
                # light: a moved shape lights the room much as before (fewer iterations). After
                # previews, the exact solve starts from the last exact response's (rec.G), as if
                # the previews had not been computed (a drag coalesced into one move)
                guess = None
                if self.warm_moves:
                    guess = rec.G if rec.preview is not None else self._scattered(rec)
                if preview is None:
                    self.nodes.guess = guess
                else:  # a preview starts from the response it replaces, the closest
                    self.nodes.guess = self._scattered(rec) if self.warm_moves else None
                    self.nodes.guess0 = guess
                try:
                    r1 = self._remove(k)
                    v = (rings, em, name)
                    self._ref = rec if rec.preview is None else rec.ref  # the last exact state
                    self._solved = rec if rec.preview is None or rec.solved is None else rec.solved
                    self._power = rec.area * rec.covered  # (its emitted power at unit emission)
                    r2 = self._add(k, LightShape(*v, moves=moves[k]), validated=v, preview=preview)
                finally:
                    self.nodes.guess = self.nodes.guess0 = self._ref = self._solved = None
                r2.kind = "reshape"
                r2.nodes_removed += r1.nodes_removed
                r2.seconds += r1.seconds
                evs.append(r2)
            elif not np.array_equal(rec.emission, em):
                evs.append(self._set_emission(k, em))
        for k, (rings, em, name) in valid.items():
            if k not in self.shapes:
                shape = LightShape(rings, em, name, moves[k])
                evs.append(self._add(k, shape, validated=(rings, em, name), preview=preview))
        if lights is not None:
            evs += self.light_part.diff(lights)
        # sums in the caller's order, not in the order of past events (so with fixed steps: Live)
        if not self.warm_moves or self.solves.response_steps:
            for recs, keys in ((self.shapes, valid), (self.lights, lights or {})):
                for k in [k for k in keys if k in recs]:
                    recs.move_to_end(k)
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

    @property
    def previewing(self):
        """True while a shape's response is a preview's (apply(preview=)): refine() replaces it."""
        return any(r.preview is not None for r in self.shapes.values())

    def refine(self) -> FrameReport:
        """Solve the previewed shapes as apply() without previews would have (from the last exact
        response's scattered light, on the hierarchy without the previews' splits): the values
        are then bitwise those of that apply(). Returns the FrameReport (no events: nothing to do)."""
        t0 = time.perf_counter()
        fr = FrameReport()
        for k in [k for k, r in self.shapes.items() if r.preview is not None]:
            rec = self.shapes[k]
            self.nodes.guess = rec.G
            try:
                r1 = self._remove(k)
                v = (rec.rings, rec.emission, rec.name)
                r2 = self._add(k, LightShape(*v, moves=rec.moves), validated=v)
            finally:
                self.nodes.guess = None
            r2.kind = "reshape"
            r2.nodes_removed += r1.nodes_removed
            fr.events.append(r2)
        if fr.events:
            fr.iterations += self._finish(fr.events)
        for e in fr.events:
            fr.iterations += e.iterations
            fr.messages += e.messages
        fr.nodes_added = sum(e.nodes_added for e in fr.events)
        fr.nodes_removed = sum(e.nodes_removed for e in fr.events)
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
        from ..hierarchy import Hierarchy

        h = self.h
        links = len(self._naive.system.links) if self._naive is not None else len(self.links)
        cached = sum(
            sum(a.nbytes for a in (r.U, r.D) if a is not None)
            for r in list(self.shapes.values()) + list(self._cache.values())
        )
        return h.n * Hierarchy.node_bytes() + links * 32 + cached

    def evaluate(self, points, patch_ids):
        """Radiance at surface points (N, 3) lying on input patches patch_ids (N,): returns
        (B (N, 3), E (N, 3)), total and emitted radiance of the leaf holding each point."""
        if self._naive is not None:
            return self._naive.evaluate(points, patch_ids)
        self._sync()
        h = self.system.h
        leaf = locate(h, patch_ids, points)
        return h.values_at(self._B, leaf, points), self.emission()[:, leaf].T.copy()

    def radiance_at(self, points, patch_ids, smooth=True):
        """Radiance (N, 3) at surface points lying on input patches (output.radiance_at on the current
        solution; under NAIVE, points covered by a light patch read that patch)."""
        if self._naive is not None:
            roots, pts = self._naive.remap(points, patch_ids)
            return radiance_at(self._naive.system.h, self._naive.system.B, roots, pts, smooth)
        self._sync()
        return radiance_at(self.system.h, self._B, patch_ids, points, smooth)

    # -- the parts' state, under the names gather.py, texels.py and the tests read ------------------
    @property
    def _Bbase(self):
        """(3, n) the solution without shapes."""
        return self.nodes.base

    @property
    def _B(self):
        return self.nodes.current

    @_B.setter
    def _B(self, B):
        self.nodes.current = B

    @property
    def n_hr(self):
        """Nodes of the HR build (ids below it); light events add nodes after them."""
        return self.nodes.n_hr

    def _push(self, D):
        return self.solves.push(D)

    def _records(self, extra=()):
        """Every record holding node arrays: shapes, cached shapes, lights, extra."""
        return (
            list(self.shapes.values()) + list(self._cache.values()) + list(self.lights.values()) + list(extra)
        )

    def _sync(self, extra=()):
        self.nodes.sync(self._records(extra))

    def _gc(self, extra=()):
        return self.nodes.gc(self._records(extra))

    def _coverage(self, rec, mean=False, pull=None):
        return self.coverage.coverage(rec, mean, pull)

    def _pieces(self, rec):
        return self.bounce.pieces(rec)

    _to2d = staticmethod(to2d)

    def _operator(self):
        return self.solves.operator()

    def off_surface_message(self, rec):
        """Why a shape on no surface looks as it does (validation.off_surface_message)."""
        return off_surface_message(rec, self.system)

    # -- events -------------------------------------------------------------------------------------
    def _stamp(self, rep, t0):
        rep.seconds = time.perf_counter() - t0
        self._counts(rep)
        return rep

    def _counts(self, rep):
        rep.nodes = self.h.n
        rep.links = len(self._naive.system.links) if self._naive is not None else len(self.links)
        rep.memory_bytes = self.memory_bytes()

    def _add(self, key, shape, validated=None, preview=None):
        t0 = time.perf_counter()
        if key in self.shapes:
            raise KeyError(
                f"A light shape with key {key!r} is already active (use apply() or remove it first)."
            )
        rings, em, name = validated or self.validator.validate(key, shape)
        rep = EventReport("add", key, name)
        n0 = self.system.h.n
        method = self.method if preview is None or preview.method is None else preview.method
        rec = _Rec(key, name, rings, em, method, moves=bool(getattr(shape, "moves", False)))
        # (an exact response cached for this outline serves a preview too)
        cached = self._cache.pop((rec.geom_key, self.method), None) if self.method != "NAIVE" else None
        if cached is not None:
            cached.emission, cached.key, cached.name = em, key, name
            rec = cached
            rep.reused = True
        else:
            shape_plane(rec, self.plane_tol)
            find_surface(rec, self.system)
            if not rec.on_surface:
                rec.used = "NAIVE"
                rec.msgs.append(self.off_surface_message(rec))
            elif self.method == "NAIVE":
                rec.used = "NAIVE"
            else:
                rep.iterations += self._incremental_add(rec, preview)
        self.shapes[key] = rec
        rep.method, rep.covered, rep.emission_l1 = rec.used, rec.covered, rec.emission_l1
        rep.direct_links = rec.direct_links
        rep.messages += rec.msgs
        rep.nodes_added = self.system.h.n - n0
        rep.seconds = time.perf_counter() - t0
        return rep

    def _incremental_add(self, rec, preview=None):
        """AR, FE, AUTO: cover the hierarchy (AUTO: and gather the first bounce), reference the
        splits the shape needs, and solve its response (response mode; a preview's: to its tol,
        the exact solve's guess kept as rec.G). Returns iterations."""
        h = self.system.h
        rec.used = rec.method
        # the final gather's passes extrapolated ("tail"), or giving all the scattered light
        ok = self.incremental == "response"
        gathered = self.gather_responses if ok else ""
        rec.gathered = gathered if preview is None else ""
        n0 = h.n  # the node budget covers the outline and the first bounce together
        self.coverage.cover(rec)
        required = [rec.cov_nodes]
        if rec.method == "AUTO" and rec.gathered != "zero":
            rec.D, req = self.bounce.direct(rec, n0)
            required.append(req)
        rec.owned = self.nodes.owned_ancestors(np.concatenate(required))
        self._sync(extra=[rec])
        self.nodes.ref[rec.owned] += 1
        self._gc(extra=[rec])  # splits made on the way that turned out unnecessary
        self._sync(extra=[rec])
        if rec.method == "AUTO" and rec.gathered != "zero":
            E = (
                np.broadcast_to(self.solves.push(rec.D), (3, h.n)).copy()
                if rec.D is not None
                else np.zeros((3, h.n))
            )
        else:
            E = np.repeat(self._coverage(rec)[None], 3, 0)
        if self.incremental == "warm":
            return 0
        guess = self.nodes.guess
        tol = None if preview is None else preview.tol
        ref = getattr(self, "_ref", None) if preview is not None else None
        solved = getattr(self, "_solved", None) if preview is not None else None

        def near(r):
            return (
                r is not None
                and preview.guess_share is not None
                and r.used == rec.method  # (AUTO's and AR's responses, previewed as FE: not its guess)
                and r.emitter is not None
                and outline_share(rec, r.emitter[1]) >= preview.guess_share
            )

        if ref is not None and ref.gathered == gathered == "zero" and near(ref):  # (a preview near a
            # gathered state: that state's indirect light scaled by the power ratio,
            # FinalGather._preview_part; rule 4's)
            rec.gathered, rec.ratio = "zero", rec.area * rec.covered / max(self._power, 1e-300)
        if rec.gathered == "zero":
            U, rep = E, EventReport("add")
            rec.solved = ref
        elif guess is not None and near(solved):  # the guess unchecked, its scattered light (the
            # last solved state's, as its unchecked followers kept it) scaled by the emitted power's
            # ratio (a scaled shape's): as the solve returns a guess whose first residual is within tol
            rec.solved = solved
            op = self.solves.operator()
            B = np.zeros((3, h.n))
            ratio = rec.area * rec.covered / max(self._power, 1e-300)
            B[:, op.leaves] = np.maximum((E + ratio * guess)[:, op.leaves], 0.0)
            U, rep = np.maximum(op.pull(B), 0.0), EventReport("add")
        else:
            if preview is not None and preview.guess_share is not None and preview.refresh_tol is not None:
                tol = preview.refresh_tol  # (the next previews' reference)
            U, rep = self.solves.solve(
                E, B0=None if guess is None else E + guess, response=True, tol=tol, owned=rec.owned
            )
            if preview is not None and rep.iterations <= 1:  # its check accepted the guess: the
                # scattered light is still that state's (its lag grows along the drag)
                rec.solved = solved
        if preview is not None:
            rec.preview, rec.G, rec.ref = preview, self.nodes.guess0, ref
        if rec.method == "AUTO" and rec.gathered != "zero":  # (pulled over the tree U was solved on)
            cov = self._coverage(rec, True, None if tol else self.solves.tree_pull(rec.owned))
            U = U + np.repeat(cov[None], 3, 0)
        rec.U = U
        return rep.iterations

    def _remove(self, key):
        t0 = time.perf_counter()
        if key not in self.shapes:
            raise KeyError(f"No active light shape with key {key!r}.")
        rec = self.shapes.pop(key)
        rep = EventReport("remove", key, rec.name, rec.used)
        if rec.owned is not None and len(rec.owned):
            self.nodes.ref[rec.owned] -= 1
            rep.nodes_removed = self._gc()
        elif rec.U is not None and self.cache_size > 0 and rec.used != "NAIVE" and rec.preview is None:
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
        em = check_emission(emission, rec.name)
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
            self._naive = _NaiveState(
                self.system,
                list(self.shapes.values()),
                list(self.lights.values()),
                self.naive_params,
                self.naive_offset,
                self.plane_tol,
                2 * self.diag + 1,
            )
            its += self._naive.iterations
            names = ", ".join(f"'{r.name}'" for r in naive if not r.on_surface)
            if self.method != "NAIVE" and names:
                reps[-1].messages.append(
                    f"NAIVE rebuild of all {len(self.shapes)} active shape(s) "
                    f"because {names} lie(s) on no surface ({time.perf_counter() - t0:.2f} s)"
                )
            return its
        self._naive = None
        self._sync()
        if self.incremental == "response":
            B = self._Bbase.copy()
            for rec in self.shapes.values():
                B += rec.emission[:, None] * rec.U
            for rec in self.lights.values():
                B += rec.scale[:, None] * rec.U
            self._B = B
        else:
            E = self.system.base_emission()
            extra = np.zeros_like(E)
            for rec in self.shapes.values():
                if rec.used == "AUTO":
                    E += rec.emission[:, None] * self.solves.push(rec.D)
                    extra += self._coverage(rec, mean=True)[None] * rec.emission[:, None]
                else:
                    E += self._coverage(rec)[None] * rec.emission[:, None]
            for rec in self.lights.values():
                E += rec.scale[:, None] * self.solves.push(rec.D)
            self.nodes.warm, rep = self.solves.solve(E, B0=self.nodes.warm)
            its += rep.iterations
            self._B = self.nodes.warm + self._operator().pull(extra)
        return its

    def _scattered(self, rec):
        """The part of rec's response carried by the links (its solve minus its emission), pulled:
        a reshaped or moved shape's new response is solved from its new emission plus this."""
        if rec.U is None or rec.used == "NAIVE" or self.incremental != "response" or rec.gathered == "zero":
            return None
        self._sync()
        cov = self._coverage(rec, mean=True)[None]  # its emission, as node means
        if rec.method == "AUTO":  # U = solve(push(D)) + pull(coverage)
            ex = self.system.h.exposure[: rec.U.shape[1]]
            pushed = self.solves.push(rec.D) * ex if rec.D is not None else 0.0
            return self._operator().pull(rec.U - cov - pushed)
        return rec.U - cov

    def solution_at(self, points, patch_ids):
        """(h, B (3, h.n), patch_ids, points) of the current solution, the points on input patches
        mapped into h (NAIVE: onto the rebuilt system's patches, under a light patch onto it)."""
        if self._naive is not None:
            return (self._naive.system.h, self._naive.system.B) + self._naive.remap(points, patch_ids)
        self._sync()
        return self.system.h, self._B, patch_ids, points
