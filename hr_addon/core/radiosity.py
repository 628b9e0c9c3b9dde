"""The engine in one object: input mesh -> patches -> hierarchy -> links -> solution."""

import copy
import time
from dataclasses import dataclass, field

import numpy as np

from .geometry import MeshInput, prepare_patches
from .hierarchy import Hierarchy
from .orientation import orient
from .output import loop_radiance
from .progress import Progress
from .corrections import push_corrections
from .params import RefineParams
from .refine import Refiner
from .solver import Operator, solve
from .visibility import make_backend


@dataclass
class BuildReport:
    patches: int = 0
    dropped: int = 0
    nodes: int = 0
    links: int = 0
    t_total: float = 0.0
    refine: dict = field(default_factory=dict)
    backend: str = ""
    warnings: list = field(default_factory=list)

    @property
    def memory_bytes(self):
        return self.nodes * Hierarchy.node_bytes() + self.links * 2 * 16


class RadiositySystem:
    def __init__(
        self, mesh: MeshInput, params: RefineParams = None, backend="auto", tol=1e-7, progress=None, threads=1
    ):
        """progress: callable(ProgressInfo) called between batches of the build; it cancels the
        build by raising (core.progress.Cancelled), which propagates out of this constructor.
        threads: for the ray backend's large batches (core.parallel; None: every core)."""
        t0 = time.perf_counter()
        self.mesh = mesh
        self.params = params or RefineParams()
        self.tol = tol
        self.patches = prepare_patches(mesh)
        self.backend = make_backend(self.patches.triangles, backend, threads)  # occluders: two-sided
        if self.params.orient:  # faces turned the wrong way are turned around, as Cycles shows them
            orient(self.patches, self.backend)
        self.h = Hierarchy(self.patches)
        self.refiner = Refiner(self.h, self.backend, self.params)
        self.refiner.progress = Progress(progress, {"clusters": 0.5, "linking": 0.4, "push corrections": 0.1})
        self.links = self.refiner.build()
        self.B = None
        self.report = None
        self._op = None
        if self.params.bfeps > 0:
            for _ in range(self.params.bf_passes):
                self.solve()
                new = self.refiner.refine_bf(self.links, self.B)
                if len(new) == len(self.links) and np.array_equal(new.a, self.links.a):
                    break
                self.links = new
        if self.params.vcorr > 0:
            self.refiner.progress.update("push corrections", 0, 1, force=True)
            t1 = time.perf_counter()
            self.links = push_corrections(
                self.h,
                self.links,
                self.params.vcorr,
                self.params.corr_budget,
                self.refiner.centres,
                self.refiner.leaf_form_factors,
                self.refiner.leaf_visibility,
            )
            self.refiner.stats["t_corr"] = time.perf_counter() - t1
        self.refiner.progress.done("push corrections")
        self._op = None
        self.B = None  # a BF pass solved with links that have changed since
        # DynamicRadiosity's base solutions (no light shapes, no lights) by solver tolerance and
        # emission, kept while the hierarchy is this build's (build_version); the scene precompute
        # stores them, so a loaded one starts without that solve
        self.bases = {}
        self.build_version = self.h.version
        self.build = BuildReport(
            len(self.patches.nv),
            self.patches.dropped,
            self.h.n,
            len(self.links),
            time.perf_counter() - t0,
            dict(self.refiner.stats),
            type(self.backend).__name__,
            list(self.patches.warnings),
        )

    def copy(self):
        """An independent copy for light events: its own hierarchy (events add nodes below the
        leaves), sharing the links and the ray backend, which events never change."""
        c = object.__new__(RadiositySystem)
        c.__dict__.update(self.__dict__)
        c.h = copy.deepcopy(self.h)
        c.refiner = Refiner(c.h, self.backend, self.params)
        c._op = None
        return c

    def base_emission(self):
        """(3, n) leaf emission from the input polygons."""
        return self.patches.emission[:, self.h.view("patch")].copy()

    def operator(self):
        if self._op is None or self._op.version != self.h.version or self._op.links is not self.links:
            self._op = Operator(self.h, self.links, self.backend.threads)
        return self._op

    def solve(self, E=None, warm=True, tol=None):
        E = self.base_emission() if E is None else E
        B0 = self.B if (warm and self.B is not None and self.B.shape[1] == self.h.n) else None
        self.B, self.report = solve(self.h, self.links, E, B0=B0, tol=tol or self.tol, op=self.operator())
        return self.B

    def loop_radiance(self, domain="CORNER", smooth_angle=30.0):
        if self.B is None:
            self.solve()
        return loop_radiance(self.h, self.B, self.mesh, smooth_angle, domain)

    # -- the solution interface, shared with DynamicRadiosity (texels, gather, lightmap plan read a
    # solution through it): a RadiositySystem is the solution without light events ---------------
    naive_active = False
    incremental = None  # no cached responses to sum

    @property
    def system(self):
        return self

    @property
    def n_hr(self):
        return self.h.n

    @property
    def shapes(self):
        return {}

    @property
    def lights(self):
        return {}

    def current(self):
        """(h, B, E, links) of the solution in effect (solved if it is not yet)."""
        if self.B is None:
            self.solve()
        return self.h, self.B, self.base_emission(), self.links

    def solution_at(self, points, patch_ids):
        """(h, B, patch_ids, points): DynamicRadiosity.solution_at without events."""
        h, B, _, _ = self.current()
        return h, B, patch_ids, points

    def loop_field(self, X, domain="CORNER", smooth_angle=30.0):
        """A node field X (3, n) other than B, per input loop (or vertex) as loop_radiance."""
        return loop_radiance(self.h, X, self.mesh, smooth_angle, domain)
