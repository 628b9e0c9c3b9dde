"""gather_precompute.py with a tally of the near hits' nearest points: calls, hits and CPU seconds
of final._nearest_point, FinalGather._remap_near and final._row_sorted (process time, wrapped; the
rest of the run as gather_precompute.py's), and the stored rows' entries per level. For comparing
two checkouts' shares of that work on one store, less noisy than their whole runs.

    .venv/bin/python benchmarks/near_point_tally.py CHECKOUT -- STORE [gather_precompute.py's options]
"""

import json
import runpy
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
root = sys.argv[1]
rest = sys.argv[sys.argv.index("--") + 1 :]
sys.path.insert(0, root)
from hr_addon.core.gather import final  # noqa: E402

tally = {}


def timed(name, fn, hits=None):
    def wrapper(*a, **k):
        c0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            t = tally.setdefault(name, dict(calls=0, hits=0, cpu=0.0))
            t["calls"] += 1
            t["cpu"] += time.process_time() - c0
            if hits is not None:
                t["hits"] += int(len(a[hits]))

    return wrapper


final._nearest_point = timed("_nearest_point", final._nearest_point, hits=1)
final._row_sorted = timed("_row_sorted", final._row_sorted, hits=0)
final.FinalGather._remap_near = timed("_remap_near", final.FinalGather._remap_near)
sys.argv = [str(Path(root) / "benchmarks" / "gather_precompute.py"), "--root", root, *rest]
g = runpy.run_path(sys.argv[0], run_name="__main__")["g"]
levels = []
while g is not None:
    levels.append(dict(samples=int(g.n), entries=int(len(g.cols)), stats=dict(g.stats)))
    g = g.second
out = dict(root=root, tally=tally, levels=levels)
print(json.dumps(out, indent=1, default=float))
