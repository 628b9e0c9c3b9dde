"""AR against FE through the final gather (issue 19 stage 3, docs/events.md session 28): Cornell at
draft with the bake's transport, solver and gather settings (bench_events.py --gather's), the window
appearing and then the second light. Prints the RMS (area-weighted over bench_events' sample points)
of the gathered light contribution's AR - FE difference as the product runs them (AR's records get no
gather_responses tail: DynamicRadiosity._incremental_add), and again with AR's records given the tail
after apply (a diagnostic: the product is not changed).

    .venv/bin/python benchmarks/events_ar_tail.py
"""

import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
import bench_events as B  # noqa: E402
from hr_testing import scenes  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, surface_samples  # noqa: E402
from hr_addon.core.gather import FinalGather  # noqa: E402
from hr_addon.core.geometry import prepare_patches  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402


def main():
    mesh = scenes.cornell_box()
    events = B.cornell_scenario()[:2]
    pts, ids, w = surface_samples(prepare_patches(mesh), 2000)
    base = RadiositySystem(mesh, RefineParams.for_gather("draft"))
    opts = DynamicRadiosity.gather_options("draft")
    g = FinalGather(
        DynamicRadiosity(base.copy(), method="FE", **opts),
        pts,
        base.patches.normal[ids],
        ids,
        seed=0,
        **B.bake_gather("draft"),
    )

    def run(method, tail=False):
        B.clear_shape_caches(g)
        dyn = DynamicRadiosity(base.copy(), method=method, **opts)
        v0 = g.evaluate(dyn, "reflected")
        out = []
        for _, cfg in events:
            dyn.apply(cfg)
            if tail:
                for r in dyn.shapes.values():
                    r.gathered = "tail"
            out.append(g.evaluate(dyn, "reflected") - v0)
        return out, [r.gathered for r in dyn.shapes.values()]

    def rms(x):
        return float(np.sqrt(np.average((x**2).sum(1), weights=w)))

    fe, gf = run("FE")
    ar, ga = run("AR")
    art, gt = run("AR", tail=True)
    print("tail flags: FE", gf, "AR", ga, "AR given the tail", gt)
    print("light contribution RMS per event", [round(rms(f), 4) for f in fe])
    print("AR - FE, as the product runs them", [round(rms(a - f), 5) for a, f in zip(ar, fe)])
    print("AR given the tail - FE", [float(f"{rms(a - f):.2g}") for a, f in zip(art, fe)])


if __name__ == "__main__":
    main()
