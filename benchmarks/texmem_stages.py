"""Where a texture bake's peak memory goes, by stage: the real bake (`python -m hr_addon bake`, bpy
as a module) with its main steps wrapped to name the stage, RSS sampled every 20 ms (bench_texel_
memory.RssSampler), each stage's RSS at entry and exit, its peak and CPU seconds; then what the
bake holds after the build (the texel plan's and the final gather's arrays, by attribute) and the
plan's texel counts: how each stage scales with the texels. One run.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/texmem_stages.py OUT.json \
        scene.blend --frames 1-1 --quality draft --output texture --threads 1 [bake options]

(the bake's arguments after OUT.json, as `python -m hr_addon bake` takes them; the .blend is
changed by the bake's lightmap UVs: pass a copy. hr_addon is imported from the working directory,
so run it from a worktree of the code to measure.)
"""

import functools
import inspect
import json
import os
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, os.getcwd())  # hr_addon from the working directory: a worktree of the code measured

import numpy as np  # noqa: E402

from bench_texel_memory import RssSampler  # noqa: E402

sys.path.insert(0, os.getcwd())  # (bench_texel_memory put its own tree first)

SAMPLER = RssSampler()
STACK = ["start"]
STAGES = []  # [name, rss at entry, rss at exit, peak, cpu s] in order of entry
HELD = {}


def _enter(name):
    path = "/".join(STACK[1:] + [name])
    STACK.append(name)
    SAMPLER.stage = path
    rec = [path, SAMPLER.rss(), None, None, time.process_time()]
    STAGES.append(rec)
    return rec


def _leave(rec):
    STACK.pop()
    rec[2] = SAMPLER.rss()
    rec[4] = time.process_time() - rec[4]
    SAMPLER.stage = "/".join(STACK[1:]) or "start"


def marked(name, fn):
    if inspect.isgeneratorfunction(fn):

        @functools.wraps(fn)
        def gen(*a, **k):
            rec = _enter(name)
            try:
                yield from fn(*a, **k)
            finally:
                _leave(rec)

        return gen

    @functools.wraps(fn)
    def wrap(*a, **k):
        rec = _enter(name)
        try:
            return fn(*a, **k)
        finally:
            _leave(rec)

    return wrap


def arrays_of(obj, prefix, out, depth=0, seen=None):
    """{attribute path: bytes} of the numpy arrays obj holds (attributes, dicts, lists, tuples)."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 4:
        return out
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        base = obj if obj.base is None else None  # views: counted at their base
        if base is not None or not isinstance(obj.base, np.ndarray):
            out[prefix] = out.get(prefix, 0) + obj.nbytes
        return out
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)):
        key = prefix + "[]"
        for v in obj:
            arrays_of(v, key, out, depth + 1, seen)
        return out
    elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("hr_addon"):
        items = vars(obj).items()
    else:
        return out
    for k, v in items:
        arrays_of(v, f"{prefix}.{k}", out, depth + 1, seen)
    return out


def census(plan, final):
    held = {}
    if plan is not None:
        held["plan"] = arrays_of(plan, "plan", {})
        held["plan_texels"] = plan.texels
        held["plan_gathered"] = int(len(plan.gathered))
        held["plan_image_texels"] = int(sum(o.res * o.res for o in plan.objects))
        held["plan_objects"] = len(plan.objects)
    if final is not None:
        held["gather"] = arrays_of(final, "gather", {})
    for k in ("plan", "gather"):
        if k in held:
            held[k + "_bytes"] = sum(held[k].values())
            held[k] = dict(sorted(held[k].items(), key=lambda kv: -kv[1])[:40])
    return held


def main():
    out, argv = sys.argv[1], sys.argv[2:]
    SAMPLER.start()
    import hr_addon.__main__ as entry

    print("hr_addon from", os.path.dirname(os.path.dirname(entry.__file__)), flush=True)
    from hr_addon.blender import bake, cli, texture
    from hr_addon.io import precompute as pc
    from hr_addon.lightmap import plan as lplan

    bake.read_snapshot = marked("snapshot", bake.read_snapshot)
    bake.RadiositySystem = marked("hierarchy", bake.RadiositySystem)
    bake.DynamicRadiosity = marked("dynamic", bake.DynamicRadiosity)
    texture.lightmap_key = marked("lightmap_key", texture.lightmap_key)
    texture.check_memory = marked("check_memory", texture.check_memory)
    bake.make_gather = marked("gather", bake.make_gather)
    pc.prepare = marked("prepare", pc.prepare)
    pc.capture = marked("capture", pc.capture)
    pc.write = marked("write", pc.write)
    pc.keep = marked("keep", pc.keep)
    bake._Bake.open_writer = marked("open_writer", bake._Bake.open_writer)
    bake._Bake.frame_loop = marked("frames", bake._Bake.frame_loop)
    lplan.TexturePlan.radiance = marked("radiance", lplan.TexturePlan.radiance)
    lplan.TexturePlan.write = marked("images", lplan.TexturePlan.write)
    bake.CacheWriter.commit = marked("commit", bake.CacheWriter.commit)
    bake.use_bake = marked("use_bake", bake.use_bake)

    if os.environ.get("TEXMEM_FINE"):  # the frame's steps too
        from hr_addon.core.gather import direct, final

        F = final.FinalGather
        for name in ("evaluate_kinds", "_incident_by_response", "direct_and_emission", "indirect", "outputs"):
            setattr(F, name, marked(name, getattr(F, name)))
        direct.edge_direct = marked("edge_direct", direct.edge_direct)
        lplan.TexturePlan._at_texels = marked("_at_texels", lplan.TexturePlan._at_texels)
    texture_plan = bake._Bake.texture_plan

    def plan_and_count(self, snap, system):
        plan = texture_plan(self, snap, system)
        if plan is not None and "objects" not in HELD:  # per object: size, texels, inside, gathered, area
            pt = system.patches
            by_name = dict(zip(pt.object_names, np.bincount(pt.object_id, pt.area, len(pt.object_names))))
            gathered = np.zeros(plan.texels, bool)
            gathered[plan.gathered] = True
            HELD["objects"] = [
                [
                    o.name,
                    o.res,
                    o.hi - o.lo,
                    int(o.inside.sum()),
                    int(gathered[o.lo : o.hi].sum()),
                    by_name.get(o.name, 0.0),
                ]
                for o in plan.objects
            ]
            if os.environ.get("TEXMEM_PLAN_ONLY"):
                with open(sys.argv[1], "w") as fh:
                    json.dump(HELD, fh, default=float)
                os._exit(0)
        return plan

    bake._Bake.texture_plan = marked("plan", plan_and_count)
    build = bake._Bake.build

    def build_and_count(self, *a, **k):
        system, dyn, final = build(self, *a, **k)
        HELD.update(census(self._plan, final), rss_after_build=SAMPLER.rss())
        return system, dyn, final

    bake._Bake.build = marked("build", build_and_count)
    t0 = time.process_time()
    try:
        code = entry.main(["bake"] + argv)
    finally:
        SAMPLER.done = True
    ru = resource.getrusage(resource.RUSAGE_SELF)
    gb = 1e-9
    rep = {
        "code": os.path.dirname(os.path.dirname(entry.__file__)),
        "argv": argv,
        "exit": code,
        "cpu_s": ru.ru_utime + ru.ru_stime,
        "cpu_in_main_s": time.process_time() - t0,
        "peak_rss_gb": ru.ru_maxrss * 1024 * gb,
        "peak_where": SAMPLER.where,
        "stages": [
            {
                "stage": s,
                "rss_in_gb": a * gb,
                "rss_out_gb": (b or 0) * gb,
                "peak_gb": SAMPLER.peaks.get(s, 0) * gb,
                "cpu_s": c,
            }
            for s, a, b, _, c in STAGES
        ],
        "peak_by_stage_gb": {k: v * gb for k, v in SAMPLER.peaks.items()},
        "held": HELD,
        "by_line_top": dict(
            sorted(((k, v * gb) for k, v in SAMPLER.by_line.items()), key=lambda kv: -kv[1])[:25]
        ),
    }
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    json.dump(rep, open(out, "w"), indent=1, default=float)
    print(f"exit {code}, CPU {rep['cpu_s']:.1f} s, peak {rep['peak_rss_gb']:.2f} GB -> {out}")
    for s in rep["stages"]:
        rss = f"in {s['rss_in_gb']:.2f} out {s['rss_out_gb']:.2f} peak {s['peak_gb']:.2f} GB"
        print(f"  {s['stage']:40s} {rss}  {s['cpu_s']:.1f} s")
    del cli
    return code


if __name__ == "__main__":
    sys.exit(main() or 0)
