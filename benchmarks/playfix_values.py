"""Bake the furnished sample (draft, frames 1-2, vertex output, its Vertex Spacing 0.25) with the
checkout REPO's code, then save every object's evaluated HR_Radiance per corner and positions at
frames 1, 2, 1 into OUT.npz (session 32, branch playfix: main's and the branch's compared bit for
bit, docs/scale.md); the sample's copy goes to OUT_blend/.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/playfix_values.py REPO OUT
"""

import sys
import time

import numpy as np

repo, out = sys.argv[-2:]
sys.path[:0] = [repo]
from hr_testing.blend import load_bpy, open_sample  # noqa: E402

bpy = load_bpy()
open_sample("furnished", out + "_blend")
scene = bpy.context.scene
scene.hr.output = "VERTEX"
from hr_addon.blender.bake import run_bake  # noqa: E402
from hr_addon.blender.playback import load_frame  # noqa: E402

c = time.process_time()
res = run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 2))
print("bake", time.process_time() - c, "s CPU; spacing", scene.hr.vertex_spacing)
arrays = {}
for f in (1, 2, 1):
    scene.frame_set(f)
    assert load_frame(scene, f)
    dg = bpy.context.evaluated_depsgraph_get()
    for o in scene.objects:
        if o.type != "MESH":
            continue
        me = o.evaluated_get(dg).data
        a = me.attributes.get("HR_Radiance")
        if a is None:
            continue
        v = np.empty(len(a.data) * 4, np.float32)
        a.data.foreach_get("color", v)
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        arrays[f"{f}/{o.name}/{a.domain}"] = v
        arrays[f"{f}/{o.name}/co"] = co
mods = sum(1 for o in scene.objects if o.modifiers.get("HR Radiance"))
print(len(arrays) // 6, "objects with HR_Radiance,", mods, "with the modifier")
np.savez(out, **arrays)
