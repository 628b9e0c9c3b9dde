"""Light shapes and event reports of DynamicRadiosity, and its per-shape record."""

from dataclasses import dataclass, field

import numpy as np


METHODS = ("NAIVE", "AR", "FE", "AUTO")


@dataclass
class LightShape:
    rings: list  # world-space rings (M_i, 3): outer first, then holes; planar
    emission: np.ndarray  # (3,) radiance (Cycles strength x colour)
    name: str = ""
    # the shape's outline changes over the animation (a bake's or Live's caller says so, from the
    # scene, never from the frames it happens to hold): the final gather reads its direct light from
    # the visibility toward its host wall (gather/hostvis.py), which pays on the second place it
    # lights; a still one (False, the default) keeps its shadow rays, cheaper at its only place
    # (docs/events.md, session 30 hvmove)
    moves: bool = False


@dataclass(frozen=True)
class Preview:
    """A cheaper estimate of the shapes a drag moves (Live Relight, docs/live.md "Progressive
    Live"): DynamicRadiosity.apply(..., preview=) solves their responses to `tol` (from the
    previous response's scattered light) with `method` (None: the DynamicRadiosity's; Live's
    PREVIEW: FE, so AR and AUTO preview without splits or first bounce) and marks them
    (_Rec.preview); the final gather gives them `shadow_rays` per output sample and reads the
    HR leaves (levels 1) or a second level without iterations with `second_shadow_rays`
    (levels 2). refine() then solves them as apply() without a preview would have.
    reuse_visibility: a moved shape's direct light is its exact unoccluded form factor times the
    visible fraction a reference had at each sample, while the outline shares at least
    `reuse_share` of its area with the reference's: the shape's last exact state (_Rec.ref), else
    the last preview that took shadow rays (FinalGather._preview_direct). The error at a sample is
    at most the form factor of the two outlines' symmetric difference (docs/live.md, "Previews
    on the furnished 100k room").
    correct: the previews of a drag add what the preview's read of the HR leaves misses of the
    last exact state's final gather (its second level and iterations; FinalGather.
    _preview_reference).
    guess_share: while the outline shares at least this much of its area with the last state whose
    scattered light was computed (outline_share; its last exact state, or a later preview whose
    solve iterated: one whose check accepted its guess at the first residual kept the older state's
    light), the response is the warm guess without the solve's check (that scattered light,
    scaled by the emitted power's ratio; None: always checked). Only where that state was solved
    with the preview's method (AUTO's and AR's exact states are not the guess's reference; their
    iterated previews are).
    refresh_tol: with guess_share, a preview outside it solves to this tolerance instead of tol
    (None: tol), so that it iterates (unless its guess is already within it) and its scattered
    light is the next previews' unchecked guess: a preview that accepted its guess at tol would
    be checked again at the next step (the lag grows by about 2e-3 per 5 cm step at 100k, so
    from 3e-3 the unchecked steps within 3/4 of the outline stay near tol)."""

    tol: float = 1e-2
    method: str = None
    shadow_rays: int = 4
    levels: int = 1
    second_shadow_rays: int = 2
    reuse_visibility: bool = True
    reuse_share: float = 0.75
    correct: bool = True
    guess_share: float = 0.75
    refresh_tol: float = 3e-3


def outline_share(rec, other):
    """The share of a validated shape record's outline inside `other`, an Emitter (a previewed
    shape's reference: its convex pieces): their intersection over the larger of the two areas;
    0 on another plane."""
    from ..clip import overlap_areas
    from .validation import to2d

    if other is None or other.normal is None or abs(other.normal @ rec.n) < 0.999:
        return 0.0
    if abs((other.point - rec.c) @ rec.n) > max(rec.tol, 1e-9):
        return 0.0
    inter = overlap_areas(rec.rings2d, to2d(rec, other.corners), other.nv).sum()
    return float(inter / max(rec.area, other.area.sum(), 1e-300))


@dataclass
class EventReport:
    kind: str  # "add", "remove", "emission", "reshape"
    key: object = None
    name: str = ""
    method: str = ""  # method actually used: NAIVE, AR, FE, AUTO, "AR+FE" (AR stopped at the budget)
    seconds: float = 0.0
    iterations: int = 0  # solver iterations
    nodes_added: int = 0
    nodes_removed: int = 0
    nodes: int = 0  # after the event
    links: int = 0  # after the event (the solver's links)
    direct_links: int = 0  # AUTO: links from the shape computed for its first bounce (not kept)
    memory_bytes: int = 0  # nodes + links + cached responses
    emission_l1: float = 0.0  # relative L1 error of the shape's emission field (exact for FE/AR/AUTO)
    covered: float = 1.0  # fraction of the shape's area lying on surfaces
    reused: bool = False  # the shape's response came from the cache (same shape seen before)
    messages: list = field(default_factory=list)  # warnings for the user


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
    rings: list  # validated world rings
    emission: np.ndarray  # (3,)
    method: str  # requested
    used: str = ""
    c: np.ndarray = None  # plane: point, normal, in-plane basis
    n: np.ndarray = None
    u: np.ndarray = None
    v: np.ndarray = None
    tol: float = 0.0  # distance tolerance of its plane (plane_tol x its own size)
    rings2d: list = None
    area: float = 0.0
    group: np.ndarray = None  # coplanar root patches (emitting side)
    roots: np.ndarray = None  # coplanar root patches the shape overlaps
    covered: float = 0.0
    on_surface: bool = False
    cov_nodes: np.ndarray = None
    cov_vals: np.ndarray = None
    owned: np.ndarray = None  # nodes whose split this shape needs (reference counted)
    U: np.ndarray = None  # (3, n) response at unit emission
    D: np.ndarray = None  # (3, n) AUTO: first-bounce radiance per unit emission, at link receivers
    emission_l1: float = 0.0
    budget_hit: bool = False
    direct_links: int = 0
    msgs: list = field(default_factory=list)
    emitter: tuple = None  # (unit, Emitter, normal): the final gather's, shared by its levels
    preview: Preview = None  # set: U is a preview's (apply(preview=)), refine() replaces it
    G: np.ndarray = None  # (3, n) a preview's: the guess its exact solve starts from (refine)
    ref: object = None  # a preview's: the record of its shape's last exact state (its visibility)
    # a preview's whose response kept an older state's scattered light (an unchecked guess, or a
    # check that accepted its guess): that state's record (its last exact state, or a preview
    # whose solve iterated; Preview.guess_share's reference); None: its own light was computed
    solved: object = None
    # no response solved: U holds the emission only and the final gather's passes, started from
    # nothing, give the scattered light (DynamicRadiosity's gather_responses); a preview's: that
    # state's indirect light scaled by `ratio`, the emitted power's (FinalGather._preview_part)
    gathered: str = ""  # "tail" / "zero" (DynamicRadiosity.gather_responses)
    ratio: float = 1.0
    moves: bool = False  # LightShape.moves

    @property
    def geom_key(self):
        """The outline's bytes, and whether it moves (its direct light depends on it: the caches
        keyed by it hold it)."""
        return tuple(r.tobytes() for r in self.rings) + (("moves",) if self.moves else ())
