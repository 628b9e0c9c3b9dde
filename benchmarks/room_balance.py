"""Issue 19 (branch kern31, docs/gather.md): the closed furnished room's balance (absorbed over
emitted) and, with uniform unit radiance (B = exposure) on one group of leaves, the power one
gather + push delivers over the power sent (1 in a closed room), bpy-free.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/room_balance.py 20k "vis_k=2"

The second argument: RefineParams fields changed from RefineParams.for_gather("draft") (orient on).
`--no-unsplit` anywhere: refine.UNSPLIT_2X2 off (main before pl32).
"""

import dataclasses
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE, balance  # noqa: E402
from kernel_split import received  # noqa: E402

import hr_addon.core.refine as RF  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def main():
    argv = [x for x in sys.argv if x != "--no-unsplit"]
    RF.UNSPLIT_2X2 = len(argv) == len(sys.argv)
    room = argv[1] if len(argv) > 1 else "20k"
    kw = eval(f"dict({argv[2]})") if len(argv) > 2 else {}  # noqa: S307 (a benchmark's arguments)
    mesh, _ = furnished_room(room)
    t0 = time.process_time()
    s = RadiositySystem(mesh, dataclasses.replace(BASE, **kw))
    bt = time.process_time() - t0
    st = s.refiner.stats
    print(
        kw,
        "unsplit 2x2",
        RF.UNSPLIT_2X2,
        "build cpu",
        round(bt, 2),
        "links",
        len(s.links.a),
        "far",
        len(s.links.far),
    )
    print("rays", st["rays"], "unsplit links traced", st["unsplit_links"])
    print("balance", np.round(balance(s), 4))
    op = s.operator()
    lf, A, ex = op.leaves, op.area, op.expo.astype(float)
    names = np.array(list(s.patches.object_names))
    nm = names[np.asarray(s.patches.object_id)[s.h.patch[lf]]].astype(str)
    for g in ("case", "ceiling_light", "wall", "floor", "ceiling", "all"):
        sel = np.char.startswith(nm, g) if g != "all" else np.ones(len(lf), bool)
        U = np.zeros((1, op.n))
        U[0, lf[sel]] = ex[lf[sel]]
        r = received(s, s.links, U)[0] / (A[lf] * U[0, lf]).sum()
        print(f"  uniform from {g}: received/sent {r:.4f}")


if __name__ == "__main__":
    main()
