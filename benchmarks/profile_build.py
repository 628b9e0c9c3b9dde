"""Issue 19: the furnished room's build + the gather's precompute (what a cold bake builds before
its first frame), CPU seconds (process time) per stage, peak RSS, optional cProfile (process time)
and an npz of every captured array (io.precompute.capture) for a bitwise comparison.

    python benchmarks/profile_build.py SIZE [--profile OUT.prof [--serial]] [--capture OUT.npz]
        [--compare REF.npz] [--build-only] [--json OUT.json]

At one thread without --profile each stage's batch maps are timed (core.parallel.profiled): its
serial CPU and the Amdahl model on 2 and 16 cores (bench_threads.amdahl_table). --serial turns
the profiler off inside the outermost batch maps, so the profile lists what runs serially.
"""

import argparse
import contextlib
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hr_testing.furnished import furnished_room  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import LoopGather  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402
from hr_addon.core import parallel  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402
from bench_threads import amdahl_table  # noqa: E402


def profile_outside_maps(prof):
    """Every hr_addon module's batch_map wrapped so that `prof` is off inside the outermost map."""
    orig = parallel.batch_map
    depth = [0]

    def batch_map(*args, **kwargs):
        if depth[0] == 0:
            prof.disable()
        depth[0] += 1
        try:
            return orig(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                prof.enable()

    for name, mod in list(sys.modules.items()):
        if name.startswith("hr_addon") and getattr(mod, "batch_map", None) is orig:
            mod.batch_map = batch_map


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("size", default="20k")
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--profile", default=None)
    ap.add_argument("--capture", default=None, help="write every captured array here (npz)")
    ap.add_argument("--compare", default=None, help="compare every captured array with this npz")
    ap.add_argument("--serial", action="store_true", help="profile only outside the batch maps")
    ap.add_argument("--build-only", action="store_true", help="stop after the hierarchy's build")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    mesh, _ = furnished_room(a.size)
    q = a.quality
    params = RefineParams.for_gather(q)
    opts = DynamicRadiosity.gather_options(q)
    settings = dict(rays=128, shadow_rays=16 if q == "draft" else 32, levels=2, iterations=4)
    prof = None
    if a.profile:
        import cProfile

        prof = cProfile.Profile(time.process_time)
        if a.serial:
            profile_outside_maps(prof)
        prof.enable()
    batches = {}
    timed = a.threads == 1 and prof is None
    c0 = time.process_time()
    with parallel.profiled() if timed else contextlib.nullcontext([]) as maps:
        system = RadiositySystem(mesh, params, threads=a.threads)
        batches["build"] = list(maps)
    c1 = time.process_time()
    if not a.build_only:
        with parallel.profiled() if timed else contextlib.nullcontext([]) as maps:
            dyn = DynamicRadiosity(system, method="FE", **opts)
            batches["base_solve"] = list(maps)
        c2 = time.process_time()
        with parallel.profiled() if timed else contextlib.nullcontext([]) as maps:
            gather = LoopGather(dyn, threads=a.threads, **settings)
            pc.prepare(gather)
            batches["gather"] = list(maps)
    c3 = time.process_time()
    if a.build_only:
        c2, gather = c3, None
    if prof is not None:
        prof.disable()
        prof.dump_stats(a.profile)
    res = dict(
        size=a.size,
        quality=q,
        links=len(system.links),
        nodes=int(system.h.n),
        build_cpu_s=round(c1 - c0, 2),
        base_solve_cpu_s=round(c2 - c1, 2),
        gather_cpu_s=round(c3 - c2, 2),
        total_cpu_s=round(c3 - c0, 2),
        peak_gb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        profiled=bool(prof),
        load_average=os.getloadavg(),
        created=time.strftime("%Y-%m-%d %H:%M"),
    )
    if timed:
        cpu = dict(build=c1 - c0, base_solve=c2 - c1, gather=c3 - c2)
        names = [k for k in cpu if k in batches]
        res["amdahl"] = amdahl_table(dict(cpu=cpu, batches=batches), names, cores=(2, 16))
    print(json.dumps(res), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    if a.capture or a.compare:
        arrays, graph = pc.capture(system, gather)
        if a.capture:
            np.savez(a.capture, **arrays)
        if a.compare:
            ref = np.load(a.compare)
            diff = sorted(set(ref.files) ^ set(arrays))
            for k in sorted(set(ref.files) & set(arrays)):
                x, y = ref[k], arrays[k]
                if x.shape != y.shape or x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=True):
                    diff.append(k)
            print("bitwise equal:", not diff, "differ:", diff[:20], flush=True)


if __name__ == "__main__":
    main()
