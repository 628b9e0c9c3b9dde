"""RefineParams: the refinement's thresholds, the quality presets and the transport preset of the
final gather."""

import dataclasses
from dataclasses import dataclass


@dataclass
class RefineParams:
    feps: float = 0.02  # form factor threshold (dimensionless)
    veps: float = 0.0  # max variation of a link's point form factor across either node (0: off)
    near: float = 4.0  # pairs closer than sqrt(near x (A_p + A_q)) get the variation test
    aeps: float = 2e-4  # minimum node area, as a fraction of the total scene area
    shadow_feps: float = 0.002  # partly visible links above this are split (0 disables)
    vis_k: int = 2  # visibility samples per node: vis_k^2, rays per link: vis_k^4
    bfeps: float = 0.0  # BF refinement threshold, relative to the brightest emitter (0: off)
    bf_passes: int = 2
    vcorr: float = 1e-4  # push corrections for links varying more than this (0: off)
    corr_budget: int = 3_000_000
    cluster: bool = True  # link through face clusters (cluster.py) instead of all patch pairs
    cluster_ratio: float = 0.3  # far links need (radius_a + radius_b) < cluster_ratio x distance
    partial_feps: float = 0.5  # far links with a partly facing cluster end need F < partial_feps x feps
    # far links may have two partly facing cluster ends when both are smaller than partial_both x
    # Aeps (0: never): a crown of small leaves, whose clusters' normals spread wide (farlinks)
    partial_both: float = 0.0
    cluster_veps: float = 1e-3  # far links need F x (radius_a + radius_b) / distance below this
    # Far links between two dark ends (no patch of the static emission in either, farlinks.LitEnds):
    # in the base solution they carry the emitters' light only after a reflection, so a share of
    # the receiver's light far below an emitter's link's. Their cluster_ratio / cluster_veps
    # (0: the same as every far link's) and whether they get the second trace (SECOND_TRACE)
    dark_ratio: float = 0.0
    dark_veps: float = 0.0
    dark_second: bool = True
    cluster_leaf: int = 4  # most patches in a leaf cluster
    contacts: bool = True  # find surfaces covered by touching geometry (contacts.py) and refine along them
    contact_gap: float = 1e-3  # how close counts as touching, relative to sqrt(total scene area)
    contact_levels: int = 2  # contact refinement goes this many quadtree levels below aeps
    ff_order: int = 3  # most Gauss points per side for a link's form factor (near pairs)
    # about ff_exposed^2 points on a partly covered node's exposed part for its near links' form
    # factors (its visibility points and the oracle's centre keep 6 x 6); 6 -> 4 (2026-12-04, was
    # refine.FF_TARGET): the exposed-part form factors 20.3 -> 8.5 s at 100k, the gathered output
    # per object within 0.02% (20k) (docs/scale.md "inexact cuts")
    ff_exposed: int = 4
    orient: bool = False  # turn around faces facing the wrong way before the build (orientation.py)

    @staticmethod
    def preset(name):
        presets = {
            "draft": RefineParams(
                feps=0.05, aeps=1e-3, shadow_feps=0.01, vcorr=1e-3, cluster_ratio=0.4, cluster_veps=1e-2
            ),
            "medium": RefineParams(),
            "high": RefineParams(
                feps=0.008, veps=0.005, aeps=5e-5, shadow_feps=0.0005, vcorr=1e-5, cluster_veps=2e-4
            ),
        }
        if name not in presets:
            raise ValueError(f"Unknown quality preset '{name}' (choose from {', '.join(presets)})")
        return presets[name]

    @staticmethod
    def for_gather(name):
        """The transport's preset when the final gather is on (core/gather.py, docs/gather.md):
        the gather reads exact direct light at two levels and the hierarchy's solution only after
        its iterations, so the links may be coarser than for showing the leaves (measured: the
        gathered output within 1% per object of the preset's, docs/gather.md, Transport)."""
        p = RefineParams.preset(name)
        return dataclasses.replace(p, **GATHER_TRANSPORT[name])


# RefineParams.for_gather: fields changed from the quality's preset when the final gather is on.
# Draft (measured, docs/gather.md, Transport): coarser link criteria and no push corrections
# (links 314k -> 181k on the 20k room, the gathered output per object median 0.1% from the
# preset's, 99% of the objects within 1%); since 2026-12-04 fewer, larger far links
# (cluster_ratio 0.5 -> 0.7, cluster_veps 0.03 -> 0.1) and one visibility ray per patch link
# (vis_k 1): links 181k -> 100k, the gathered output per object median <= 0.09% from before,
# bias within 0.1%. feps is not what limits draft's links (0.1 -> 0.8: 181k -> 180.7k links);
# shadow_feps 0.1 with the larger far links biased it by -0.2% and the furnished room's
# Cycles bias by -0.4 points (not taken). Medium and high: the same rule one step down (the link
# criteria of the quality below, no push corrections), leaves (aeps) and contacts as the preset's;
# medium measured on the 20k room (links 1.44 M -> 380k, every object within 0.51%), high not.
# Medium takes draft's far links and vis_k since 2026-12-04 (20k room, FE: links 380k -> 188k,
# build 37.2 -> 25.2 s CPU, the gathered output per object median <= 0.05% from before, worst
# 0.43%, bias within 0.04%; Cornell medium worst surface 0.26 -> 0.28%, docs/gather.md).
# Draft's exposed-part form factors from about 3 x 3 points (ff_exposed 3, was 4) since session
# 31 (issue 19, build60): the gathered output per object 0.001% from before (20k), inside the seed
# floor at 20k and 100k (docs/scale.md, session 31). ff_order 1 (one Gauss point a side) moved the
# output by 0.002-0.003% and saved ~4.6 s at 100k, but touching pairs' exchange (a book's side and
# its board, tests/test_clusters.py) read 0.62 of the exact (3: 0.90, 2: 1.24): not taken.
# Draft's far links between two dark ends: dark_ratio 0.9 since session 32 (farlink): draft's
# events solve no response (gather_responses "zero"), so the links carry only the base solution,
# whose light enters at the emitting patches; a pair of dark ends carries it after a reflection.
# build60's 1.0 / 0.3 for every far link moved the 20k room's output 0.027% per object (median,
# p95 0.15%), this 0.015% (p95 0.03%), inside the seed floor; 100k build x0.948. dark_ratio 1.0
# made the 20k base solve take twice the GMRES steps (its power balance 5e-3 off), 0.95 and 0.9 did
# not; dark_veps 0.3 (weak far links' visibility 0.992 of a dense one) and dark_second False (strong
# ones' +3.8%) fail tests/test_clusters.py's bound of 0.5%: not taken (docs/scale.md, session 32).
# Draft's partial_both 1.0 since session 35 (leaves): two ends below Aeps that fail only the facing
# test (a crown's leaves) link with the clamped cosine on both; the loft's links 1.46 M -> 0.64 M,
# the furnished 20k's 108k -> 93k (its output per object 0.0001% median), 100k 635k -> 453k.
GATHER_TRANSPORT = {
    "draft": dict(
        feps=0.1,
        shadow_feps=0.03,
        vcorr=0.0,
        cluster_ratio=0.7,
        cluster_veps=0.1,
        dark_ratio=0.9,
        vis_k=1,
        ff_exposed=3,
        partial_both=1.0,
    ),
    "medium": dict(feps=0.05, shadow_feps=0.01, vcorr=0.0, cluster_ratio=0.7, cluster_veps=0.1, vis_k=1),
    "high": dict(feps=0.02, shadow_feps=0.002, vcorr=0.0, cluster_ratio=0.3, cluster_veps=1e-3),
}
