"""Issue 20's Cornell box lit by one Blender light (hr_testing.cycles_lights.solve(KIND)): the texels
whose direct light is averaged over their area (core.gather.texel_edges: a light's edge crosses
them) against Cycles' cached bakes (benchmarks/out/cycles_lights_cache/, `cycles_lights.py --cache`
makes them), with the edge texels on and off (centres only), per surface: how many texels it
changes, the root mean square and the mean of (ours - Cycles) over them relative to the surface's
mean, Cycles' own noise there (the seeds' spread / sqrt(seeds)), and the cost (the tested and edge
texels, extra shadow rays, process CPU s).

Run: .venv/bin/python benchmarks/texel_edges.py [KIND ...] [--spp 1024] [--seeds 1,...,8]"""

import json
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
CACHE = str(Path(__file__).resolve().parent / "out" / "cycles_lights_cache")


def main(kind, spp, seeds):
    import hr_addon.core.gather.texel_edges as te
    from hr_testing import cycles_lights as CL

    on = CL.solve(kind)
    edge_direct = te.edge_direct
    te.edge_direct = lambda g, light, centre, *a, **k: np.asarray(centre, np.float64)  # centres only
    try:
        off = CL.solve(kind)
    finally:
        te.edge_direct = edge_direct
    refs = [CL._cached_bake(on.rs, kind, spp, s, CACHE) for s in seeds]
    out = {
        "kind": kind,
        "spp": spp,
        "seeds": list(seeds),
        "tested_edge_rays": on.gather.stats.get("edge_texels"),
        "edge_cpu_s": round(on.gather.stats.get("edge_texels_cpu", 0.0), 3),
        "surfaces": {},
    }
    for n in on.rs.objects:
        a, b = on.res[n]["gather_refl"], off.res[n]["gather_refl"]
        r = np.array([x[n] for x in refs])
        ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & np.isfinite(r).all((0, 2))
        ref = r.mean(0)
        mean = ref[ok].mean()
        ch = ok & (np.abs(a - b).max(1) > 0)
        if not ch.any():
            out["surfaces"][n] = {"changed": 0}
            continue

        def err(v):
            d = (v[ch] - ref[ch]).mean(1) / mean
            return round(float(np.sqrt(np.mean(d**2))), 3), round(float(d.sum() / ok.sum()), 4)

        noise = r[:, ch].mean(2).std(0, ddof=1) / np.sqrt(len(seeds)) / mean
        out["surfaces"][n] = {
            "texels": int(ok.sum()),
            "changed": int(ch.sum()),
            "rms_centres": err(b)[0],
            "rms_areas": err(a)[0],
            "rms_cycles_noise": round(float(np.sqrt(np.mean(noise**2))), 3),
            "of_surface_centres": err(b)[1],
            "of_surface_areas": err(a)[1],
        }
    print("RESULT " + json.dumps(out), flush=True)


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a = sys.argv[1:]
    spp, seeds = 1024, tuple(range(1, 9))
    if "--spp" in a:
        i = a.index("--spp")
        spp = int(a[i + 1])
        del a[i : i + 2]
    if "--seeds" in a:
        i = a.index("--seeds")
        seeds = tuple(int(v) for v in a[i + 1].split(","))
        del a[i : i + 2]
    for kind in a or ["SPOT"]:
        main(kind, spp, seeds)
