"""The vertex output's gather precompute (LoopGather + precompute.prepare, as a bake builds and
stores it) on a stored build's system and base solution (bench_gather_events.py --cache), with the
code of the checkout given: CPU seconds, one run. For comparing checkouts on the same system.

    .venv/bin/python benchmarks/gather_precompute.py /work/cache/STORE [--root CHECKOUT] \
        [--set layouts.SPLIT=False]
"""

import argparse
import os
import sys
import time
from pathlib import Path

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("store", help="folder of a stored build (bench_gather_events.py --cache)")
ap.add_argument("--root", default=str(Path(__file__).resolve().parent.parent), help="checkout timed")
ap.add_argument("--set", action="append", default=[], help="module.NAME=value in hr_addon.core.gather")
args = ap.parse_args()
sys.path.insert(0, args.root)
sys.path.insert(0, os.path.join(args.root, "benchmarks"))

from bench_gather_events import load_store  # noqa: E402
from hr_addon.core import gather  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

for kv in args.set:
    name, value = kv.split("=", 1)
    mod, attr = name.rsplit(".", 1)
    setattr(getattr(gather, mod), attr, eval(value))
s, g, _ = load_store(Path(args.store) / pc.FILENAME)
pc.use_threads(s, g, 1)
del g
dyn = DynamicRadiosity(s, method="FE", **DynamicRadiosity.gather_options("draft"))
c0 = time.process_time()
g = gather.LoopGather(dyn, rays=128, levels=2, iterations=4, threads=1, shadow_rays=16)
pc.prepare(g)
print(
    f"{args.root}: gather precompute {time.process_time() - c0:.2f} s CPU, {g.n:,} samples, "
    f"load {os.getloadavg()[0]:.2f}"
)
