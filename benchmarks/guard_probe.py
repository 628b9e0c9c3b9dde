"""What the subdividing group's guard costs per write, by how it is built (session 33, branch
livebake; docs/live.md): opens a baked .blend IN PLACE (never saves it), brings its modifiers to
this version's group (bench_bpy_frames.regroup), then gives them copies of the group whose guard is
built another way, each computed in full but the helper shown (an OR with True on its Switch), and
times frame 2's write of every object + view_layer.update(), CPU ms median of 5, in rounds:

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/guard_probe.py \
        [--rounds 2] [VARIANT ...] BAKED.blend

current: this version's group; v6: version 6's guard (a Hash Value per field, the helper's GUARD
sampled per corner); packed: what
the guard reads per corner and once per mesh in one 4x4 matrix, one Hash Value; scalar: version 6's
hashes, their float sum (Attribute Statistic) compared with one value instead of the helper's GUARD;
scalar_sum: scalar with the value compared sampled from the helper (a float attribute at index 0);
packed_scalar: both; noguard: the group's output the helper's Object Info (no guard)."""

import sys
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]
from hr_testing.blend import load_bpy  # noqa: E402

args = sys.argv[1:-1]
rounds = 2
if args[:1] == ["--rounds"]:
    rounds, args = int(args[1]), args[2:]
VARIANTS = args or ["current", "v6", "scalar", "scalar_sum", "noguard"]

bpy = load_bpy()
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1], load_ui=False)
scene = bpy.context.scene
import bench_bpy_frames as b  # noqa: E402
from bench_bpy_frames import cpu_ms as t  # noqa: E402

from hr_addon.blender import own_values as ov  # noqa: E402
from hr_addon.blender import playback  # noqa: E402
from hr_addon.blender.names import GUARD  # noqa: E402

b.regroup(bpy, scene, "CORNER")
scene.frame_set(2)
reader = playback.get_reader(playback.bake_dir_abs(scene))
arrays = reader.load(2)
mods = [(o, ov._modifier(o)) for o in scene.objects if ov.subdividing(o) > 0]
base = mods[0][1].node_group
print(f"{len(arrays)} objects written; {len(mods)} modifiers of {base.name!r} ({len(base.nodes)} nodes)")


def upstream(node):
    seen, todo = set(), [node]
    while todo:
        n = todo.pop()
        if n.name in seen:
            continue
        seen.add(n.name)
        todo += [lk.from_node for s in n.inputs for lk in s.links]
    return seen


def variant(kind):
    """A copy of the group with its guard built as `kind` (the helper shown: OR True)."""
    g = base.copy()
    g.name = f"probe {kind}"
    nodes, link = g.nodes, g.links.new
    (go,) = [n for n in nodes if n.type == "GROUP_OUTPUT"]
    (gi,) = [n for n in nodes if n.type == "GROUP_INPUT"]
    (sw,) = [n for n in nodes if n.type == "SWITCH" and n.input_type == "GEOMETRY"]
    keep = sw.inputs["False"].links[0].from_node  # Store GUARD on the subdivided mesh
    subdivided = keep.inputs["Geometry"].links[0].from_socket
    info = sw.inputs["True"].links[0].from_node
    if kind == "current":
        guard_ok = sw.inputs["Switch"].links[0].from_socket
    else:
        stay = upstream(subdivided.node) | {gi.name, go.name}
        for n in [n for n in nodes if n.name not in stay]:
            nodes.remove(n)
        info = nodes.new("GeometryNodeObjectInfo")
        link(gi.outputs["Values"], info.inputs["Object"])
        if kind == "noguard":
            link(info.outputs["Geometry"], go.inputs[0])
            return g
        guard_ok = build(
            nodes, link, gi, info, subdivided, go, "packed" in kind, "scalar" in kind, "sum" in kind
        )
    sw = [n for n in nodes if n.type == "SWITCH" and n.input_type == "GEOMETRY"][0]
    orn = nodes.new("FunctionNodeBooleanMath")
    orn.operation, orn.inputs[1].default_value = "OR", True
    link(guard_ok, orn.inputs[0])
    link(orn.outputs[0], sw.inputs["Switch"])
    return g


def build(nodes, link, gi, info, subdivided, go, packed, scalar, helper_sum=False):
    made = []
    node = partial(ov._add_node, nodes, made)
    hashed = partial(ov._hashed, node, link)

    received = gi.outputs["Geometry"]
    size = node("GeometryNodeAttributeDomainSize", component="MESH")
    link(received, size.inputs["Geometry"])
    skip = node("GeometryNodeSwitch", input_type="INT")
    used = node("FunctionNodeCompare", data_type="STRING", operation="NOT_EQUAL")
    link(gi.outputs[f"{ov.GUARDS} 1"], next(i for i in used.inputs if i.identifier == "A_STR"))
    link(used.outputs[0], skip.inputs["Switch"])
    per_corner = [
        node("GeometryNodeInputShadeSmooth").outputs[0],
        node("GeometryNodeInputMaterialIndex").outputs[0],
        node("GeometryNodeFaceOfCorner").outputs["Face Index"],
        node("GeometryNodeVertexOfCorner").outputs["Vertex Index"],
    ]
    if packed:
        seed = None
        for k in range(ov.GUARDED):
            attr = node("GeometryNodeInputNamedAttribute", data_type="FLOAT_COLOR")
            link(gi.outputs[f"{ov.GUARDS} {k + 1}"], attr.inputs["Name"])
            seed = hashed(attr.outputs["Attribute"], seed, "RGBA")
        link(seed, skip.inputs["True"])  # (False: 0)
        pos = node("ShaderNodeSeparateXYZ")
        link(node("GeometryNodeInputPosition").outputs[0], pos.inputs[0])
        sc = node("ShaderNodeSeparateXYZ")
        link(gi.outputs[ov.SCALE], sc.inputs[0])
        m = node("FunctionNodeCombineMatrix")
        src = [*pos.outputs[:3], *per_corner]
        src += [size.outputs[n] for n in ("Point Count", "Edge Count", "Face Count", "Face Corner Count")]
        src += [gi.outputs[ov.SPACING], *sc.outputs[:3]]
        for s, i in zip(src, m.inputs):
            link(s, i)
        corner = hashed(m.outputs[0], skip.outputs[0], "MATRIX")
    else:
        seed = None
        for n in ("Point Count", "Edge Count", "Face Count", "Face Corner Count"):
            seed = hashed(size.outputs[n], seed, "INT")
        seed = hashed(gi.outputs[ov.SCALE], hashed(gi.outputs[ov.SPACING], seed, "FLOAT"), "VECTOR")
        link(seed, skip.inputs["False"])
        s2 = seed
        for k in range(ov.GUARDED):
            attr = node("GeometryNodeInputNamedAttribute", data_type="FLOAT_COLOR")
            link(gi.outputs[f"{ov.GUARDS} {k + 1}"], attr.inputs["Name"])
            s2 = hashed(attr.outputs["Attribute"], s2, "RGBA")
        link(s2, skip.inputs["True"])
        seed = skip.outputs[0]
        for f in per_corner:
            seed = hashed(f, seed, "INT")
        corner = hashed(node("GeometryNodeInputPosition").outputs[0], seed, "VECTOR")
    index = node("GeometryNodeInputIndex").outputs[0]

    def at(geometry, field):
        sample = node("GeometryNodeSampleIndex", data_type="INT", domain="CORNER")
        link(geometry, sample.inputs["Geometry"])
        link(field, sample.inputs[1])
        link(index, sample.inputs["Index"])
        return sample.outputs[0]

    keep = node("GeometryNodeStoreNamedAttribute", data_type="INT", domain="CORNER")
    keep.inputs["Name"].default_value = GUARD
    link(subdivided, keep.inputs["Geometry"])
    if scalar:
        stat = node("GeometryNodeAttributeStatistic", data_type="FLOAT", domain="CORNER")
        link(received, stat.inputs["Geometry"])
        link(corner, stat.inputs["Attribute"])
        holds = node("FunctionNodeCompare", data_type="FLOAT", operation="EQUAL")
        next(i for i in holds.inputs if i.name == "Epsilon").default_value = 0.0
        link(stat.outputs["Sum"], holds.inputs[0])
        holds.inputs[1].default_value = 12345.0
        if helper_sum:  # the value compared read from the helper (its GUARD at index 0)
            stored = node("GeometryNodeInputNamedAttribute", data_type="FLOAT")
            stored.inputs["Name"].default_value = "position"
            first = node("GeometryNodeSampleIndex", data_type="FLOAT", domain="POINT")
            link(info.outputs["Geometry"], first.inputs["Geometry"])
            link(stored.outputs["Attribute"], first.inputs[1])
            link(first.outputs[0], holds.inputs[1])
        link(corner, keep.inputs["Value"])  # (stored as the sum would be: what the probe times is the guard)
    else:
        stored = node("GeometryNodeInputNamedAttribute", data_type="INT")
        stored.inputs["Name"].default_value = GUARD
        differ = node("FunctionNodeCompare", data_type="INT", operation="NOT_EQUAL")
        link(corner, differ.inputs[2])
        link(at(info.outputs["Geometry"], stored.outputs["Attribute"]), differ.inputs[3])
        stat = node("GeometryNodeAttributeStatistic", data_type="FLOAT", domain="CORNER")
        link(received, stat.inputs["Geometry"])
        link(differ.outputs[0], stat.inputs["Attribute"])
        holds = node("FunctionNodeCompare", data_type="FLOAT", operation="LESS_THAN")
        link(stat.outputs["Max"], holds.inputs[0])
        holds.inputs[1].default_value = 0.5
        link(at(received, corner), keep.inputs["Value"])
    switch = node("GeometryNodeSwitch", input_type="GEOMETRY")
    link(keep.outputs["Geometry"], switch.inputs["False"])
    link(info.outputs["Geometry"], switch.inputs["True"])
    link(switch.outputs[0], go.inputs[0])
    print(f"  {len(made)} guard nodes", flush=True)
    return holds.outputs[0]


def write():
    playback.apply_arrays(scene, arrays, reader.domain, objects={})
    bpy.context.view_layer.update()


groups = {v: variant(v) for v in VARIANTS}
keys = [ov._socket(mods[0][1], n) for n in ("Values", ov.SPACING, ov.SCALE)]
keys += [ov._socket(mods[0][1], f"{ov.GUARDS} {k + 1}") for k in range(ov.GUARDED)]
for r in range(rounds):
    for v in VARIANTS:
        for o, m in mods:
            vals = {
                k: m[k] if isinstance(m[k], (str, float, int, bpy.types.ID)) else tuple(m[k]) for k in keys
            }
            m.node_group = groups[v]
            for k, x in vals.items():
                m[k] = x
            o.update_tag()
        bpy.context.view_layer.update()
        print(f"{v} (round {r + 1}): write + update", t(write), flush=True)
