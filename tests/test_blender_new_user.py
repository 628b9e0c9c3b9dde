"""Issue 18, a new user's trial: no black bake without a word (nothing emits; Blender lights and
the World take part since issue 20), light shapes that cannot emit, checks before
the build, a clean unregister, the words a user reads and what the saved file carries."""

import os
import subprocess
import sys

import numpy as np
import pytest

from test_blender_helpers import REPO_ROOT, SAMPLES, load_bpy, make_samples_module, open_sample
from test_blender_cli import run_cli

pytestmark = pytest.mark.bpy

pytest.importorskip("bpy")


def _bake(**kw):
    import bpy
    from hr_addon.blender.bake import run_bake

    kw.setdefault("quality", "draft")
    kw.setdefault("frames", (1, 1))
    return run_bake(bpy.context.scene, log=lambda *a, **k: None, **kw)


def _factory_file(path):
    """Blender's factory scene (a cube, a point light, a grey World), saved to path."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_factory_startup=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    return path


def test_factory_scene_without_its_light_and_world_is_refused_before_the_build(tmp_path):
    """The factory scene baked to all 0.0 with exit 0. Its point light and its grey World now light
    the bake (issue 20, tests/test_blender_lights.py); without both nothing emits and the bake is
    refused, naming the World left out when it lights the render."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_factory_startup=True)
    bpy.data.objects.remove(bpy.data.objects["Light"])
    bpy.context.scene.hr.use_world = False
    blend = tmp_path / "factory.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    proc = run_cli(blend, "--cache-dir", tmp_path / "cache")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    err = [ln for ln in proc.stderr.splitlines() if ln.startswith("hr_bake: error:")]
    assert len(err) == 1, proc.stderr
    assert "Nothing in the scene emits light, so the bake would be black" in err[0]
    assert "The World's background lights the render, but the bake leaves it out" in err[0]
    assert "Building the hierarchy" not in proc.stdout and "Traceback" not in proc.stderr
    assert not (tmp_path / "cache").exists()


def test_operator_refuses_a_black_scene_and_the_panel_says_why(tmp_path):
    bpy = load_bpy()
    from hr_addon.blender import background
    from hr_addon.blender.state import STATE
    from hr_addon.blender.scene_in import SceneError

    _factory_file(tmp_path / "factory.blend")
    bpy.data.lights["Light"].energy = 0.0  # a light with no power gives no light
    bpy.data.worlds["World"].node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene = bpy.context.scene
    with pytest.raises(SceneError, match="Nothing in the scene emits light"):  # the interactive bake
        background.BackgroundBake(scene, bpy.context.view_layer).start()
    assert not background.running()
    with pytest.raises(RuntimeError, match="Nothing in the scene emits light"):  # bpy.ops.hr.bake()
        bpy.ops.hr.bake()
    assert "Nothing in the scene emits light" in STATE.errors[scene.name_full]  # panel
    assert not scene.hr.bake_dir


def test_the_world_lights_the_bake_and_can_be_left_out(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "AREA"))
    bpy.context.scene.collection.objects.link(lamp)
    floor = bpy.data.objects["floor"]
    dark = _bake(method="FE")
    assert not [w for w in dark.warnings if "World" in w]

    def floor_mean():
        return np.mean([d.color[:3] for d in floor.data.color_attributes["HR_Radiance"].data])

    v0 = floor_mean()
    bg = bpy.context.scene.world.node_tree.nodes["Background"]
    bg.inputs["Strength"].default_value = 1.0
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1)
    res = _bake(method="FE")  # the open front lets the sky in
    assert not [w for w in res.warnings if "World" in w or "not supported" in w], res.warnings
    assert floor_mean() > 1.01 * v0
    bpy.context.scene.hr.use_world = False
    off = [w for w in _bake(method="FE").warnings if "World" in w]
    assert off == [
        "The World's background lights the render, but the bake leaves it out (Lights > World is off)."
    ]


def test_light_shapes_that_cannot_emit_are_named_when_marked_and_at_bake_time(tmp_path, capfd):
    """Marking a closed box or a non-emissive object said "1 object(s) marked", and the bake said
    nothing more."""
    bpy = load_bpy()
    ms = make_samples_module()
    open_sample("cornell", tmp_path)
    bpy.ops.mesh.primitive_cube_add(size=0.05, location=(0.3, 0.3, 0.2))
    box = bpy.context.object
    box.name = "Lantern"
    box.data.materials.append(ms.emission("Lantern light", (1, 1, 1), 3.0))
    dull = ms.mesh_object(
        "Poster",
        [(0.1, 0.5592, 0.1), (0.2, 0.5592, 0.1), (0.2, 0.5592, 0.2), (0.1, 0.5592, 0.2)][::-1],
        [[0, 1, 2, 3]],
        ms.diffuse("Paper", (0.5, 0.5, 0.5)),
    )
    bpy.ops.object.select_all(action="DESELECT")
    for o in (box, dull):
        o.select_set(True)
    capfd.readouterr()
    assert bpy.ops.hr.mark_light_shape() == {"FINISHED"}
    out = capfd.readouterr().out
    assert (
        "Light shape 'Lantern': it is not flat (its faces do not lie in one plane, like a closed box)" in out
    )
    assert "Light shape 'Poster': its material does not emit" in out
    assert "2 object(s) marked as light shapes; 2 with a problem (see the warnings)" in out
    bpy.ops.object.select_all(action="DESELECT")
    for name in ("Window", "Back Patch"):  # the sample's shapes: flat and emissive
        bpy.data.objects[name].select_set(True)
    capfd.readouterr()
    bpy.ops.hr.mark_light_shape()
    assert "Warning" not in capfd.readouterr().out
    res = _bake(method="FE")
    assert [w for w in res.warnings if w.startswith("Light shape ")] == [
        "Light shape 'Lantern': it is not flat (its faces do not lie in one plane, like a closed box); a "
        "light shape is a flat patch on a surface, so each face is taken as a shape of its own.",
        "Light shape 'Poster': its material does not emit (no Emission shader, or Emission Strength 0), "
        "so it adds no light; give it an emissive material.",
    ], res.warnings


@pytest.mark.parametrize(
    "save, text",
    [
        ("missing_folder/copy.blend", "the folder {tmp}/missing_folder does not exist"),
        ("copy.txt", "the copy needs a .blend file name"),
        ("a_folder.blend", "{tmp}/a_folder.blend is a folder"),
    ],
)
def test_save_path_is_checked_before_the_build_and_said_once(tmp_path, save, text):
    """A bad --save path was found only after the whole bake, and its error printed twice."""
    (tmp_path / "a_folder.blend").mkdir()
    proc = run_cli(SAMPLES / "cornell.blend", "--cache-dir", tmp_path / "cache", "--save", tmp_path / save)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"hr_bake: error: --save {tmp_path / save}: {text.format(tmp=tmp_path)}"
    ], proc.stderr
    assert "Building the hierarchy" not in proc.stdout and not (tmp_path / "cache").exists()


def test_frames_outside_the_scene_range_are_named_and_thresholds_print_rounded(tmp_path):
    proc = run_cli(
        SAMPLES / "cornell.blend", "--cache-dir", tmp_path / "c", "--quality", "draft", "--frames", "23-26"
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (
        "HR Radiosity: warning: Frames 25-26 lie outside the scene's frame range 1-24: baked as asked "
        "(is the frame range right?)." in proc.stdout.splitlines()
    ), proc.stdout
    proc = run_cli(SAMPLES / "cornell.blend", "--feps", "2")
    assert proc.returncode == 2
    # the sample's own aeps (a float32 property: 0.00019999999494757503), printed rounded
    assert proc.stderr.strip().splitlines()[-1] == (
        "hr_bake: error: bad thresholds feps=2 aeps=0.0002 (need 0 < feps <= 1, 0 < aeps < 1)"
    )


def _python(code, cwd):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=120
    )


def test_unregister_is_clean_at_exit(tmp_path):
    """ "Exception in module unregister() ... missing bl_rna attribute" at exit: our atexit hook
    unregistered the enabled extension, then Blender's exit disabled it again."""
    proc = _python("import bpy, hr_addon; hr_addon.register(); hr_addon.unregister()", REPO_ROOT)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    (tmp_path / "addons").mkdir()
    (tmp_path / "addons" / "hr_radiosity").symlink_to(REPO_ROOT, target_is_directory=True)
    proc = _python(
        f"import sys; sys.path.insert(0, {str(tmp_path / 'addons')!r})\n"
        "import bpy, addon_utils\n"
        "addon_utils.enable('hr_radiosity', default_set=True, handle_error=None)\n"
        "assert hasattr(bpy.types.Scene, 'hr')\n",
        tmp_path,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Exception" not in out and "Traceback" not in out, out
    proc = run_cli(
        SAMPLES / "cornell.blend", "--cache-dir", tmp_path / "c", "--frames", "1", "--quality", "draft"
    )
    assert proc.returncode == 0 and "Traceback" not in proc.stdout + proc.stderr, proc.stderr


def test_method_names_and_a_tooltip_on_every_setting():
    bpy = load_bpy()
    scene_props = bpy.types.Scene.bl_rna.properties["hr"].fixed_type.properties
    names = {i.identifier: i.name for i in scene_props["method"].enum_items}
    assert names == {
        "AUTO": "Auto: chosen per element by an error bound",
        "AR": "Adaptive refinement (AR)",
        "FE": "Fractional emission (FE)",
        "NAIVE": "Rebuild (naive)",
    }
    for owner in (bpy.types.Scene, bpy.types.Object):
        for p in owner.bl_rna.properties["hr"].fixed_type.properties:
            if p.identifier in ("rna_type", "name"):  # Blender's own
                continue
            assert p.description.strip(), f"{owner.__name__}.hr.{p.identifier} has no tooltip"
            for item in getattr(p, "enum_items", ()):
                assert item.description.strip(), (p.identifier, item.identifier)


def test_custom_frame_range_starts_from_the_scene_range(tmp_path):
    """It started at 1-250 whatever the scene's range."""
    bpy = load_bpy()
    from hr_addon.blender.bake import frame_range_for

    open_sample("cornell", tmp_path)  # frames 1-24
    scene = bpy.context.scene
    scene.frame_start = 3
    hr = scene.hr
    hr.use_frame_range = True  # by a script: Start and End not set yet are the scene's
    assert frame_range_for(scene) == (3, 24)
    hr.use_frame_range = False
    bpy.ops.hr.custom_frame_range()  # the panel's checkbox: copies the scene's range
    assert hr.use_frame_range and (hr.frame_start, hr.frame_end) == (3, 24)
    hr.frame_end = 10
    bpy.ops.hr.custom_frame_range()
    assert not hr.use_frame_range and frame_range_for(scene) == (3, 24)
    bpy.ops.hr.custom_frame_range()  # a range once set is kept
    assert frame_range_for(scene) == (3, 10)


def test_progress_lines_give_real_fractions_and_each_frames_time(tmp_path):
    """The build printed "clusters: 50% (1/1)" (the build's share next to the phase's count) and
    "push corrections: 90% (0/1)"; frame lines had no time."""
    import re

    bpy = load_bpy()
    from hr_addon.blender.bake import run_bake

    open_sample("cornell", tmp_path)
    lines = []
    run_bake(
        bpy.context.scene, log=lambda m, **k: lines.append(m), frames=(5, 7), method="FE", quality="draft"
    )
    build = [ln for ln in lines if ln.startswith("HR Radiosity: Building the hierarchy: ")]
    assert build, lines
    for ln in build:
        m = re.fullmatch(
            r".*: ([a-z ]+) (\d+)%(?: \(([\d,]+)/([\d,]+)\))?, build (\d+)%(, about .* left)?", ln
        )
        assert m, ln
        if m[3]:
            done, total = int(m[3].replace(",", "")), int(m[4].replace(",", ""))
            assert int(m[2]) == round(100 * done / total), ln
    assert build[-1].endswith("push corrections 100%, build 100%"), build
    frames = [ln for ln in lines if ln.startswith("HR Radiosity: Frame ")]
    assert [re.sub(r"\d+\.\d\d s$", "T s", ln) for ln in frames] == [
        "HR Radiosity: Frame 5 (1/3): T s",
        "HR Radiosity: Frame 6 (2/3): T s",
        "HR Radiosity: Frame 7 (3/3): unchanged",
    ], frames


def test_texture_bake_from_the_cli_can_be_shown_with_or_without_save(tmp_path, capfd):
    """After `--output texture --save copy.blend` the copy said Output: Vertex; without --save the
    HR_Lightmap UV map existed only in the process that baked, so the file could not show it."""
    bpy = load_bpy()
    from hr_addon.blender import texture
    from hr_addon.io.cache import CacheReader

    blend = open_sample("cornell", tmp_path)
    args = ["--frames", "1-2", "--quality", "draft", "--method", "fe", "--output", "texture"]
    proc = run_cli(blend, *args, "--resolution", "32", "--feps", "0.03", "--save", tmp_path / "copy.blend")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "copy.blend"), load_ui=False)
    hr = bpy.context.scene.hr
    assert (hr.output, hr.method, hr.quality, hr.texture_resolution) == ("TEXTURE", "FE", "CUSTOM", 32)
    assert hr.feps == pytest.approx(0.03) and hr.bake_dir
    assert "HR_Lightmap" in bpy.data.objects["floor"].data.uv_layers

    proc = run_cli(blend, *args)  # the bake goes to the default cache of cornell.blend, no copy
    assert proc.returncode == 0, proc.stdout + proc.stderr
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    objs = [o for o in bpy.context.scene.objects if o.type == "MESH" and not o.hr.is_light_shape]
    assert not any("HR_Lightmap" in o.data.uv_layers for o in objs)
    assert bpy.ops.hr.add_preview() == {"FINISHED"}  # makes the map again, as the bake made it
    reader = CacheReader(str(tmp_path / "hr_cache" / "cornell"))
    dg = bpy.context.evaluated_depsgraph_get()
    for o in objs:
        assert texture.uv_digest(o, dg) == reader.objects[o.name]["uv"], o.name
        assert o.material_slots[0].material.get(texture.TAG) == o.name  # the helper shows the images
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    bpy.data.objects["floor"].scale = (3, 1, 1)  # edited since the bake: packed otherwise
    capfd.readouterr()
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    assert "The HR_Lightmap UV map made again differs from the bake's on 'floor'" in capfd.readouterr().out


# -- more silently wrong light: warnings --------------------------------------------------------------
def test_metal_glass_and_alpha_are_named_as_read_diffuse():
    load_bpy()
    ms = make_samples_module()
    ms.reset()
    from hr_addon.blender.materials import read_material

    for name, socket, value in (
        ("Steel", "Metallic", 1.0),
        ("Window Glass", "Transmission Weight", 1.0),
        ("Leaves", "Alpha", 0.3),
    ):
        m = ms.principled(name, (0.5, 0.5, 0.5))
        m.node_tree.nodes["Principled BSDF"].inputs[socket].default_value = value
        what = {"Metallic": "metallic", "Transmission Weight": "transmission", "Alpha": "alpha"}[socket]
        assert read_material(m).warnings == [
            f"Material '{name}': {what} read as opaque diffuse: the bake has no metal, glass or see-through "
            "surfaces, so the light this surface reflects or lets through differs from a render"
        ]
    assert read_material(ms.principled("Plain", (0.5, 0.5, 0.5))).warnings == []


def test_animated_emission_on_geometry_is_named_as_not_followed(tmp_path):
    """A keyframed emission strength or a moving emissive plate was frozen at the first frame."""
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    light = bpy.data.objects["light"]
    strength = light.active_material.node_tree.nodes["Principled BSDF"].inputs["Emission Strength"]
    strength.keyframe_insert("default_value", frame=1)
    res = _bake(method="FE")
    assert any(
        w.startswith(
            "Object 'light' emits light and is animated (material 'Ceiling Light'), but ordinary "
            "geometry is read once, on frame 1"
        )
        for w in res.warnings
    ), res.warnings
    light.active_material.node_tree.animation_data_clear()
    light.keyframe_insert("location", frame=1)
    assert any(
        "Object 'light' emits light and is animated (it moves)" in w for w in _bake(method="FE").warnings
    )
    light.animation_data_clear()
    assert not any("is animated" in w for w in _bake(method="FE").warnings)


def test_a_light_shape_without_area_on_one_frame_is_off_on_that_frame(tmp_path):
    """A shape keyed to scale 0 on one frame aborted the whole bake, with nothing written."""
    bpy = load_bpy()
    from test_blender_helpers import attribute

    open_sample("cornell", tmp_path)
    win = bpy.data.objects["Window"]  # on from frame 6
    for f, s in ((6, 1.0), (7, 0.0), (8, 1.0)):
        win.scale = (s, s, s)
        win.keyframe_insert("scale", frame=f)
    make_samples_module().constant_interpolation(win)
    res = _bake(method="FE", frames=(5, 8))
    assert [w for w in res.warnings if "no area" in w] == [
        "Light shape 'Window' has no area on frame 7 (scaled to 0 or squashed to a line): off on that frame."
    ], res.warnings
    scene = bpy.context.scene
    shown = {}
    for f in (5, 6, 7):
        scene.frame_set(f)
        shown[f] = attribute(bpy.data.objects["floor"]).copy()
    np.testing.assert_array_equal(shown[7], shown[5])  # the window is off on frame 7
    assert not np.array_equal(shown[6], shown[5])


def test_linked_meshes_are_named_as_unwritable(tmp_path):
    """Linked-library meshes played back white (1, 1, 1) with no message."""
    bpy, ms = load_bpy(), make_samples_module()
    ms.reset()
    ms.mesh_object("Statue", *_box(0.1), ms.diffuse("Stone", (0.5, 0.5, 0.5)), location=(0.2, 0.2, 0.0))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "lib.blend"), check_existing=False)
    open_sample("cornell", tmp_path)
    with bpy.data.libraries.load(str(tmp_path / "lib.blend"), link=True) as (src, dst):
        dst.objects = ["Statue"]
    bpy.context.scene.collection.objects.link(dst.objects[0])
    res = _bake(method="FE")
    assert any(
        w.startswith("1 object(s) use a mesh linked from a library ('Statue'): HR_Radiance cannot be written")
        for w in res.warnings
    ), res.warnings


def _box(s):
    v = [(x, y, z) for x in (0, s) for y in (0, s) for z in (0, s)]
    f = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return v, f
