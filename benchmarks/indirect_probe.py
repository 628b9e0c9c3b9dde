"""Issue 19 (branch indirect, session 32, docs/accuracy.md): where the draft bake loses indirect light
on hr_testing/two_rooms.py, bpy-free. The bake's own pipeline (solver_setup's params, the
quality's gather transport and solve options, a DynamicRadiosity with the scene's Blender lights
(frame 1: the floor lamp and the bedroom's area light, as lights_in.blender_lights reads them),
a FinalGather with the quality's settings) at stratified samples over every surface, one change at
a time; each variant's indirect light (incident minus the exact direct light) over a reference's
per class of surface and room, on the same samples and rays.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/indirect_probe.py \
        [--per-area 1] [--variants draft,steps,tail,...] [--json OUT]

Variants: draft (the product), main (the product before branch indirect: a Blender light's
passes without their tail), steps (the lights' response solved to 1e-7, not 3 GMRES steps),
tail (the passes' geometric tail for the lights too), conv (16 passes and their tail: the passes'
limit), medium (the medium transport and solve options), ... (see VARIANTS).
"""

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from hr_addon.blender.settings import GATHER, refine_params, solve_options, solver_setup  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.events.planar import surface_samples  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.lights import Light, area_outline  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing import two_rooms as TR  # noqa: E402


def lights():
    """Frame 1's Blender lights as lights_in.blender_lights makes them (bpy-free)."""
    L = TR.LAMP
    lamp = Light("POINT", L["color"], L["energy"], position=L["location"], radius=L["radius"], name="lamp")
    A = TR.AREA
    M = np.eye(4)
    M[:3, 3] = A["location"]  # unrotated: its -z (down) the direction
    area = Light(
        "AREA",
        A["color"],
        A["energy"],
        position=A["location"],
        direction=(0, 0, -1),
        outline=area_outline("RECTANGLE", *A["size"], M),
        name="area",
    )
    return {"light:lamp": lamp, "light:area": area}


def cornell():
    """Cornell's box without its emitter, lit by a point light under its ceiling (a control: its
    surfaces are the box's five walls and two blocks)."""
    from hr_testing import scenes

    mesh = scenes.cornell_box()
    mesh.emission[:] = 0.0
    return mesh, {"light:p": Light("POINT", (1, 0.8, 0.6), 20.0, position=(0.28, 0.28, 0.4), name="p")}


def klass(name):
    kinds = ("floor", "ceiling", "wall", "doorway", "blind", "shelf", "item", "sofa", "bed", "step", "table")
    for c in kinds:
        if c in name:
            return c
    return "other"


def build(mesh, quality, kw=None):
    p = refine_params(quality, final_gather=True)
    p, min_area_rel, _ = solver_setup(mesh, p)
    if kw:
        p = dataclasses.replace(p, **kw)
    t0 = time.process_time()
    s = RadiositySystem(mesh, p)
    return s, min_area_rel, time.process_time() - t0


def run(s, min_area_rel, quality, pts, patch, gopt=None, sopt=None, tail=False, iterations=None, share=None):
    opts = dict(solve_options(quality, True), **(sopt or {}))
    dyn = DynamicRadiosity(s, method="FE", min_area_rel=min_area_rel, warm_moves=False, **opts)
    g = FinalGather(dyn, pts, s.patches.normal[patch], patch, **dict(GATHER[quality.upper()], **(gopt or {})))
    if iterations is not None:
        g.iterations = iterations
    if share is not None:  # the passes' stopping rule (FinalGather.TAIL_SHARE)
        g.TAIL_SHARE = share
    if tail == "off":  # main before branch indirect: a light's 1 + iterations passes alone
        g._lights_tail = lambda dyn: False
    elif tail:
        lv = g._levels
        g._levels = lambda V, direct, *_, f=lv: f(V, direct, True, tail == "until")
    t0 = time.process_time()
    dyn.apply({}, LIGHTS)
    inc = g.evaluate(dyn, "incident")
    D = g.direct_and_emission(dyn)[0]
    D[g.dark] = 0
    return inc, D, g, time.process_time() - t0


LIGHTS = None  # the scene's Blender lights (main)
VARIANTS = {  # name: (quality, transport fields, solve options, gather keywords, tail, iterations[, share])
    "draft": ("draft", None, None, None, False, None),
    "main": ("draft", None, None, None, "off", None),
    "medium_main": ("medium", None, None, None, "off", None),
    "steps": ("draft", None, dict(response_steps=None, response_tol=1e-7), None, False, None),
    "tail": ("draft", None, None, None, True, None),
    "steps_tail": ("draft", None, dict(response_steps=None, response_tol=1e-7), None, True, None),
    "until": ("draft", None, None, None, "until", None),
    "medium_until": ("medium", None, None, None, "until", None),
    "share005": ("draft", None, None, None, False, None, 0.005),
    "medium_share005": ("medium", None, None, None, False, None, 0.005),
    "conv": ("draft", None, dict(response_steps=None, response_tol=1e-7), None, True, 16),
    "medium": ("medium", None, None, None, False, None),
    "medium_conv": ("medium", None, dict(response_steps=None, response_tol=1e-7), None, True, 16),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-area", type=float, default=1.0)
    ap.add_argument("--variants", default="draft,steps,tail,steps_tail,conv,medium,medium_conv")
    ap.add_argument("--ref", default="conv", help="the variant the others are read against")
    ap.add_argument("--scene", default="two_rooms", help="two_rooms (frame 1's lights) or cornell")
    ap.add_argument("--json", default=os.path.join(HERE, "out", "indirect_probe.json"))
    a = ap.parse_args()
    global LIGHTS
    if a.scene == "cornell":
        mesh, LIGHTS = cornell()
    else:
        (mesh, _), LIGHTS = TR.two_rooms(), lights()
    names = a.variants.split(",")
    systems, out, res = {}, {}, {}
    pts = patch = None
    for v in names:
        q, tkw, sopt, gopt, tail, it, *share = VARIANTS[v]
        key = (q, json.dumps(tkw, sort_keys=True))
        if key not in systems:
            systems[key] = build(mesh, q, tkw)
            s, _, bt = systems[key]
            print(f"{key}: build {bt:.1f} s, links {len(s.links.a)} far {len(s.links.far)}", flush=True)
        s, mar, _ = systems[key]
        if pts is None:  # the same samples for every variant (the input patches are the same)
            pts, patch, _ = surface_samples(s.patches, a.per_area, min_k=1)
            pt = s.patches
            kl = [klass(n) if a.scene == "two_rooms" else n for n in pt.object_names]
            cls = np.array(kl)[np.asarray(pt.object_id)][patch]
            room = np.where(pts[:, 0] < 5.1, "A", "B") if a.scene == "two_rooms" else np.full(len(pts), "A")
            print("samples", len(pts), flush=True)
        inc, D, g, et = run(s, mar, q, pts, patch, gopt, sopt, tail, it, *share)
        out[v] = (inc, D, g.rho, g.dark)
        print(f"{v}: evaluate {et:.1f} s, tail passes {g.stats.get('tail_passes')}", flush=True)
    ref = out[a.ref]
    rows = {}
    for v in names:
        inc, D, rho, dark = out[v]
        ok = ~dark & ~ref[3]
        row = {}
        for grp, m in (
            [("all", ok)]
            + [(f"room {r}", ok & (room == r)) for r in "AB"]
            + [(c, ok & (cls == c)) for c in np.unique(cls)]
        ):
            ind, ind_r = (rho * (inc - D))[m].sum(), (ref[2] * (ref[0] - ref[1]))[m].sum()
            tot, tot_r = (rho * inc)[m].sum(), (ref[2] * ref[0])[m].sum()
            row[grp] = dict(
                n=int(m.sum()),
                indirect=float(ind / ind_r - 1),
                total=float(tot / tot_r - 1),
                ind_share=float(ind_r / tot_r),
            )
        rows[v] = row
        head = list(row.items())[:3]
        print(
            f"{v:12s} vs {a.ref}: "
            + "  ".join(f"{k} ind {r['indirect'] * 100:+.2f}% tot {r['total'] * 100:+.2f}%" for k, r in head),
            flush=True,
        )
    res = dict(per_area=a.per_area, ref=a.ref, rows=rows)
    json.dump(res, open(a.json, "w"), indent=1)
    for v in names:
        print(v, " ".join(f"{k}:{r['indirect'] * 100:+.1f}" for k, r in rows[v].items() if k not in ("all",)))


if __name__ == "__main__":
    main()
