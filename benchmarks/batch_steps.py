"""The build's large maps at other batch sizes (issue 23, docs/threads.md, session 36): the room's
build on 1 thread; the first two maps of each caller in farlinks / refine with at least 2^17
items (batches (i, j)) are run again over ranges(n, step) for each step before the real run (their
batches are pure or write their own slice of the same values), each twice: per step the CPU, the
GIL-held CPU (--gil: thread_cpu.py's sampler), this thread's minor faults and system CPU.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/batch_steps.py --size 100k
        --steps 4096,8192,16384,32768 [--gil] [--json out.json]   (run from the checkout to measure)
"""

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, ".")  # the checkout it runs from (thread_cpu.py from this script's folder)
sys.path.insert(1, str(Path(__file__).resolve().parent))

import thread_cpu as tc  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="100k")
    ap.add_argument("--steps", default="4096,8192,16384,32768")
    ap.add_argument("--gil", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    from hr_addon.core import farlinks, parallel, refine
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_testing.furnished import furnished_room

    steps, seen, out = [int(x) for x in args.steps.split(",")], {}, []
    if args.gil:
        tc.gil_sampler()

    def wrap(mod):
        orig = mod.batch_map

        def bm(fn, batches, threads=1, progress=None, poll=0.1):
            batches = list(batches)
            f = sys._getframe(1)
            where = f"{mod.__name__.split('.')[-1]}.{f.f_code.co_name}:{f.f_lineno}"
            big = (
                batches
                and len(batches[0]) == 2
                and isinstance(batches[-1][1], int)
                and batches[-1][1] >= 1 << 17
            )
            if big and seen.get(where, 0) < 2 and not parallel.in_worker():
                seen[where] = seen.get(where, 0) + 1
                n = batches[-1][1]
                for rep in range(2):
                    for step in steps:
                        r0, g0, c0 = (
                            resource.getrusage(resource.RUSAGE_THREAD),
                            tc.gil_counts(),
                            time.thread_time(),
                        )
                        for i, j in parallel.ranges(n, step):
                            fn(i, j)
                        c1, g1, r1 = (
                            time.thread_time(),
                            tc.gil_counts(),
                            resource.getrusage(resource.RUSAGE_THREAD),
                        )
                        held = (g1[1] - g0[1]) / max(g1[0] - g0[0], 1) * (c1 - c0)
                        rec = dict(where=where, n=n, step=step, rep=rep, cpu=c1 - c0, held=held)
                        rec.update(minflt=r1.ru_minflt - r0.ru_minflt, sys=r1.ru_stime - r0.ru_stime)
                        out.append(rec)
                        print(json.dumps(rec), flush=True)
            return orig(fn, batches, threads, progress, poll)

        mod.batch_map = bm

    wrap(farlinks)
    wrap(refine)
    RadiositySystem(furnished_room(args.size)[0], RefineParams.for_gather("draft"), threads=1)
    if args.json:
        Path(args.json).write_text(json.dumps(out))


if __name__ == "__main__":
    main()
