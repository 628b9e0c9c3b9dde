"""Issue 19 (bld32, docs/scale.md): far30's second trace (farlinks.SECOND_TRACE: the strong far links
the oracle keeps are traced again, 16 segments each) with fewer segments (farlinks.SECOND_SEGMENTS 8),
an inexact cut of the build's rays: each far link's traced visibility against a dense kernel-weighted
one (far_vis_check.dense_visibility, 16 x 16 points an end), weighted by the link's unoccluded
exchange, strong links (the oracle's: traced again) and weak ones apart: the bias (traced / dense)
and the spread (the exchange-weighted RMS of traced - dense), every far link kept (KEEP_OCCLUDED);
the room's balance and the build CPU.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/second_trace_check.py 20k \
        --segments 8 --json benchmarks/out/bld32/second8_20k.json
"""

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE, balance, dense_visibility, link_vis  # noqa: E402

import hr_addon.core.farlinks as FL  # noqa: E402
from hr_addon.core.cluster import Ends, estimate  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("room", default="20k")
    ap.add_argument("--segments", type=int, default=16)
    ap.add_argument("--points", type=int, default=16)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    FL.SECOND_SEGMENTS = a.segments
    # every far link (those traced wholly occluded kept, at 0: far_vis_check --all-links), so
    # that the traced values are not selected by themselves; the room's balance is the same
    FL.KEEP_OCCLUDED = True
    mesh, _ = furnished_room(a.room)
    t0 = time.process_time()
    s = RadiositySystem(mesh, BASE)
    out = dict(room=a.room, segments=a.segments, build_cpu_s=time.process_time() - t0)
    out["rays"] = int(s.refiner.stats["rays"])
    far = s.links.far
    out["links"], out["far_links"] = len(s.links), len(far)
    out["balance"] = balance(s).tolist()
    va, vk, ex = dense_visibility(s, far, a.points)
    lv = link_vis(far)
    f_ab, f_ba, _ = estimate(Ends(far.tree, s.h, far.a), Ends(far.tree, s.h, far.b), both=True)
    strong = np.maximum(f_ab, f_ba) >= BASE.shadow_feps
    for name, sel in (("strong", strong), ("weak", ~strong), ("all", np.ones(len(far), bool))):
        w = ex[sel] / ex[sel].sum()
        out[f"{name}_n"] = int(sel.sum())
        out[f"{name}_exchange_share"] = float(ex[sel].sum() / ex.sum())
        out[f"{name}_bias"] = float((lv[sel] * w).sum() / (vk[sel] * w).sum() - 1)
        out[f"{name}_rms"] = float(np.sqrt((w * (lv[sel] - vk[sel]) ** 2).sum()))
        out[f"{name}_mean_abs"] = float((w * np.abs(lv[sel] - vk[sel])).sum())
    print(json.dumps(out, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
