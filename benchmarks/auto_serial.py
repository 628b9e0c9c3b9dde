"""Threads (issue 23, session 21): the AUTO event's serial CPU in bench_threads.py's order on the
stored 100k room: the FE DynamicRadiosity's copy of the system makes its covered tests first (as
the bench's in-process gather precompute does), then an AUTO DynamicRadiosity on a new copy adds
the window. CPU of the add and its serial part (outside the batch maps, parallel.profiled), 1
thread; --root runs another checkout (main's, for a before / after pair).

    taskset -c 0 nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/auto_serial.py
        [--store /work/cache/s20main] [--root CHECKOUT] [--json out.json]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/s20main")
    ap.add_argument("--root", default=str(ROOT))
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    sys.path.insert(0, args.root)
    from hr_addon.core import parallel  # (first: bench_gather_events puts this checkout first)
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    sys.path.insert(1, str(ROOT / "benchmarks"))
    from bench_gather_events import load_store

    _, frame = furnished_room("100k")[1]["light_wall"]
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    pc.use_threads(s, g, 1)
    s.links.extended(s.h)
    kw = DynamicRadiosity.gather_options("draft")
    h = DynamicRadiosity(s.copy(), method="FE", **kw).system.h
    part = np.flatnonzero((h.exposure[: h.n] > 0) & (h.exposure[: h.n] < 1))[:2000]
    c0 = time.process_time()
    h.dark(part, h.centre[part])  # the FE copy's first covered test
    fe = time.process_time() - c0
    auto = DynamicRadiosity(s.copy(), method="AUTO", **kw)
    rect = S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2)
    win = LightShape(S.on_plane(rect, frame), np.full(3, 20.0), "window")
    with parallel.profiled() as maps:
        c0 = time.process_time()
        auto.add("w", win)
        cpu = time.process_time() - c0
    out = dict(
        hr_addon=str(Path(parallel.__file__).parents[1]),
        fe_covered=fe,
        cpu=cpu,
        serial=cpu - sum(map(sum, maps)),
        B=float(np.abs(auto.B).sum()),
    )
    print(json.dumps(out))
    if args.json:
        Path(args.json).write_text(json.dumps(out))


if __name__ == "__main__":
    main()
