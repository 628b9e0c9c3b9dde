"""Preview: show HR_Radiance through an Emission shader (viewport and renders).

Each material of the participating objects gets three extra nodes (Attribute "HR_Radiance" ->
Emission -> Material Output, all named "HR Preview ...") and that output becomes the active
one; the original nodes stay untouched and are restored by remove_preview(). Objects without a
material get the shared "HR Preview" material, which the bake treats as no material (grey 0.8).
Emission strength 1 reproduces the cached radiance exactly (view transform Standard).
"""

import bpy

from .materials import PREVIEW
from .playback import ATTRIBUTE

N_ATTR, N_EMIT, N_OUT = PREVIEW + " Attribute", PREVIEW + " Emission", PREVIEW + " Output"


def _add_nodes(mat):
    tree = mat.node_tree
    if tree is None:
        return False
    if N_OUT in tree.nodes:
        tree.nodes[N_OUT].is_active_output = True
        return True
    x = max((n.location.x for n in tree.nodes), default=0) + 300
    attr = tree.nodes.new("ShaderNodeAttribute")
    attr.name = attr.label = N_ATTR
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = ATTRIBUTE
    attr.location = (x, -400)
    emit = tree.nodes.new("ShaderNodeEmission")
    emit.name = emit.label = N_EMIT
    emit.inputs["Strength"].default_value = 1.0
    emit.location = (x + 200, -400)
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.name = out.label = N_OUT
    out.target = "ALL"
    out.location = (x + 400, -400)
    tree.links.new(attr.outputs["Color"], emit.inputs["Color"])
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    out.is_active_output = True
    return True


def _preview_material():
    mat = bpy.data.materials.get(PREVIEW)
    if mat is None or not mat.get("hr_preview"):
        mat = bpy.data.materials.new(PREVIEW)
        mat["hr_preview"] = True
        if bpy.app.version < (5, 0, 0):
            mat.use_nodes = True
    _add_nodes(mat)
    return mat


def add_preview(objects):
    """Returns the number of materials switched to the preview."""
    done = set()
    for obj in objects:
        if obj.type != "MESH":
            continue
        mats = [s.material for s in obj.material_slots if s.material is not None]
        if not mats:
            obj.data.materials.append(_preview_material())
            continue
        for m in mats:
            if m.name_full not in done:
                if bpy.app.version < (5, 0, 0) and not m.use_nodes:
                    m.use_nodes = True
                _add_nodes(m)
                done.add(m.name_full)
    return len(done)


def remove_preview(objects=None):
    """Remove the preview nodes from every material (or those of `objects`)."""
    mats = (
        bpy.data.materials
        if objects is None
        else {s.material for o in objects for s in o.material_slots if s.material is not None}
    )
    n = 0
    for m in list(mats):
        if m.get("hr_preview"):
            continue
        tree = m.node_tree
        if tree is None or N_OUT not in tree.nodes:
            continue
        for name in (N_OUT, N_EMIT, N_ATTR):
            if name in tree.nodes:
                tree.nodes.remove(tree.nodes[name])
        outs = [x for x in tree.nodes if x.type == "OUTPUT_MATERIAL"]
        if outs and not any(x.is_active_output for x in outs):
            outs[0].is_active_output = True
        n += 1
    for o in bpy.data.objects if objects is None else objects:
        if o.type == "MESH":
            for i in reversed(range(len(o.data.materials))):
                m = o.data.materials[i]
                if m is not None and m.get("hr_preview"):
                    o.data.materials.pop(index=i)
    return n


def has_preview():
    """True when some material carries preview nodes, is the shared preview material, or is a
    baked-texture helper material (what Remove Preview removes)."""
    from .texture import TAG

    for m in bpy.data.materials:
        if m.get("hr_preview") or m.get(TAG) is not None:
            return True
        tree = m.node_tree
        if tree is not None and N_OUT in tree.nodes:
            return True
    return False
