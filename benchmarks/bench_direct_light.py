"""A light shape's direct light at both gather levels on a stored build (bench_gather_events.py
--cache DIR): CPU seconds (time.process_time) of FinalGather.direct_light for one window, the
values saved for a bitwise comparison of two code versions, optionally a cProfile (process time).

    .venv/bin/python benchmarks/bench_direct_light.py --cache DIR --size 100k --out d.npz [--profile]
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", required=True)
    ap.add_argument("--size", default="20k")
    ap.add_argument("--out", default=None, help="npz of the direct light per level")
    ap.add_argument("--compare", default=None, help="an earlier --out: bitwise equal?")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args(argv)

    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc

    arrays, header = pc.read(Path(args.cache) / pc.FILENAME)
    s, g = pc.restore(arrays, header["graph"])
    pc.use_threads(s, g, 1)
    s.backend._numpy()  # built at the first re-traced ray, once per process: outside the timing
    _, frame = furnished_room(args.size)[1]["light_wall"]
    rect = S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame)  # bench_gather_events' window
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    dyn.add("w", LightShape(rect, np.full(3, 20.0), "window"))
    rec = next(iter(dyn.shapes.values()))
    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile(time.process_time)
    res, total = {}, 0.0
    for name, lv in (("top", g), ("second", g.second)):
        em = lv._shape_emitter(dyn, rec)[0]
        lv.shafts(em)  # the clear-shaft grid: built once per emitter plane, shared by the levels
        if prof is not None:
            prof.enable()
        c0 = time.process_time()
        res[name] = lv.direct_light(em)
        c1 = time.process_time()
        if prof is not None:
            prof.disable()
        total += c1 - c0
        lit = int((res[name] > 0).sum())
        print(f"{name}: {lv.n} samples, {lit} lit, {lv.shadow_rays} shadow rays, {c1 - c0:.3f} s CPU")
    print(f"both levels: {total:.3f} s CPU")
    if args.out:
        np.savez(args.out, **res)
    if args.compare:
        ref = np.load(args.compare)
        print("bitwise equal to", args.compare, all(np.array_equal(ref[k], res[k]) for k in res))
    if prof is not None:
        import pstats

        pstats.Stats(prof).sort_stats("tottime").print_stats(20)


if __name__ == "__main__":
    main()
