"""The 100k room's vertex gather precompute (the bake's draft settings) with near hits on (argv 4) or
off (0): CPU s and peak RSS, from the stored build of bench_gather_events.py --cache DIR (argv 2).

    .venv/bin/python benchmarks/near_hits_100k.py 4 /work/cache/c100k
"""

import os
import resource
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from hr_addon.io import precompute as pc  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402

near = int(sys.argv[1])
arrays, header = pc.read(os.path.join(sys.argv[2], pc.FILENAME))
s, _ = pc.restore(arrays, header["graph"])
del _, arrays
s.links.extended(s.h)
r0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
dyn = DynamicRadiosity(s, method="FE", **DynamicRadiosity.gather_options("draft"))
c0 = time.process_time()
g = LoopGather(dyn, rays=128, levels=2, iterations=4, shadow_rays=16, near_points=near)
pc.prepare(g)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
print(
    f"near_points={near}: precompute {time.process_time() - c0:.1f} s CPU, peak before {r0:.2f} GB, "
    f"after {peak:.2f} GB, weights {g.weights_bytes / 1e6:.0f} MB",
    flush=True,
)
