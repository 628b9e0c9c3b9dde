"""Blender lights in a bake (issue 20): the factory scene bakes to a lit cube in Cycles' units,
unsupported light features are named, a keyframed spot equals fresh bakes of each frame."""

import math

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, shown

from hr_addon.core.gather.layouts import OUTPUT_INSET
from hr_addon.core.lights import Light, sized_point_unit

pytestmark = pytest.mark.bpy

pytest.importorskip("bpy")


def _bake(tmp_path, sub="cache", **kw):
    import bpy
    from hr_addon.blender.bake import run_bake

    kw.setdefault("quality", "draft")
    kw.setdefault("frames", (1, 1))
    return run_bake(bpy.context.scene, log=lambda *a, **k: None, cache_dir=str(tmp_path / sub), **kw)


def _factory(tmp_path, world=False, spacing=0.0):
    """The factory scene saved to tmp_path; world False: its grey World left out of the bake
    (Lights > World off), so the light under test is the only one. spacing: the Vertex Spacing (0:
    the lights' values at the cube's own corners, what these tests compare; None: the default)."""
    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_factory_startup=True)
    bpy.context.scene.hr.use_world = world
    if spacing is not None:
        bpy.context.scene.hr.vertex_spacing = spacing
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "factory.blend"), check_existing=False)
    return bpy


@pytest.mark.parametrize("final_gather", [True, False])
def test_factory_scene_bakes_to_a_lit_cube(tmp_path, final_gather):
    """The factory scene (a 2 m cube, a 1000 W point light of radius 0.1, a grey World) baked to
    all 0.0; now the faces the light sees read rho (E / pi + L) with E from the point light's closed
    form in Cycles' units (lights.sized_point_unit: the +Y face, 5.5 mm below the light's centre,
    lit by the part of its disc above the face's plane) and L the World's radiance (the cube is convex and
    alone: every direction above a face is open sky, E = pi L), the faces turned away rho L. At the
    default Vertex Spacing (0.25 m, session 23) with the final gather: at the corners of the cube's
    faces subdivided 8 x 8 (its evaluated mesh); without the gather the spacing is not used."""
    bpy = _factory(tmp_path, world=True, spacing=None)
    res = _bake(tmp_path, final_gather=final_gather, method="FE")
    assert not [w for w in res.warnings if "Nothing" in w or "World" in w]
    cube = bpy.data.objects["Cube"]
    light = bpy.data.objects["Light"]
    bg = bpy.context.scene.world.node_tree.nodes["Background"]
    sky = np.array(bg.inputs["Color"].default_value[:3]) * bg.inputs["Strength"].default_value
    assert sky.min() > 0.05  # the factory World: (0.0509, 0.0509, 0.0509) x 1
    v = shown(cube)[:, :3].astype(np.float64)
    me = cube.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    assert len(me.polygons) == (6 * 64 if final_gather else 6)
    M = np.array(cube.matrix_world)
    rho = np.array(
        cube.active_material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value[:3]
    )
    v = v - rho * sky  # the World's part: exact with the final gather (every sky ray escapes)
    c = np.array(light.location)
    r, P = light.data.shadow_soft_size, light.data.energy
    L = Light("POINT", (1, 1, 1), 1.0, position=c, radius=r, soft_falloff=light.data.use_soft_falloff)

    def irradiance(x, nrm):
        # Cycles' soft-falloff disc facing x (lights.sized_point_unit, = cf.point_light_irradiance
        # while above the horizon), cut by the face's horizon: the factory +Y face, 5.5 mm below
        # the light's centre, sees the part of the disc above its plane (the convex cube is not in
        # its way); r / d < 0.03 elsewhere
        d = c - x
        dist = np.linalg.norm(d, axis=-1)
        return np.pi * P * sized_point_unit(L, np.atleast_1d(dist), np.atleast_1d(d @ nrm / dist))

    lit_faces, want, straddle = 0, {}, 0
    for poly in me.polygons:
        nrm = M[:3, :3] @ np.array(poly.normal)
        nrm /= np.linalg.norm(nrm)
        loops = list(poly.loop_indices)
        centre = M[:3, :3] @ np.array(poly.center) + M[:3, 3]
        sees = (c - centre) @ nrm > 0
        if not sees:
            assert np.abs(v[loops]).max() < 1e-6, poly.index
            continue
        lit_faces += 1
        straddle += (c - centre) @ nrm < r
        if final_gather:
            # each loop's sample lies OUTPUT_INSET of the way from its corner to the face's centre
            # (gather.loop_samples on the finer corners of the default Vertex Spacing)
            for li in loops:
                p = M[:3, :3] @ np.array(me.vertices[me.loops[li].vertex_index].co) + M[:3, 3]
                x = p + OUTPUT_INSET * (centre - p)
                key = (me.loops[li].vertex_index, tuple(np.round(nrm, 6)))
                want[li] = (key, rho * irradiance(x, nrm)[0] / np.pi)
        else:
            # leaf values: the face's mean (2 x 2 Gauss points per leaf), against the face's mean
            # of the closed form (40 x 40 points)
            co = np.array([M[:3, :3] @ np.array(me.vertices[i].co) + M[:3, 3] for i in poly.vertices])
            g = (np.arange(40) + 0.5) / 40
            uu, vv = np.meshgrid(g, g)
            a, b = co[1] - co[0], co[3] - co[0]
            x = co[0] + uu.reshape(-1, 1) * a + vv.reshape(-1, 1) * b
            E = irradiance(x, nrm).mean()
            assert v[loops].mean(0) == pytest.approx(rho * E / np.pi, rel=0.15), poly.index
    assert lit_faces == len(me.polygons) // 2  # +X, +Y, +Z
    assert straddle == len(me.polygons) // 6  # the +Y face's (its parts')
    # a vertex's loops in one plane (the subdivided faces') read the mean of their samples
    # (gather.loop_samples: the loops within the smooth angle averaged); across the cube's edges none
    groups = {}
    for key, x in want.values():
        groups.setdefault(key, []).append(x)
    for li, (key, _) in want.items():
        assert v[li] == pytest.approx(np.mean(groups[key], 0), rel=1e-3), li
    assert len(want) == 3 * len(me.polygons) // 6 * 4 if final_gather else not want


def test_unsupported_light_features_are_named(tmp_path):
    bpy = _factory(tmp_path)
    light = bpy.data.objects["Light"]
    light.data.use_nodes = True
    spot = bpy.data.objects.new("Spot", bpy.data.lights.new("Spot", "SPOT"))
    spot.location = (0, 0, 4)
    spot.data.energy = 500
    spot.data.use_square = True
    bpy.context.scene.collection.objects.link(spot)
    area = bpy.data.objects.new("Panel", bpy.data.lights.new("Panel", "AREA"))
    area.location = (0, 3, 0)
    area.rotation_euler = (math.radians(90), 0, 0)
    area.data.spread = math.radians(60)
    area.light_linking.receiver_collection = bpy.data.collections.new("Only these")
    bpy.context.scene.collection.objects.link(area)
    res = _bake(tmp_path, final_gather=False)
    named = [w for w in res.warnings if "is not supported by the bake" in w]
    assert (
        "Light 'Light': light nodes (IES profiles, textures: the node setup is ignored) is not "
        "supported by the bake." in named
    ), res.warnings
    assert "Light 'Spot': a square spot (a round cone is used) is not supported by the bake." in named
    assert any("'Panel': light linking" in w for w in named) and any(
        "'Panel': area spread" in w for w in named
    )
    # and the bake still used the lights
    assert attribute(bpy.data.objects["Cube"])[:, :3].max() > 0


def test_keyframed_spot_rotation_equals_fresh_bakes_per_frame(tmp_path):
    """A spot keyframed to sweep the cube over frames 1-3 (one light event per frame) gives, frame
    by frame, the values of a bake of that frame alone (a fresh system)."""
    bpy = _factory(tmp_path)
    scene = bpy.context.scene
    bpy.data.objects.remove(bpy.data.objects["Light"])
    bpy.ops.mesh.primitive_plane_add(size=12, location=(0, 0, -1))
    spot = bpy.data.objects.new("Beam", bpy.data.lights.new("Beam", "SPOT"))
    spot.location = (0, 0, 5)
    spot.data.energy = 3000
    spot.data.spot_size = math.radians(40)
    spot.data.spot_blend = 0.3
    scene.collection.objects.link(spot)
    for f, a in ((1, -25.0), (2, 0.0), (3, 25.0)):
        spot.rotation_euler = (0, math.radians(a), 0)
        spot.keyframe_insert("rotation_euler", frame=f)
    spot.data.color = (1, 0.8, 0.6)
    spot.data.keyframe_insert("color", frame=1)
    spot.data.color = (0.6, 0.8, 1)
    spot.data.keyframe_insert("color", frame=3)
    scene.frame_start, scene.frame_end = 1, 3
    res = _bake(tmp_path, "sweep", frames=(1, 3), method="FE", final_gather=False)
    assert res.solved == 3
    objs = [bpy.data.objects["Cube"], bpy.data.objects["Plane"]]
    swept = {}
    for f in (1, 2, 3):
        scene.frame_set(f)
        swept[f] = [attribute(o)[:, :3].copy() for o in objs]
    for f in (1, 2, 3):
        scene.frame_set(f)
        _bake(tmp_path, f"fresh{f}", frames=(f, f), method="FE", final_gather=False)
        scene.frame_set(f)
        for o, a in zip(objs, swept[f]):
            b = attribute(o)[:, :3]
            assert a.max() > 0
            # float32 values; the responses are solved to 1e-7 from a warm start or cold
            assert np.allclose(a, b, rtol=1e-4, atol=1e-5 * a.max()), (f, o.name)
    assert not np.allclose(swept[1][1], swept[3][1])  # the beam moved


def test_live_follows_a_light_power_edit_as_a_scale_and_a_move(tmp_path):
    """Live Relight reads Blender lights: doubling the power doubles the values (a scale, no
    solve), moving the light changes them, and Live equals a bake of the same state."""
    bpy = _factory(tmp_path)
    from hr_addon.blender import live

    scene = bpy.context.scene
    scene.hr.quality = "DRAFT"
    cube = bpy.data.objects["Cube"]
    live.start(scene)
    try:
        live.update(scene)
        a = attribute(cube)[:, :3].copy()
        assert a.max() > 0
        bpy.data.lights["Light"].energy *= 2
        live.update(scene)
        b = attribute(cube)[:, :3].copy()
        assert np.allclose(b, 2 * a, rtol=1e-5, atol=1e-7 * a.max())
        bpy.data.objects["Light"].location = (0.5, -3.0, 2.5)
        live.update(scene)
        c = attribute(cube)[:, :3].copy()
        assert np.abs(c - b).max() > 0.1 * b.max()
    finally:
        live.stop(scene)
    _bake(tmp_path, quality="draft")
    d = attribute(cube)[:, :3]
    # Live solves responses to 1e-5 in float32 (docs/ARCHITECTURE.md); direct light is the same rays
    assert np.allclose(c, d, rtol=1e-4, atol=1e-5 * d.max())


def test_a_world_edit_wakes_live(tmp_path):
    """Under the World alone, editing its strength marks the Live session dirty from the depsgraph
    handler (no hr.live_update call needed to notice it), and the next update doubles the values."""
    bpy = _factory(tmp_path, world=True)
    from hr_addon.blender import live

    scene = bpy.context.scene
    scene.hr.quality = "DRAFT"
    bpy.data.objects.remove(bpy.data.objects["Light"])
    cube = bpy.data.objects["Cube"]
    live.start(scene)
    try:
        live.update(scene)
        a = attribute(cube)[:, :3].copy()
        assert a.min() > 0
        sess = live.session(scene)
        sess.dirty = False
        bpy.context.view_layer.update()
        assert not sess.dirty  # an evaluation with nothing edited leaves Live asleep
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value *= 2
        bpy.context.view_layer.update()
        assert sess.dirty
        live.update(scene)
        assert np.allclose(attribute(cube)[:, :3], 2 * a, rtol=1e-5, atol=1e-7 * a.max())
    finally:
        live.stop(scene)


def test_a_partial_bake_drops_frames_baked_with_other_lights(tmp_path):
    bpy = _factory(tmp_path)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 2
    res = _bake(tmp_path, frames=(1, 2), final_gather=False)
    assert res.solved + res.reused == 2
    lamp = bpy.data.objects.new("Fill", bpy.data.lights.new("Fill", "POINT"))
    lamp.location = (-3, -3, 3)
    scene.collection.objects.link(lamp)
    res = _bake(tmp_path, frames=(1, 1), final_gather=False)
    assert not res.kept, res.warnings
    assert any("other Blender lights: 'Fill' is new" in w for w in res.warnings), res.warnings


def test_a_partial_bake_rebakes_kept_frames_whose_light_changed(tmp_path):
    """A lamp's power edited after a bake of frames 1-3, then frame 1 baked alone: frames 2-3 were
    baked with the old power, so they are baked again (named in a warning), not kept stale. With
    nothing edited, a partial bake keeps the other frames as they are."""
    bpy = _factory(tmp_path)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    cube = bpy.data.objects["Cube"]
    _bake(tmp_path, frames=(1, 3), final_gather=False)
    res = _bake(tmp_path, frames=(1, 1), final_gather=False)
    assert res.kept == 2 and not res.rebaked, res.warnings
    scene.frame_set(2)
    before = attribute(cube)[:, :3].copy()
    bpy.data.lights["Light"].energy *= 2
    res = _bake(tmp_path, frames=(1, 1), final_gather=False)
    assert res.rebaked == [2, 3] and res.kept == 0, (res.rebaked, res.kept)
    assert any("Frames 2-3 of the previous bake were baked with other light" in w for w in res.warnings)
    scene.frame_set(1)
    scene.frame_set(2)
    assert np.allclose(attribute(cube)[:, :3], 2 * before, rtol=1e-5, atol=1e-7 * before.max())


@pytest.mark.parametrize("final_gather", [True, False])
def test_factory_scene_bakes_lit_textures(tmp_path, final_gather):
    """Texture output: the cube's baked image is lit where the light reaches (faces turned away: 0),
    its brightest texel close to the brightest corner value of the vertex bake."""
    from test_blender_helpers import read_image

    bpy = _factory(tmp_path)
    _bake(tmp_path, "verts", final_gather=final_gather)
    vmax = float(attribute(bpy.data.objects["Cube"])[:, :3].max())
    _bake(tmp_path, "tex", output="TEXTURE", resolution=32, texel_density=0, final_gather=final_gather)
    px = read_image(tmp_path / "tex" / "textures" / "Cube_000001.exr")
    assert px.max() > 0 and (px.max(-1) == 0).any()
    # texels reach nearer the light's corner than the corner samples (half way to the centre)
    assert 0.8 * vmax < px.max() < 3 * vmax


def test_a_light_excluded_in_the_panel_takes_no_part(tmp_path):
    bpy = _factory(tmp_path)
    from hr_addon.blender import panels
    from hr_addon.blender.scene_in import SceneError

    assert bpy.types.HR_PT_radiosity_lights.bl_parent_id == "HR_PT_radiosity"
    assert panels.HR_PT_object.poll(type("C", (), {"object": bpy.data.objects["Light"]})())
    lamp = bpy.data.objects.new("Fill", bpy.data.lights.new("Fill", "SUN"))
    lamp.rotation_euler = (0.3, 0.2, 0)
    bpy.context.scene.collection.objects.link(lamp)
    _bake(tmp_path, "both", final_gather=False)
    both = attribute(bpy.data.objects["Cube"])[:, :3].copy()
    lamp.hr.exclude = True
    _bake(tmp_path, "one", final_gather=False)
    one = attribute(bpy.data.objects["Cube"])[:, :3].copy()
    assert both.sum() > one.sum() > 0
    bpy.data.objects["Light"].hr.exclude = True
    with pytest.raises(SceneError, match="Nothing in the scene emits light"):
        _bake(tmp_path, "none", final_gather=False)


def test_keyframed_light_visibility_and_power(tmp_path):
    """hide_render and energy keyframed: frame 2 dark, frame 3 back at twice the power of frame 1."""
    bpy = _factory(tmp_path)
    scene = bpy.context.scene
    light = bpy.data.objects["Light"]
    for f, hidden, energy in ((1, False, 1000.0), (2, True, 1000.0), (3, False, 2000.0)):
        light.hide_render = hidden
        light.keyframe_insert("hide_render", frame=f)
        light.data.energy = energy
        light.data.keyframe_insert("energy", frame=f)
    scene.frame_start, scene.frame_end = 1, 3
    res = _bake(tmp_path, frames=(1, 3), method="FE")
    assert res.solved == 3
    vals = {}
    for f in (1, 2, 3):
        scene.frame_set(f)
        vals[f] = attribute(bpy.data.objects["Cube"])[:, :3].copy()
    assert vals[1].max() > 0 and vals[2].max() == 0
    assert np.allclose(vals[3], 2 * vals[1], rtol=1e-5, atol=1e-7 * vals[1].max())


def test_world_colour_environment_and_setups_not_followed(tmp_path):
    """The World as a sky (core/sky.py): a Background colour x strength; an equirectangular
    Environment Texture reduced to a table (one light per channel when coloured); a setup the
    reader cannot follow (a Mapping node on the texture's vector) rendered with Cycles; a Light Path
    node, or a render that fails (then its average colour), named in one warning."""
    bpy = _factory(tmp_path, world=True)
    from hr_addon.blender.lights_in import world_sky
    from hr_addon.core.lights import Light

    scene = bpy.context.scene
    tree = scene.world.node_tree
    bg = tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1)
    bg.inputs["Strength"].default_value = 2.0
    w = []
    sky = world_sky(scene, Light, w)
    assert list(sky) == ["world"] and not w
    assert np.allclose(sky["world"].scale, [0.4, 0.6, 0.8]) and sky["world"].sky is None
    # blue from above the horizon, a dimmer red ground (Blender's image rows start at the bottom)
    img = bpy.data.images.new("Sky", 64, 32, float_buffer=True)
    px = np.zeros((32, 64, 4), np.float32)
    px[..., 3] = 1
    px[16:, :, 2] = 1.0
    px[:16, :, 0] = 0.5
    img.pixels.foreach_set(px.ravel())
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    w = []
    sky = world_sky(scene, Light, w)
    assert sorted(sky) == ["world:B", "world:R"] and not w
    b, r = sky["world:B"], sky["world:R"]
    # each half is half the sphere: channel means 0.5 (blue) and 0.25 (red), x strength 2
    assert np.allclose(b.scale, [0, 0, 1.0]) and np.allclose(r.scale, [0.5, 0, 0])
    assert np.allclose(b.sky[16:], 2.0) and np.allclose(b.sky[:16], 0.0)
    # a setup the reader does not follow is rendered with Cycles (world_probe): an image that varies
    # round the horizon, turned a quarter about +Z by a Mapping node, is the direct table turned
    ramp = np.tile(np.linspace(0.1, 1.0, 64, dtype=np.float32), (32, 1))
    img.pixels.foreach_set(np.dstack([ramp] * 3 + [px[..., 3]]).ravel())
    img.pack()
    direct = world_sky(scene, Light, w)["world"]
    coords, mp = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeMapping")
    tree.links.new(coords.outputs["Generated"], mp.inputs["Vector"])
    tree.links.new(mp.outputs["Vector"], env.inputs["Vector"])
    mp.inputs["Rotation"].default_value = (0, 0, math.pi / 2)
    w = []
    turned = world_sky(scene, Light, w)
    assert list(turned) == ["world"] and not w, w
    assert np.allclose(turned["world"].scale, direct.scale, rtol=2e-3)
    rel = np.abs(turned["world"].sky / np.roll(direct.sky, 16, 1) - 1)
    seam = [15, 16]  # the image's edge u = 0 turned: the texture interpolates across it there
    assert np.median(rel) < 1e-3 and np.delete(rel, seam, 1).max() < 0.02, rel.max(0)
    # a Light Path trick renders as the camera sees it: named
    tree.nodes.new("ShaderNodeLightPath")
    w = []
    world_sky(scene, Light, w)
    assert len(w) == 1 and "Light Path" in w[0], w
    # rendering failed (no Cycles): the average colour it could read, named
    from hr_addon.blender import world_probe

    def no_cycles(*a):
        raise RuntimeError("no Cycles")

    orig, world_probe.probe = world_probe.probe, no_cycles
    try:
        w = []
        sky = world_sky(scene, Light, w)
    finally:
        world_probe.probe = orig
    assert list(sky) == ["world"] and sky["world"].sky is None
    assert len(w) == 1 and "the Environment Texture" in w[0] and "rendering it with Cycles failed" in w[0], w
    scene.hr.use_world = False
    assert world_sky(scene, Light, w) == {}


def test_sky_texture_is_a_rendered_sky_and_a_sun(tmp_path):
    """A Sky Texture (Nishita): its sky rendered into the table, its sun disc a SUN light toward
    the node's sun, whose irradiance equals what a Cycles bake of a white plane facing the sun gets
    from the disc (the bake with the disc minus the bake without it), within 1%."""
    bpy = _factory(tmp_path, world=True)
    from mathutils import Vector

    from hr_addon.blender.lights_in import world_sky
    from hr_addon.core.lights import Light

    scene = bpy.context.scene
    for ob in list(scene.objects):
        bpy.data.objects.remove(ob)
    tree = scene.world.node_tree
    bg = tree.nodes["Background"]
    bg.inputs["Strength"].default_value = 0.5
    st = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(st.outputs["Color"], bg.inputs["Color"])
    st.sun_elevation, st.sun_rotation = 0.6, 0.8
    w = []
    lights = world_sky(scene, Light, w)
    assert not w and "world:sun0" in lights
    assert any(k != "world:sun0" and lights[k].kind == "SKY" for k in lights)
    sun = lights["world:sun0"]
    d = np.array([math.cos(0.6) * math.sin(0.8), math.cos(0.6) * math.cos(0.8), math.sin(0.6)])
    assert sun.kind == "SUN" and np.allclose(-sun.direction, d) and sun.angle == pytest.approx(st.sun_size)
    bpy.ops.mesh.primitive_plane_add(size=0.1)
    plane = bpy.context.object
    plane.rotation_euler = Vector(d).to_track_quat("Z", "Y").to_euler()
    mat = bpy.data.materials.new("white")
    plane.data.materials.append(mat)
    if mat.node_tree is None:  # (Blender < 5)
        mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (1, 1, 1, 1)
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = bpy.data.images.new("bake", 4, 4, float_buffer=True)
    mat.node_tree.nodes.active = tex
    scene.render.engine, scene.cycles.samples, scene.cycles.device = "CYCLES", 64, "CPU"
    baked = []
    for on in (True, False):
        st.sun_disc = on
        bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT"}, margin=0)
        baked.append(np.array(tex.image.pixels[:]).reshape(-1, 4)[:, :3].mean(0))
    np.testing.assert_allclose(sun.color * sun.strength / math.pi, baked[0] - baked[1], rtol=0.01)


def test_keyframed_world_strength_is_a_scale_and_the_sky_is_shadowed(tmp_path):
    """The factory cube over a ground plane under the World alone: the World's strength keyframed
    1 -> 3 triples every value (a scale of the cached parts); the ground under the cube is darker
    than its rim (the cube hides the sky from it)."""
    bpy = _factory(tmp_path, world=True)
    scene = bpy.context.scene
    bpy.data.objects.remove(bpy.data.objects["Light"])
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=12, y_subdivisions=12, size=12, location=(0, 0, -1.5))
    strength = scene.world.node_tree.nodes["Background"].inputs["Strength"]
    for f, s in ((1, 1.0), (2, 3.0)):
        strength.default_value = s
        strength.keyframe_insert("default_value", frame=f)
    scene.frame_start, scene.frame_end = 1, 2
    res = _bake(tmp_path, frames=(1, 2), method="FE")
    assert res.solved == 2, res.warnings
    objs = [bpy.data.objects["Cube"], bpy.data.objects["Grid"]]
    vals = {}
    for f in (1, 2):
        scene.frame_set(f)
        vals[f] = [attribute(o)[:, :3].copy() for o in objs]
    for a, b in zip(vals[1], vals[2]):
        assert a.min() > 0
        assert np.allclose(b, 3 * a, rtol=1e-5, atol=1e-7 * a.max())
    plane = bpy.data.objects["Grid"]
    M = plane.matrix_world
    xy = np.array([(M @ plane.data.vertices[lp.vertex_index].co)[:2] for lp in plane.data.loops])
    ground = vals[1][1]
    under = np.abs(xy).max(1) < 1.5
    rim = np.abs(xy).max(1) > 5.5
    assert under.any() and rim.any()
    assert ground[under].mean() < 0.8 * ground[rim].mean()
