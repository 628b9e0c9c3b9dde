"""Live relighting's worker (no bpy): one DynamicRadiosity, kept in memory, and the latest light
state computed off the UI thread.

The UI thread (live.py) reads the scene and hands the worker a *request*: a BuildSpec (build the
hierarchy: the first time, and again when the geometry or the settings change) and/or the full set
of active light shapes. The worker keeps only the newest request of each kind: edits that arrive
while it computes replace the pending one (coalescing), so after a drag only the last position is
computed. DynamicRadiosity.apply() turns a new shape set into light events (a move is a remove plus
an add, a strength or colour change scales the shape's stored response). The result, RGBA values
per object, waits in one slot for the UI thread, which writes it into HR_Radiance; until then the
previous result stays on screen.

Progressive Live (docs/live.md, "Progressive Live"): with `preview` set (the threaded worker, the
UI's), a light state that moves, reshapes or adds a shape is first computed as a preview (PREVIEW:
a cheaper response and output), and once no request arrived for REFINE_AFTER seconds (the drag
pauses) the worker refines it: the exact result, bitwise what the same requests give without
previews. flush() refines too (refine=False: only the pending requests, as previews).

threaded=False (Blender in background mode, tests, scripts) computes in the caller's thread when
flush() is called. The DynamicRadiosity is only ever used by one thread at a time.
"""

import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from ..core.events import DynamicRadiosity, Preview
from ..core.gather import LoopGather, OutputLayout
from ..core.geometry import InputError
from ..core.lights import indirect_incident
from ..core.progress import Cancelled
from ..core.radiosity import RadiositySystem
from ..io import precompute as pc


@dataclass
class BuildSpec:
    """Everything the worker needs to build (read from the scene by the UI thread)."""

    mesh: object  # core MeshInput
    params: object  # core RefineParams (already scaled as the bake scales them)
    method: str  # AUTO, AR, FE, NAIVE
    min_area_rel: float
    domain: str  # CORNER or POINT
    extract: object  # callable((L, 3) loop radiance) -> {object name: (N, 3) values}
    reason: str = ""  # shown while building ("first build", "'back' changed")
    polygons: int = 0
    gather: dict = None  # the final gather's settings (settings.gather_params), None: off
    threads: int = 1  # core.parallel's threads (BakeConfig.live_threads: one core kept for the UI)
    cache_dir: str = None  # where the bake keeps the scene precompute (None: the .blend is not saved)
    precompute: dict = None  # what it must match (settings.precompute_key): loaded instead of built if valid
    mode: str = "RADIANCE"  # what HR_Radiance gets (BakeConfig.live_mode): RADIANCE or INDIRECT
    solve: dict = None  # the bake's solver options (settings.solve_options) with the gather; None: Live's own
    output: tuple = None  # (finer mesh, transport polygon per polygon): the gather's OutputLayout (Vertex
    # Spacing after a bake added the modifiers; `mesh` is then the mesh they receive), None: on `mesh`
    prepare: object = None  # callable(spec) -> [message]: run first by the worker (it sets params,
    # min_area_rel and precompute: the solver's setup and the precompute key, numpy off the UI thread)


@dataclass
class Result:
    generation: int  # build it belongs to
    serial: int = 0  # the light-state request it answers
    sig: str = ""  # digest of that light state
    values: dict = None  # {object name: (N, 4) float32 RGBA}, None on error
    report: object = None  # core FrameReport of the apply
    error: str = ""
    fatal: bool = False  # the worker cannot go on (build failed, internal error)
    kind: str = "frame"  # "frame", "build" or "refine" (a preview made exact)
    t_apply: float = 0.0  # seconds in DynamicRadiosity.apply
    t_output: float = 0.0  # seconds computing the per-object values
    preview: bool = False  # a drag's preview (the exact result follows: refine)
    requested: float = 0.0  # time.perf_counter() of the request (latency)
    messages: list = field(default_factory=list)


# Live's light-shape responses: HR_Radiance is float32, and a relative residual of 1e-5 with float32
# gathers leaves errors of about 1.5e-7 of the brightest value (measured on the Cornell sample:
# float32 rounding) for 13 instead of 16 GMRES iterations. The base solution keeps the bake's settings.
# With the final gather on, Live takes the bake's solver options (BuildSpec.solve): a response is a
# fixed number of GMRES steps from zero there, so Live shows what a bake of the state gives.
RESPONSE_TOL = 1e-5

# Live's preview of a dragged shape (docs/live.md, "Progressive Live"): chosen by its error against
# the exact result over the 56 recorded Cornell edits (benchmarks/live_replay.py preview)
PREVIEW = Preview(method="FE")  # AR and AUTO preview as FE (no splits, no first bounce)
REFINE_AFTER = 0.25  # seconds without a new request before a preview is refined (the drag paused)


def _rgba(v):
    v = np.asarray(v, np.float32)
    return np.concatenate([v, np.ones((len(v), 1), np.float32)], 1)


class LiveWorker:
    def __init__(self, threaded=True, preview="auto"):
        self.threaded = threaded
        # previews while edits arrive (the UI's threaded worker); None: every state exact at once
        self.preview = (PREVIEW if threaded else None) if preview == "auto" else preview
        self.previewing = False  # the state shown is a preview, its refine not done yet
        self._shown = None  # (serial, sig, t_request) of the newest state computed
        self._cond = threading.Condition()
        self._busy = False
        self._closed = False
        self._build = None  # pending (generation, BuildSpec)
        self._shapes = None  # pending (serial, sig, shapes, t_request)
        self._last_shapes = None  # the newest light-state request (re-applied after a rebuild)
        self._result = None  # newest finished frame Result, not yet taken
        self._build_result = None  # newest finished build Result, not yet taken
        self.thread = None
        self.dyn = self.gather = None
        self.spec = None
        self.generation = 0  # builds requested
        self.built = 0  # generation of self.dyn (0: none yet)
        self.phase = "idle"  # idle, building, computing, failed, closed
        self.fraction = 0.0  # of the build
        self.eta = float("nan")
        self.build_message = ""
        self.build_seconds = 0.0
        self.build_report = None
        self.precompute = ""  # how the last build went: "precompute loaded" or "built (no precompute: why)"
        self.computed = 0  # light states computed (the coalescing test counts them)
        self.builds = 0  # builds finished

    # -- the UI thread ---------------------------------------------------------------------------
    def request_build(self, spec, serial, sig, shapes):
        """Build a new hierarchy from `spec`, then compute `shapes` on it. A build still running is
        cancelled at its next progress report (superseded)."""
        with self._cond:
            self.generation += 1
            self._build = (self.generation, spec)
            self._shapes = self._last_shapes = (serial, sig, shapes, time.perf_counter())
            self._result = None
            self.phase = "building"
            self.fraction, self.eta, self.build_message = 0.0, float("nan"), ""
            self._cond.notify_all()
        self._ensure_thread()
        return self.generation

    def request(self, serial, sig, shapes):
        """Compute this light state (replacing a pending one that was not started yet)."""
        with self._cond:
            self._shapes = self._last_shapes = (serial, sig, shapes, time.perf_counter())
            self._cond.notify_all()
        self._ensure_thread()

    def take(self):
        """(build Result or None, frame Result or None) finished since the last call."""
        with self._cond:
            b, r = self._build_result, self._result
            self._build_result = self._result = None
        if r is not None and r.generation != self.generation:
            r = None  # computed on a hierarchy that has been replaced since
        return b, r

    @property
    def pending(self):
        """A request or a preview's refine is still to be computed."""
        with self._cond:
            return self._busy or self._build is not None or self._shapes is not None or self.previewing

    def flush(self, timeout=None, refine=True):
        """Compute every pending request now (in this thread when not threaded, else wait for the
        worker thread), and refine a preview (refine=False: not when not threaded; the benchmarks'
        preview latency). Returns False if the timeout expired first."""
        if not self.threaded or self.thread is None:
            while self._step(block=False, refine=refine):
                pass
            return True
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while self._busy or self._build is not None or self._shapes is not None or self.previewing:
                if not self.thread.is_alive():
                    return False
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return False
                self._cond.wait(left if left is not None else 0.5)
        return True

    def close(self):
        """Stop the worker (a running build is cancelled at its next progress report)."""
        with self._cond:
            self._closed = True
            self._build = self._shapes = None
            self.phase = "closed"
            self._cond.notify_all()
        self.dyn = self.gather = None

    def join(self, timeout=None):
        """Wait for the worker thread to end (after close(): it finishes the light state it is
        computing; a build stops at its next progress report)."""
        if self.thread is not None:
            self.thread.join(timeout)

    # -- the worker thread -------------------------------------------------------------------------
    def _ensure_thread(self):
        if self.threaded and (self.thread is None or not self.thread.is_alive()) and not self._closed:
            self.thread = threading.Thread(target=self._loop, name="HR Live", daemon=True)
            self.thread.start()

    def _loop(self):
        while self._step(block=True):
            pass

    def _step(self, block, refine=True):
        """Take the newest pending request and compute it, or refine a preview once no request
        arrived for REFINE_AFTER s (at once when not blocking). False when there is nothing (more)
        to do."""
        with self._cond:
            while block and not self._closed and self._build is None and self._shapes is None:
                wait = None
                if self.previewing:  # refine once the edits pause
                    wait = self._shown[2] + REFINE_AFTER - time.perf_counter()
                    if wait <= 0:
                        break
                self._cond.wait(wait)
            if self._closed:
                return False
            if self._build is not None:
                job, self._build = ("build",) + self._build, None
            elif self._shapes is not None:
                job, self._shapes = ("shapes",) + self._shapes, None
            elif self.previewing and refine:
                job = ("refine",)
            else:
                return False
            self._busy = True
        try:
            if job[0] == "build":
                self._do_build(*job[1:])
            elif job[0] == "refine":
                self._do_refine()
            else:
                self._do_shapes(*job[1:])
        except BaseException as exc:  # never leave the UI waiting for a thread that died
            msg = "".join(traceback.format_exception_only(type(exc), exc)).strip()
            with self._cond:
                self.dyn = self.gather = None
                self.phase = "failed"
                self._build_result = Result(
                    self.generation, error=f"internal error: {msg}", fatal=True, kind="build"
                )
            traceback.print_exc()
        finally:
            with self._cond:
                self._busy = False
                self._cond.notify_all()
        return True

    def _superseded(self):
        return self._closed or self._build is not None

    def _do_build(self, generation, spec):
        t0 = time.perf_counter()

        def progress(info):
            if self._superseded():
                raise Cancelled()
            self.fraction, self.eta, self.build_message = float(info.fraction), float(info.eta), info.message

        self.dyn = self.gather = None  # the old ones are of no use any more (and may be large)
        try:
            notes = spec.prepare(spec) if spec.prepare is not None else []
            spec.prepare = None  # (done: a spec handed over again is not prepared twice)
            if self._superseded():
                return
            system, gather, why = (
                pc.load(spec.cache_dir, spec.precompute)
                if spec.cache_dir
                else (None, None, "no saved .blend")
            )
            # Live only reads the bake's precompute: writing it is the bake's (its lock, its folder)
            self.precompute = "precompute loaded" if system is not None else f"built (no precompute: {why})"
            pc.use_threads(system, gather, spec.threads)
            if system is None:
                system = RadiositySystem(spec.mesh, spec.params, progress=progress, threads=spec.threads)
            if self._superseded():
                return
            options = spec.solve or dict(response_tol=RESPONSE_TOL, response_float32=True)
            dyn = DynamicRadiosity(system, method=spec.method, min_area_rel=spec.min_area_rel, **options)
            if self._superseded():
                return
            # the output stage: its rays are traced once here, each edit is a sparse product
            if gather is None and spec.gather is not None:
                layout = None if spec.output is None else OutputLayout(system, *spec.output)
                gather = LoopGather(dyn, threads=spec.threads, output=layout, **spec.gather)
        except Cancelled:
            return
        except (InputError, ValueError, RuntimeError, MemoryError) as exc:
            with self._cond:
                self.phase = "failed"
                self._build_result = Result(generation, error=str(exc), fatal=True, kind="build")
            return
        with self._cond:
            if self._superseded():
                return
            self.dyn, self.gather, self.spec, self.built = dyn, gather, spec, generation
            self.previewing = False
            self.build_seconds = time.perf_counter() - t0
            self.build_report = system.build
            self.builds += 1
            self.fraction = 1.0
            self.phase = "computing"
            notes += [m for m in system.build.warnings if m not in notes]
            self._build_result = Result(generation, kind="build", messages=notes)
            if self._shapes is None and self._last_shapes is not None:
                self._shapes = self._last_shapes  # the newest light state, on the new hierarchy

    def _do_shapes(self, serial, sig, shapes, t_request):
        dyn, spec, generation = self.dyn, self.spec, self.built
        if dyn is None or generation != self.generation:
            return  # no hierarchy yet (its build re-queues the newest state)
        self.phase = "computing"
        t0 = time.perf_counter()
        try:
            from ..core.lights import Light

            lights = {k: v for k, v in shapes.items() if isinstance(v, Light)}
            shapes = {k: v for k, v in shapes.items() if k not in lights}
            # (the preview's keyword only when set: tests hold apply(shapes, lights) in a wrapper)
            report = dyn.apply(shapes, lights, **({} if self.preview is None else {"preview": self.preview}))
        except InputError as exc:  # an invalid shape: apply() validates before changing anything
            with self._cond:
                self._result = Result(generation, serial, sig, error=str(exc), requested=t_request)
                self.phase = "idle"
            return
        self._shown = (serial, sig, t_request)
        self.computed += 1
        self._publish(dyn, spec, generation, report, t0, time.perf_counter(), serial, sig, t_request)

    def _do_refine(self):
        """The shown preview made exact (DynamicRadiosity.refine), delivered as a new result."""
        dyn, spec, generation = self.dyn, self.spec, self.built
        if dyn is None or generation != self.generation:
            with self._cond:
                self.previewing = False
            return
        self.phase = "computing"
        t0 = time.perf_counter()
        report = dyn.refine()
        self._publish(dyn, spec, generation, report, t0, time.perf_counter(), *self._shown, kind="refine")

    def _publish(self, dyn, spec, generation, report, t0, t1, serial, sig, t_request, kind="frame"):
        """The per-object values of dyn's current state into the result slot."""
        values = self._values(dyn, spec)
        t2 = time.perf_counter()
        with self._cond:
            self.previewing = dyn.previewing
            self._result = Result(
                generation,
                serial,
                sig,
                values,
                report,
                t_apply=t1 - t0,
                t_output=t2 - t1,
                requested=t_request,
                messages=list(report.messages),
                preview=self.previewing,
                kind=kind,
            )
            self.phase = "idle"

    def _values(self, dyn, spec):
        """{object name: (N, 4) float32 RGBA} of dyn's current state."""
        gather, fx = self.gather, spec.extract
        by_rows = gather is not None and spec.domain == "CORNER" and getattr(fx, "flat", False)
        if by_rows and spec.mode != "INDIRECT":
            # the gather writes the targets' loops straight into the RGBA rows (a colour edit: one sum)
            return fx.rgba(None, lambda rows, out: gather.loop_radiance(dyn, rows=rows, out=out))
        if spec.mode == "INDIRECT":  # (BakeConfig: with the final gather only)
            loops = gather.loop_values(indirect_incident(gather, dyn), spec.domain)
        elif gather is not None:
            loops = gather.loop_radiance(dyn, spec.domain)
        else:
            loops = dyn.loop_radiance(spec.domain)
        rgba = getattr(fx, "rgba", None)  # scene_in.FlatExtract: RGBA slices of one array
        return rgba(loops) if rgba is not None else {k: _rgba(v) for k, v in fx(loops).items()}
