"""Issue 19 (branch pl32, docs/gather.md): the build's CPU with and without refine.UNSPLIT_2X2
(strong patch links that neither end can split traced from 2 x 2 points an end), back to back in
one process, bpy-free, on the furnished room (draft gather transport, orient on).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/unsplit_cost.py 20k --pairs 2

Each pair builds main's form (UNSPLIT_2X2 off: main's values; since ead5230 with the 2 x 2 points
made once per node, so no longer main's cost: compare against main's own code for that) then
pl32's; the build timed by time.process_time() around the RadiositySystem constructor. --segments
4: the unsplit links' 4 segments i -> 3 - i.
"""

import argparse
import dataclasses
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE  # noqa: E402

import hr_addon.core.refine as RF  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def build(mesh, on):
    RF.UNSPLIT_2X2 = on
    t0 = time.process_time()
    s = RadiositySystem(mesh, dataclasses.replace(BASE))
    t = time.process_time() - t0
    st = s.refiner.stats
    print(
        f"  unsplit {'on ' if on else 'off'}: build {t:.2f} s, rays {st['rays']:,}, patch links "
        f"{len(s.links.a):,}, unsplit traced {st['unsplit_links']:,}, t_vis {st['t_vis']:.2f} s",
        flush=True,
    )
    return t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("room", nargs="?", default="20k")
    ap.add_argument("--pairs", type=int, default=2)
    ap.add_argument("--segments", type=int, default=16)
    args = ap.parse_args()
    RF.UNSPLIT_SEGMENTS = args.segments
    mesh, _ = furnished_room(args.room)
    for i in range(args.pairs):
        a, b = build(mesh, False), build(mesh, True)
        print(f"pair {i + 1}: {a:.2f} -> {b:.2f} s, x{b / a:.3f}", flush=True)


if __name__ == "__main__":
    main()
