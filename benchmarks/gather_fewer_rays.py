"""gather_precompute.py with the top level's qualifying samples (gather_converged.py --mask) tracing
1/k of their rays, each its own pattern: the noise half of sharing one stratified ray set among k
neighbours on a plane (the same independent rays per object), without its bias (each sample keeps
its own position) and without the joint stratification of one shared pattern (each half is its
own pattern): an estimate of such a cut's noise, judged against the seed floor (docs/scale.md,
session 27).

    .venv/bin/python benchmarks/gather_fewer_rays.py MASK.npz KEY K -- STORE [gather_precompute.py's options]
"""

import runpy
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
mask_file, key, k = sys.argv[1], sys.argv[2], int(sys.argv[3])
rest = sys.argv[sys.argv.index("--") + 1 :]
sys.path.insert(0, str(HERE.parent))
from hr_addon.core.gather import final  # noqa: E402

mask = np.load(mask_file)[key]
init = final.FinalGather.__init__


def patched(self, system, points, *a, **kw):
    sr = kw.get("sample_rays")
    if sr is not None and len(sr) == len(mask) and kw.get("levels", 1) >= 2:  # (the top level only)
        sr = np.asarray(sr, np.int64).copy()
        sr[mask] = np.maximum(sr[mask] // k, 1)
        kw["sample_rays"] = sr
        print(f"{int(mask.sum()):,} of {len(mask):,} samples trace 1/{k} of their rays", flush=True)
    init(self, system, points, *a, **kw)


final.FinalGather.__init__ = patched
sys.argv = [str(HERE / "gather_precompute.py"), *rest]
runpy.run_path(str(HERE / "gather_precompute.py"), run_name="__main__")
