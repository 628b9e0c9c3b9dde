"""Where the furnished sample's books keep their light in Cycles (issue 19, docs/gather.md "Narrow
gaps"): the books' texels by how far their centre lies from the open edge of the gap a neighbour's
side covers (in gap widths h: the smallest open_edge of contacts.Contacts.covered that uncovers
it), with Cycles' share of the books' reflected light in each band. Needs the cached furnished
reference of cycles_compare.py / furnished_vs_cycles.py.

    .venv/bin/python benchmarks/books_gap_profile.py
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
import numpy as np  # noqa: E402

import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

cfg = CC.SCENES["furnished"]
rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
a, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
b, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
ours = C.Ours(rs, s)
con = s.h.contacts
books = [n for n in rs.objects if "_book" in n]
ladder = [0.0, 1, 2, 5, 10, 20, 50, 1e9]
light = np.zeros(len(ladder) + 1)
count = np.zeros(len(ladder) + 1, int)
for n in books:
    at = rs.atlases[n]
    cen = np.flatnonzero(at.s_centre)
    patch = ours.samples[n][0][cen]
    x = at.s_point[cen]
    ref = ((a[n] + b[n]) / 2)[at.s_texel[cen]].mean(1)
    ok = np.isfinite(ref)
    band = np.full(len(cen), len(ladder))  # still covered at the largest open_edge
    for k in range(len(ladder) - 1, -1, -1):
        cov = con.covered(x, patch, open_edge=ladder[k])
        band[~cov] = k
    light += np.bincount(band[ok], ref[ok], len(ladder) + 1)
    count += np.bincount(band[ok], minlength=len(ladder) + 1)
tot = light.sum()
print(f"{len(books)} books, {count.sum()} texels, texel {1000 * rs.atlases[books[0]].texel:.0f} mm")
print("band (centre's distance to the open edge, gap widths) | texels | share of the books' light in Cycles")
labels = ["uncovered"] + [f"< {c:g} h" for c in ladder[1:-1]] + ["beyond 50 h", "touching (h = 0)"]
for k in range(len(ladder) + 1):
    print(f"{labels[k]:>24s} | {count[k]:6d} | {100 * light[k] / tot:5.1f}%")
