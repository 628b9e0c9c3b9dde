"""The first gathered output of a stored vertex precompute in the core alone (session 32, branch
gathermem; docs/scale.md): restores a precompute.hrpc (no code check: the same stored arrays for
two versions of the code), makes its DynamicRadiosity (FE, the base solution), io.precompute.prepare
(as a bake before its write) and times
loop_radiance twice (the first builds the loop map, the shifts and the cached responses),
with tracemalloc's current and peak memory (numpy's arrays) before and after each, and saves the
values for a bit-for-bit comparison of two versions:

    cd WORKTREE && nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python \\
        benchmarks/gathermem_frame.py STORE/precompute.hrpc OUT.npz [OTHER.npz]

OTHER.npz: compare the values with another version's (equal bit for bit, or the largest change)."""

import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

path, out = sys.argv[1], sys.argv[2]
arrays, header = pc.read(path)
system, g = pc.restore(arrays, header["graph"])
del arrays
dyn = DynamicRadiosity(system, method="FE", warm_moves=False)
pc.prepare(g)  # (as a bake before its precompute's write: what this code makes there)
tracemalloc.start()
res = {}
for k in range(2):
    cur0 = tracemalloc.get_traced_memory()[0]
    tracemalloc.reset_peak()
    c0 = time.process_time()
    v = g.loop_radiance(dyn)
    cpu = time.process_time() - c0
    cur, peak = tracemalloc.get_traced_memory()
    print(
        f"loop_radiance {k + 1}: {cpu:.2f} s CPU; traced before {cur0 / 1e6:.0f} MB, after {cur / 1e6:.0f} MB"
        f" (+{(cur - cur0) / 1e6:.0f}), peak +{(peak - cur0) / 1e6:.0f} MB",
        flush=True,
    )
    res[f"v{k}"] = v
    del v
np.savez(out, **res)
if len(sys.argv) > 3:
    other = np.load(sys.argv[3])
    for k in res:
        a, b = res[k], other[k]
        same = a.shape == b.shape and np.array_equal(a.view(np.uint32), b.view(np.uint32))
        print(k, "bit for bit" if same else f"differs: max |d| {np.abs(a - b).max():.3g}")
