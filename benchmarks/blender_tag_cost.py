"""What Blender's depsgraph costs for one tagged object by scene size, without the extension
(session 29, lvbudget): the furnished room's objects (bench_live.make_furnished) and nothing else.

    nice -n 5 .venv/bin/python benchmarks/blender_tag_cost.py 100k     # or 2k, 20k
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
import bpy  # noqa: E402

import bench_live as bl  # noqa: E402

size = sys.argv[1] if len(sys.argv) > 1 else "100k"
scene, obj, *_ = bl.make_furnished(tempfile.mkdtemp(), size)
vl = bpy.context.view_layer
vl.update()
objs = [o for o in scene.objects if o.type == "MESH" and o is not obj]


def t(label, fn, reps=5):
    ts = []
    for i in range(reps):
        fn(i)
        c0 = time.process_time()
        vl.update()
        ts.append(1000 * (time.process_time() - c0))
    print(f"{size} ({len(scene.objects)} objects): {label}: {np.median(ts):.1f} ms", flush=True)


t("obj.update_tag() on one object", lambda i: objs[i].update_tag())
t("mesh.update_tag() on one mesh", lambda i: objs[i].data.update_tag())
t("location of one object", lambda i: setattr(objs[i], "location", tuple(objs[i].location)))
t("the window's location", lambda i: setattr(obj, "location", tuple(obj.location)))
