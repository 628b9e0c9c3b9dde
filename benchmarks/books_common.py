"""The setup books_texels.py and books_sides.py share: the furnished sample against its cached
Cycles reference (frame 1), one draft FE solution, and the bake's gather setting."""

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

BASE = dict(rays=128, shadow_rays=16, levels=2, iterations=4)  # the bake's draft gather


def variants(argv):
    """{name: texel_gather keywords} from name=dict(...) arguments, "main" (BASE) first."""
    out = {"main": {}}
    out.update({k: eval(v) for k, v in (x.split("=", 1) for x in argv)})
    return out


def furnished():
    """(rs, Cycles' two seeds {name: (texels, 3)}, system, dyn, ours) of the furnished sample."""
    cfg = CC.SCENES["furnished"]
    rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
    a, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
    b, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
    t0 = time.process_time()
    s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
    dyn = DynamicRadiosity(s, method="FE")
    dyn.apply(C.shape_proxies(rs, 1))
    print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)
    return rs, (a, b), s, dyn, C.Ours(rs, s, dyn)


def book_boxes(rs):
    """{book: (lo, hi)}: each book's box from its vertices."""
    mesh = rs.scene_in.mesh
    tg = {t.name: t for t in rs.scene_in.targets}
    box = {}
    for n in (n for n in rs.objects if "_book" in n):
        lo_l, hi_l = tg[n].loops
        v = mesh.verts[mesh.loop_verts[lo_l:hi_l]]
        box[n] = (v.min(0), v.max(0))
    return box


def neighbour(box, n, side):
    """The box facing book n's side -x (side 0) or +x (side 1): the next book of its row, or None
    (the case's sides, 1 cm from a row's first book, are not looked at)."""
    case, row, k = n.split("_")[0], n.split("_")[1], int(n.split("_")[2])
    return box.get(f"{case}_{row}_{k + (1 if side else -1)}")


def centre_texels(rs, ours, ref, n):
    """Object n's texels sampled at their centre: (points, patches, axes, triangles, the Cycles
    reference ref[n] at them, grey)."""
    at = rs.atlases[n]
    cen = np.flatnonzero(at.s_centre)
    return (
        at.s_point[cen],
        ours.samples[n][0][cen],
        at.s_axes[cen],
        at.s_tri[cen],
        ref[n][at.s_texel[cen]].mean(1),
    )
