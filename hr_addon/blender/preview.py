"""Preview: show HR_Radiance through an Emission shader (viewport and renders).

Each material of the participating objects gets extra nodes (Attribute "HR_Radiance" ->
Emission -> Material Output, all named "HR Preview ...") and that output becomes the active
one; the original nodes stay untouched and are restored by remove_preview(). Objects without a
material get the shared "HR Preview" material, which the bake treats as no material (grey 0.8).
Emission strength 1 reproduces the cached radiance exactly (view transform Standard).
An irradiance bake (Scene.hr.radiance_mode IRRADIANCE) is shown times the material's own base
colour (the node output feeding it, textures included) plus its emission (colour_chain), so a
textured surface shows its texture. An Indirect-only bake (INDIRECT, for EEVEE) is shown as the
material's own surface shader plus an Emission of base colour x HR_Radiance (Add Shader): the
render engine lights the material with the lamps and the World itself, the bake adds the bounce.
"""

import bpy

from ..io.cache import CacheError, CacheReader
from .materials import base_color_socket, read_material
from .names import ATTRIBUTE, N_ADD, N_ATTR, N_EMIT, N_MUL, N_OUT, N_PATH, N_SEEN, N_SHADER, PREVIEW, TAG
from .paths import bake_dir_abs
from .steps import finish


def bake_mode(scene):
    """Radiance mode of the scene's bake (settings.ENUMS["radiance_mode"]; the setting if not baked)."""
    d = bake_dir_abs(scene)
    try:
        return CacheReader(d).manifest.get("radiance_mode", "RADIANCE") if d else scene.hr.radiance_mode
    except CacheError:
        return scene.hr.radiance_mode


def node_named(tree, name, kind, location):
    """The node called `name` in tree, made (or remade, if of another kind) at location."""
    n = tree.nodes.get(name)
    if n is not None and n.bl_idname != kind:
        tree.nodes.remove(n)
        n = None
    if n is None:
        n = tree.nodes.new(kind)
        n.name = n.label = name
        n.location = location
    return n


def colour_chain(mat, tree, src, location, mode):
    """The colour output the preview's Emission shows for the bake's radiance mode: src itself
    (RADIANCE), or src x the material's base colour (the same upstream output, linked, or the
    socket's colour), for IRRADIANCE + its emission (read_material's value; INDIRECT: the
    material's own shader emits it). Removes the chain's nodes when not needed."""
    multiply = mode in ("IRRADIANCE", "INDIRECT")
    for name, needed in ((N_MUL, multiply), (N_ADD, mode == "IRRADIANCE")):
        if not needed and name in tree.nodes:
            tree.nodes.remove(tree.nodes[name])
    if not multiply:
        return src
    x, y = location
    mul = node_named(tree, N_MUL, "ShaderNodeMix", (x, y))
    mul.data_type, mul.blend_type, mul.clamp_result = "RGBA", "MULTIPLY", False
    ids = {s.identifier: s for s in mul.inputs}
    ids["Factor_Float"].default_value = 1.0
    tree.links.new(src, ids["A_Color"])
    base = base_color_socket(mat)
    if base is not None and base.id_data != tree:
        base = None  # the shader sits in a node group: its links cannot be used here; the average
    for lk in list(ids["B_Color"].links):
        tree.links.remove(lk)
    if base is not None and base.is_linked:
        tree.links.new(base.links[0].from_socket, ids["B_Color"])
    else:
        rho = base.default_value[:3] if base is not None else read_material(mat).reflectance
        ids["B_Color"].default_value = (*map(float, rho), 1.0)
    res = next(s for s in mul.outputs if s.identifier == "Result_Color")
    if mode == "INDIRECT":
        return res
    add = node_named(tree, N_ADD, "ShaderNodeVectorMath", (x + 200, y))
    add.operation = "ADD"
    add.inputs[1].default_value = tuple(map(float, read_material(mat).emission))
    tree.links.new(res, add.inputs[0])
    return add.outputs["Vector"]


def _add_nodes(mat, mode="RADIANCE", name_now=True):
    """The preview's nodes in mat. name_now False: the Attribute node is left unnamed (it reads
    nothing until _name_attribute): naming one makes Blender rebuild the depsgraph's relations at
    its next evaluation, about 0.6 s at 100k however many were named (measured; nodes, links and
    the active output cost it 20-30 ms), so a start spread over timer ticks names them all in one
    last step instead of costing that once per tick."""
    tree = mat.node_tree
    if tree is None:
        return False
    x = max((n.location.x for n in tree.nodes if not n.name.startswith(PREVIEW)), default=0) + 300
    attr = node_named(tree, N_ATTR, "ShaderNodeAttribute", (x, -400))
    if name_now:
        _name_attribute(tree)
    emission_output(mat, tree, attr.outputs["Color"], x + 600, mode)
    return True


def _name_attribute(tree):
    """The preview's Attribute node reads HR_Radiance (set only when not so already: an unchanged
    node costs Blender no relations update)."""
    attr = tree.nodes[N_ATTR]
    if attr.attribute_type != "GEOMETRY":
        attr.attribute_type = "GEOMETRY"
    if attr.attribute_name != ATTRIBUTE:
        attr.attribute_name = ATTRIBUTE


def own_output(tree):
    """The material's own Material Output that EEVEE renders (None: it has none)."""
    outs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and not n.name.startswith(PREVIEW)]
    outs = [n for n in outs if n.target in ("ALL", "EEVEE")] or outs
    return next((n for n in outs if n.is_active_output), outs[0] if outs else None)


def emission_output(mat, tree, colour, x, mode):
    """colour -> colour_chain -> Emission (strength 1) at x -> Material Output (all engines), made
    the active output: how the vertex preview and the baked textures show radiance. INDIRECT: the
    Emission is added (Add Shader) to the shader of the material's own output, whose other inputs
    (volume, displacement) our output takes too, so the material renders as before plus the bake.
    Diffuse rays do not see that Emission (Light Path): it is the bounce light already, which a
    renderer tracing diffuse rays (Cycles, EEVEE's light probes) would otherwise bounce again."""
    emit = node_named(tree, N_EMIT, "ShaderNodeEmission", (x, -400))
    emit.inputs["Strength"].default_value = 1.0
    own = own_output(tree) if mode == "INDIRECT" else None
    for name in (N_SHADER, N_PATH, N_SEEN) if own is None else ():
        if name in tree.nodes:
            tree.nodes.remove(tree.nodes[name])
    out = node_named(tree, N_OUT, "ShaderNodeOutputMaterial", (x + 400, -400))
    out.target = "ALL"
    add = node_named(tree, N_SHADER, "ShaderNodeAddShader", (x + 200, -300)) if own is not None else None
    for lk in [lk for n in (out, add) if n is not None for s in n.inputs for lk in s.links]:
        tree.links.remove(lk)  # wired afresh (the mode or the material's own output changed)
    col = colour_chain(mat, tree, colour, (x - 400, -400), mode)
    tree.links.new(col, emit.inputs["Color"])
    shader = emit.outputs["Emission"]
    if add is not None:
        for s in own.inputs:
            if s.is_linked:
                target = add.inputs[0] if s.name == "Surface" else out.inputs.get(s.name)
                if target is not None:
                    tree.links.new(s.links[0].from_socket, target)
        tree.links.new(shader, add.inputs[1])
        shader = add.outputs[0]
        path = node_named(tree, N_PATH, "ShaderNodeLightPath", (x - 400, -100))
        seen = node_named(tree, N_SEEN, "ShaderNodeMath", (x - 200, -200))
        seen.operation = "LESS_THAN"
        seen.inputs[1].default_value = 0.5
        tree.links.new(path.outputs["Is Diffuse Ray"], seen.inputs[0])
        tree.links.new(seen.outputs[0], emit.inputs["Strength"])
    tree.links.new(shader, out.inputs["Surface"])
    out.is_active_output = True


def _preview_material():
    mat = bpy.data.materials.get(PREVIEW)
    if mat is None or not mat.get("hr_preview"):
        mat = bpy.data.materials.new(PREVIEW)
        mat["hr_preview"] = True
        if bpy.app.version < (5, 0, 0):
            mat.use_nodes = True
    return mat


def add_preview(objects, mode="RADIANCE"):
    """Returns the number of materials switched to the preview. mode: the bake's radiance mode
    (see colour_chain, emission_output)."""
    return finish(add_preview_steps(objects, mode))


def add_preview_steps(objects, mode="RADIANCE", last=False):
    """add_preview a material at a time: a generator yielding after each material it wires (the
    count is its return value), for the UI to spread over timer ticks. Each node it names costs
    Blender a pass over every ID of the file (the node's animation paths): 3,641 materials of the
    furnished 100k room took 30 s CPU in one call. last: the Attribute nodes are named in one last
    step (_add_nodes' name_now: one relations update of Blender's, not one per tick; 0.3 ms a
    node at 100k); the same nodes in the end."""
    done, trees = set(), []
    for obj in objects:
        if obj.type != "MESH":
            continue
        mats = [s.material for s in obj.material_slots if s.material is not None]
        if not mats:
            mat = _preview_material()
            if _add_nodes(mat, mode, name_now=not last) and last:
                trees.append(mat.node_tree)
            obj.data.materials.append(mat)
            yield
            continue
        for m in mats:
            if m.name_full not in done:
                if bpy.app.version < (5, 0, 0) and not m.use_nodes:
                    m.use_nodes = True
                if _add_nodes(m, mode, name_now=not last) and last:
                    trees.append(m.node_tree)
                done.add(m.name_full)
                yield
    for tree in trees:
        _name_attribute(tree)
    if trees:
        yield  # (Blender's relations update falls into the redraw after this step, not the next one)
    return len(done)


def remove_preview(objects=None):
    """Remove the preview nodes from every material (or those of `objects`)."""
    return finish(remove_preview_steps(objects))


def remove_preview_steps(objects=None):
    """remove_preview a material at a time (a generator yielding after each material; the count is
    its return value): removing nodes costs Blender a pass over every ID of the file too (removing
    a named Attribute node costs no relations update: measured)."""
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
        for name in (N_OUT, N_EMIT, N_ATTR, N_MUL, N_ADD, N_SHADER, N_PATH, N_SEEN):
            if name in tree.nodes:
                tree.nodes.remove(tree.nodes[name])
        outs = [x for x in tree.nodes if x.type == "OUTPUT_MATERIAL"]
        if outs and not any(x.is_active_output for x in outs):
            outs[0].is_active_output = True
        n += 1
        yield
    for k, o in enumerate(bpy.data.objects if objects is None else objects):
        if o.type == "MESH":
            for i in reversed(range(len(o.data.materials))):
                m = o.data.materials[i]
                if m is not None and m.get("hr_preview"):
                    o.data.materials.pop(index=i)
        if k % 256 == 255:
            yield  # (3,882 objects' slots at 100k: about 0.1 s)
    return n


def has_preview():
    """True when some material carries preview nodes, is the shared preview material, or is a
    baked-texture helper material (what Remove Preview removes)."""
    for m in bpy.data.materials:
        if m.get("hr_preview") or m.get(TAG) is not None:
            return True
        tree = m.node_tree
        if tree is not None and N_OUT in tree.nodes:
            return True
    return False


def refresh_preview(objects, mode):
    """Re-wire the materials of `objects` that show the preview (a new bake may change the mode)."""
    return finish(refresh_preview_steps(objects, mode))


def refresh_preview_steps(objects, mode):
    """refresh_preview a material at a time (a generator yielding after each material it re-wires)."""
    mats = {s.material for o in objects if o.type == "MESH" for s in o.material_slots if s.material}
    for m in mats:
        if m.node_tree is not None and N_OUT in m.node_tree.nodes:
            _add_nodes(m, mode)
            yield


def wired_mode(tree):
    """The radiance mode a material's preview nodes show."""
    return "INDIRECT" if N_SHADER in tree.nodes else "IRRADIANCE" if N_MUL in tree.nodes else "RADIANCE"


def show_radiance(objects, mode="RADIANCE"):
    """Make `objects` show HR_Radiance as values of `mode` (Live Relight: outgoing radiance, or the
    Indirect-only values): the preview nodes where they are missing ("added"), or a preview of
    another mode re-wired ("rewired"); "" when they show it already. undo_show_radiance() puts
    back what this changed."""
    change = radiance_change(objects, mode)
    finish(show_radiance_steps(objects, mode, change))
    return change


def radiance_change(objects, mode):
    """What show_radiance(objects, mode) has to do: "added", "rewired" or "" (nothing)."""
    mats = [s.material for o in objects for s in o.material_slots if s.material is not None]
    shown = all(m.node_tree is not None and N_OUT in m.node_tree.nodes for m in mats) and all(
        o.material_slots for o in objects
    )
    if not shown:
        return "added"
    if any(wired_mode(m.node_tree) != mode for m in mats):
        return "rewired"
    return ""


def show_radiance_steps(objects, mode, change):
    """show_radiance a material at a time, `change` being radiance_change's answer (Live Relight's
    start spreads it over timer ticks: 3,641 materials took 26 s CPU in one call at 100k). Stopped
    half way, undo_show_radiance(..., change) still puts everything back: "added" removes the
    preview from every material of `objects`, "rewired" wires every one to the bake's mode."""
    if change == "added":
        yield from add_preview_steps(objects, mode, last=True)
    elif change == "rewired":
        yield from refresh_preview_steps(objects, mode)


def undo_show_radiance(scene, objects, change):
    finish(undo_show_radiance_steps(scene, objects, change))


def undo_show_radiance_steps(scene, objects, change):
    """undo_show_radiance a material at a time (Live Relight's stop, over timer ticks)."""
    if change == "added":
        yield from remove_preview_steps(objects)
    elif change == "rewired":
        yield from refresh_preview_steps(objects, bake_mode(scene))
