"""Vertex output of objects whose mesh cannot hold their values (hr_addon/blender/own_values.py):
modifiers that change the topology and linked duplicates show their own light through a helper
mesh and a geometry-nodes modifier, as the same objects applied and made single-user do."""

import numpy as np
import pytest

from test_blender_helpers import empty_scene

pytestmark = pytest.mark.bpy

BOX = (
    [(x, y, z) for z in (0, 0.3) for y in (0, 0.3) for x in (0, 0.3)],
    [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]],
)
MODIFIED = ["Array", "Shelf", "Subdivision", "Twin far", "Twin near"]


def _scene(ms):
    """A floor lit from its west end; a box with Subdivision Surface, a plane with Solidify, an
    Array of three boxes going east, and two linked duplicates (one mesh) near and far from the light."""
    import bpy

    grey = ms.diffuse("Grey", (0.5, 0.5, 0.5))
    ms.mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [[0, 1, 2, 3]], grey)
    lamp = [(-1.6, -1, 0.02), (-1.6, 1, 0.02), (-1.6, 1, 0.8), (-1.6, -1, 0.8)]
    ms.mesh_object("Lamp", lamp, [[0, 1, 2, 3]], ms.emission("Glow", (1, 1, 1), 5.0))
    ms.mesh_object("Subdivision", *BOX, grey, location=(-1.2, 1.0, 0.01)).modifiers.new("S", "SUBSURF")
    plane = [(0, 0, 0), (0.6, 0, 0), (0.6, 0.3, 0), (0, 0.3, 0)]
    shelf = ms.mesh_object("Shelf", plane, [[0, 1, 2, 3]], grey, location=(-1.3, -1.5, 0.5))
    shelf.modifiers.new("Solidify", "SOLIDIFY").thickness = 0.03
    arr = ms.mesh_object("Array", *BOX, grey, location=(-1.3, -0.15, 0.01))
    m = arr.modifiers.new("Array", "ARRAY")
    m.count, m.relative_offset_displace = 3, (3.0, 0, 0)
    near = ms.mesh_object("Twin near", *BOX, grey, location=(-1.2, 0.5, 0.01))
    far = bpy.data.objects.new("Twin far", near.data)
    far.location = (1.5, 0.5, 0.01)
    bpy.context.scene.collection.objects.link(far)


def _bake_and_read(scene):
    """Bake frame 1 (vertex output), load it; {object: its evaluated mesh's HR_Radiance (N, 3)}."""
    import bpy
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame

    res = run_bake(
        scene, log=lambda *a, **k: None, quality="draft", method="FE", frames=(1, 1), final_gather=False
    )
    assert load_frame(scene, 1)
    dg = bpy.context.evaluated_depsgraph_get()
    out = {}
    for name in MODIFIED:
        me = bpy.data.objects[name].evaluated_get(dg).data
        a = me.attributes["HR_Radiance"]
        v = np.empty(len(a.data) * 4, np.float32)
        a.data.foreach_get("color", v)
        out[name] = v.reshape(-1, 4)[:, :3]
    return out, res.warnings


def test_modified_objects_and_linked_duplicates_show_their_own_light(tmp_path):
    """The bake's values on every corner of the modifiers' result and on each linked duplicate equal
    those of the same scene with the modifiers applied and the duplicates made single-user. Before,
    the modifiers interpolated the original mesh's corner values (Solidify's lower shell showed the
    upper's light, the Array's far boxes the first's) and both twins showed one twin's light."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.own_values import N_VALUES

    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "own.blend"))
    got, warnings = _bake_and_read(scene)
    notes = [w for w in warnings if f"modifier '{N_VALUES}'" in w]
    assert len(notes) == 1 and notes[0].startswith("5 object(s)"), warnings
    assert not [w for w in warnings if "share mesh data" in w or "HR_Radiance is transferred" in w], warnings
    for name in MODIFIED:
        assert bpy.data.objects[name].modifiers[-1].name == N_VALUES
        assert f"{N_VALUES} {name}" in bpy.data.objects
    # Delete Bake takes the modifiers and helpers away again
    from hr_addon.blender.ops import _forget_bake

    dg = bpy.context.evaluated_depsgraph_get()
    evaluated = {n: bpy.data.meshes.new_from_object(bpy.data.objects[n].evaluated_get(dg)) for n in MODIFIED}
    helper_meshes = [bpy.data.objects[f"{N_VALUES} {n}"].data.name for n in MODIFIED]
    _forget_bake(scene)
    assert not [m for o in bpy.data.objects for m in o.modifiers if m.name == N_VALUES]
    assert not [o for o in bpy.data.objects if o.name.startswith(N_VALUES)]
    assert not [n for n in helper_meshes if n in bpy.data.meshes]  # their meshes too
    # the same objects applied and single-user: values on their own meshes, no helpers
    for name in MODIFIED:
        ob = bpy.data.objects[name]
        me = evaluated[name]
        me.attributes.remove(me.attributes["HR_Radiance"])
        ob.modifiers.clear()
        ob.data = me
    want, warnings = _bake_and_read(scene)
    assert not [w for w in warnings if f"modifier '{N_VALUES}'" in w], warnings
    for name in MODIFIED:
        assert not bpy.data.objects[name].modifiers
        np.testing.assert_allclose(got[name], want[name], rtol=1e-5, atol=1e-7, err_msg=name)
    # the light differs where the old transfer showed one value: the lower shell, the far box, twin
    assert want["Twin far"].mean() < 0.5 * want["Twin near"].mean()
