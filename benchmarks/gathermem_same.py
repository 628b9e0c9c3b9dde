"""Digests of a built final gather, for a bit-for-bit check of two versions of the code (session
32, branch gathermem; docs/scale.md): builds the core's furnished room (hr_testing.furnished), its
DynamicRadiosity (FE) and a LoopGather as bench_gather_events.py does (128 rays, two levels, 4
iterations, 16 shadow rays), io.precompute.prepare, then the first loop_radiance, with the CPU
and peak RSS (ru_maxrss) after each; writes a SHA-1 per array of every level (the columns as the
leaf values they read: leaf_columns where the code has it) and of the output:

    cd WORKTREE && nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python \\
        benchmarks/gathermem_same.py OUT.json [--size 20k] [--threads 1]

Compare two OUT.json with `diff` (the "stats" entry aside: diagnostics, not values)."""

import argparse
import hashlib
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

ap = argparse.ArgumentParser()
ap.add_argument("out")
ap.add_argument("--size", default="20k")
ap.add_argument("--threads", type=int, default=1)
args = ap.parse_args()

from hr_testing.furnished import furnished_room  # noqa: E402

from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402


def peak():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


mesh, _ = furnished_room(args.size)
c0 = time.process_time()
s = RadiositySystem(mesh, RefineParams.preset("draft"), threads=args.threads)
dyn = DynamicRadiosity(s, method="FE")
build = (time.process_time() - c0, peak())
c0 = time.process_time()
g = LoopGather(dyn, rays=128, levels=2, iterations=4, shadow_rays=16, threads=args.threads)
pc.prepare(g)
cpu = time.process_time() - c0


def digest(a):
    a = np.ascontiguousarray(a)
    return f"{a.dtype.str}{list(a.shape)}:" + hashlib.sha1(a.tobytes()).hexdigest()[:16]


out, lv, k = (
    {"build_cpu_s": build[0], "build_peak_gb": build[1], "gather_cpu_s": cpu, "gather_peak_gb": peak()},
    g,
    0,
)
while lv is not None:
    cols = lv.leaf_columns() if hasattr(lv, "leaf_columns") else lv.cols
    out[f"level{k}.cols"] = digest(np.asarray(cols, np.int64))
    for name, v in sorted(vars(lv).items()):
        if isinstance(v, np.ndarray) and name not in ("cols",):
            out[f"level{k}.{name}"] = digest(v)
    out[f"level{k}.stats"] = {n: v for n, v in lv.stats.items() if n != "precompute_cpu"}
    lv, k = lv.second, k + 1
c0 = time.process_time()
out["loop_radiance"] = digest(g.loop_radiance(dyn))
out["output_cpu_s"], out["peak_gb"] = time.process_time() - c0, peak()
out["loop_radiance_again"] = digest(g.loop_radiance(dyn))
Path(args.out).write_text(json.dumps(out, indent=1, default=str))
print(json.dumps(out, indent=1, default=str))
