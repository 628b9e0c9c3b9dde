"""The near hits' fine-leaf rule on the 20k room (docs/gather.md "Near hits", follow-up): the vertex
gather at the bake's draft settings (two levels + 4 iterations, 128 rays, 16 shadow rays), its
precompute CPU s, second-level samples, fine leaves and weights, and the output saved for a
comparison. HR_CODE: the repository whose hr_addon runs (default: this one's).

    HR_CODE=/work/main python benchmarks/near_rule_20k.py 4 out.npz
"""

import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.environ.get("HR_CODE", str(Path(__file__).resolve().parents[1])))
from hr_testing.furnished import furnished_room  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

near = int(sys.argv[1])
mesh, _ = furnished_room("20k")
s = RadiositySystem(mesh, RefineParams.for_gather("draft"))
dyn = DynamicRadiosity(s, method="FE", **DynamicRadiosity.gather_options("draft"))
c0 = time.process_time()
g = LoopGather(dyn, rays=128, shadow_rays=16, levels=2, iterations=4, near_points=near)
pre = time.process_time() - c0
fg = g
c0 = time.process_time()
out = g.loop_radiance(dyn)
ev = time.process_time() - c0
print(
    f"near_points={near} ({sys.path[0]}): precompute {pre:.1f} s CPU, samples {fg.n} + second "
    f"{fg.second.n}, fine leaves {fg.stats.get('near_leaves', 0)} of {fg.n_hr}, weights "
    f"{fg.weights_bytes / 1e6:.1f} MB (second {fg.second.weights_bytes / 1e6:.1f}), "
    f"first evaluate {ev:.1f} s CPU",
    flush=True,
)
if len(sys.argv) > 2:
    np.savez(sys.argv[2], out=out)
