"""The vertex output's gather precompute (LoopGather + precompute.prepare, as gather_precompute.py
runs it on a stored build) by stage: CPU seconds (process time, one thread) of each timed function
per gather level (the output's, the probe's, the second level's), counts (samples, rays, hits,
entries), one run. Times are inclusive (a stage's nested stages are in it: gather_batch holds the
rays, the lookups and the keys); a function's recursive calls count once.

    .venv/bin/python benchmarks/precompute_stages.py /work/cache/STORE [--root CHECKOUT] [--json FILE] \
        [--output]

--output: gather on the stored gather's output layout (a Blender bake's precompute.hrpc: the vertex
output on the Vertex Spacing mesh's corners, as the bake gathers), not on the system's own corners.
--rays: the ray backend's calls by level and caller (the nearest hr_addon function outside
visibility.py): CPU of first_hit / occluded(_cm), of _first inside them and of Embree's own
_nearest / _any_hit (the rest is numpy around the tracer), and their rays. --dups: per level, how
many traced samples share their origin, normal and ray count (and their position key: the same
rays bit for bit) with another (np.unique over them, its CPU printed apart).
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
ap.add_argument("--rays", action="store_true", help="the ray backend's calls by caller, Embree's own time")
ap.add_argument("--dups", action="store_true", help="traced samples with the same origin, normal, rays")
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
ray_cpu = defaultdict(float)  # (level, caller, call) -> s (--rays)
ray_n = defaultdict(int)
if args.rays:
    import traceback

    import numpy as np

    from hr_addon.core import visibility as vis

    outer = []  # the backend calls running now (a nested one counts under the outermost's caller)

    def caller():  # the nearest hr_addon frame outside visibility.py
        for fr in reversed(traceback.extract_stack(limit=16)[:-2]):
            if "hr_addon" in fr.filename and "visibility.py" not in fr.filename:
                return fr.name
        return "?"

    def backend_timed(cls, meth):
        f = getattr(cls, meth)
        tag = ("numpy" if cls is vis.NumpyBackend else "") + meth  # (numpy's re-traces apart)

        @functools.wraps(f)
        def run(self, *a, **k):
            key = (level[-1], caller() if not outer else outer[0][1], tag)
            outer.append(key)
            t0 = time.process_time()
            try:
                return f(self, *a, **k)
            finally:
                ray_cpu[key] += time.process_time() - t0
                outer.pop()
                if meth == "occluded_cm":
                    ray_n[key] += a[1].shape[1]
                elif meth == "occluded":
                    ray_n[key] += int(np.prod(np.broadcast_shapes(np.shape(a[0])[:-1], np.shape(a[1])[:-1])))
                else:
                    ray_n[key] += len(a[1])

        setattr(cls, meth, run)

    for cls, meth in (
        (vis.RayBackend, "first_hit"),
        (vis.RayBackend, "occluded"),
        (vis.RayBackend, "occluded_cm"),
        (vis._Float32Backend, "_first"),
        (vis.EmbreeBackend, "_nearest"),
        (vis.EmbreeBackend, "_any_hit"),
        (vis.NumpyBackend, "_first"),
        (vis.NumpyBackend, "_occluded"),
    ):
        backend_timed(cls, meth)
dups = {}
dup_cpu = [0.0]
if args.dups:
    import numpy as np

    batches = FG.batches

    def dup_batches(self, per_sample):  # (once per level, before its hemisphere rays)
        if getattr(self, "_trace", None) is None or level[-1] in dups:
            return batches(self, per_sample)
        t0 = time.process_time()
        tr = np.flatnonzero(self._trace)
        rr = np.full(self.n, self.rays) if self.sample_rays is None else self.sample_rays
        key = np.column_stack([self._origins(tr), self.normals[tr], rr[tr].astype(float)])
        u = np.unique(key, axis=0)
        uk = np.unique(np.column_stack([key, self.keys[tr].view(np.float64)]), axis=0)
        up = np.unique(np.column_stack([self.points[tr], self.normals[tr]]), axis=0)
        dups[level[-1]] = dict(
            traced=int(len(tr)),
            rays=int(rr[tr].sum()),
            unique_origin_normal_rays=int(len(u)),
            their_rays=int(u[:, 6].sum()),
            unique_with_key=int(len(uk)),
            their_rays_with_key=int(uk[:, 6].sum()),
            unique_point_normal=int(len(up)),
        )
        dup_cpu[0] += time.process_time() - t0
        return batches(self, per_sample)

    FG.batches = dup_batches
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
if args.rays:
    print(f"{'level':8} {'caller':24} {'call':12} {'CPU s':>8} {'rays':>12}")
    for k, v in sorted(ray_cpu.items(), key=lambda kv: (kv[0][0], kv[0][1], -kv[1])):
        print(f"{k[0]:8} {k[1]:24} {k[2]:12} {v:8.2f} {ray_n[k]:12,}")
for lv, d in dups.items():
    print(lv, d)
if dups:
    print(f"(the duplicates' count {dup_cpu[0]:.2f} s CPU, inside the levels' times)")
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
                rays={"/".join(k): [v, ray_n[k]] for k, v in ray_cpu.items()},
                dups=dups,
                dup_cpu=dup_cpu[0],
            ),
            indent=1,
        )
    )
