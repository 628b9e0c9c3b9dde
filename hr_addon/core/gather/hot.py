"""Hot secondary sources: the HR leaves a final gather should take a Blender light's first bounce
off explicitly (lights.leaf_bounce: exact form factor x shadow rays) instead of finding them with
its hemisphere rays (issue 19, session 35, branch shade; docs/gather.md, "Hot secondary sources").

A small surface lit from a few cm (a lamp shade's inside around its bulb, a sconce's wall, a cove)
reflects far more radiance than the rest of the room: 128 cosine rays per output sample hit it, or
not, and neighbouring samples read values apart by a large factor (the loft's ceiling and walls
around the pendant: blotches the vertex output spreads). Such a source is known only once the
light is solved: a run-time property of each light's first bounce (cached with it, per light
geometry, FinalGather._light_bounce).

Two rules, the first kept from session 15 (lights.bright_leaves): a first bounce that few leaves
hold (at most `most` of them 95% of its power: a sun through a hole, a spot's footprint) is
integrated whole. Else the leaves whose first-bounce radiance is more than HOT x the light's
mean over the exposed area it lights (the brightest `most` of them) are. A ray reading such a
leaf adds radiance / mean / R of the light around it at once: with HOT = 8 and 128 rays one hit
is 6% of a sample's indirect light. The mean is over the lit area, not the whole scene's: a
bedroom's ceiling panel lights the bedroom only, and against the whole two-room flat its walls
read 9-23x the mean (256 leaves, 47% of its bounce, well found by the rays: none is picked now).
Taking a leaf out of the rays and integrating it exactly is unbiased whatever the rule picks; the
rule only decides where that is worth its cost (N samples x the picked leaves' form factors, at
both gather levels, one pass per light geometry). The loft's pendant (a point light 2 cm inside
a cone shade's mouth): 154 leaves, 55% of its first bounce, the shade's 32 lit faces at 1370x
the mean among them.
"""

import numpy as np

from ..lights import BRIGHT_LEAVES, bright_leaves

HOT = 8.0  # a leaf's first-bounce radiance over the light's area-weighted mean: above it, explicit
SECOND = True  # the second level's samples too (FinalGather._hot_second): their rays found the hot
# leaves or not, and the leaf values the top level reads (the walls' means) scattered with them


def bounce_leaves(radiance, area, most=None, hot=None):
    """Indices (ascending) of the leaves whose first bounce of one light, radiance (m,) (>= 0, a
    luminance) on exposed areas area (m,), a gather integrates explicitly: bright_leaves' few
    leaves holding the bounce; else those brighter than `hot` (HOT) x the mean radiance over the
    lit area, at most `most` (BRIGHT_LEAVES), the brightest first; none without light."""
    most = BRIGHT_LEAVES if most is None else most
    hot = HOT if hot is None else hot
    radiance = np.asarray(radiance, np.float64)
    area = np.asarray(area, np.float64)
    power = radiance * area
    idx = bright_leaves(power, most)
    if len(idx) or not hot or not np.isfinite(hot):
        return idx
    lit = (radiance > 0) & (area > 0)
    if not lit.any():
        return idx
    above = np.flatnonzero((radiance > hot * power[lit].sum() / area[lit].sum()) & lit)
    if len(above) > most:
        above = above[np.argsort(-radiance[above], kind="stable")[:most]]
    return np.sort(above)
