"""Furnished sample against its cached Cycles reference (frame 1), for refinement variants: which
setting moves which surface. Needs the reference of `cycles_compare.py --scenes furnished`.

    .venv/bin/python benchmarks/furnished_vs_cycles.py 'clusters={}' 'plain=dict(cluster=False)' \
        'nograd=dict(grad_cone=0.0)' 'med=dict(q="medium")'

Each argument is name=dict(RefineParams fields, q=preset, grad_cone=cluster.GRAD_CONE).
"""

import dataclasses
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
import numpy as np
import cycles_compare as CC
import cycles_ref as C
from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

cfg = CC.SCENES["furnished"]
scene = CC.open_scene("furnished")
rs = C.prepare(scene, texel_rel=cfg["texel_rel"])
a, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
b, _, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
ref = {n: (a[n] + b[n]) / 2 for n in rs.objects}
shapes = C.shape_proxies(rs, 1)
variants = {k: eval(v) for k, v in (x.split("=", 1) for x in sys.argv[1:])}
for name, kw in variants.items():
    q = kw.pop("q", "draft")
    import hr_addon.core.cluster as CL, hr_addon.core.farlinks as FL

    g = kw.pop("grad_cone", 0.03)
    CL.GRAD_CONE = FL.GRAD_CONE = g
    t0 = time.process_time()
    base = RadiositySystem(rs.scene_in.mesh, dataclasses.replace(RefineParams.preset(q), **kw))
    tb = time.process_time() - t0
    dyn = DynamicRadiosity(base, method="FE")
    dyn.apply(shapes)
    res = C.Ours(rs, dyn.system, dyn).evaluate(shapes, smooth=False)
    cmp_ = CC.compare(res, ref, 0.0, rs.objects)["refl_leaf"]
    al, per = cmp_["all"], cmp_["surfaces"]
    big = sorted((n for n in per if per[n]["texels"] >= 0.01 * al["texels"]), key=lambda n: -per[n]["texels"])
    print(
        f"{name} ({q}, {kw}): build {tb:.0f} s CPU, links {len(base.links)}, bias {100 * al['bias']:+.2f}%, "
        f"worst surface {100 * al['worst_mre']:.1f}% ({al['worst_surface']})",
        flush=True,
    )
    print(
        "   big surfaces bias:", ", ".join(f"{n} {100 * per[n]['bias']:+.1f}%" for n in big[:12]), flush=True
    )
    # objects lit well enough for a relative error to mean something (Cycles noise, near-black objects)
    lit = [n for n in per if np.mean(per[n]["mean_ref"]) > 0.05 * np.mean(al["mean_ref"])]
    w = np.array([per[n]["texels"] for n in lit])
    e = np.array([per[n]["mre"] for n in lit])
    print(
        f"   {len(lit)} lit objects: texel-weighted error of the mean {100 * np.sum(w * e) / w.sum():.1f}%, "
        f"within 5%: {np.mean(e < 0.05) * 100:.0f}%, median {100 * np.median(e):.1f}%, median signed "
        f"{100 * np.median([per[n]['bias'] for n in lit]):+.1f}%",
        flush=True,
    )
