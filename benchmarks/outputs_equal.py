"""The stored 100k room's gathered outputs (per method, the base parts' and after a new window),
written to --dump for a bitwise before / after comparison of two checkouts (--root) or thread
counts (session 21: main against branch thr24, 1 and 2 threads).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/outputs_equal.py --root CHECKOUT
        --threads 1 --dump a.npz [--store /work/cache/s20main] [--compare b.npz]
"""

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/s20main")
    ap.add_argument("--root", default=str(ROOT))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dump", required=True)
    ap.add_argument("--compare", default=None, help="an earlier --dump: print which outputs are equal")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.root)
    from hr_addon.io import precompute as pc  # (first: bench_gather_events puts this checkout first)
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    sys.path.insert(1, str(ROOT / "benchmarks"))
    from bench_gather_events import load_store

    _, frame = furnished_room("100k")[1]["light_wall"]
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    pc.use_threads(s, g, args.threads)
    rect = S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame)
    out = {}
    for m in ("FE", "AUTO"):
        dyn = DynamicRadiosity(s.copy(), method=m, **DynamicRadiosity.gather_options("draft"))
        out[f"{m}_base"] = g.loop_radiance(dyn)
        dyn.add("w", LightShape(rect, np.full(3, 20.0), "window"))
        out[f"{m}_window"] = g.loop_radiance(dyn)
    np.savez(args.dump, **out)
    print(Path(pc.__file__).parents[1], "written", args.dump)
    if args.compare:
        ref = np.load(args.compare)
        print("equal:", {k: bool(np.array_equal(ref[k], v)) for k, v in out.items()})


if __name__ == "__main__":
    main()
