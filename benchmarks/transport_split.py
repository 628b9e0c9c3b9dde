"""Issue 19 (branch ind28, docs/gather.md): where the draft transport's V loses light, bpy-free, on
the furnished 20k room (hr_testing.furnished, the room furnished.blend is built from).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/transport_split.py \
        [--variants draft,nocluster,...] [--rays 64] [--per-area 4]

For each transport variant (VARIANTS: RefineParams.for_gather("draft") with one change) the room is
built and solved, and a final gather is set up on samples over the room's big surfaces (ceiling,
walls, floor: surface_samples, --per-area per m^2). Printed per variant and class of surface:
- one: the one-level gather (the hits read the transport's V, as bias_split's levels1),
- conv: the two-level gather with 12 passes and their tail (the passes' limit: V hardly matters),
- one / conv - 1: V's darkness as the ceiling read it in bias27 (-8.05% on the draft transport
  against Cycles in Blender; the converged gather reads about -1% there).
Also the transport's own energy balance (solver report) and V against the converged second-level
leaf means Y per object class (area x exposure weighted, the leaves the second level samples).
JSON: benchmarks/out/transport_split.json (one entry per variant, CPU seconds of build + solve).
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

from hr_addon.core.events import surface_samples  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.params import RefineParams  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402

BASE = dataclasses.replace(RefineParams.for_gather("draft"), orient=True)
VARIANTS = {
    "draft": {},
    "nocluster": dict(cluster=False),
    "vcorr": dict(vcorr=1e-3),
    "visk2": dict(vis_k=2),
    "aeps": dict(aeps=2e-4),
    "feps": dict(feps=0.05, shadow_feps=0.01),
    "shadow": dict(shadow_feps=0.003),
    "shadow01": dict(shadow_feps=0.01),
    "medium": "medium",
}
CLASSES = ("ceiling", "wall", "floor")


def klass(name):
    for c in CLASSES:
        if name.startswith(c):
            return c
    return "other"


def run(name, per_area, rays):
    v = VARIANTS[name]
    p = (
        dataclasses.replace(RefineParams.for_gather("medium"), orient=True)
        if v == "medium"
        else (dataclasses.replace(BASE, **v))
    )
    mesh, _ = furnished_room("20k")
    c0 = time.process_time()
    s = RadiositySystem(mesh, p)
    s.solve()
    t_build = time.process_time() - c0
    pt = s.patches
    names = [klass(n) for n in pt_names(s)]
    cls = np.array(names)[np.asarray(pt.object_id)]
    big = np.isin(cls, CLASSES)
    pts, patch, wts = surface_samples(pt, per_area)
    keep = big[patch] & (np.asarray(pt.object_id)[patch] != light_id(s))
    pts, patch, wts = pts[keep], patch[keep], wts[keep]
    out = dict(
        params={k: getattr(p, k) for k in ("feps", "shadow_feps", "aeps", "vcorr", "vis_k", "cluster")}
    )
    out.update(links=len(s.links), leaves=int(s.h.is_leaf.sum()), cpu_build_solve=t_build)
    out["energy_error"] = float(s.report.energy_error)
    res = {}
    for lv, it in (("one", None), ("conv", 12)):
        kw = dict(levels=1) if it is None else dict(levels=2, iterations=it)
        c1 = time.process_time()
        g = FinalGather(s, pts, pt.normal[patch], patch, rays=rays, shadow_rays=16, **kw)
        if it is None:
            val = g.evaluate(s)
        else:
            # the passes' limit: _levels with its tail (as bias27's `tail` variant)
            lv_ = g._levels
            g._levels = lambda V, direct, tail=False, f=lv_: f(V, direct, True)
            val = g.evaluate(s)
            L = g._levels(g.solution_values(s), lambda x: x.direct_and_emission(s)[0])
            Vs = g.solution_values(s)
            Y = L[0][: g.n_hr]
            used = g._second_map[0]
            h = s.h
            a = h.area[used] * h.exposure[used]
            lc = cls[h.patch[used]]
            vy = {}
            for c in CLASSES + ("other",):
                m = lc == c
                vy[c] = float(
                    (a[m, None] * Vs[used][m]).sum() / max((a[m, None] * Y[used][m]).sum(), 1e-300) - 1
                )
            m = np.ones(len(used), bool)
            vy["all"] = float((a[m, None] * Vs[used]).sum() / (a[m, None] * Y[used]).sum() - 1)
            out["V_over_Y"] = vy
        res[lv] = (val, time.process_time() - c1)
    seen = ~g.dark
    pc = cls[patch]
    rows = {}
    for c in CLASSES:
        m = (pc == c) & seen
        w = wts[m, None]
        one = (w * res["one"][0][m]).sum() / (w * res["conv"][0][m]).sum() - 1
        rows[c] = float(one)
    out["one_over_conv"] = rows
    out["cpu_gather"] = {k: v[1] for k, v in res.items()}
    return out


def pt_names(s):
    return list(s.patches.object_names)


def light_id(s):
    return list(s.patches.object_names).index("ceiling_light")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--variants", default="draft,nocluster")
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--per-area", type=float, default=4.0)
    ap.add_argument("--json", default=os.path.join(HERE, "out", "transport_split.json"))
    a = ap.parse_args()
    dump = json.load(open(a.json)) if os.path.exists(a.json) else {}
    for v in a.variants.split(","):
        r = run(v, a.per_area, a.rays)
        dump[v] = r
        print(v, json.dumps(r), flush=True)
        json.dump(dump, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    main()
