"""The vertex output's gather precompute (LoopGather + precompute.prepare, as gather_precompute.py
runs it on a stored build) by stage: CPU seconds (process time, one thread) of each timed function
per gather level (the output's, the probe's, the second level's), counts (samples, rays, hits,
entries), one run. Times are inclusive (a stage's nested stages are in it: gather_batch holds the
rays, the lookups and the keys); a function's recursive calls count once.

    .venv/bin/python benchmarks/precompute_stages.py /work/cache/STORE [--root CHECKOUT] [--json FILE] \
        [--output]

--output: gather on the stored gather's output layout (a Blender bake's precompute.hrpc: the vertex
output on the Vertex Spacing mesh's corners, as the bake gathers), not on the system's own corners.
"""

import argparse
import functools
import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("store", help="folder of a stored build (bench_gather_events.py --cache)")
ap.add_argument("--root", default=str(Path(__file__).resolve().parent.parent), help="checkout timed")
ap.add_argument("--json", default=None)
ap.add_argument("--output", action="store_true", help="on the stored gather's output layout (a bake's)")
args = ap.parse_args()
sys.path.insert(0, args.root)
sys.path.insert(0, os.path.join(args.root, "benchmarks"))

from bench_gather_events import load_store  # noqa: E402
from hr_addon.core import gather  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.core.gather import final  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

cpu = defaultdict(float)  # (level, stage) -> s
calls = defaultdict(int)
count = defaultdict(int)  # (level, what) -> n
level = ["setup"]  # the FinalGather under construction (a stack)
active = set()  # stages running now (a recursive call counts once)


def timed(name, fn):
    @functools.wraps(fn)
    def run(*a, **k):
        key = (level[-1], name)
        if key in active:
            return fn(*a, **k)
        active.add(key)
        t0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            cpu[key] += time.process_time() - t0
            calls[key] += 1
            active.discard(key)

    return run


def patch_function(mod_names, name):
    """Time function `name` wherever an hr_addon module imported it (its own module's name too)."""
    orig = None
    for m in mod_names:
        mod = sys.modules[m]
        if hasattr(mod, name):
            orig = getattr(mod, name)
            break
    wrapped = timed(name, orig)
    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("hr_addon") and getattr(mod, name, None) is orig:
            setattr(mod, name, wrapped)


FG = final.FinalGather
init = FG.__init__


def labelled_init(self, system, *a, **k):
    nl = k.get("near_layout")  # (the probe's: (None, None); the second level's: None or (off, None))
    name = "output" if len(level) == 1 else "probe" if nl is not None and nl[0] is None else "second"
    level.append(name)
    t0 = time.process_time()
    try:
        init(self, system, *a, **k)
    finally:
        cpu[(name, "FinalGather.__init__")] += time.process_time() - t0
        level.pop()
    count[(name, "samples")] += self.n
    count[(name, "uncovered samples")] += int((~self.dark).sum())
    count[(name, "entries")] += len(self.cols)


FG.__init__ = labelled_init
for meth in (
    "gather_batch",
    "first_hit",
    "merge",
    "_remap_near",
    "_fine_leaves",
    "_reuse_rows",
    "_slots",
    "direct_static",
    "_origins",
):
    f = FG.__dict__[meth]
    setattr(
        FG, meth, staticmethod(timed(meth, f.__func__)) if isinstance(f, staticmethod) else timed(meth, f)
    )
for fn in (
    "locate_below",
    "onto_patch",
    "cosine_directions",
    "_nearest_point",
    "_row_sorted",
    "_exposed_quadrature",
    "_near_points",
    "_diameters",
    "split_lines",
    "position_keys",
    "isolated_objects",
    "loop_samples",
    "cut_patches",
    "slot_split",
    "_buried",
    "shared_rays",
    "probe_reach",
):
    patch_function(
        [
            "hr_addon.core.gather.final",
            "hr_addon.core.gather.layouts",
            "hr_addon.core.gather.points",
            "hr_addon.core.gather.sampling",
        ],
        fn,
    )
# the hits: rays traced per level (first_hit's rays)
first_hit = FG.first_hit


def counted_first_hit(self, org, dirs, per=None):
    count[(level[-1], "rays")] += len(dirs)
    prim, t = first_hit(self, org, dirs, per)
    count[(level[-1], "hits")] += int((prim >= 0).sum())
    return prim, t


FG.first_hit = counted_first_hit
# the hierarchy's covered test (h.dark): per level
s, g, header = load_store(Path(args.store) / pc.FILENAME)
pc.use_threads(s, g, 1)
layout = dict(output=g.output, smooth_angle=g.smooth_angle) if args.output else {}
del g
h = s.h
h.dark = timed("h.dark", h.dark)
if h.contacts is not None:
    h.contacts.covered = timed("Contacts.covered", h.contacts.covered)
dyn = DynamicRadiosity(s, method="FE", **DynamicRadiosity.gather_options("draft"))
t0 = time.process_time()
level[:] = ["layout"]
g = gather.LoopGather(dyn, rays=128, levels=2, iterations=4, threads=1, shadow_rays=16, **layout)
level[:] = ["prepare"]
pc.prepare(g)
total = time.process_time() - t0
print(f"{args.root}: precompute {total:.2f} s CPU, load {os.getloadavg()[0]:.2f}")
print(f"{'level':8} {'stage':24} {'CPU s':>8} {'share':>7} {'calls':>6}")
for (lv, st), v in sorted(cpu.items(), key=lambda kv: -kv[1]):
    if v >= 0.05:
        print(f"{lv:8} {st:24} {v:8.2f} {v / total:7.1%} {calls[(lv, st)]:6d}")
for (lv, what), n in sorted(count.items()):
    print(f"{lv:8} {what:24} {n:,}")
if args.json:
    Path(args.json).write_text(
        json.dumps(
            dict(
                root=args.root,
                total=total,
                load=os.getloadavg()[0],
                cpu={f"{lv}/{st}": v for (lv, st), v in cpu.items()},
                calls={f"{lv}/{st}": v for (lv, st), v in calls.items()},
                counts={f"{lv}/{w}": n for (lv, w), n in count.items()},
            ),
            indent=1,
        )
    )
