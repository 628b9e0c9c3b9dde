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
  row of weights over those leaves (hits / R, duplicates merged, kept as the hit counts where R is
  a power of two; rays that escape, hit a back face or a covered point contribute nothing). At
  run time I = W @ (reflected radiance of the solution at the leaves): B - E (the node's own,
  possibly fractional, emission is taken out: the exact direct term carries all emission), shown
  on the node's uncovered part (Hierarchy.shown).
- E_point: the emitter's own radiance exactly at the point: the input patch's emission, plus a
  light shape's radiance inside its outline (point in polygon with holes, on the surface it lies
  on); outside the outline 0, whatever fraction of it the coarse nodes carry for transport.
- Points Hierarchy.dark() calls covered (contacts) output exactly 0, except in a slot (a gap
  h > 0 under a face lit through its open edges, contacts.Contacts.slots): those gather a gap
  width inside their nearest mouth, their incident light scaled by the slot's transfer
  (FinalGather._slots).

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

Modules: sampling.py (random streams, hemisphere and solid-angle sampling, Emitter), points.py
(HR leaves of points), direct.py (direct light per emitter), final.py (FinalGather: precompute,
leaf values, output), layouts.py (LoopGather at the mesh's corners, texel_gather). The batches run
on core.parallel's threads (`threads=`), with results equal for any thread count.
"""

from .direct import DirectLight, _clipped_rings
from .final import KINDS, FinalGather, _csr_matvec
from .layouts import LoopGather, OutputLayout, loop_samples, texel_gather
from .points import _into_patch, _triple, locate_below
from .sampling import (
    Emitter,
    _frame,
    _mix,
    _unit_rows,
    cosine_directions,
    hammersley,
    hash_uniform,
    position_keys,
    sample_spherical_triangle,
    solid_angles,
    spherical_setup,
)

__all__ = [
    "KINDS",
    "DirectLight",
    "Emitter",
    "FinalGather",
    "LoopGather",
    "OutputLayout",
    "cosine_directions",
    "hammersley",
    "hash_uniform",
    "locate_below",
    "loop_samples",
    "position_keys",
    "sample_spherical_triangle",
    "solid_angles",
    "spherical_setup",
    "texel_gather",
    "_clipped_rings",
    "_csr_matvec",
    "_frame",
    "_into_patch",
    "_mix",
    "_triple",
    "_unit_rows",
]
