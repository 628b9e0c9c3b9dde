"""In-process A/B of a light event's part (DynamicRadiosity.add of bench_gather_events.py's window,
then its move), CPU seconds (time.process_time), on a stored build: DynamicRadiosity options
alternating in one process, a fresh copy of the system each time (the gathered output is not
evaluated: it does not depend on these options' cost).

    .venv/bin/python benchmarks/event_ab.py /work/cache/c100k_s13 \\
        '[("FE_6", "FE", dict(response_steps=6)), ("FE", "FE", {})]' [repeats] [size]

Each variant: (name, method, overrides of DynamicRadiosity.gather_options("draft")).
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def main(argv):
    from bench_gather_events import load_store
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    s, _, _ = load_store(Path(argv[0]) / pc.FILENAME)
    s.links.extended(s.h)  # the solver's far-link terms (not stored), as the bench pays them first
    variants = eval(argv[1])
    repeats = int(argv[2]) if len(argv) > 2 else 3
    _, info = furnished_room(argv[3] if len(argv) > 3 else "100k")
    _, frame = info["light_wall"]

    def window(cx):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.full(3, 20.0), "window")

    base = DynamicRadiosity.gather_options("draft")
    res = {v[0]: [] for v in variants}
    for _ in range(repeats):
        for name, method, kw in variants:
            dyn = DynamicRadiosity(s.copy(), method=method, **{**base, **kw})
            c0 = time.process_time()
            dyn.add("w", window(0.7))
            c1 = time.process_time()
            dyn.apply({"w": window(1.2)})
            c2 = time.process_time()
            res[name].append((c1 - c0, c2 - c1))
            print(f"{name}: add {c1 - c0:.3f} s, move {c2 - c1:.3f} s", flush=True)
    for name, v in res.items():
        print(f"{name}: median add %.3f s, move %.3f s" % tuple(np.median(np.array(v), 0)))


if __name__ == "__main__":
    main(sys.argv[1:])
