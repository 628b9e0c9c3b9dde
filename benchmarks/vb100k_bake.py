"""bench_bpy_frames.py --path bake of one worktree's code, plus the CPU of ensure_own_values and
near_clutter, the objects near_clutter names, the corners (rows of frame 1's .npz) and, with
--marks, the process's peak and current RSS around RadiositySystem, make_gather and the
precompute's write (session 31, branch vb100k; docs/scale.md):

    nice -n 10 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/vb100k_bake.py \\
        WORKTREE /tmp/x/furnished_100k.blend OUT.json [--marks]

WORKTREE: the code baked (a worktree of main, or one at an older commit: the script only wraps
what exists there). The .blend: bench_bpy_frames.py --make's, one copy per run."""

import glob
import json
import resource
import sys
import time
from pathlib import Path

WT, BLEND, OUT = sys.argv[1:4]
for p in (WT, WT + "/benchmarks", WT + "/scripts"):
    sys.path.insert(0, p)

import bench_bpy_frames as b  # noqa: E402
import numpy as np  # noqa: E402

from hr_addon.blender import background, snapshot  # noqa: E402
from hr_addon.blender import bake as bk  # noqa: E402
from hr_addon.blender import own_values as ov  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

extra = dict(ensure=[], near_clutter=[], cluttered=[], marks=[])


def wrap(owner, name, key, keep=None):
    fn = getattr(owner, name)

    def timed(*a, **k):
        c0, w0 = time.process_time(), time.perf_counter()
        r = fn(*a, **k)
        rec = dict(cpu_s=time.process_time() - c0, wall_s=time.perf_counter() - w0)
        rec.update(keep(a, k, r) if keep else {})
        extra[key].append(rec)
        return r

    setattr(owner, name, timed)


def rss_gb():
    with open("/proc/self/status") as f:
        return next(int(x.split()[1]) for x in f if x.startswith("VmRSS")) / 1e6


def marked(owner, name):
    fn = getattr(owner, name)

    def w(*a, **k):
        extra["marks"].append((name + " before", b._rss_gb(), rss_gb()))
        try:
            return fn(*a, **k)
        finally:
            extra["marks"].append((name + " after", b._rss_gb(), rss_gb()))
            print("marks", extra["marks"][-2:], flush=True)

    setattr(owner, name, w)


wrap(ov, "ensure_own_values", "ensure", lambda a, k, r: dict(notes=r))
snapshot.ensure_own_values = background.ensure_own_values = ov.ensure_own_values
if hasattr(ov, "near_clutter"):  # vbudget's
    wrap(
        ov,
        "near_clutter",
        "near_clutter",
        lambda a, k, r: dict(candidates=len(a[1]), area={n: float(v) for n, v in r.items() if v > 0}),
    )
    wrap(ov, "_cluttered", "cluttered", lambda a, k, r: dict(names=list(r)))
if "--marks" in sys.argv:
    for owner, name in ((bk, "RadiositySystem"), (bk, "make_gather"), (pc, "write")):
        marked(owner, name)
res = b.run_bake(
    b.argparse.Namespace(blend=BLEND, output="vertex", resolution=16, vertex_spacing=None, profile=None)
)
npz = sorted(glob.glob(str(Path(BLEND).parent / "**" / "*000001.npz"), recursive=True))
if npz:
    z = np.load(npz[0])
    res["corners_frame1"] = int(sum(z[k].shape[0] for k in z.files if z[k].ndim == 2))
    res["npz_members"] = len(z.files)
res["own_values"] = extra
res["peak_rss_gb_ru"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
Path(OUT).write_text(json.dumps(res, indent=1, default=str))
print(
    "ensure_own_values",
    [round(e["cpu_s"], 2) for e in extra["ensure"]],
    "near_clutter",
    [(round(e["cpu_s"], 2), e["candidates"], len(e["area"])) for e in extra["near_clutter"]],
    "named",
    [len(e["names"]) for e in extra["cluttered"]],
    "corners",
    res.get("corners_frame1"),
)
