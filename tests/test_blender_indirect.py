"""Values "Indirect only (for EEVEE)" (issue 20, docs/lights.md): the bake's values are the
Irradiance values without the Blender lights' and the World's direct light (core.lights
.indirect_incident), in vertex and texture output, in Live Relight and on the command line; the
preview adds base colour x HR_Radiance to the material's own shader and takes it off again.

Scene: the factory scene (a 2 m cube, a 1000 W point light of radius 0.1, its grey World) plus an
emissive panel (Principled, base colour 0.5, emission 3) beside the cube's -X face, reaching above
its top: the -X and +Z faces see it, the panel is lit by the lamp, so those faces get the panel's
own light and the lamp's light bounced off it."""

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, read_image
from tests import closed_forms as cf

pytestmark = pytest.mark.bpy

pytest.importorskip("bpy")

# face normals (the factory cube is axis-aligned) whose hemisphere the panel does not enter
OPEN_SKY = ((1, 0, 0), (0, -1, 0), (0, 0, -1), (0, 1, 0))


def _scene(tmp_path, lamp=True, world=False):
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_factory_startup=True)
    from test_blender_helpers import make_samples_module

    ms = make_samples_module()
    scene = bpy.context.scene
    scene.hr.use_world = world
    scene.hr.quality = "DRAFT"
    scene.hr.vertex_spacing = 0  # the modes' analytic light at the cube's own corners (spacing: own tests)
    if not lamp:
        bpy.data.objects.remove(bpy.data.objects["Light"])
    verts = [(-2.5, -0.5, 0.5), (-2.5, 0.5, 0.5), (-2.5, 0.5, 2.5), (-2.5, -0.5, 2.5)]  # facing +X
    ms.mesh_object("Panel", verts, [[0, 1, 2, 3]], ms.principled("Glow", (0.5, 0.5, 0.5), strength=3.0))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "indirect.blend"), check_existing=False)
    return bpy


def _bake(tmp_path, mode, sub=None, **kw):
    import bpy
    from hr_addon.blender.bake import run_bake

    kw.setdefault("frames", (1, 1))
    kw.setdefault("method", "FE")
    res = run_bake(
        bpy.context.scene,
        log=lambda *a, **k: None,
        cache_dir=str(tmp_path / (sub or mode.lower())),
        radiance_mode=mode,
        **kw,
    )
    return res


def _cube_values():
    import bpy

    return attribute(bpy.data.objects["Cube"])[:, :3].astype(np.float64)


def _faces(bpy):
    """Per face of the cube: (world normal, loop indices, world sample points of its loops: half
    way from the corner to the face's centre, gather.loop_samples)."""
    cube = bpy.data.objects["Cube"]
    me, M = cube.data, np.array(cube.matrix_world)
    out = []
    for poly in me.polygons:
        nrm = M[:3, :3] @ np.array(poly.normal)
        centre = M[:3, :3] @ np.array(poly.center) + M[:3, 3]
        loops = list(poly.loop_indices)
        pts = []
        for li in loops:
            p = M[:3, :3] @ np.array(me.vertices[me.loops[li].vertex_index].co) + M[:3, 3]
            pts.append(p + 0.5 * (centre - p))
        out.append((nrm / np.linalg.norm(nrm), loops, pts))
    return out


@pytest.mark.parametrize("world", [False, True])
def test_indirect_is_irradiance_without_the_lamps_and_the_worlds_direct_light(tmp_path, world):
    """Per corner sample of the cube: Irradiance - Indirect = the point light's E / pi from its
    closed form in Cycles' units (tests/closed_forms.py) where the lamp sees the sample, 0 where
    not, plus the World's L on faces under open sky (every sky ray escapes there); Indirect keeps
    the panel's light and the lamp's bounce off it (> 0 on the faces that see the panel)."""
    bpy = _scene(tmp_path, world=world)
    res = _bake(tmp_path, "IRRADIANCE")
    assert not [w for w in res.warnings if "Nothing" in w], res.warnings
    irr = _cube_values()
    _bake(tmp_path, "INDIRECT")
    ind = _cube_values()
    assert (ind >= 0).all()
    bg = bpy.context.scene.world.node_tree.nodes["Background"]
    sky = np.array(bg.inputs["Color"].default_value[:3]) * bg.inputs["Strength"].default_value
    light = bpy.data.objects["Light"]
    c, r, P = np.array(light.location), light.data.shadow_soft_size, light.data.energy
    checked = 0
    for nrm, loops, pts in _faces(bpy):
        open_sky = any(np.allclose(nrm, n, atol=1e-6) for n in OPEN_SKY)
        if world and not open_sky:
            continue  # the panel hides part of the sky: no closed form for the World there
        centre = np.mean(pts, 0)
        if 0 < (c - centre) @ nrm < 2 * r:
            continue  # the lamp's sphere straddles the face's plane (the factory +Y face)
        for li, x in zip(loops, pts):
            d = c - x
            dist = np.linalg.norm(d)
            cos = d @ nrm / dist
            E = cf.point_light_irradiance(P, dist, cos, r) if cos > 0 else 0.0
            want = E / np.pi + (sky if world else 0.0)
            # the same float32 parts subtracted (measured: 1.4e-7 of the closed form at most)
            assert irr[li] - ind[li] == pytest.approx(np.full(3, want), rel=1e-5, abs=1e-6 * irr.max())
            checked += 1
    assert checked == (12 if world else 20)
    sees_panel = [loops for nrm, loops, _ in _faces(bpy) if nrm[0] < -0.99 or nrm[2] > 0.99]
    for loops in sees_panel:
        assert ind[loops].min() > 0.01 * irr.max(), ind[loops]


def test_indirect_equals_irradiance_without_lamps_and_world(tmp_path):
    """Only an emissive mesh lights the scene: its direct light stays (EEVEE does not light with
    meshes), so Indirect only equals Irradiance, in vertex and in texture output; with the lamp the
    texture's Indirect values lie between 0 and its Irradiance values and below them where the
    lamp shines."""
    _scene(tmp_path, lamp=False)
    _bake(tmp_path, "IRRADIANCE")
    irr = _cube_values()
    _bake(tmp_path, "INDIRECT")
    ind = _cube_values()
    assert irr.max() > 0
    np.testing.assert_array_equal(ind, irr)
    tex = {}
    for mode in ("IRRADIANCE", "INDIRECT"):
        _bake(tmp_path, mode, f"tex_{mode}", output="TEXTURE", resolution=16, texel_density=0)
        tex[mode] = read_image(tmp_path / f"tex_{mode}" / "textures" / "Cube_000001.exr")
    assert tex["IRRADIANCE"].max() > 0
    np.testing.assert_array_equal(tex["INDIRECT"], tex["IRRADIANCE"])
    _scene(tmp_path)
    for mode in ("IRRADIANCE", "INDIRECT"):
        _bake(tmp_path, mode, f"lamp_{mode}", output="TEXTURE", resolution=16, texel_density=0)
        tex[mode] = read_image(tmp_path / f"lamp_{mode}" / "textures" / "Cube_000001.exr")
    a, b = tex["IRRADIANCE"], tex["INDIRECT"]
    assert (b >= 0).all() and (b <= a + 1e-6 * a.max()).all()
    assert (a - b).max() > 0.3 * a.max()  # the lamp's direct light, taken out
    assert b.max() > 0  # the panel's light and the bounce stay


def _snapshot(mat):
    t = mat.node_tree
    nodes = sorted((n.name, n.bl_idname) for n in t.nodes)
    links = sorted(
        (lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier)
        for lk in t.links
    )
    active = [n.name for n in t.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output]
    return nodes, links, active


def test_preview_adds_base_colour_times_the_bake_to_the_material_and_removes_it(tmp_path):
    """Preview of an Indirect bake: the material's own shader + Emission(base colour x
    HR_Radiance, unseen by diffuse rays) through Add Shader into the active output, which takes the
    material's displacement too; Remove Preview gives back the material node for node and link for link;
    a Radiance bake re-wires the preview without the material's shader. Baked textures: the
    helper copy is wired the same way, the image in place of the attribute."""
    bpy = _scene(tmp_path)
    from hr_addon.blender import names, preview

    mat = bpy.data.objects["Cube"].active_material
    t = mat.node_tree
    bsdf = t.nodes["Principled BSDF"]
    disp = t.nodes.new("ShaderNodeDisplacement")
    t.links.new(disp.outputs[0], t.nodes["Material Output"].inputs["Displacement"])
    before = _snapshot(mat)
    _bake(tmp_path, "INDIRECT")
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    n = t.nodes
    out = n[names.N_OUT]
    assert out.is_active_output and not t.nodes["Material Output"].is_active_output
    add = n[names.N_SHADER]
    assert out.inputs["Surface"].links[0].from_node == add
    assert add.inputs[0].links[0].from_node == bsdf and add.inputs[1].links[0].from_node == n[names.N_EMIT]
    assert out.inputs["Displacement"].links[0].from_node == disp
    mul = n[names.N_MUL]
    assert n[names.N_EMIT].inputs["Color"].links[0].from_node == mul
    a, b = (next(s for s in mul.inputs if s.identifier == k) for k in ("A_Color", "B_Color"))
    assert a.links[0].from_node == n[names.N_ATTR] and not b.is_linked
    assert tuple(b.default_value[:3]) == pytest.approx(tuple(bsdf.inputs["Base Color"].default_value[:3]))
    assert names.N_ADD not in n  # the material's own shader emits its emission
    seen = n[names.N_SEEN]  # diffuse rays do not see the bounce light (it would bounce twice)
    assert n[names.N_EMIT].inputs["Strength"].links[0].from_node == seen and seen.operation == "LESS_THAN"
    assert seen.inputs[0].links[0].from_socket == n[names.N_PATH].outputs["Is Diffuse Ray"]
    glow = bpy.data.objects["Panel"].active_material.node_tree.nodes
    assert glow[names.N_SHADER].inputs[0].links[0].from_node.name == "Principled BSDF"
    assert preview.wired_mode(t) == "INDIRECT"
    preview.refresh_preview([bpy.data.objects["Cube"]], "RADIANCE")
    assert not {names.N_SHADER, names.N_MUL, names.N_PATH, names.N_SEEN} & {x.name for x in n}
    assert not n[names.N_EMIT].inputs["Strength"].is_linked
    assert out.inputs["Surface"].links[0].from_node == n[names.N_EMIT]
    assert not out.inputs["Displacement"].is_linked
    preview.refresh_preview([bpy.data.objects["Cube"]], "INDIRECT")
    assert bpy.ops.hr.remove_preview() == {"FINISHED"}
    assert _snapshot(mat) == before
    _bake(tmp_path, "INDIRECT", "tex", output="TEXTURE", resolution=16, texel_density=0)
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    helper = bpy.data.objects["Cube"].material_slots[0].material
    assert helper != mat and helper.get(names.TAG) == "Cube"
    h = helper.node_tree.nodes
    assert h[names.N_OUT].inputs["Surface"].links[0].from_node == h[names.N_SHADER]
    assert h[names.N_SHADER].inputs[0].links[0].from_node.name == "Principled BSDF"
    a = next(s for s in h[names.N_MUL].inputs if s.identifier == "A_Color")
    assert a.links[0].from_node.name == names.N_TEX
    assert bpy.ops.hr.remove_preview() == {"FINISHED"}
    assert bpy.data.objects["Cube"].material_slots[0].material == mat and _snapshot(mat) == before


def test_live_relight_writes_the_indirect_values_through_the_indirect_preview(tmp_path):
    """Live in the Indirect-only mode writes what a bake of the same state writes (to Live's
    float32 response tolerance, docs/ARCHITECTURE.md) and shows it through the Indirect preview;
    ending Live removes the preview it added."""
    bpy = _scene(tmp_path)
    from hr_addon.blender import live, names

    scene = bpy.context.scene
    scene.hr.radiance_mode = "INDIRECT"
    t = bpy.data.objects["Cube"].active_material.node_tree
    live.start(scene)
    try:
        live.update(scene)
        a = _cube_values()
        assert names.N_SHADER in t.nodes and t.nodes[names.N_OUT].is_active_output
    finally:
        live.stop(scene)
    assert names.N_OUT not in t.nodes
    _bake(tmp_path, "INDIRECT")
    b = _cube_values()
    assert b.max() > 0
    assert np.allclose(a, b, rtol=1e-4, atol=1e-5 * b.max())


def test_command_line_indirect_mode(tmp_path, capsys):
    """--radiance-mode indirect (the choices come from settings.py) goes into the manifest; a bake
    in another mode does not keep its frames; without the final gather it is refused, saying why."""
    _scene(tmp_path)
    from hr_addon.blender import cli
    from hr_addon.io.cache import CacheReader

    args = [str(tmp_path / "indirect.blend"), "--quality", "draft", "--output", "vertex"]
    assert cli.run(args + ["--frames", "1-1", "--radiance-mode", "indirect"]) == 0
    cache = tmp_path / "hr_cache" / "indirect"
    assert CacheReader(cache).manifest["radiance_mode"] == "INDIRECT"
    capsys.readouterr()
    assert cli.run(args + ["--frames", "2-2", "--radiance-mode", "irradiance"]) == 0
    out = capsys.readouterr().out
    assert "discarded: it used radiance mode indirect (this bake: irradiance)" in out, out
    assert cli.run(args + ["--frames", "1-1", "--radiance-mode", "indirect", "--no-final-gather"]) == 1
    err = capsys.readouterr()
    assert "need the Final Gather" in err.out + err.err


def _blocks(img, k):
    h, w = img.shape[:2]
    return img[: h // k * k, : w // k * k].reshape(k, h // k, k, w // k, 3).mean((1, 3))


@pytest.mark.cycles
@pytest.mark.slow
def test_indirect_preview_plus_cycles_direct_light_is_full_cycles(tmp_path):
    """The wiring end to end: the Cornell sample lit by an area light in place of its emitter
    (hr_testing.cycles_lights.add_light), baked Indirect only (vertex, draft); rendered by Cycles
    with the preview on and no bounces (Cycles renders the lamp's direct light on the materials'
    own shaders, the preview adds base colour x our indirect) against a full Cycles render of the
    materials (64 bounces). The preview's Emission is kept from Cycles' light sampling
    (emission_sampling NONE; EEVEE does not light with meshes) and its diffuse rays (the wiring's
    Light Path), so the bounce is not counted twice. Image 48 x 48, 64 spp, the full render the
    mean of seeds 1 and 2: measured image mean +0.56 / +0.01 / +0.15% (R, G, B); 4 x 4 blocks'
    median error 0.78%, the two seeds' blocks 1.0% apart. Without the Light Path factor the
    composite was 13-34% brighter per block (the preview's emission lit the other surfaces once
    more)."""
    import os

    bpy = load_bpy()
    from hr_testing import cycles_lights, cycles_ref as C
    from hr_testing.blend import open_sample
    from hr_addon.blender import preview, texture

    open_sample("cornell", tmp_path)
    cycles_lights.add_light("AREA")
    scene = bpy.context.scene
    scene.hr.use_world = False
    bpy.ops.wm.save_mainfile()
    _bake(tmp_path, "INDIRECT", quality="draft")
    texture.remove_material()
    preview.remove_preview()
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"

    def render(name, bounces, seed=1):
        C.configure_cycles(scene, 64, seed=seed, threads=os.cpu_count() or 1, bounces=bounces)
        scene.render.filepath = str(tmp_path / name)
        bpy.ops.render.render(write_still=True)
        return read_image(tmp_path / name)

    full = [render(f"full{s}.exr", 64, s) for s in (1, 2)]
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    for m in bpy.data.materials:
        m.cycles.emission_sampling = "NONE"
    comp = render("comp.exr", 0)
    ref = (full[0] + full[1]) / 2
    mean = comp.mean((0, 1)) / ref.mean((0, 1)) - 1
    assert np.abs(mean).max() <= 0.02, mean
    err = np.abs(_blocks(comp, 4) / _blocks(ref, 4) - 1)
    noise = np.abs(_blocks(full[0], 4) / _blocks(full[1], 4) - 1)
    assert np.median(err) <= 2 * np.median(noise) + 0.01, (np.median(err), np.median(noise))
