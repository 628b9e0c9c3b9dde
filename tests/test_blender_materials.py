"""Reading reflectance and emission from Blender materials (hr_addon/blender/materials.py)."""

import numpy as np
import pytest

from test_blender_helpers import empty_scene, load_bpy

pytestmark = pytest.mark.bpy


@pytest.fixture
def env():
    return empty_scene()


def _read(mat):
    from hr_addon.blender.materials import read_material

    return read_material(mat)


def test_principled(env):
    bpy, ms, _ = env
    s = _read(ms.principled("P", (0.2, 0.4, 0.6), (1.0, 0.5, 0.25), 4.0))
    assert np.allclose(s.reflectance, [0.2, 0.4, 0.6])
    assert np.allclose(s.emission, [4.0, 2.0, 1.0])
    assert s.warnings == []


def test_diffuse_and_emission(env):
    bpy, ms, _ = env
    s = _read(ms.diffuse("D", (0.1, 0.2, 0.3)))
    assert np.allclose(s.reflectance, [0.1, 0.2, 0.3]) and np.allclose(s.emission, 0)
    s = _read(ms.emission("E", (0.5, 1.0, 0.25), 8.0))
    assert np.allclose(s.reflectance, 0) and np.allclose(s.emission, [4.0, 8.0, 2.0])


def test_no_material_is_default_grey(env):
    from hr_addon.blender.materials import DEFAULT_REFLECTANCE

    s = _read(None)
    assert DEFAULT_REFLECTANCE == 0.8
    assert np.allclose(s.reflectance, 0.8) and np.allclose(s.emission, 0) and s.warnings == []


def test_mix_and_add(env):
    bpy, ms, _ = env
    m = bpy.data.materials.new("Mix")
    t = m.node_tree
    for n in list(t.nodes):
        if n.type != "OUTPUT_MATERIAL":
            t.nodes.remove(n)
    d = t.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (0.6, 0.6, 0.6, 1)
    e = t.nodes.new("ShaderNodeEmission")
    e.inputs["Color"].default_value = (1, 1, 1, 1)
    e.inputs["Strength"].default_value = 2.0
    mix = t.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.25
    t.links.new(d.outputs[0], mix.inputs[1])
    t.links.new(e.outputs[0], mix.inputs[2])
    t.links.new(mix.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    s = _read(m)
    assert np.allclose(s.reflectance, 0.45) and np.allclose(s.emission, 0.5)
    add = t.nodes.new("ShaderNodeAddShader")
    t.links.new(d.outputs[0], add.inputs[0])
    t.links.new(e.outputs[0], add.inputs[1])
    t.links.new(add.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    s = _read(m)
    assert np.allclose(s.reflectance, 0.6) and np.allclose(s.emission, 2.0)


def test_image_texture_average(env):
    bpy, ms, _ = env
    from mathutils import Color

    img = bpy.data.images.new("Tex", 4, 4)  # 8-bit sRGB
    px = np.zeros((16, 4), np.float32)
    px[:8] = (1.0, 0.0, 0.0, 1.0)
    px[8:] = (0.0, 0.0, 1.0, 1.0)
    img.pixels.foreach_set(px.ravel())
    m = ms.principled("Textured", (0.5, 0.5, 0.5))
    tex = m.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    m.node_tree.links.new(tex.outputs["Color"], m.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    s = _read(m)
    assert np.allclose(s.reflectance, [0.5, 0, 0.5], atol=1e-6), s.reflectance
    # Mid grey 0.5 (8-bit 128) is linearised from sRGB before averaging.
    px[:] = (0.5, 0.5, 0.5, 1.0)
    img.pixels.foreach_set(px.ravel())
    img.update()
    s = _read(m)
    assert np.allclose(s.reflectance, Color((128 / 255,) * 3).from_srgb_to_scene_linear()[0], atol=1e-4)
    # A float (linear) image is averaged as is.
    imgf = bpy.data.images.new("TexF", 2, 2, float_buffer=True)
    imgf.pixels.foreach_set(np.array([0.2, 0.2, 0.2, 1] * 2 + [0.6, 0.6, 0.6, 1] * 2, np.float32))
    tex.image = imgf
    assert np.allclose(_read(m).reflectance, 0.4, atol=1e-6)


def test_srgb_curves_match_blender():
    """io.images' sRGB pair (material textures, PNG lightmaps) against Blender's colour management."""
    load_bpy()
    from mathutils import Color
    from hr_addon.io.images import linear_to_srgb, srgb_to_linear

    x = np.linspace(0.0, 1.0, 501)
    to_lin = np.array([Color((v, v, v)).from_srgb_to_scene_linear()[0] for v in x])
    to_srgb = np.array([Color((v, v, v)).from_scene_linear_to_srgb()[0] for v in x])
    np.testing.assert_allclose(srgb_to_linear(x), to_lin, atol=1e-6)
    # Blender's linear -> sRGB direction is an approximation (up to 1.1e-4 off the curve; its
    # sRGB -> linear is exact to 4e-7), hence the looser bound, and the exact round trip
    np.testing.assert_allclose(linear_to_srgb(x), to_srgb, atol=2e-4)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)


def test_unsupported_shader_warns_and_falls_back(env):
    bpy, ms, _ = env
    m = bpy.data.materials.new("Glassy")
    t = m.node_tree
    for n in list(t.nodes):
        if n.type != "OUTPUT_MATERIAL":
            t.nodes.remove(n)
    g = t.nodes.new("ShaderNodeBsdfGlass")
    t.links.new(g.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    s = _read(m)
    assert np.allclose(s.reflectance, 0.8) and np.allclose(s.emission, 0)
    assert len(s.warnings) == 1 and "'Glassy'" in s.warnings[0] and "Glass" in s.warnings[0]


def test_unsupported_colour_input_warns(env):
    bpy, ms, _ = env
    m = ms.principled("Noisy", (0.3, 0.3, 0.3))
    noise = m.node_tree.nodes.new("ShaderNodeTexNoise")
    m.node_tree.links.new(noise.outputs["Color"], m.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    s = _read(m)
    assert np.allclose(s.reflectance, 0.3)
    assert s.warnings and "'Noisy'" in s.warnings[0]


def test_reflectance_clamped_with_warning(env):
    bpy, ms, _ = env
    s = _read(ms.diffuse("Snow", (1.0, 0.5, 1.2)))
    assert np.allclose(s.reflectance, [0.99, 0.5, 0.99])
    assert len(s.warnings) == 1 and "'Snow'" in s.warnings[0] and "clamped" in s.warnings[0]


def test_emission_keyframes_are_evaluated(env):
    bpy, ms, scene = env
    from hr_addon.blender.materials import read_material

    m = ms.emission("Anim", (1, 1, 1), 1.0)
    ms.mesh_object(
        "Plane", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [[0, 1, 2, 3]], m
    )  # in the depsgraph
    s = m.node_tree.nodes["Emission"].inputs["Strength"]
    s.keyframe_insert("default_value", frame=1)
    s.default_value = 9.0
    s.keyframe_insert("default_value", frame=9)
    scene.frame_set(9)
    dg = bpy.context.evaluated_depsgraph_get()
    assert np.allclose(read_material(m.evaluated_get(dg)).emission, 9.0)
    scene.frame_set(1)
    dg = bpy.context.evaluated_depsgraph_get()
    assert np.allclose(read_material(m.evaluated_get(dg)).emission, 1.0)


def test_albedo_texture_simple_cases_only(env):
    """materials.albedo_texture: an Image Texture on Base Color (default UV map, or a UV Map node,
    or through one Mix node with a colour) qualifies; the reader's average goes with it. Other
    setups give a reason naming why (the bake then keeps the average and says so)."""
    bpy, ms, _ = env
    from hr_addon.blender.materials import albedo_texture, base_color_socket

    img = bpy.data.images.new("T", 2, 2, float_buffer=True)
    img.pixels.foreach_set(np.array([0.2, 0.4, 0.6, 1] * 2 + [0.6, 0.4, 0.2, 1] * 2, np.float32))
    m = ms.principled("Tex", (0.5, 0.5, 0.5))
    t = m.node_tree
    bsdf = t.nodes["Principled BSDF"]
    tex = t.nodes.new("ShaderNodeTexImage")
    tex.image = img
    t.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    spec, why = albedo_texture(m)
    assert why == "" and spec.uv_map == "" and spec.mix is None and spec.pixels.shape == (2, 2, 3)
    np.testing.assert_allclose(spec.average, 0.4, atol=1e-6)
    assert base_color_socket(m) == bsdf.inputs["Base Color"]
    uvn = t.nodes.new("ShaderNodeUVMap")
    uvn.uv_map = "Paint"
    t.links.new(uvn.outputs["UV"], tex.inputs["Vector"])
    assert albedo_texture(m)[0].uv_map == "Paint"
    # through a Multiply with a colour: the reader averages the mix, the spec carries it
    mix = t.nodes.new("ShaderNodeMix")
    mix.data_type, mix.blend_type = "RGBA", "MULTIPLY"
    ids = {s.identifier: s for s in mix.inputs}
    ids["Factor_Float"].default_value = 1.0
    ids["B_Color"].default_value = (0.5, 1.0, 1.0, 1.0)
    t.links.new(tex.outputs["Color"], ids["A_Color"])
    t.links.new(next(s for s in mix.outputs if s.identifier == "Result_Color"), bsdf.inputs["Base Color"])
    spec, why = albedo_texture(m)
    assert why == "" and spec.mix[0] == "MULTIPLY" and spec.mix[3] is True
    np.testing.assert_allclose(spec.average, [0.2, 0.4, 0.4], atol=1e-6)
    np.testing.assert_allclose(_read(m).reflectance, [0.2, 0.4, 0.4], atol=1e-6)
    # a Mapping node on the vector: not followed
    mp = t.nodes.new("ShaderNodeMapping")
    t.links.new(mp.outputs[0], tex.inputs["Vector"])
    spec, why = albedo_texture(m)
    assert spec is None and "Image Texture" in why
    # no texture at all: nothing to say
    assert albedo_texture(ms.diffuse("Plain", (0.3, 0.3, 0.3))) == (None, "")
    assert albedo_texture(None) == (None, "")


def _group_material(bpy, name, color_outside):
    """A material whose Emission shader sits inside a node group (Group node -> Material Output).
    color_outside: the group's Color and Strength inputs are set on the Group node (else inside)."""
    g = bpy.data.node_groups.new(name + "Group", "ShaderNodeTree")
    g.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    gin = g.nodes.new("NodeGroupInput")
    gout = g.nodes.new("NodeGroupOutput")
    e = g.nodes.new("ShaderNodeEmission")
    reroute = g.nodes.new("NodeReroute")
    g.links.new(e.outputs[0], reroute.inputs[0])
    g.links.new(reroute.outputs[0], gout.inputs[0])
    if color_outside:
        g.interface.new_socket("Color", in_out="INPUT", socket_type="NodeSocketColor")
        g.interface.new_socket("Strength", in_out="INPUT", socket_type="NodeSocketFloat")
        g.links.new(gin.outputs["Color"], e.inputs["Color"])
        g.links.new(gin.outputs["Strength"], e.inputs["Strength"])
        e.inputs["Color"].default_value = (0.1, 0.1, 0.1, 1)  # not used: the Group node's are
        e.inputs["Strength"].default_value = 99.0
    else:
        e.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1)
        e.inputs["Strength"].default_value = 4.0
    m = bpy.data.materials.new(name)
    t = m.node_tree
    for n in list(t.nodes):
        if n.type != "OUTPUT_MATERIAL":
            t.nodes.remove(n)
    grp = t.nodes.new("ShaderNodeGroup")
    grp.node_tree = g
    if color_outside:
        grp.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1)
        val = t.nodes.new("ShaderNodeValue")
        val.outputs[0].default_value = 4.0
        t.links.new(val.outputs[0], grp.inputs["Strength"])
    out = next(n for n in t.nodes if n.type == "OUTPUT_MATERIAL")
    t.links.new(grp.outputs[0], out.inputs["Surface"])
    return m


@pytest.mark.parametrize("color_outside", [False, True])
def test_emission_inside_a_node_group(env, color_outside):
    """A node group used as the material output turned an emitter black (grey, no emission): the
    Group node is followed to its Group Output, and its inputs back out to the Group node's."""
    bpy, ms, _ = env
    s = _read(_group_material(bpy, "Grouped", color_outside))
    assert s.warnings == []
    assert np.allclose(s.emission, [4.0, 2.0, 1.0]) and np.allclose(s.reflectance, 0)


def test_diffuse_colour_inside_a_node_group_and_two_uses(env):
    """The same group used twice (its Color input set differently) is read per use."""
    bpy, ms, _ = env
    g = bpy.data.node_groups.new("Paint", "ShaderNodeTree")
    g.interface.new_socket("Color", in_out="INPUT", socket_type="NodeSocketColor")
    g.interface.new_socket("BSDF", in_out="OUTPUT", socket_type="NodeSocketShader")
    gin, gout = g.nodes.new("NodeGroupInput"), g.nodes.new("NodeGroupOutput")
    d = g.nodes.new("ShaderNodeBsdfDiffuse")
    g.links.new(gin.outputs["Color"], d.inputs["Color"])
    g.links.new(d.outputs[0], gout.inputs["BSDF"])
    m = bpy.data.materials.new("TwoPaints")
    t = m.node_tree
    for n in list(t.nodes):
        if n.type != "OUTPUT_MATERIAL":
            t.nodes.remove(n)
    a, b = t.nodes.new("ShaderNodeGroup"), t.nodes.new("ShaderNodeGroup")
    a.node_tree = b.node_tree = g
    a.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1)
    b.inputs["Color"].default_value = (0.6, 0.2, 0.0, 1)
    mix = t.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.5
    t.links.new(a.outputs[0], mix.inputs[1])
    t.links.new(b.outputs[0], mix.inputs[2])
    out = next(n for n in t.nodes if n.type == "OUTPUT_MATERIAL")
    t.links.new(mix.outputs[0], out.inputs["Surface"])
    s = _read(m)
    assert s.warnings == []
    assert np.allclose(s.reflectance, [0.4, 0.3, 0.3]) and np.allclose(s.emission, 0)


def test_node_group_without_output_is_named(env):
    bpy, ms, _ = env
    m = _group_material(bpy, "Broken", False)
    g = bpy.data.node_groups["BrokenGroup"]
    for lk in list(g.links):
        if lk.to_node.type == "GROUP_OUTPUT":
            g.links.remove(lk)
    s = _read(m)
    assert any("'Broken'" in w and "node group 'BrokenGroup'" in w for w in s.warnings), s.warnings
