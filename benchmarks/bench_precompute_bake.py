"""Issue 22 phase 2: the bake's build stage with the scene precompute, in bpy, on the furnished
20k room (sample_blends/furnished.blend, draft, final gather as the scene sets it). One run: a
cold bake of one frame (builds and stores the precompute), then the window's location keyframe
moved and the same frame baked again (loads it). Prints and stores both build stages, the
messages, and whether the re-bake's values equal a cold bake's of the moved window. Wall and CPU
seconds (this process's, all threads: the machine is shared) and the load average.

    python benchmarks/bench_precompute_bake.py [FRAME]
"""

import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hr_testing.blend import load_bpy, open_sample  # noqa: E402


def _bake(bpy, frame, **kw):
    """(BakeResult, CPU seconds {build: the build stage (_Bake.build), bake: all})."""
    from hr_addon.blender import bake

    cpu, c0 = {}, time.process_time()
    build = bake._Bake.build

    def timed(*a, **k):  # the build stage's CPU time (all threads of this process)
        c = time.process_time()
        try:
            return build(*a, **k)
        finally:
            cpu["build"] = round(time.process_time() - c, 2)

    bake._Bake.build = timed
    try:
        res = bake.run_bake(
            bpy.context.scene, log=lambda *a, **k: None, frames=(frame, frame), quality="draft", **kw
        )
    finally:
        bake._Bake.build = build
    cpu["bake"] = round(time.process_time() - c0, 2)
    return res, cpu


def _values(bpy):
    return {
        o.name: np.array([c.color[:] for c in o.data.color_attributes["HR_Radiance"].data])
        for o in bpy.context.scene.objects
        if o.type == "MESH" and "HR_Radiance" in o.data.color_attributes
    }


def main(frame=5):
    bpy = load_bpy()
    tmp = Path(tempfile.mkdtemp(prefix="bench_pc_bake_"))
    try:
        open_sample("furnished", tmp)
        tris = sum(
            len(p.vertices) - 2
            for o in bpy.data.objects
            if o.type == "MESH" and not o.hr.is_light_shape
            for p in o.data.polygons
        )
        t0 = time.perf_counter()
        load0 = os.getloadavg()
        cold, cpu_cold = _bake(bpy, frame)
        t_cold = time.perf_counter() - t0
        pc_bytes = (Path(cold.cache_dir) / "precompute.hrpc").stat().st_size
        win = bpy.data.objects["Window"]
        win.location.z += 0.1  # a light-shape keyframe edit: the window moves up 10 cm at this frame
        win.keyframe_insert("location", frame=frame)
        t1 = time.perf_counter()
        warm, cpu_warm = _bake(bpy, frame)
        t_warm = time.perf_counter() - t1
        bpy.context.scene.frame_set(frame)
        v_warm = _values(bpy)
        out = {
            "scene": "furnished 20k (sample_blends/furnished.blend)",
            "triangles": tris,
            "quality": "draft",
            "frame": frame,
            "precompute_bytes": pc_bytes,
            "cold": {
                "build_stage_s": cold.build_seconds + cold.gather_seconds,
                "hierarchy_s": cold.build_seconds,
                "gather_s": cold.gather_seconds,
                "bake_s": t_cold,
                "cpu_s": cpu_cold,
                "messages": cold.precompute,
            },
            "rebake_load_s": warm.load_seconds,
            "rebake_after_keyframe": {
                "build_stage_s": warm.build_seconds,
                "bake_s": t_warm,
                "cpu_s": cpu_warm,
                "messages": warm.precompute,
            },
            "ratio_rebake_build_to_cold_build": warm.build_seconds
            / (cold.build_seconds + cold.gather_seconds),
            "ratio_cpu_rebake_build_to_cold_build": cpu_warm["build"] / cpu_cold["build"],
            "date": time.strftime("%Y-%m-%d %H:%M"),
            "load_average": [load0, os.getloadavg()],
        }
        _store(out)  # (the check below takes a cold bake's time again)
        t2 = time.perf_counter()
        # the same light, the precompute rebuilt: the reference
        cold2, cpu_cold2 = _bake(bpy, frame, rebuild=True)
        bpy.context.scene.frame_set(frame)
        v_cold2 = _values(bpy)
        out["rebuild_same_light"] = {
            "build_stage_s": cold2.build_seconds + cold2.gather_seconds,
            "bake_s": time.perf_counter() - t2,
            "cpu_s": cpu_cold2,
            "messages": cold2.precompute,
        }
        out["rebake_equals_rebuilt_bitwise"] = all(np.array_equal(v_warm[k], v_cold2[k]) for k in v_cold2)
        out["load_average"].append(os.getloadavg())
        _store(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _store(out):
    print(json.dumps(out, indent=1), flush=True)
    o = Path(__file__).parent / "out"
    o.mkdir(exist_ok=True)
    (o / f"precompute_bake_20k_draft{sys.argv[2] if len(sys.argv) > 2 else ''}.json").write_text(
        json.dumps(out, indent=1)
    )


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
