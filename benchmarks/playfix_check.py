"""A baked .blend's (vb100k's 100k vertex bake; opened in place, never saved) Live-like write and
stale check with the file's group, then regrouped to this version's (bench_bpy_frames.regroup;
session 32, branch playfix, docs/scale.md), CPU ms median of 3: every object's values written
(playback.apply_arrays, frame 2's) and view_layer.update(); check_scene(force); sync_materials over
every mesh object (nothing to change: what each check adds).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/playfix_check.py BAKED.blend
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
from hr_testing.blend import load_bpy  # noqa: E402

bpy = load_bpy()
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1], load_ui=False)
scene = bpy.context.scene
import bench_bpy_frames as b  # noqa: E402

from hr_addon.blender import own_values as ov  # noqa: E402
from hr_addon.blender import playback  # noqa: E402


def t(f, n=3):
    out = []
    for _ in range(n):
        c = time.process_time()
        r = f()
        out.append(1000 * (time.process_time() - c))
    return sorted(out)[n // 2], r


objs = [o for o in scene.objects if o.type == "MESH"]
scene.frame_set(2)
reader = playback.get_reader(playback.bake_dir_abs(scene))
arrays = reader.load(2)


def live():
    playback.apply_arrays(scene, arrays, reader.domain, objects={})
    bpy.context.view_layer.update()


print("file's group: write all + update", t(live))
print(
    "file's group: check",
    t(lambda: playback.check_scene(scene, force=True)),
    "sync",
    t(lambda: len(ov.sync_materials(objs)))[0],
)
b.regroup(bpy, scene, "CORNER")
scene.frame_set(2)
print(
    "regrouped: check",
    t(lambda: playback.check_scene(scene, force=True)),
    "sync",
    t(lambda: len(ov.sync_materials(objs)))[0],
)
print("regrouped: write all + update", t(live))
