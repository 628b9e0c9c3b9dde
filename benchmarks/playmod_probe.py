"""What a playback frame change costs in the "HR Radiance" modifiers' subdivision (session 31,
branch playmod; docs/scale.md): opens a baked .blend IN PLACE (never saves it), times frame
changes 1 -> 5, 6, 7 (CPU ms) with the file's group, then with the subdividing group edited in
memory to VARIANT, and compares every modified object's evaluated mesh at frame 6 with the
first pass (HR_Radiance per corner, positions, named attributes, material slots) and the stale
check's message:

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/playmod_probe.py \\
        BAKED.blend VARIANT

VARIANT: off (the modifiers switched off), nosample (subdivision, no helper values), nomerge
(no Merge by Distance: other positions), replace (the group's output = the helper's geometry by
Object Info, Original: no subdivision), replace_mat (replace, the helpers holding their object's
materials), replace_guard (replace_mat behind a lazy Switch on an always-true check of the input:
Domain Size + Attribute Statistic of its positions, the cost of such a guard)."""

import hashlib
import sys
import time
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
BLEND, VARIANT = sys.argv[-2:]
bpy.ops.wm.open_mainfile(filepath=BLEND)
import hr_addon  # noqa: E402
from hr_addon.blender import playback  # noqa: E402
from hr_addon.blender.names import ATTRIBUTE  # noqa: E402

hr_addon.register()
scene = bpy.context.scene
mods = [(o, m) for o in scene.objects if o.type == "MESH" for m in o.modifiers if m.name == "HR Radiance"]
print("objects with the modifier", len(mods), {m.node_group.name for o, m in mods}, flush=True)
KEY = {"FLOAT": ("value", 1), "INT": ("value", 1), "BOOLEAN": ("value", 1), "FLOAT2": ("vector", 2)}
KEY |= {"FLOAT_VECTOR": ("vector", 3), "FLOAT_COLOR": ("color", 4)}


def run(tag):
    scene.frame_set(1)
    ts = []
    for f in (5, 6, 7):
        c = time.process_time()
        scene.frame_set(f)
        ts.append(1000 * (time.process_time() - c))
    print(tag, [round(t) for t in ts], "ms, median", round(sorted(ts)[1]), flush=True)


def evaluated():
    scene.frame_set(6)
    dg = bpy.context.evaluated_depsgraph_get()
    out = {}
    for o, _ in mods:
        ob = o.evaluated_get(dg)
        ev, named = ob.data, []
        for a in sorted(ev.attributes, key=lambda a: a.name):
            if a.name.startswith(".") or a.data_type not in KEY:
                continue  # (internal and anonymous attributes: Capture Attribute's seam flag)
            key, w = KEY[a.data_type]
            buf = np.empty(len(a.data) * w, {"INT": np.int32, "BOOLEAN": bool}.get(a.data_type, np.float32))
            a.data.foreach_get(key, buf)
            named.append((a.name, a.data_type, a.domain, hashlib.sha1(buf.tobytes()).hexdigest()))
        slots = [getattr(s.material, "name", None) for s in ob.material_slots]
        out[o.name] = (named, [u.name for u in ev.uv_layers], slots)
    return out


run("file's group")
ref = evaluated()
g = mods[0][1].node_group
nodes, link = g.nodes, g.links.new
(go,) = [n for n in nodes if n.type == "GROUP_OUTPUT"]
(gi,) = [n for n in nodes if n.type == "GROUP_INPUT"]
(st,) = [x for x in nodes if x.type == "STORE_NAMED_ATTRIBUTE" and x.inputs[2].default_value == ATTRIBUTE]
(info,) = [n for n in nodes if n.type == "OBJECT_INFO"]
if VARIANT == "off":
    for _, m in mods:
        m.show_viewport = False
elif VARIANT == "nosample":
    link(st.inputs["Geometry"].links[0].from_socket, go.inputs[0])
elif VARIANT == "nomerge":
    link([n for n in nodes if n.type == "JOIN_GEOMETRY"][0].outputs[0], st.inputs["Geometry"])
elif VARIANT.startswith("replace"):
    if VARIANT != "replace":
        for o, m in mods:
            h = m[g.interface.items_tree["Values"].identifier]
            h.data.materials.clear()
            for mt in o.data.materials:
                h.data.materials.append(mt)
    out = info.outputs["Geometry"]
    if VARIANT == "replace_guard":
        stat = nodes.new("GeometryNodeAttributeStatistic")
        stat.data_type, stat.domain = "FLOAT_VECTOR", "POINT"
        link(gi.outputs["Geometry"], stat.inputs["Geometry"])
        link(nodes.new("GeometryNodeInputPosition").outputs[0], stat.inputs["Attribute"])
        size = nodes.new("GeometryNodeAttributeDomainSize")
        link(gi.outputs["Geometry"], size.inputs["Geometry"])
        faces = nodes.new("FunctionNodeCompare")
        faces.data_type, faces.operation = "INT", "GREATER_THAN"
        link(size.outputs["Face Count"], faces.inputs[2])
        length = nodes.new("ShaderNodeVectorMath")
        length.operation = "LENGTH"
        link(stat.outputs["Sum"], length.inputs[0])
        sums = nodes.new("FunctionNodeCompare")
        sums.data_type, sums.operation = "FLOAT", "GREATER_EQUAL"
        link(length.outputs["Value"], sums.inputs[0])
        both = nodes.new("FunctionNodeBooleanMath")
        both.operation = "AND"
        link(faces.outputs[0], both.inputs[0])
        link(sums.outputs[0], both.inputs[1])
        switch = nodes.new("GeometryNodeSwitch")
        switch.input_type = "GEOMETRY"
        link(both.outputs[0], switch.inputs["Switch"])
        link(st.outputs["Geometry"], switch.inputs["False"])
        link(out, switch.inputs["True"])
        out = switch.outputs[0]
    link(out, go.inputs[0])
else:
    raise SystemExit(f"unknown variant {VARIANT!r}")
bpy.context.view_layer.update()
run(VARIANT)
new = evaluated()
WHAT = ("named attributes", "uv maps", "materials")
same = {w: sum(ref[k][i] == new[k][i] for k in ref) for i, w in enumerate(WHAT)}


def radiance_of(named):
    return [a for a in named if a[0] == ATTRIBUTE]


radiance = sum(radiance_of(ref[k][0]) == radiance_of(new[k][0]) for k in ref)
print(VARIANT, "of", len(ref), "objects the same: HR_Radiance", radiance, same, flush=True)
print("stale check:", repr(playback.check_scene(scene, force=True)), flush=True)
