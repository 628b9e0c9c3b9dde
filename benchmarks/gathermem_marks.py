"""Memory by stage of a Blender bake (session 32, branch gathermem; docs/scale.md): runs
`python -m hr_addon bake ARGS...` with marks before and after the build's and the first frame's
stages: peak RSS (ru_maxrss), current RSS, glibc's heap in use / free and mmapped (mallinfo2), and
with --trace tracemalloc's current and peak since the previous mark (numpy's arrays included):

    cd WORKTREE && /usr/bin/time -v nice -n 5 env OPENBLAS_NUM_THREADS=1 \\
        /work/main/.venv/bin/python benchmarks/gathermem_marks.py OUT.json [--trace] -- \\
        bake furnished_100k.blend --frames 1-1 --threads 1 --save baked.blend

The .blend: bench_bpy_frames.py --make's (one copy per run: the bake writes its cache beside it)."""

import json
import resource
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from heapinfo import mallinfo, rss_gb  # noqa: E402

OUT = sys.argv[1]
TRACE = "--trace" in sys.argv[2 : sys.argv.index("--")]
ARGS = sys.argv[sys.argv.index("--") + 1 :]
marks = []


def mark(what):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    m = dict(at=what, cpu_s=round(time.process_time(), 2), peak_gb=peak)
    m["rss_gb"] = rss_gb()
    if (mi := mallinfo()) is not None:
        m.update(heap_used_gb=mi.uordblks / 1e9, heap_free_gb=mi.fordblks / 1e9, mmap_gb=mi.hblkhd / 1e9)
    if tracemalloc.is_tracing():
        cur, peak = tracemalloc.get_traced_memory()
        m.update(traced_gb=cur / 1e9, traced_peak_gb=peak / 1e9)
        tracemalloc.reset_peak()
    marks.append(m)
    text = " ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in m.items())
    print("MARK", text, flush=True)


def around(owner, name, label=None):
    fn = getattr(owner, name)
    label = label or name

    def w(*a, **k):
        mark(label + " <")
        try:
            return fn(*a, **k)
        finally:
            mark(label + " >")

    setattr(owner, name, staticmethod(w) if isinstance(owner.__dict__.get(name), staticmethod) else w)


if TRACE:
    tracemalloc.start()
import bpy  # noqa: E402

mark("bpy imported")
from hr_addon.blender import bake as bk  # noqa: E402
from hr_addon.blender import own_values as ov  # noqa: E402
from hr_addon.blender import scene_in as si  # noqa: E402
from hr_addon.blender import snapshot as sn  # noqa: E402
from hr_addon.core.gather import final, layouts  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

for owner, name in (
    (bk, "read_snapshot"),
    (sn, "ensure_own_values"),
    (ov, "near_clutter"),
    (sn, "collect_geometry"),
    (ov, "before_subdivision"),
    (si, "collect_instances"),
    (bk, "RadiositySystem"),
    (bk, "DynamicRadiosity"),
    (bk, "make_gather"),
    (pc, "prepare"),
    (pc, "write"),
    (bk._Bake, "frame_values"),
    (layouts, "loop_samples"),
    (layouts, "slot_split"),
    (layouts.LoopGather, "_loops"),
    (layouts.LoopGather, "_radiance_by_response"),
    (final.FinalGather, "_response_parts"),
    (final.FinalGather, "merge"),
    (final.FinalGather, "_reuse_rows"),
    (final.FinalGather, "_remap_near"),
    (bk.CacheWriter, "write"),
):
    around(owner, name)
_init = final.FinalGather.__init__


def _gather_init(self, *a, **k):
    n = len(a[1]) if len(a) > 1 else len(k.get("points", ()))
    mark(f"FinalGather({n}) <")
    try:
        _init(self, *a, **k)
    finally:
        mark(f"FinalGather({n}) >")


final.FinalGather.__init__ = _gather_init
for when, sign in ((bpy.app.handlers.load_pre, "<"), (bpy.app.handlers.load_post, ">")):
    when.append(bpy.app.handlers.persistent(lambda *a, s=sign: mark(f"open_mainfile {s}")))
from hr_addon.__main__ import main  # noqa: E402

mark("start")
rc = main(ARGS)
mark("end")
Path(OUT).write_text(json.dumps(dict(args=ARGS, trace=TRACE, rc=rc, marks=marks), indent=1))
sys.exit(rc)
