"""Which light shapes move (lights_in.moving_shapes, core LightShape.moves): read from the scene's
animation, constraints and modifiers, never from the frames a bake holds; a moving shape's direct
light comes from the host visibility (core gather/hostvis.py), a still one's from shadow rays."""

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, make_samples_module, open_sample

pytestmark = pytest.mark.bpy

QUAD = [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.1, 0.1, 0.0), (0.0, 0.1, 0.0)]


def _moving(bpy):
    from hr_addon.blender.lights_in import moving_shapes
    from hr_addon.blender.scene_in import light_shape_objects

    return set(moving_shapes(light_shape_objects(bpy.context.view_layer, include_hidden=True)))


def test_what_moves_is_read_from_the_scene(tmp_path):
    """Cornell's shapes are keyed on hide_render only: still. Still too: a material's strength and
    colour keyframes, a shape under a parent that does not move, a constraint or a modifier naming a
    still object. Moving: location keyframes, a driver on the delta transform, a parent (an empty)
    keyed up the chain, a constraint naming a keyed object, animated shape keys, a geometry-nodes
    modifier. The flag reaches each LightShape and its frame's signature."""
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    ms = make_samples_module()
    scene = bpy.context.scene
    assert _moving(bpy) == set()
    patch_mat = bpy.data.materials["Patch Light"]
    node = next(n for n in patch_mat.node_tree.nodes if n.type == "EMISSION")
    node.inputs["Strength"].keyframe_insert("default_value", frame=1)
    node.inputs["Color"].keyframe_insert("default_value", frame=1)

    def empty(name, parent=None):
        e = bpy.data.objects.new(name, None)
        scene.collection.objects.link(e)
        e.parent = parent
        return e

    def shape(name, z):
        return ms.light_shape(name, [(x, y, z) for x, y, _ in QUAD], [[0, 1, 2, 3]], patch_mat)

    still_root, moving_root = empty("Still Root"), empty("Moving Root")
    moving_root.keyframe_insert("rotation_euler", frame=1)
    mid = empty("Mid", parent=moving_root)  # (not keyed itself: its parent is)
    s = {
        n: shape(n, 0.01 * i)
        for i, n in enumerate(
            [
                "keyed",
                "driven",
                "under_still",
                "under_chain",
                "copy_still",
                "copy_moving",
                "array_still",
                "shape_keys",
                "geometry_nodes",
            ]
        )
    }
    s["keyed"].keyframe_insert("location", frame=1)
    s["driven"].driver_add("delta_location", 0).driver.expression = "frame / 100"
    s["under_still"].parent = still_root
    s["under_chain"].parent = mid
    s["copy_still"].constraints.new("COPY_LOCATION").target = still_root
    s["copy_moving"].constraints.new("COPY_LOCATION").target = mid
    s["array_still"].modifiers.new("Array", "ARRAY").offset_object = still_root
    ob = s["shape_keys"]
    ob.shape_key_add(name="Basis")
    ob.shape_key_add(name="Wide").data[1].co.x = 0.2
    ob.data.shape_keys.key_blocks["Wide"].keyframe_insert("value", frame=1)
    s["geometry_nodes"].modifiers.new("GN", "NODES")
    want = {"keyed", "driven", "under_chain", "copy_moving", "shape_keys", "geometry_nodes"}
    assert _moving(bpy) == want

    from hr_addon.blender.lights_in import collect_light_shapes, shapes_signature
    from hr_addon.core.events import LightShape

    scene.frame_set(21)  # (the Back Patch shown, the Window hidden)
    vl = bpy.context.view_layer
    got = collect_light_shapes(vl, vl.depsgraph, LightShape)
    assert {v.name for v in got.values() if v.moves} == want
    assert {v.name for v in got.values() if not v.moves} == set(s) - want | {"Back Patch"}
    again = collect_light_shapes(vl, vl.depsgraph, LightShape, moving=frozenset(want - {"keyed"}))
    assert not again["keyed:0"].moves and shapes_signature(again) != shapes_signature(got)


def _baked(bpy, monkeypatch, cache, frames, frame, hostvis_on=True):
    """The mesh objects' values on `frame` of a draft bake of `frames` into `cache` (the playback
    handler loads the frame), host visibility on or off."""
    from hr_addon.blender.bake import run_bake
    from hr_addon.core.gather import hostvis

    monkeypatch.setattr(hostvis, "ENABLED", hostvis_on)
    scene = bpy.context.scene
    res = run_bake(scene, log=lambda *a, **k: None, frames=frames, quality="draft", cache_dir=str(cache))
    assert res.solved >= 1
    scene.frame_set(frame)
    return {
        o.name: attribute(o)[:, :3].copy()
        for o in scene.objects
        if o.type == "MESH" and not o.hr.is_light_shape
    }


def test_a_frame_is_the_same_in_any_frame_range_and_a_still_shape_takes_its_shadow_rays(
    tmp_path, monkeypatch
):
    """Cornell with the Window keyed in place from frame 1 to 14 and moved by frame 20: on frame 13
    (the Window and the Back Patch) the Window moves (its keys say so) though it has not moved by
    then, so a bake of frame 13 alone and one of frames 13-20 give the same values bit for bit (a
    rule from the frames a bake holds would call it still in the first and moving in the second);
    with the host visibility off, frame 13 differs (the moving Window read it). On frame 21 (the
    Back Patch alone, keyed on hide_render only: still) the bake with the host visibility off gives
    the same values bit for bit: a still shape takes the shadow rays' path."""
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    window = bpy.data.objects["Window"]
    for f, dy in ((1, 0.0), (14, 0.0), (20, 0.05)):
        window.location.y = dy
        window.keyframe_insert("location", index=1, frame=f)
    assert _moving(bpy) == {"Window"}
    alone = _baked(bpy, monkeypatch, tmp_path / "alone", (13, 13), 13)
    ranged = _baked(bpy, monkeypatch, tmp_path / "range", (13, 20), 13)
    off = _baked(bpy, monkeypatch, tmp_path / "off", (13, 13), 13, hostvis_on=False)
    for k in alone:
        np.testing.assert_array_equal(alone[k], ranged[k], err_msg=k)
    assert any(not np.array_equal(alone[k], off[k]) for k in alone)
    # frame 21: the Window hidden (its hide_render keys), the Back Patch alone
    on = _baked(bpy, monkeypatch, tmp_path / "p_on", (21, 21), 21)
    off = _baked(bpy, monkeypatch, tmp_path / "p_off", (21, 21), 21, hostvis_on=False)
    for k in on:
        np.testing.assert_array_equal(on[k], off[k], err_msg=k)


def test_live_reads_what_moves_as_a_bake_does(tmp_path):
    """Live Relight names the moving shapes from the scene as a bake does, not from the user's edits
    (docs/live.md, session 30): the Window moved by hand (no keys) stays still, and keyed where it
    is the next read makes it moving (its light changes: the host visibility); each exact state
    equals a bake of it bit for bit (as test_blender_live's edits)."""
    from hr_addon.blender import live
    from hr_addon.blender.bake import run_bake

    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    scene = bpy.context.scene
    scene.hr.method, scene.hr.quality = "FE", "DRAFT"
    for o in scene.objects:
        if o.hr.is_light_shape:
            o.animation_data_clear()
            o.hide_render = False
    window = bpy.data.objects["Window"]
    scene.hr.live = True
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    sess = live.session(scene)

    def shown():
        return {n: attribute(bpy.data.objects[n])[:, :3].copy() for n in sess.targets}

    window.location.y += 0.03
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    assert sess.moving == frozenset()
    still = shown()
    window.keyframe_insert("location", frame=scene.frame_current)
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    assert sess.moving == {"Window"} and sess.updates == 3
    moving = shown()
    assert any(not np.array_equal(still[k], moving[k]) for k in still)
    f = scene.frame_current
    run_bake(scene, log=lambda *a, **k: None, frames=(f, f))  # (ends Live)
    for k, v in moving.items():
        np.testing.assert_array_equal(v, attribute(bpy.data.objects[k])[:, :3], err_msg=k)
