"""Furnished sample against its cached Cycles reference (frame 1), for refinement variants: which
setting moves which surface. Needs the reference of `cycles_compare.py --scenes furnished`.

    .venv/bin/python benchmarks/furnished_vs_cycles.py 'clusters={}' 'plain=dict(cluster=False)' \
        'nograd=dict(grad_cone=0.0)' 'med=dict(q="medium")'

Each argument is name=dict(RefineParams fields, q=preset, grad_cone=cluster.GRAD_CONE,
method="FE", gather=dict(rays=128, shadow_rays=32, vertex=True), transport="gather", fit=True,
every=False, dyn=dict(...)). fit=False: the vertex output's corners unshifted (gather/layouts.FIT,
corner_fit); every=True: every face shifted, not only those cut by another solid (corner_fit.EVERY).
dyn: DynamicRadiosity options over gather_options'. transport="gather":
the bake's transport with the final gather on (RefineParams.for_gather + the fields given,
DynamicRadiosity.gather_options, updated by dyn) instead of the preset's. With `gather` the final gather
(hr_addon.core.gather) is compared too: at texel centres (refl_gather) and at the mesh's corners
(total_gvertex, against today's vertex output total_vertex), with its cost. The vertex rows come
twice: over every texel and over the unburied ones (`_unburied`: no sub-sample inside another
object's closed mesh, unburied_texels' winding test, not our contacts code), as a camera sees them:

    .venv/bin/python benchmarks/furnished_vs_cycles.py 'fg=dict(gather=dict(rays=128))'
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
from unburied import unburied_texels
from hr_testing import cycles_ref as C
from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams


cfg = CC.SCENES["furnished"]
scene = CC.open_scene("furnished")
rs = C.prepare(scene, texel_rel=cfg["texel_rel"])
a, ta, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[0])
b, tb_, _ = CC.cycles_bake(rs, "furnished", 1, cfg["ref_spp"], CC.REF_SEEDS[1])
ref = {n: (a[n] + b[n]) / 2 for n in rs.objects}
shapes = C.shape_proxies(rs, 1)
t0 = time.process_time()
unburied = unburied_texels(rs, 5e-5 * rs.diag)
n_tex = sum(len(m) for m in unburied.values())
n_bur = n_tex - sum(int(m.sum()) for m in unburied.values())
print(
    f"buried texels (a sub-sample inside another object): {n_bur} of {n_tex}, "
    f"{sum(not m.all() for m in unburied.values())} objects, {time.process_time() - t0:.0f} s CPU",
    flush=True,
)
variants = {k: eval(v) for k, v in (x.split("=", 1) for x in sys.argv[1:])}
for name, kw in variants.items():
    q = kw.pop("q", "draft")
    gkw = kw.pop("gather", None)
    method = kw.pop("method", "FE")
    gt = kw.pop("transport", None) == "gather"
    from hr_addon.core.gather import layouts

    layouts.FIT = kw.pop("fit", True)  # the vertex output's faces keep their light (corner_fit)
    layouts.corner_fit.EVERY = kw.pop("every", False)  # True: every face, not only the cut ones
    dkw = kw.pop("dyn", {})  # DynamicRadiosity options over gather_options' (transport="gather")
    import hr_addon.core.cluster as CL
    import hr_addon.core.farlinks as FL

    g = kw.pop("grad_cone", 0.03)
    CL.GRAD_CONE = FL.GRAD_CONE = g
    t0 = time.process_time()
    pre = RefineParams.for_gather(q) if gt else RefineParams.preset(q)
    base = RadiositySystem(rs.scene_in.mesh, dataclasses.replace(pre, **kw))
    tb = time.process_time() - t0
    t0 = time.process_time()
    dyn = DynamicRadiosity(base, method=method, **(DynamicRadiosity.gather_options(q) if gt else {}) | dkw)
    dyn.apply(shapes)
    t_apply = time.process_time() - t0
    ours = C.Ours(rs, dyn.system, dyn)
    res = ours.evaluate(shapes, smooth=False)
    if gkw is not None:
        gres, cost = C.gather_results(rs, ours, dyn, **gkw)
        for n in rs.objects:
            res[n].update(gres[n])
        # the per-texel values for a closer look (benchmarks/books_daylight.py --room panel; git-ignored)
        np.savez_compressed(
            os.path.join(HERE, "out", f"furnished_vs_cycles_{name}_ours.npz"),
            **{
                f"{n}|gather_refl": res[n]["gather_refl"].astype(np.float32)
                for n in rs.objects
                if "gather_refl" in res[n]
            },
        )
        txt = ", ".join(f"{k} {v:.3g}" for k, v in cost.items())
        print(f"   final gather cost ({gkw}): {txt}", flush=True)
    allcmp = CC.compare(res, ref, 0.0, rs.objects)
    # the vertex outputs over the unburied texels alone (unburied_texels): what a camera sees
    ub = CC.unburied_vertex(res, unburied, rs.objects)
    for var, m in CC.compare(ub, ref, 0.0, rs.objects).items():
        allcmp[var + "_unburied"] = m
    cmp_ = allcmp["refl_leaf"]
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
    dump = {"variant": name, "quality": q, "method": method, "gather": gkw, "objects": {}}
    # CPU seconds: the hierarchy's build, DynamicRadiosity + frame 1 (all shapes appear), and each
    # Cycles reference bake (cached bakes keep the time of the run that baked them)
    dump["cpu_seconds"] = {"build": tb, "frame1_apply": t_apply, "cycles_ref_bakes": [ta, tb_]}
    dump["cycles_ref_spp"] = cfg["ref_spp"]
    dump["buried_texels"] = {"excluded": n_bur, "texels": n_tex, "eps": 5e-5 * rs.diag}
    for var in (
        "refl_leaf",
        "total_vertex",
        "total_vertex_unburied",
        "refl_gather",
        "total_gvertex",
        "total_gvertex_unburied",
    ):
        if var not in allcmp:
            continue
        for n, m in allcmp[var]["surfaces"].items():
            dump["objects"].setdefault(n, {})[var] = {k: m[k] for k in ("mre", "bias", "texels", "mean_ref")}
        pv = allcmp[var]["surfaces"]
        # the books standing 2 mm apart in the bookcases (most of the lit objects) apart
        for part, keep in (
            ("", lambda n: True),
            ("books", lambda n: "_book" in n),
            ("others", lambda n: "_book" not in n),
        ):
            st = C.object_summary(pv, [n for n in lit if keep(n)])
            pooled = allcmp[var]["all"]["bias"] if not part else st["pooled_bias"]
            print(
                f"   {var:13s} {part or 'all':6s} {st['objects']} lit objects: texel-weighted error of the "
                f"mean {100 * st['weighted']:.1f}%, within 5%: {st['within_5'] * 100:.0f}%, median "
                f"{100 * st['median']:.1f}%, median signed {100 * st['median_signed']:+.1f}%, "
                f"pooled bias {100 * pooled:+.2f}%",
                flush=True,
            )
    dump["lit"] = lit
    for n in rs.objects:
        if "gather_dark_frac" in res[n]:
            dump["objects"].setdefault(n, {})["gather_dark_frac"] = res[n]["gather_dark_frac"]
    if gkw is not None:
        dump["gather_cost"] = cost
    C.write_json(os.path.join(HERE, "out", f"furnished_vs_cycles_{name}.json"), dump)
