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
report says so. Invalid shapes (NaN, not planar, degenerate, an outline that crosses itself, holes outside
the outline or overlapping) raise InputError naming the shape.
"""

from ..output import locate
from .dynamic import DynamicRadiosity
from .planar import slab_decomposition, surface_samples
from .records import METHODS, EventReport, FrameReport, LightShape, Preview
from .validation import outline_problem

__all__ = [
    "METHODS",
    "DynamicRadiosity",
    "EventReport",
    "FrameReport",
    "LightShape",
    "Preview",
    "locate",
    "outline_problem",
    "slab_decomposition",
    "surface_samples",
]
