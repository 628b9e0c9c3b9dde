"""Where a Live-like write on a baked 100k vertex room goes (session 32, branch helpwrite;
docs/live.md): opens a baked .blend IN PLACE (never saves it), brings its subdividing modifiers
to this version's group in memory (bench_bpy_frames.regroup), then times, CPU ms median of 3,
a write of frame 2's values and view_layer.update() in parts and with the group edited in memory:

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/helpwrite_probe.py BAKED.blend

all: every object written (playback.apply_arrays) and updated; helpers / plain: only the helpers'
meshes, only the other objects'; tag: every written mesh tagged (update_tag), nothing written;
noguard: the group's output linked to the helper's Object Info (no guard evaluated: what a guard
checked once per bake would cost at best); lean: noguard with the group's other nodes removed
(last: the group is not restored); slots: the guard computed but the helper shown (an OR with
True), its slots empty against "position" x4, alternately; off: the modifiers hidden (the helpers and plain
meshes alone). Then every modified object's evaluated HR_Radiance per corner against the first
("all") pass (--dump FILE: their digests, HR_Radiance and vertex positions, into FILE)."""

import hashlib
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
from hr_testing.blend import load_bpy  # noqa: E402

bpy = load_bpy()
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1], load_ui=False)
scene = bpy.context.scene
import bench_bpy_frames as b  # noqa: E402
import numpy as np  # noqa: E402

from hr_addon.blender import own_values as ov  # noqa: E402
from hr_addon.blender import playback  # noqa: E402
from hr_addon.blender.names import ATTRIBUTE  # noqa: E402

args = sys.argv[1:-1]
DUMP = None
if "--dump" in args:  # the digests of the values after "all" into this JSON (to compare versions)
    k = args.index("--dump")
    DUMP, args = args[k + 1], args[:k] + args[k + 2 :]
VARIANTS = args or ["all", "helpers", "plain", "tag", "noguard", "off"]


def t(f, n=3):
    return b.cpu_ms(f, n)


b.regroup(bpy, scene, "CORNER")
scene.frame_set(2)
reader = playback.get_reader(playback.bake_dir_abs(scene))
arrays = reader.load(2)
helpers = {n: v for n, v in arrays.items() if n.startswith(playback.HELPER)}
plain = {n: v for n, v in arrays.items() if n not in helpers}
mods = [(o, ov._modifier(o)) for o in scene.objects if ov.subdividing(o) > 0]
print(
    f"{len(arrays)} objects written: {len(helpers)} helpers, {len(plain)} plain; {len(mods)} modifiers",
    flush=True,
)


def write(which):
    def run():
        playback.apply_arrays(scene, which, reader.domain, objects={})
        bpy.context.view_layer.update()

    return run


objs = playback.objects_by_name(scene, arrays)


def tag():
    for o in objs.values():
        o.data.update_tag()
    bpy.context.view_layer.update()


def radiance():
    dg = bpy.context.evaluated_depsgraph_get()
    out = {}
    for o, _ in mods:
        me = o.evaluated_get(dg).data
        a = me.attributes[ATTRIBUTE]
        buf = np.empty(4 * len(a.data), np.float32)
        a.data.foreach_get("color", buf)
        co = np.empty(3 * len(me.vertices), np.float32)
        me.vertices.foreach_get("co", co)
        out[o.name] = hashlib.sha1(buf.tobytes() + co.tobytes()).hexdigest()
    return out


ref = None
g = mods[0][1].node_group
for v in VARIANTS:
    if v == "all":
        print("all: write + update", t(write(arrays)), flush=True)
        ref = radiance()
        if DUMP:
            Path(DUMP).write_text(json.dumps(ref, indent=0))
    elif v == "helpers":
        print("helpers only: write + update", t(write(helpers)), flush=True)
    elif v == "plain":
        print("plain only: write + update", t(write(plain)), flush=True)
    elif v == "tag":
        print("tag all, no write: update", t(tag), flush=True)
    elif v == "noguard":
        (go,) = [n for n in g.nodes if n.type == "GROUP_OUTPUT"]
        (sw,) = [n for n in g.nodes if n.type == "SWITCH" and n.input_type == "GEOMETRY"]
        keep = sw.inputs["True"].links[0].from_socket
        g.links.new(keep, go.inputs[0])
        bpy.context.view_layer.update()
        print("noguard: write + update", t(write(arrays)), flush=True)
        g.links.new(sw.outputs[0], go.inputs[0])
        bpy.context.view_layer.update()
    elif v == "slots":  # the guard computed (Boolean OR True: still the helper), its 4 slots empty
        # (skipped) against "position" each (hashed, as version 5), alternately, 3 rounds, median of 5
        (sw,) = [n for n in g.nodes if n.type == "SWITCH" and n.input_type == "GEOMETRY"]
        orn = g.nodes.new("FunctionNodeBooleanMath")
        orn.operation, orn.inputs[1].default_value = "OR", True
        g.links.new(sw.inputs["Switch"].links[0].from_socket, orn.inputs[0])
        g.links.new(orn.outputs[0], sw.inputs["Switch"])
        keys = [ov._socket(mods[0][1], f"{ov.GUARDS} {k + 1}") for k in range(ov.GUARDED)]
        for r in range(3):
            for name in ("", "position"):
                for o, m in mods:
                    for k in keys:
                        m[k] = name
                    o.update_tag()
                bpy.context.view_layer.update()
                print(f"slots {name!r} (round {r + 1}): write + update", t(write(arrays), 5), flush=True)
        for o, m in mods:
            for k in keys:
                m[k] = ""
            o.update_tag()
        g.links.new(orn.inputs[0].links[0].from_socket, sw.inputs["Switch"])
        g.nodes.remove(orn)
        bpy.context.view_layer.update()
    elif v == "lean":  # noguard in a group of 3 nodes: what the unused nodes cost (never saved)
        (go,) = [n for n in g.nodes if n.type == "GROUP_OUTPUT"]
        (sw,) = [n for n in g.nodes if n.type == "SWITCH" and n.input_type == "GEOMETRY"]
        info = sw.inputs["True"].links[0].from_node
        g.links.new(info.outputs["Geometry"], go.inputs[0])
        for n in [n for n in g.nodes if n not in (go, info) and n.type != "GROUP_INPUT"]:
            g.nodes.remove(n)
        bpy.context.view_layer.update()
        print("lean: write + update", t(write(arrays)), flush=True)
    elif v == "off":
        for _, m in mods:
            m.show_viewport = False
        bpy.context.view_layer.update()
        print("off: write + update", t(write(arrays)), flush=True)
        for _, m in mods:
            m.show_viewport = True
        bpy.context.view_layer.update()
if ref is not None:
    new = radiance()
    print("evaluated HR_Radiance the same:", sum(new[k] == ref[k] for k in ref), "of", len(ref), flush=True)
