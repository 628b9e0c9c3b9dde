"""What Blender 5.0 re-evaluates after a colour-attribute write (session 31, reeval): N small mesh
objects (a grid each, HR_Radiance FLOAT_COLOR on corners), no add-on; CPU ms of view_layer.update()
after each variant, median of REPS.

    nice -n 5 .venv/bin/python benchmarks/reeval_probe.py [N ...] [--mod] [--own-materials] [--layers K]

--mod gives every object a Weighted Normal modifier, --own-materials a material of its own (else one
shared), --layers K K float attributes more per mesh; --reps R medians of R updates (5).
LD_PRELOAD=/usr/lib/x86_64-linux-gnu/libjemalloc.so.2 (Debian's libjemalloc2) puts jemalloc under
it, as Blender's own Linux builds are linked (the bpy module is built without it). docs/live.md,
session 31 reeval, has the figures and what perf and gdb showed of Blender's work.
"""

import sys
import time

import bpy
import numpy as np

args = [
    a
    for i, a in enumerate(sys.argv[1:], 1)
    if not a.startswith("--") and sys.argv[i - 1] not in ("--layers", "--reps")
]
MOD = "--mod" in sys.argv
OWN_MATERIALS = "--own-materials" in sys.argv  # a material per object (the 100k room: 3,642 materials)
LAYERS = int(sys.argv[sys.argv.index("--layers") + 1]) if "--layers" in sys.argv else 0
REPS = int(sys.argv[sys.argv.index("--reps") + 1]) if "--reps" in sys.argv else 5
SIZES = [int(a) for a in args if a.isdigit()] or [500, 1000, 2000, 4000]


def build(n):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    # one grid of 4x4 quads: 25 verts, 64 corners (the 100k room: 58 rows per object on average, median 24)
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(-1, 2)
    verts = [(x, y, 0.0) for x, y in g]
    faces = [
        (i * 5 + j, i * 5 + j + 1, (i + 1) * 5 + j + 1, (i + 1) * 5 + j) for i in range(4) for j in range(4)
    ]
    mat = bpy.data.materials.new("shared")
    mat.use_nodes = True
    objs = []
    for k in range(n):
        me = bpy.data.meshes.new(f"m{k}")
        me.from_pydata(verts, [], faces)
        me.color_attributes.new("HR_Radiance", "FLOAT_COLOR", "CORNER")
        me.materials.append(mat.copy() if OWN_MATERIALS else mat)
        for j in range(LAYERS):  # other attributes a user's mesh may carry (UV maps, masks)
            me.attributes.new(f"extra{j}", "FLOAT", "CORNER")
        ob = bpy.data.objects.new(f"o{k}", me)
        ob.location = (k % 70 * 6.0, k // 70 * 6.0, 0.0)
        scene.collection.objects.link(ob)
        if MOD:
            ob.modifiers.new("wn", "WEIGHTED_NORMAL")
        objs.append(ob)
    vl = bpy.context.view_layer
    vl.update()
    return vl, objs


def run(n):
    vl, objs = build(n)
    vals = np.random.default_rng(0).random((n, 64 * 4), dtype=np.float32)
    meshes = [o.data for o in objs]

    def write(ks, i):
        for k in ks:
            meshes[k].attributes["HR_Radiance"].data.foreach_set("color", vals[(k + i) % n])

    variants = {
        "nothing": lambda i: None,
        "foreach_set 1 mesh": lambda i: write([i], i),
        "mesh.update_tag() 1": lambda i: meshes[i].update_tag(),
        "obj.update_tag(DATA) 1": lambda i: objs[i].update_tag(refresh={"DATA"}),
        "obj.update_tag(OBJECT) 1": lambda i: objs[i].update_tag(refresh={"OBJECT"}),
        "location 1": lambda i: setattr(objs[i], "location", tuple(objs[i].location)),
        "shared material's node value": lambda i: setattr(
            bpy.data.materials["shared"].node_tree.nodes["Principled BSDF"].inputs["Roughness"],
            "default_value",
            0.1 + 0.01 * i,
        ),
        "foreach_set 10%": lambda i: write(range(i, n, 10), i),
        "foreach_set all": lambda i: write(range(n), i),
        "mesh.update_tag() all": lambda i: [m.update_tag() for m in meshes],
    }
    for label, fn in variants.items():
        ts, tw = [], []
        for i in range(REPS):
            c0 = time.process_time()
            fn(i)
            c1 = time.process_time()
            vl.update()
            ts.append(1000 * (time.process_time() - c1))
            tw.append(1000 * (c1 - c0))
        print(
            f"N={n} mod={int(MOD)} layers={LAYERS} {label:28s} "
            f"set {np.median(tw):7.2f}  update {np.median(ts):7.2f} ms",
            flush=True,
        )
    # does the evaluated mesh hold the written values?
    dg = bpy.context.evaluated_depsgraph_get()
    write([0], 7)
    vl.update()
    ev = objs[0].evaluated_get(dg).data.attributes["HR_Radiance"].data
    got = np.empty(len(ev) * 4, np.float32)
    ev.foreach_get("color", got)
    print(f"N={n} evaluated holds the write: {np.array_equal(got, vals[7 % n])}", flush=True)


for n in SIZES:
    run(n)
