"""Textured surfaces (issue: the output lost the texture): the irradiance mode against Cycles' Diffuse
bake without Color, the texture output modulated by the Image Texture's albedo against the Diffuse
bake with Color, and the preview materials that multiply irradiance by the base colour.

Scene: make_samples.textured_room(), a 3 x 3 x 2.4 m room, a 0.8 m ceiling emitter (strength 12),
the floor a Principled BSDF whose Base Color is an 8 x 8 checker Image Texture (0.8/0.62/0.4 and
0.08/0.09/0.12, float image) in the default UV map. Our bake: Baked Textures at RES texels, medium
quality. Cycles: the same HR_Lightmap UVs, one-sided Diffuse reference materials (the floor's fed
by the same image through the same UV map), SPP samples (hr_testing/cycles_ref.py settings).
Only texels whose centre lies in a UV triangle are compared (what Cycles bakes with margin 0).

Tolerances (see docs/accuracy.md, "Textured surfaces"), with the values measured at these settings:
- irradiance, every surface but the emitter: |mean ours - mean Cycles| / mean Cycles <= MRE_TOL,
  the tolerance of test_cycles_agreement.py (measured 0.5-1.0%, ours darker); all texels: bias
  within +-BIAS_TOL (measured -0.75%), texel RMSE <= RMSE_TOL x mean (measured 0.088, mostly
  Cycles noise at SPP samples);
- floor, outgoing radiance with the texture: texel RMSE <= MOD_RMSE_TOL x mean (measured 0.065;
  median texel error 4%), bias within +-BIAS_TOL (-0.6%); the same light with the average albedo
  (the output before this mode) >= FLAT_RMSE_MIN x mean (measured 0.76; median texel error 45%).
"""

import os

import numpy as np
import pytest

from test_blender_helpers import empty_scene, read_image

pytestmark = [pytest.mark.bpy]

RES = 48
SPP = 64
MRE_TOL = 0.04
BIAS_TOL = 0.03
RMSE_TOL = 0.22
MOD_RMSE_TOL = 0.12
FLAT_RMSE_MIN = 0.5
SURFACES = ["ceiling", "floor", "wall_x0", "wall_x1", "wall_y0", "wall_y1"]


def _bake(scene, **kw):
    from hr_addon.blender.bake import run_bake

    kw.setdefault("quality", "medium")
    return run_bake(
        scene,
        log=lambda *a, **k: None,
        output="texture",
        resolution=RES,
        texel_density=0,
        frames=(1, 1),
        **kw,
    )


def _textures(cache):
    return {n: read_image(cache / "textures" / f"{n}_000001.exr") for n in SURFACES + ["light"]}


def _cycles_bakes(bpy, objs, passes):
    """Cycles Diffuse bakes into RES x RES images in HR_Lightmap: {pass name: {object: (RES, RES, 4)}}."""
    from hr_testing import cycles_ref as C

    scene = bpy.context.scene
    images = {}
    for name, ob in objs.items():
        # the floor: the same image through the same UV map as the user's material
        ref = C.reference_material(f"REF_{name}", ob.material_slots[0].material, textured=name == "floor")
        t = ref.node_tree
        img = bpy.data.images.new(f"REFIMG_{name}", RES, RES, alpha=True, float_buffer=True)
        img.colorspace_settings.name = "Non-Color"
        target = t.nodes.new("ShaderNodeTexImage")
        target.image = img
        t.nodes.active = target
        ob.material_slots[0].link = "OBJECT"
        ob.material_slots[0].material = ref
        lay = ob.data.uv_layers["HR_Lightmap"]
        ob.data.uv_layers.active = lay
        lay.active_render = True
        images[name] = img
    C.configure_cycles(scene, SPP, seed=1, threads=os.cpu_count() or 1)
    for ob in bpy.context.view_layer.objects:
        ob.select_set(ob.name in objs)
    bpy.context.view_layer.objects.active = objs["floor"]
    out = {}
    for key, pf in passes.items():
        for img in images.values():
            C.clear_image(img)
        bpy.ops.object.bake(
            type="DIFFUSE", pass_filter=pf, margin=0, use_clear=False, target="IMAGE_TEXTURES"
        )
        out[key] = {}
        for name, img in images.items():
            px = np.empty(RES * RES * 4, np.float32)
            img.pixels.foreach_get(px)
            out[key][name] = px.reshape(RES, RES, 4).astype(np.float64)
    return out


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    bpy, ms, scene = empty_scene()
    objs = ms.textured_room()
    d = tmp_path_factory.mktemp("albedo")
    bpy.ops.wm.save_as_mainfile(filepath=str(d / "room.blend"))
    from hr_addon.blender.materials import read_material

    cache = d / "hr_cache" / "room"
    res = _bake(scene, radiance_mode="RADIANCE")
    assert res.warnings == [], res.warnings
    rad = _textures(cache)
    res = _bake(scene, radiance_mode="IRRADIANCE")
    assert res.warnings == [], res.warnings
    irr = _textures(cache)
    avg = read_material(objs["floor"].material_slots[0].material).reflectance
    cyc = _cycles_bakes(
        bpy,
        {n: objs[n] for n in SURFACES + ["light"]},
        {"irr": {"DIRECT", "INDIRECT"}, "col": {"DIRECT", "INDIRECT", "COLOR"}},
    )
    return {"rad": rad, "irr": irr, "cyc": cyc, "avg": avg}


def _pairs(ours, ref):
    """(ours, ref) at the texels Cycles baked (alpha set: centre inside a UV triangle)."""
    m = ref[..., 3] > 0.5
    return ours[m].astype(np.float64), ref[..., :3][m]


@pytest.mark.cycles
def test_irradiance_mode_matches_cycles_diffuse_bake_without_color(room):
    from hr_testing import cycles_ref as C

    per, allo, allr = {}, [], []
    for n in SURFACES:
        o, r = _pairs(room["irr"][n], room["cyc"]["irr"][n])
        assert len(o) > 500, n
        per[n] = C.metrics(o, r)
        allo.append(o)
        allr.append(r)
    bad = {n: round(m["mre"], 4) for n, m in per.items() if m["mre"] > MRE_TOL}
    assert not bad, f"surface mean irradiance differs from Cycles by more than {MRE_TOL:.0%}: {bad}"
    m = C.metrics(np.concatenate(allo), np.concatenate(allr))
    assert abs(m["bias"]) <= BIAS_TOL and m["rel_rmse"] <= RMSE_TOL, m
    # no emission in the irradiance mode: the emitter holds the light it receives, far below its own
    assert room["irr"]["light"].max() < 0.5 * 12


@pytest.mark.cycles
def test_texture_output_carries_the_albedo_texture(room):
    """Outgoing radiance on the textured floor = Cycles' Diffuse bake with Color per texel; the same
    light with the average albedo (what the output was before) is not."""
    from hr_testing import cycles_ref as C

    ref = room["cyc"]["col"]["floor"]
    o, r = _pairs(room["rad"]["floor"], ref)
    flat, _ = _pairs(room["irr"]["floor"] * room["avg"], ref)
    mod = C.metrics(o, r)
    avg = C.metrics(flat, r)
    assert mod["rel_rmse"] <= MOD_RMSE_TOL, mod
    assert avg["rel_rmse"] >= FLAT_RMSE_MIN, avg
    assert abs(mod["bias"]) <= BIAS_TOL, mod
    # both modes see the same light: radiance = irradiance x the texture's albedo (no emission here)
    io, _ = _pairs(room["irr"]["floor"], ref)
    ratio = o / np.maximum(io, 1e-9)
    assert ratio.max() > 5 * ratio.min()  # the checker's two colours (0.8 against 0.08)
    # untextured walls: the outgoing radiance is the irradiance times their reflectance
    w, _ = _pairs(room["rad"]["wall_x0"], room["cyc"]["col"]["wall_x0"])
    wi, _ = _pairs(room["irr"]["wall_x0"], room["cyc"]["col"]["wall_x0"])
    np.testing.assert_allclose(w, wi * [0.7, 0.2, 0.15], rtol=2e-3, atol=1e-5)


def _camera_down(bpy, scene, size=(3.0, 3.0, 2.4)):
    cam = bpy.data.cameras.new("Top")
    cam.type = "ORTHO"
    cam.ortho_scale = size[0]
    ob = bpy.data.objects.new("Top", cam)
    scene.collection.objects.link(ob)
    ob.location = (size[0] / 2, size[1] / 2, 2.0)  # below the emitter, looking straight down
    scene.camera = ob


def _render(bpy, scene, path, px=32):
    r = scene.render
    r.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.device, scene.cycles.use_denoising = 4, "CPU", False
    r.resolution_x = r.resolution_y = px
    r.resolution_percentage = 100
    r.image_settings.file_format = "OPEN_EXR"
    scene.view_settings.view_transform = "Standard"
    r.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return read_image(path)


@pytest.mark.cycles
def test_preview_multiplies_irradiance_by_the_base_colour(tmp_path):
    """Irradiance bakes: the helper material (textures) and the preview nodes (vertex colours) feed
    the Emission with irradiance x the material's own base colour input (the checker image, linked)
    + its emission; a render of the floor shows the checker. Outgoing radiance: no multiply."""
    bpy, ms, scene = empty_scene()
    objs = ms.textured_room()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "room.blend"))
    from hr_addon.blender import names, preview, texture

    checker = objs["floor"].data.materials[0].node_tree.nodes["Image Texture"].image
    from hr_addon.blender.bake import run_bake

    def bake(**kw):
        run_bake(
            scene,
            log=lambda *a, **k: None,
            frames=(1, 1),
            quality="draft",
            resolution=32,
            texel_density=0,
            **kw,
        )

    bake(output="TEXTURE", radiance_mode="IRRADIANCE")
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    mat = objs["floor"].material_slots[0].material
    nodes = mat.node_tree.nodes
    assert mat[texture.TAG] == "floor"
    mul = nodes[preview.N_MUL]
    a, b = (next(s for s in mul.inputs if s.identifier == k) for k in ("A_Color", "B_Color"))
    assert mul.blend_type == "MULTIPLY" and a.links[0].from_node.name == texture.N_TEX
    src = b.links[0].from_node
    assert src.type == "TEX_IMAGE" and src.image == checker and src.name != texture.N_TEX
    emit = nodes[names.N_EMIT]
    assert emit.inputs["Color"].links[0].from_node.name == preview.N_ADD
    lamp = objs["light"].material_slots[0].material.node_tree.nodes
    np.testing.assert_allclose(lamp[preview.N_ADD].inputs[1].default_value, [12.0, 11.4, 10.2], rtol=1e-6)
    wall = objs["wall_x0"].material_slots[0].material.node_tree.nodes[preview.N_MUL]
    wall_b = next(s for s in wall.inputs if s.identifier == "B_Color")
    assert not wall_b.is_linked and np.allclose(wall_b.default_value[:3], [0.7, 0.2, 0.15])
    # a render of the floor from above: the two checker colours (albedo 0.8 against 0.08 in red)
    _camera_down(bpy, scene)
    img = _render(bpy, scene, tmp_path / "top.exr")
    lo, hi = np.percentile(img[..., 0], [10, 90])
    assert hi > 5 * lo, (lo, hi)
    irr = read_image(tmp_path / "hr_cache" / "room" / "textures" / "floor_000001.exr")
    assert img[..., 0].max() <= 1.05 * 0.8 * irr[..., 0].max()
    # vertex colours, irradiance: the preview nodes multiply by the same base colour input
    bake(output="VERTEX", radiance_mode="IRRADIANCE")
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    user = objs["floor"].data.materials[0]
    assert objs["floor"].material_slots[0].material == user
    mul = user.node_tree.nodes[preview.N_MUL]
    b = next(s for s in mul.inputs if s.identifier == "B_Color")
    assert b.links[0].from_node.image == checker
    # a radiance bake re-wires the preview without the multiply; Remove Preview removes it all
    bake(output="VERTEX", radiance_mode="RADIANCE")
    assert preview.N_MUL not in user.node_tree.nodes and preview.N_OUT in user.node_tree.nodes
    emit = user.node_tree.nodes[preview.N_EMIT]
    assert emit.inputs["Color"].links[0].from_node.name == preview.N_ATTR
    assert bpy.ops.hr.remove_preview() == {"FINISHED"}
    assert not [n for n in user.node_tree.nodes if n.name.startswith("HR Preview")]


def test_unfollowed_texture_setup_keeps_the_average_and_says_so(tmp_path):
    bpy, ms, scene = empty_scene()
    objs = ms.textured_room()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "room.blend"))
    from hr_addon.blender.bake import run_bake

    t = objs["floor"].data.materials[0].node_tree
    mp = t.nodes.new("ShaderNodeMapping")
    t.links.new(mp.outputs[0], t.nodes["Image Texture"].inputs["Vector"])
    res = run_bake(
        scene,
        log=lambda *a, **k: None,
        frames=(1, 1),
        quality="draft",
        output="TEXTURE",
        resolution=16,
        texel_density=0,
    )
    w = [x for x in res.warnings if "Checker Floor" in x]
    assert len(w) == 1 and "average colour" in w[0], res.warnings
    img = read_image(tmp_path / "hr_cache" / "room" / "textures" / "floor_000001.exr")
    assert img[4:12, 4:12, 0].max() < 2.0 * img[4:12, 4:12, 0].min()  # smooth light, no checker


def test_command_line_radiance_mode_and_partial_bakes(tmp_path, capsys):
    """--radiance-mode goes into the manifest; a bake in the other mode does not keep its frames."""
    bpy, ms, scene = empty_scene()
    ms.textured_room()
    path = tmp_path / "room.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    from hr_addon.blender import cli
    from hr_addon.io.cache import CacheReader

    args = [str(path), "--quality", "draft", "--output", "vertex"]
    assert cli.run(args + ["--frames", "1-1", "--radiance-mode", "irradiance"]) == 0
    cache = tmp_path / "hr_cache" / "room"
    assert CacheReader(cache).manifest["radiance_mode"] == "IRRADIANCE"
    capsys.readouterr()
    assert cli.run(args + ["--frames", "2-2"]) == 0  # the scene's setting: outgoing radiance
    out = capsys.readouterr().out
    assert "discarded: it used radiance mode irradiance (this bake: radiance)" in out, out
    m = CacheReader(cache).manifest
    assert m["radiance_mode"] == "RADIANCE" and sorted(m["frames"]) == ["2"], m["frames"]


def test_live_relight_shows_radiance_through_an_irradiance_preview(tmp_path):
    """Live writes outgoing radiance: while it runs the preview does not multiply by the base colour;
    when it ends the irradiance bake's preview multiplies again."""
    bpy, ms, scene = empty_scene()
    objs = ms.textured_room()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "room.blend"))
    from hr_addon.blender import preview
    from hr_addon.blender.bake import run_bake

    run_bake(scene, log=lambda *a, **k: None, frames=(1, 1), quality="draft", radiance_mode="IRRADIANCE")
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    tree = objs["floor"].data.materials[0].node_tree
    assert preview.N_MUL in tree.nodes
    assert bpy.ops.hr.live_toggle() == {"FINISHED"}  # on (background mode: computes at once)
    assert preview.N_MUL not in tree.nodes and preview.N_OUT in tree.nodes
    assert bpy.ops.hr.live_toggle() == {"FINISHED"}  # off: the bake's playback and preview again
    assert preview.N_MUL in tree.nodes


@pytest.mark.cycles
@pytest.mark.parametrize("float_image", [False, True])
def test_texel_albedo_samples_the_image_like_cycles(float_image):
    """The albedo the texture output uses (albedo_texture + lightmap.albedo.sample_image) against
    Cycles' Emit bake of the same Image Texture into an Emission shader (128 x 4 texels over a 4 x 1
    image): bilinear between pixel centres, Repeat at the edges, 8-bit sRGB interpolated as stored,
    then linearised, as Cycles does (linearising first is up to 0.28 off between the pixels)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.materials import albedo_texture
    from hr_addon.io.images import srgb_to_linear
    from hr_addon.lightmap.albedo import sample_image

    img = bpy.data.images.new("Row", 4, 1, float_buffer=float_image)
    img.pixels.foreach_set(
        np.array([[v, 0.5 * v, 1 - v, 1] for v in (0.0, 1.0, 0.2, 0.7)], np.float32).ravel()
    )
    m, t = ms._bare_material("Tex")
    bsdf = t.nodes.new("ShaderNodeBsdfDiffuse")
    tex = t.nodes.new("ShaderNodeTexImage")
    tex.image = img
    t.links.new(tex.outputs["Color"], bsdf.inputs["Color"])
    t.links.new(bsdf.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    spec, why = albedo_texture(m)
    assert why == "" and spec.srgb is not float_image
    # Cycles: the same texture as emission, baked in the plane's UV map
    em = t.nodes.new("ShaderNodeEmission")
    t.links.new(tex.outputs["Color"], em.inputs["Color"])
    t.links.new(em.outputs[0], t.nodes["Material Output"].inputs["Surface"])
    out = bpy.data.images.new("Out", 128, 4, float_buffer=True)
    out.colorspace_settings.name = "Non-Color"
    target = t.nodes.new("ShaderNodeTexImage")
    target.image = out
    t.nodes.active = target
    ob = ms.mesh_object("P", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [[0, 1, 2, 3]], m)
    ob.data.uv_layers.new(name="UVMap").uv.foreach_set(
        "vector", np.array([0, 0, 1, 0, 1, 1, 0, 1], np.float32)
    )
    bpy.context.view_layer.objects.active = ob
    ob.select_set(True)
    scene.cycles.samples = 16
    bpy.ops.object.bake(type="EMIT", margin=0)
    px = np.empty(128 * 4 * 4, np.float32)
    out.pixels.foreach_get(px)
    got = px.reshape(4, 128, 4)[2, :, :3]  # v = 0.625: the image has one row
    uv = np.column_stack([(np.arange(128) + 0.5) / 128, np.full(128, 0.625)])
    want = sample_image(spec.pixels, uv, spec.interpolation, spec.extension)
    want = srgb_to_linear(want) if spec.srgb else want
    np.testing.assert_allclose(got, want, atol=0.015)
    if not float_image:
        assert np.abs(sample_image(srgb_to_linear(spec.pixels), uv) - got).max() > 0.1
