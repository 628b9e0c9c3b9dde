"""Vertex Spacing (Scene.hr.vertex_spacing, own_values): objects with edges longer than the spacing
show their light at the corners of their mesh subdivided in the HR Radiance modifier, so a one-quad
wall shows the light that changes across it; off, the bake is today's, and Delete Bake leaves the
user's meshes and modifiers as they were."""

import numpy as np
import pytest
from tests import closed_forms as cf

from hr_addon.core.gather import layouts
from hr_addon.core.gather.layouts import OUTPUT_INSET

from test_blender_helpers import empty_scene, load_bpy, open_sample, scale_scene

pytestmark = pytest.mark.bpy

RHO, STRENGTH = 0.5, 5.0
# a 4 x 2.5 m wall facing +y, one quad; a 0.4 m square lamp 0.3 m in front of its west end, facing it
WALL = ([(0, 0, 0), (0, 0, 2.5), (4, 0, 2.5), (4, 0, 0)], [[0, 1, 2, 3]])
LAMP = ([(0.2, 0.3, 1.05), (0.6, 0.3, 1.05), (0.6, 0.3, 1.45), (0.2, 0.3, 1.45)], [[0, 1, 2, 3]])


def _scene(ms):
    import bpy

    wall = ms.mesh_object("Wall", *WALL, ms.diffuse("Grey", (RHO,) * 3))
    ms.mesh_object("Lamp", *LAMP, ms.emission("Glow", (1, 1, 1), STRENGTH))
    # a point light before the wall's east end, on at frame 2 only
    point = bpy.data.objects.new("Point", bpy.data.lights.new("Point", "POINT"))
    point.data.energy, point.location = 100.0, (3.5, 0.5, 1.25)
    bpy.context.scene.collection.objects.link(point)
    for frame, off in ((1, True), (2, False)):
        point.hide_render = off
        point.keyframe_insert("hide_render", frame=frame)
    ms.interpolation(point, "CONSTANT")
    # a user's modifier on another object, which Delete Bake must leave alone (behind the wall: dark)
    box = ms.mesh_object(
        "Box",
        [(x, y, z) for z in (0, 0.2) for y in (-1.2, -1) for x in (3, 3.2)],
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]],
        ms.diffuse("Grey box", (RHO,) * 3),
    )
    box.modifiers.new("Bevel", "BEVEL").width = 0.02
    # 0.6 m edges, 0.15 m after its Subdivision Surface (levels 2): finer than 0.25 m already
    plane = [(1, -1, 0.5), (1.6, -1, 0.5), (1.6, -1, 1.1), (1, -1, 1.1)]
    ms.mesh_object("Smooth", plane, [[0, 1, 2, 3]], ms.diffuse("Grey smooth", (RHO,) * 3))
    bpy.data.objects["Smooth"].modifiers.new("Subdivision", "SUBSURF").levels = 2
    return wall


def _bake(scene, spacing, results=None):
    """Bake frames 1-2 (vertex output, draft, final gather on) with Vertex Spacing `spacing`, show
    frame 1; the wall's evaluated mesh (_wall) and the bake's warnings (results: a list the
    BakeResult is appended to)."""
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame

    scene.hr.vertex_spacing = spacing
    res = run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 2))
    if results is not None:
        results.append(res)
    assert load_frame(scene, 1)
    return _wall(), res.warnings


def _wall():
    """The wall's evaluated mesh: (world positions (V, 3), loop_start, loop_total, loop_verts,
    HR_Radiance per corner (L, 3))."""
    import bpy
    from hr_addon.blender.scene_in import mesh_topology

    dg = bpy.context.evaluated_depsgraph_get()
    me = bpy.data.objects["Wall"].evaluated_get(dg).data
    co, ls, lt, lv = mesh_topology(me)
    a = me.attributes["HR_Radiance"]
    assert a.domain == "CORNER"
    v = np.empty(len(a.data) * 4, np.float32)
    a.data.foreach_get("color", v)
    return co.astype(np.float64), ls, lt, lv, v.reshape(-1, 4)[:, :3].astype(np.float64)


def _reference(co, ls, lt, lv, inset=OUTPUT_INSET):
    """Per corner, the wall's radiance rho L F (nothing else lights it, it sees nothing else) as the
    vertex output's layout reads a corner (layouts.loop_samples): the mean over the corners at its
    vertex of the value `inset` of the way from each to its face's centre (the finer corners'
    OUTPUT_INSET; 0.5 on the user's own corners)."""
    poly = np.repeat(np.arange(len(ls)), lt)
    centre = np.stack([np.bincount(poly, co[lv, c]) / lt[poly][np.r_[ls]] for c in range(3)], 1)
    at = co[lv] + inset * (centre[poly] - co[lv])
    b = RHO * STRENGTH * cf.point_to_polygon_contour(at, np.array([0.0, 1.0, 0.0]), np.array(LAMP[0], float))
    per_vert = np.bincount(lv, b, len(co)) / np.maximum(np.bincount(lv, minlength=len(co)), 1)
    return per_vert[lv]


def _needs_the_guard(bpy):
    """The group's guard hashes with Hash Value (Blender 4.3+); on 4.2 the group subdivides at every
    evaluation (own_values._from_helper): what these tests check does not exist there."""
    if not hasattr(bpy.types, "FunctionNodeHashValue"):
        pytest.skip("Blender 4.2: the group has no guard (no Hash Value node)")


def test_one_quad_wall_shows_the_light_across_it(tmp_path):
    """Vertex Spacing 0.25 m: the one-quad wall's modifier subdivides it 16 x 16 (level 4: 4 m /
    16 = 0.25 m; the lamp too, not the plane its Subdivision Surface makes finer already), and its
    corners read the analytic light (from 22 down to 0.002 x the wall's mean) as the vertex layout
    reads it, within 1e-5; its own four corners (spacing 0) interpolated over it are far off the
    same light (the lamp's bright patch shows at none of them)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.own_values import N_VALUES, SPACING

    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    made = []
    (co, ls, lt, lv, val), warnings = _bake(scene, 0.25, made)
    # the hierarchy on the user's meshes (session 22): the wall and the lamp one patch each, not
    # 256 + 4; only the output on the finer corners
    (spaced,), zero = made, []
    md = bpy.data.objects["Wall"].modifiers[-1]
    assert md.name == N_VALUES and md[md.node_group.interface.items_tree[SPACING].identifier] == 0.25
    assert len(ls) == 256 and len(co) == 17 * 17
    # the objects subdivided: a log line (the bake's notes, its progress messages), not a warning
    assert [n for n in spaced.notes if n.startswith("Vertex Spacing 0.25: 2 object(s)") and "'Wall'" in n], (
        spaced.notes
    )
    assert not [w for w in warnings if w.startswith("Vertex Spacing")], warnings
    ref = _reference(co, ls, lt, lv)
    assert ref.max() / ref.mean() > 20 and ref.min() / ref.mean() < 0.002  # a gradient across the wall
    # the final gather's direct light is exact (measured: within 5e-7, the float32 values' rounding)
    np.testing.assert_allclose(val, np.repeat(ref[:, None], 3, 1), rtol=1e-5)
    # playback: frame 2 (the point light on: its light across the wall too) and back
    from hr_addon.blender.playback import load_frame

    assert load_frame(scene, 2)
    added = (_wall()[4] - val).mean(1)
    assert added.min() > 0 and added.max() / added.min() > 10, (added.min(), added.max())
    assert load_frame(scene, 1)
    np.testing.assert_array_equal(_wall()[4], val)
    # the plain wall: its four corners, interpolated over it as the render does (bilinear in x, z)
    (co0, _, _, lv0, val0), _ = _bake(scene, 0.0, zero)
    assert spaced.build_report.patches == zero[0].build_report.patches
    assert not [m for m in bpy.data.objects["Wall"].modifiers if m.name == N_VALUES]
    assert len(co0) == 4
    by = {(round(x, 3), round(z, 3)): v for (x, _, z), v in zip(co0[lv0], val0.mean(1))}
    u, w = co[lv, 0] / 4, co[lv, 2] / 2.5
    coarse = (
        by[0, 0] * (1 - u) * (1 - w) + by[4, 0] * u * (1 - w) + by[0, 2.5] * (1 - u) * w + by[4, 2.5] * u * w
    )
    assert np.median(np.abs(coarse / ref - 1)) > 1  # (measured: 5.3)


def test_the_hierarchy_is_built_on_the_mesh_the_modifier_receives(tmp_path, monkeypatch):
    """A user's Triangulate before the HR Radiance modifier: the wall is two triangles, then finer
    quads at 0.25 m. The hierarchy is built on the two triangles (read with the modifier's
    spacing set to 0 for one evaluation, own_values.before_subdivision; the lamp, whose only
    modifier it is, from its own mesh): as many patches as the bake at spacing 0 has, and the
    modifier's spacing is 0.25 again after the bake. Each finer corner's sample is gathered on the
    triangle under it: the values are those of the hierarchy built on the finer mesh (before
    session 22) within 1e-5 (the wall's light is the lamp's direct light, exact), and the analytic
    light within 0.5% (both read 0.1-0.2% below it on this wall's quads, which are not
    parallelograms: measured, not explained)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values
    from hr_addon.blender.own_values import SPACING

    wall = _scene(ms)
    wall.modifiers.new("Triangulate", "TRIANGULATE")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    made, zero, fine = [], [], []
    (co, ls, lt, lv, val), _ = _bake(scene, 0.25, made)
    assert len(ls) > 100  # (Subdivide Mesh makes quads of a triangle: 3 per triangle, then 4 per quad)
    md = wall.modifiers[-1]
    assert md[md.node_group.interface.items_tree[SPACING].identifier] == 0.25
    ref = _reference(co, ls, lt, lv)
    np.testing.assert_allclose(val, np.repeat(ref[:, None], 3, 1), rtol=5e-3)
    _bake(scene, 0.0, zero)
    assert made[0].build_report.patches == zero[0].build_report.patches
    with monkeypatch.context() as m:  # the hierarchy on the finer mesh, as before
        m.setattr(own_values, "before_subdivision", lambda *a: {})
        # (its corners are the system's own: their inset the finer corners' for the comparison)
        m.setattr(layouts, "INSET", layouts.OUTPUT_INSET)
        (_, _, _, _, val1), _ = _bake(scene, 0.25, fine)
    assert fine[0].build_report.patches > made[0].build_report.patches + 100
    np.testing.assert_allclose(val, val1, rtol=1e-5)


def test_a_transport_at_twice_the_spacing(tmp_path, monkeypatch):
    """own_values.TRANSPORT_FACTOR 2 (an experiment, off by default): the hierarchy on the user's
    faces subdivided at 0.5 m (the wall 8 x 8), the output at 0.25 m (16 x 16); each finer face onto
    the coarser face of its HR_Face whose centre is nearest. The finer corners read the analytic
    light within 1e-5 (measured 4.7e-7)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values

    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    monkeypatch.setattr(own_values, "TRANSPORT_FACTOR", 2.0)
    made, zero = [], []
    (co, ls, lt, lv, val), _ = _bake(scene, 0.25, made)
    assert len(ls) == 256
    np.testing.assert_allclose(val, np.repeat(_reference(co, ls, lt, lv)[:, None], 3, 1), rtol=1e-5)
    _bake(scene, 0.0, zero)
    assert made[0].build_report.patches == zero[0].build_report.patches + 63  # the wall's 64 quads


def test_only_the_coarse_faces_get_finer():
    """A bar 0.5 x 0.1 x 0.05 m scaled x2 along its length (its four long faces 1 m long in the
    world: level 2 at 0.25 m, 4 x 4 each; its two 0.1 x 0.05 m ends: none): 4 x 16 + 2 faces, the
    vertices the level classes' seams had in common one again (80, each position once), the end
    faces' edges keeping T-junctions with the finer faces' vertices exactly on them (no crack), and
    the helper the evaluated mesh's topology."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.own_values import ensure_own_values, values_object
    from hr_addon.blender.scene_in import mesh_topology

    bar = ms.mesh_object(
        "Bar",
        [(x, y, z) for z in (0, 0.05) for y in (0, 0.1) for x in (0, 0.5)],
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]],
        ms.diffuse("Grey", (RHO,) * 3),
    )
    bar.scale = (2, 1, 1)
    dg = bpy.context.evaluated_depsgraph_get()
    assert ensure_own_values([bar], "CORNER", dg, 0.25)
    dg.update()
    me = bar.evaluated_get(dg).data
    co, ls, lt, lv = mesh_topology(me)
    assert (len(ls), len(co)) == (66, 80) and len(np.unique(co, axis=0)) == 80
    assert (lt == 4).all()
    # the seams: each end face's rim, 4 edges of 4 segments each, every vertex on the rim's edges
    rim = co[np.isin(co[:, 0], np.float32([0, 0.5]))]
    assert len(rim) == 2 * 16
    assert (np.isin(rim[:, 1], np.float32([0, 0.1])) | np.isin(rim[:, 2], np.float32([0, 0.05]))).all()
    assert values_object(bar, len(me.loops), len(me.vertices)) is not None


def test_the_spacing_scaled_with_the_scene_gives_the_same_bake(tmp_path):
    """The Cornell sample (walls of 8 x 8 quads of 7 cm) at 0.05 m and inside a parent scaled x8 at
    0.4 m: the same faces subdivided (the walls', the light's and the tall block's by their edges: the
    group measures edges with the object's world scale; since session 32 near_clutter's faces one
    or two levels finer by their FINER: the ceiling's above the light, the floor's around the
    blocks; since session 33 the faces the light shapes' outlines cross (Back Patch on the back
    wall, Window on the right one) and no longer the walls' and floor's along each other: the same
    faces at both scales) and the same values, bit for bit (x8 is exact in binary)."""
    bpy = load_bpy()
    from hr_addon.blender.bake import run_bake

    def bake(scale, spacing):
        open_sample("cornell", tmp_path / str(scale))
        scene = bpy.context.scene
        scale_scene(scene, scale)
        scene.hr.vertex_spacing = spacing
        run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(13, 13), method="FE")
        scene.frame_set(13)
        dg = bpy.context.evaluated_depsgraph_get()
        out = {}
        for o in scene.objects:
            if o.type == "MESH" and not o.hr.is_light_shape:
                a = o.evaluated_get(dg).data.attributes["HR_Radiance"]
                out[o.name] = np.empty(len(a.data) * 4, np.float32)
                a.data.foreach_get("color", out[o.name])
        return out

    one, eight = bake(1, 0.05), bake(8, 0.4)
    assert {n: len(v) // 4 for n, v in one.items()} == {
        "floor": 2272,
        "ceiling": 1216,
        "back": 3424,
        "right_green": 4864,
        "left_red": 1024,
        "short_block": 320,
        "tall_block": 1088,
        "light": 64,
    }
    for name, v in one.items():
        np.testing.assert_array_equal(eight[name], v, err_msg=name)


def test_off_is_todays_bake_and_delete_bake_restores_the_meshes(tmp_path):
    """Spacing 0 after a bake with a spacing: the subdividing modifier and its helper go again (the
    bevelled box keeps today's, for its topology) and the values are those of the first bake with
    spacing 0, bit for bit; Delete Bake leaves the user's mesh and modifiers as they were."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.own_values import N_VALUES
    from hr_addon.blender.ops import _forget_bake
    from hr_addon.blender.scene_in import mesh_topology

    wall = _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    before = [np.array(a) for a in mesh_topology(wall.data)]
    stacks = {o.name: [(m.name, m.type) for m in o.modifiers] for o in bpy.data.objects}
    first, _ = _bake(scene, 0.0)
    baked = {o.name: [(m.name, m.type) for m in o.modifiers] for o in bpy.data.objects}
    assert baked["Wall"] == [] and baked["Box"] == [("Bevel", "BEVEL"), (N_VALUES, "NODES")]  # today's
    fine, _ = _bake(scene, 0.3)
    assert len(fine[1]) > len(first[1]) and wall.modifiers[-1].name == N_VALUES
    assert bpy.data.objects["Box"].modifiers[-1].name == N_VALUES  # (for its bevel: 0.2 m edges)
    again, _ = _bake(scene, 0.0)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert {o.name: [(m.name, m.type) for m in o.modifiers] for o in bpy.data.objects} == baked
    _bake(scene, 0.3)
    _forget_bake(scene)
    assert {o.name: [(m.name, m.type) for m in o.modifiers] for o in bpy.data.objects} == stacks
    assert not [o for o in bpy.data.objects if o.name.startswith(N_VALUES)]
    for a, b in zip(before, mesh_topology(wall.data)):
        np.testing.assert_array_equal(a, b)


def test_panel_shows_the_setting_and_the_live_note():
    """Render > HR Radiosity: Vertex Spacing under the vertex output's settings, and with a spacing
    (the default, 0.25 m) the note that Live Relight shows the finer corners once a bake has added
    them; without the final gather the setting is greyed out (the bake uses none) and the note goes."""
    from types import SimpleNamespace

    bpy, ms, scene = empty_scene()
    from hr_addon.blender import panels

    class Layout:
        def __init__(self):
            self.props, self.labels, self.inactive = [], [], []

        def __getattr__(self, name):  # column, row, box, operator, progress, ...: this layout again
            return lambda *a, **kw: self

        def prop(self, owner, name, **kw):
            self.props.append(name)
            if not self.__dict__.get("active", True):
                self.inactive.append(name)

        def label(self, text="", **kw):
            self.labels.append(text)

    def drawn(cls):
        lay = Layout()
        cls.draw(SimpleNamespace(layout=lay), SimpleNamespace(scene=scene, object=None))
        return lay

    note = "Live Relight: the finer corners once a bake has added them"
    lay = drawn(panels.HR_PT_radiosity_settings)
    assert scene.hr.vertex_spacing == 0.25 and "vertex_spacing" in lay.props and note in lay.labels
    assert "vertex_spacing" not in lay.inactive
    scene.hr.vertex_spacing = 0
    lay = drawn(panels.HR_PT_radiosity_settings)
    assert "vertex_spacing" in lay.props and not [t for t in lay.labels if t.startswith("Live Relight:")]
    scene.hr.vertex_spacing, scene.hr.final_gather = 0.25, False
    lay = drawn(panels.HR_PT_radiosity_settings)
    assert "vertex_spacing" in lay.inactive and note not in lay.labels
    scene.hr.output = "TEXTURE"
    assert "vertex_spacing" not in drawn(panels.HR_PT_radiosity_settings).props


def test_file_without_the_extension_shows_the_same(tmp_path):
    """The subdivision and the values are plain geometry nodes and a helper mesh saved with the
    file: opened with the extension off, the wall shows the bake's subdivided mesh and values."""
    bpy, ms, scene = empty_scene()
    import hr_addon

    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    baked, _ = _bake(scene, 0.25)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "baked.blend"))
    hr_addon.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "baked.blend"))
        assert not hasattr(bpy.context.scene, "hr")
        got = _wall()
    finally:
        hr_addon.register()
    for a, b in zip(baked, got):
        np.testing.assert_array_equal(a, b)


def test_live_relight_works_on_the_subdivided_mesh_after_a_bake(tmp_path, monkeypatch):
    """Live Relight makes no helpers: before any bake it shows the wall's own four corners; after a
    bake with the spacing it writes the subdivided wall's corners (a strength x2 doubles them). Its
    hierarchy is the bake's split (session 23): built on the mesh the modifier receives (the wall
    one polygon, as at spacing 0), the output on the finer corners; built by Live itself (the
    bake's precompute not loaded) it reads the bake's values within 1e-5 (the lamp's direct light,
    exact). The wall has a user's Triangulate before the modifier, so Live reads its transport by
    setting the spacing to 0 for one evaluation (own_values.before_subdivision): the depsgraph
    updates that fire do not make Live rebuild (its geometry signature holds)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import live as live_mod
    from hr_addon.io import precompute as pc

    _scene(ms).modifiers.new("Triangulate", "TRIANGULATE")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    glow = bpy.data.materials["Glow"].node_tree.nodes["Emission"].inputs["Strength"]
    scene.hr.vertex_spacing, scene.hr.quality = 0.25, "DRAFT"  # (the bakes' quality: Live loads theirs)

    def live():
        scene.hr.live = True
        assert bpy.ops.hr.live_update() == {"FINISHED"}
        return _wall()

    def off():
        scene.hr.live = False
        assert bpy.ops.hr.live_update() == {"FINISHED"}

    assert len(live()[3]) == 6  # no bake yet: the mesh's own corners (two triangles)
    coarse = live_mod.session(scene).worker
    assert coarse.spec.output is None
    off()
    zero = []
    _bake(scene, 0.0, zero)
    baked, _ = _bake(scene, 0.25)
    first = live()
    w = live_mod.session(scene).worker
    assert len(first[3]) > 100 and w.precompute == "precompute loaded"
    assert w.spec.output is not None and len(w.spec.output[0].loop_start) > w.spec.polygons
    assert w.build_report.patches == zero[0].build_report.patches  # the transport: the user's meshes
    np.testing.assert_allclose(first[4], baked[4], rtol=1e-5)
    glow.default_value *= 2
    np.testing.assert_allclose(live()[4], 2 * first[4], rtol=1e-5)  # (an emitter's material: rebuilt)
    off()
    glow.default_value /= 2
    monkeypatch.setattr(pc, "load", lambda *a, **k: (None, None, "test: built by Live"))
    own = live()
    w = live_mod.session(scene).worker
    assert w.precompute.startswith("built") and w.build_report.patches == zero[0].build_report.patches
    np.testing.assert_allclose(own[4], baked[4], rtol=1e-5)
    sess = live_mod.session(scene)
    bpy.context.view_layer.update()  # (the handler sees the evaluations before_subdivision made)
    for _ in range(2):
        assert live_mod.update(scene, check_geometry=True)[0] is sess and sess.worker.builds == 1
    off()


def _rug_room(ms):
    """The artist room's floor in small: a 4 x 3 x 2.5 m room (inward faces), a floor quad 1 mm above
    its bottom, a one-sided 12-gon rug (0.9 m) 3 mm above that facing up, a ceiling lamp, and a
    0.8 x 0.6 m painting 1 cm before a wall facing it (turned around with or without a spacing)."""
    box = np.array([[x, y, z] for x in (0, 4) for y in (0, 3) for z in (0, 2.5)], float)
    quads = [(0, 2, 6, 4), (1, 5, 7, 3), (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6)]
    inward = []
    for q in quads:
        c = box[list(q)]
        inward.append(
            list(q) if np.cross(c[1] - c[0], c[2] - c[0]) @ (box.mean(0) - c.mean(0)) > 0 else q[::-1]
        )
    grey = ms.diffuse("Grey", (RHO,) * 3)
    ms.mesh_object("Room", box, inward, grey)
    ms.mesh_object(
        "Floor",
        [(0.001, 0.001, 0.001), (3.999, 0.001, 0.001), (3.999, 2.999, 0.001), (0.001, 2.999, 0.001)],
        [[0, 1, 2, 3]],
        grey,
    )
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    rug = np.column_stack([2 + 0.9 * np.cos(a), 1.5 + 0.9 * np.sin(a), np.full(12, 0.004)])
    ms.mesh_object("Rug", rug, [list(range(12))], grey)
    lamp = [(1.7, 1.2, 2.49), (1.7, 1.8, 2.49), (2.3, 1.8, 2.49), (2.3, 1.2, 2.49)]  # facing down
    ms.mesh_object("Lamp", lamp, [[0, 1, 2, 3]], ms.emission("Glow", (1, 1, 1), STRENGTH))
    painting = [(0.01, 1.1, 1.2), (0.01, 1.1, 1.8), (0.01, 1.9, 1.8), (0.01, 1.9, 1.2)]  # facing -x
    ms.mesh_object("Painting", painting, [[0, 1, 2, 3]], grey)


def test_the_spacing_turns_around_what_the_bake_without_it_does(tmp_path, monkeypatch):
    """A floor under a one-sided rug: subdivided at 0.25 m, its faces under the rug alone see only the
    rug's back before them and the room's bottom behind ("faced away from everything": 40 of its
    256 turned around when judged alone, below); judged as the user's face (the FACE attribute the
    group stores) it stays, as without the spacing, and the painting facing its wall is turned
    around in both, named once. (near_clutter off: the rug 3 mm over the floor would make the
    floor finer, and the counts here are 0.25 m's.)"""
    from hr_addon.blender import own_values

    monkeypatch.setattr(own_values, "CLUTTER_LEVELS", 0)
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.scene_in import collect_geometry
    from hr_addon.core.geometry import prepare_patches
    from hr_addon.core.orientation import find_reversed
    from hr_addon.core.visibility import make_backend

    _rug_room(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "rug.blend"))

    def turned(spacing):
        scene.hr.vertex_spacing = spacing
        res = run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 1))
        return [w for w in res.warnings if "turned around" in w]

    without = turned(0.0)
    assert len(without) == 1 and "1 polygon(s) faced a surface right in front" in without[0], without
    assert "1 in 'Painting'" in without[0] and "Floor" not in without[0]
    assert turned(0.25) == without
    mesh = collect_geometry(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get()).mesh
    floor = np.asarray(mesh.object_id) == mesh.object_names.index("Floor")
    assert floor.sum() == 256 and (mesh.face_groups()[floor] == np.flatnonzero(floor)[0]).all()
    mesh.face_group = None  # the subdivided faces judged alone: what vsub2 did
    pt = prepare_patches(mesh)
    flip, _ = find_reversed(pt, make_backend(pt.triangles, "auto", 1))
    alone = np.unique(pt.poly[flip & (pt.object_id == mesh.object_names.index("Floor"))])
    assert len(alone) == 40  # (measured; the rug covers about 54 of the 256)


def test_a_file_baked_with_the_second_group_gets_the_new_one():
    """A group of version 2 (no FACE attribute) is replaced at the next bake's ensure_own_values: the
    modifier gets the current group, the old one is renamed aside, the finer faces carry FACE."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)
    from hr_addon.blender.names import FACE, TAG
    from hr_addon.blender.own_values import FINER_VERSION, ensure_own_values

    wall = _scene(ms)
    dg = bpy.context.evaluated_depsgraph_get()
    ensure_own_values([wall], "CORNER", dg, 0.25)
    g = wall.modifiers[-1].node_group
    st = next(
        n
        for n in g.nodes
        if n.bl_idname == "GeometryNodeStoreNamedAttribute" and n.inputs["Name"].default_value == FACE
    )
    src = st.inputs["Geometry"].links[0].from_socket
    for lk in list(st.outputs["Geometry"].links):
        g.links.new(src, lk.to_socket)
    g.nodes.remove(st)
    (switch,) = [n for n in g.nodes if n.bl_idname == "GeometryNodeSwitch" and n.input_type == "GEOMETRY"]
    # (version 2 always subdivided)
    (out,) = [n for n in g.nodes if n.bl_idname == "NodeGroupOutput"]
    g.links.new(switch.inputs["False"].links[0].from_socket, out.inputs[0])
    g[TAG] = 2
    wall.update_tag()
    dg.update()
    assert FACE not in wall.evaluated_get(dg).data.attributes
    ensure_own_values([wall], "CORNER", dg, 0.25)
    dg.update()
    new = wall.modifiers[-1].node_group
    assert new[TAG] == FINER_VERSION and g.name.endswith("(v2)") and new is not g
    me = wall.evaluated_get(dg).data
    face = np.empty(len(me.polygons), np.int32)
    me.attributes[FACE].data.foreach_get("value", face)
    assert len(face) == 256 and (face == 0).all()


def test_the_default_is_0_25_and_used_with_the_final_gather_only(tmp_path):
    """The default (session 23): 0.25 m in the scene's setting, BakeConfig and the command line's
    help. Without the final gather the bake uses no spacing (BakeConfig.spacing 0): the hierarchy's
    leaves are the output there, and the classic output stays the mesh's own corners, bit for bit
    the bake at spacing 0 (issue 19: the gather off reproduces it); a log line says so, no warning,
    and a subdividing modifier of an earlier bake goes."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import cli
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.own_values import N_VALUES
    from hr_addon.blender.settings import VERTEX_SPACING, BakeConfig

    assert VERTEX_SPACING == 0.25 and scene.hr.vertex_spacing == VERTEX_SPACING
    cfg = BakeConfig.resolve(scene.hr)
    assert cfg.vertex_spacing == cfg.spacing == 0.25 and BakeConfig.vertex_spacing == 0.25
    assert BakeConfig.resolve(scene.hr, final_gather=False).spacing == 0.0
    assert BakeConfig.resolve(scene.hr, output="TEXTURE").spacing == 0.0
    assert "0.25 unless set" in " ".join(cli.make_parser().format_help().split())
    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))

    def bake(spacing, gather):
        scene.hr.vertex_spacing = spacing
        res = run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 2), final_gather=gather)
        scene.frame_set(1)
        return _wall(), res

    _bake(scene, 0.25)  # a default bake: the wall subdivided
    assert bpy.data.objects["Wall"].modifiers[-1].name == N_VALUES
    (off, res) = bake(0.25, False)
    assert not [m for m in bpy.data.objects["Wall"].modifiers if m.name == N_VALUES]
    assert len(off[0]) == 4 and not [w for w in res.warnings if "Vertex Spacing" in w], res.warnings
    assert [n for n in res.notes if n.startswith("Vertex Spacing 0.25 is not used without")], res.notes
    (zero, res0) = bake(0.0, False)
    assert not res0.notes
    for a, b in zip(off, zero):
        np.testing.assert_array_equal(a, b)


def test_a_small_light_shape_on_a_one_quad_wall_is_warned_about_at_spacing_0_only(tmp_path):
    """A 0.4 m light shape on the one-quad wall (10 m2): at spacing 0 its light can only show at the
    wall's four corners, and the bake names it (bake.small_shape_warnings, with the remedy); at the
    default 0.25 m the wall's finer faces (1/16 m2) are smaller than the shape: no warning."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender.bake import run_bake

    ms.mesh_object("Wall", *WALL, ms.diffuse("Grey", (RHO,) * 3))
    ms.mesh_object("Lamp", *LAMP, ms.emission("Glow", (1, 1, 1), STRENGTH))
    patch = [(1.8, 0.0, 1.05), (1.8, 0.0, 1.45), (2.2, 0.0, 1.45), (2.2, 0.0, 1.05)]  # on the wall, facing +y
    ms.light_shape("Patch", patch, [[0, 1, 2, 3]], ms.emission("Patch glow", (1, 1, 1), STRENGTH))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "patch.blend"))

    def small(spacing):
        scene.hr.vertex_spacing = spacing
        res = run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 1))
        return [w for w in res.warnings if "of the face of 'Wall'" in w]

    (w,) = small(0.0)
    assert w.startswith("Light shape 'Patch' covers 2% of the face of 'Wall'"), w
    assert small(0.25) == []


# a 1 km terrain of 100 x 100 quads (10 m), a 2 m lamp 5 m above its middle facing down
TERRAIN_N, TERRAIN_SIZE = 100, 1000.0


def _terrain(ms):
    n, step = TERRAIN_N, TERRAIN_SIZE / TERRAIN_N
    verts = [(i * step, j * step, 0.0) for j in range(n + 1) for i in range(n + 1)]
    quads = [
        [j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i]
        for j in range(n)
        for i in range(n)
    ]
    terrain = ms.mesh_object("Terrain", verts, quads, ms.diffuse("Ground", (RHO,) * 3))
    c = TERRAIN_SIZE / 2
    lamp = [(c - 1, c - 1, 5), (c - 1, c + 1, 5), (c + 1, c + 1, 5), (c + 1, c - 1, 5)]  # (facing -z)
    ms.mesh_object("Sun lamp", lamp, [[0, 1, 2, 3]], ms.emission("Sun glow", (1, 1, 1), STRENGTH))
    return terrain


def test_a_large_terrain_stays_within_the_corner_budget_and_bakes(tmp_path):
    """A 1 km terrain of 100 x 100 quads at 0.25 m would get level 6 on every 10 m quad: 4,096 faces
    a face, 163,840,000 corners. The corner budget (own_values.budget, 200,000 for its 40,000 or so)
    raises the terrain's spacing alone (the largest object first) to just above 5 m, where each
    quad is cut once (level 1: 160,000 corners; level 2 would make 640,000), and says so in one log
    line; the wall and the lamp beside it keep 0.25 m (16 x 16 and 8 x 8). The counted corners are
    the evaluated meshes'; the bake runs, and the brightest corner of the terrain lies under the lamp."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame

    terrain = _terrain(ms)
    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "terrain.blend"))
    dg = bpy.context.evaluated_depsgraph_get()
    longest, n = ov.face_edges(terrain, dg)
    assert ov.corners_at(longest, n, 0.25) == 4 * 4**6 * TERRAIN_N**2
    own = sum(len(o.evaluated_get(dg).data.loops) for o in scene.objects if o.type == "MESH")
    assert 160_000 + 2_000 < ov.budget(own) < 4 * 160_000  # (level 1 fits with the rest, level 2 not)
    scene.hr.vertex_spacing = 0.25
    lines = []
    res = run_bake(scene, log=lambda line, **k: lines.append(line), quality="draft", frames=(1, 1))
    assert load_frame(scene, 1)
    budget_lines = [x for x in lines if "corner budget" in x]
    assert len(budget_lines) == 1 and "raised the spacing of 1 object(s): 'Terrain' 5 m" in budget_lines[0], (
        lines
    )
    assert not [w for w in res.warnings if "corner budget" in w]
    assert 5 < ov.subdividing(terrain) < 5 * (1 + 1e-5)
    assert {o.name: ov.subdividing(o) for o in bpy.data.objects if o.name in ("Wall", "Lamp", "Box")} == {
        "Wall": 0.25,
        "Lamp": 0.25,
        "Box": 0.0,  # (0.2 m edges: only its Bevel's helper)
    }
    dg = bpy.context.evaluated_depsgraph_get()
    corners = {o.name: len(o.evaluated_get(dg).data.loops) for o in scene.objects if o.type == "MESH"}
    assert corners["Terrain"] == 4 * 4 * TERRAIN_N**2 and corners["Wall"] == 1024
    assert sum(corners.values()) <= ov.budget(own)
    me = terrain.evaluated_get(dg).data
    a = me.attributes["HR_Radiance"]
    v = np.empty(len(a.data) * 4, np.float32)
    a.data.foreach_get("color", v)
    v = v.reshape(-1, 4)[:, :3].mean(1)
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    lv = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", lv)
    assert np.isfinite(v).all() and v.max() > 0
    assert np.abs(co.reshape(-1, 3)[lv[v.argmax()], :2] - TERRAIN_SIZE / 2).max() <= 10


def test_the_corner_budget_raises_the_largest_objects_first():
    """own_values.corner_budget on a 1 m bar (264 corners at 0.25 m: its long faces at level 2) and
    the one-quad wall (1,024: level 4), each budget one corner under the last result: the largest
    object's spacing is raised first, just past the next face threshold (4 m / 2^k for the wall:
    0.5 m gives 256 corners, 1 m 64, 2 m 16), the bar's when it is the largest (0.5 m: 72 corners;
    1 m: 24, its own faces: not subdivided, None), down to the objects' own corners when the budget
    is under them; a budget the scene fits changes nothing (empty)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    bar = ms.mesh_object(
        "Bar",
        [(x, y, z) for z in (0, 0.05) for y in (0, 0.1) for x in (0, 1.0)],
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]],
    )
    wall = ms.mesh_object("Wall", *WALL)
    dg = bpy.context.evaluated_depsgraph_get()
    objects = [bar, wall]
    assert ov.corners_at(*ov.face_edges(bar, dg), 0.25) == 4 * 16 * 4 + 2 * 4
    assert ov.corners_at(*ov.face_edges(wall, dg), 0.25) == 1024

    def raised(limit):
        out, counts, _ = ov.corner_budget(objects, objects, 0.25, dg, limit=limit)
        assert counts[:2] == (28, 1024 + 264)
        return {k: round(v, 4) if v is not None else v for k, v in out.items()}, counts[2]

    assert raised(1288) == ({}, 1288)
    assert raised(1287) == ({"Wall": 0.5}, 256 + 264)
    assert raised(519) == ({"Wall": 0.5, "Bar": 0.5}, 256 + 72)  # (the bar's 264 above 256)
    assert raised(327) == ({"Wall": 1.0, "Bar": 0.5}, 64 + 72)
    assert raised(135) == ({"Wall": 1.0, "Bar": None}, 64 + 24)  # (the bar at 1 m: its own faces)
    assert raised(87) == ({"Wall": 2.0, "Bar": None}, 16 + 24)
    assert raised(39) == ({"Wall": None, "Bar": None}, 4 + 24)
    assert raised(27) == ({"Wall": None, "Bar": None}, 28)  # (under the own corners: the least)
    # the raised spacings make what was counted: the wall at 1 m (just above) is cut 4 x 4
    out, _, _ = ov.corner_budget(objects, objects, 0.25, dg, limit=327)
    ov.ensure_own_values([wall], "CORNER", dg, out["Wall"])
    dg.update()
    assert len(wall.evaluated_get(dg).data.loops) == 64


def test_a_normal_room_is_left_as_it_was_by_the_corner_budget(tmp_path, monkeypatch):
    """The furnished sample at 0.25 m (92,104 corners for its 42,676) is within the budget: no
    budget line; the 509 objects with edges over 0.25 m at 0.25 m, and near_clutter's faces finer
    (one log line, 383 objects, the floor's and the walls' faces along furniture first; each face
    one or two levels finer: 153,472 corners counted on the evaluated meshes (session 32: 152,884
    on 144 objects, with the walls' faces along each other and the floor; session 33 leaves those
    concave junctions out: 133,480 on 138; session 34 adds thin faces, the books' spines and edges,
    within THIN_SHARE x BUDGET_FLOOR = 20,000 corners); 785 objects subdivided (579 before session
    34), every one at 0.25 m: the walls' 0.23 m quads by their FINER alone); at 0.15 m nothing
    raised. The
    wall scene (nothing within 0.25 m before its faces) baked at 0.25 m with the budget and
    without it (corner_budget replaced by one that changes nothing: the code before the budget)
    gives the same meshes and values, bit for bit."""
    bpy = load_bpy()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER
    from hr_addon.blender.scene_in import geometry_objects

    open_sample("furnished", tmp_path / "furnished")
    scene = bpy.context.scene
    dg = scene.view_layers[0].depsgraph
    objects = geometry_objects(scene.view_layers[0])  # at 0.15 m: 257,032 corners (x6.0), within
    finer = [o for o in objects if ov.has_coarse_edges(o, 0.15, dg)]
    assert ov.corner_budget(objects, finer, 0.15, dg) == ({}, (42_676, 257_032, 257_032), {})
    lines = []
    ov.ensure_own_values(objects, "CORNER", dg, 0.25, log=lines.append)
    # (the spacing's own note goes to log too since def26: only no budget line)
    clutter, line = lines
    assert "corner budget" not in line and line.startswith("Vertex Spacing 0.25: 785"), line
    assert clutter.startswith(
        "Vertex Spacing 0.25: 383 object(s) with surfaces close in front of part of their faces or a "
        "light's edge across them ('floor' 306 faces 17 m^2, 'wall_north' 162 faces 8.7 m^2"
    ), clutter
    spacings = {o.name: ov.subdividing(o) for o in scene.objects if o.type == "MESH" and ov.subdividing(o)}
    assert len(spacings) == 785 and set(spacings.values()) == {0.25}
    fine = {}
    for o in objects:
        if FINER in o.data.attributes:
            fine[o.name] = np.empty(len(o.data.polygons), np.int32)
            o.data.attributes[FINER].data.foreach_get("value", fine[o.name])
    assert len(fine) == 383 and np.bincount(fine["wall_north"]).tolist() == [150, 43, 119]
    dg.update()
    assert sum(len(o.evaluated_get(dg).data.loops) for o in objects) == 153_472

    bpy, ms, scene = empty_scene()
    _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))

    def bake():
        _bake(scene, 0.25)
        dg = bpy.context.evaluated_depsgraph_get()
        out = {}
        for o in scene.objects:
            if o.type == "MESH":
                me = o.evaluated_get(dg).data
                a = me.attributes["HR_Radiance"]
                v = np.empty(len(a.data) * 4, np.float32)
                a.data.foreach_get("color", v)
                co = np.empty(len(me.vertices) * 3, np.float32)
                me.vertices.foreach_get("co", co)
                out[o.name] = (co, v)
        return out

    with_budget = bake()
    monkeypatch.setattr(ov, "corner_budget", lambda *a, **k: ({}, None, {}))
    without = bake()
    assert with_budget.keys() == without.keys()
    for name, (co, v) in with_budget.items():
        np.testing.assert_array_equal(co, without[name][0], err_msg=name)
        np.testing.assert_array_equal(v, without[name][1], err_msg=name)


def _grid_wall(ms, name="Grid wall", nx=10, nz=5, step=0.2):
    """A 2 x 1 m wall at y = 0 facing +y, nx x nz quads of `step` m (under 0.25 m: the default spacing
    cuts none of them)."""
    verts = [(i * step, 0.0, k * step) for k in range(nz + 1) for i in range(nx + 1)]
    at = lambda i, k: k * (nx + 1) + i  # noqa: E731
    faces = [[at(i, k), at(i, k + 1), at(i + 1, k + 1), at(i + 1, k)] for k in range(nz) for i in range(nx)]
    return ms.mesh_object(name, verts, faces, ms.diffuse("Grey wall", (RHO,) * 3))


def _plate(ms, y, top, name="Plate"):
    """A plate wider than the grid wall and below it, parallel to it `y` m in front, from z = -0.2 to
    `top`."""
    return ms.mesh_object(
        name,
        [(-0.2, y, -0.2), (2.2, y, -0.2), (2.2, y, top), (-0.2, y, top)],
        [[0, 1, 2, 3]],
        ms.diffuse("Grey plate", (RHO,) * 3),
    )


@pytest.mark.parametrize(
    "y, top, cut",
    [
        (0.05, 0.45, True),  # 5 cm in front, over the lower 0.45 m: the faces at 0.4-0.6 m in part
        (0.05, 1.2, False),  # the whole wall behind it: no face of the wall in part
        (0.5, 0.45, False),  # 0.5 m in front: further than the spacing (CLUTTER_REACH 1)
    ],
)
def test_a_wall_with_something_close_before_part_of_it_gets_finer_corners(y, top, cut):
    """near_clutter on a 2 x 1 m wall of 0.2 m quads and a plate before it: with the plate 5 cm in front
    of its lower 0.45 m, the ten faces at 0.4-0.6 m (the third row) are covered in part (of their rays,
    from points 1/5 of a face apart, along the normal and tilted 45 degrees, some meet the plate, some
    pass above it: a share of 0.24), the rows below wholly, those above not at all. Only those ten
    faces take a finer level: the mesh's FINER 1 there (0.25 / 2: each 2 x 2, 12 corners more; 0.25 /
    4, 60 more, is not worth it at CLUTTER_WORTH 0.5 for a face a quarter in part), the modifier's
    spacing stays 0.25 m, 200 + 120 corners counted on the wall's evaluated mesh, and one log line
    names it; the plate over all of it, or half a metre away: no face in part, the wall keeps its own
    200 corners and gets no modifier. Delete Bake (remove_own_values) takes FINER off the mesh with
    the modifier."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER

    wall = _grid_wall(ms)
    plate = _plate(ms, y, top)
    dg = bpy.context.evaluated_depsgraph_get()
    share, area, _ = ov.near_clutter([wall, plate], [wall], dg, 0.25, 0.25)["Grid wall"]
    np.testing.assert_allclose(area, 0.04, rtol=1e-6)  # (float32 vertices)
    rows = share.reshape(5, 10)  # (faces row by row from z = 0)
    if cut:
        assert (rows[:2] == 1).all() and (rows[3:] == 0).all() and ((rows[2] > 0) & (rows[2] < 1)).all(), rows
    else:
        assert (share == (1 if top > 1 else 0)).all(), rows
    lines = []
    ov.ensure_own_values([wall, plate], "CORNER", dg, 0.25, log=lines.append)
    dg.update()
    assert len(wall.evaluated_get(dg).data.loops) == (320 if cut else 200)
    assert ov.subdividing(wall) == (0.25 if cut else 0.0)
    a = wall.data.attributes.get(FINER)
    assert (a is not None) == cut
    if cut:
        finer = np.empty(50, np.int32)
        a.data.foreach_get("value", finer)
        assert (finer.reshape(5, 10) == np.repeat([0, 0, 1, 0, 0], 10).reshape(5, 10)).all()
    # (the plate 5 cm before the wall is in part too, where it reaches past the wall: its one face
    # finer since session 33, when near_clutter's faces no longer share 1 x the scene's corners at
    # the spacing, 456 here, too few for its 2.4 x 1.4 m face)
    named = {
        (True, True): "'Plate' 1 faces 1.6 m^2, 'Grid wall' 10 faces 0.4 m^2",
        (True, False): "'Plate' 1 faces 3.4 m^2",
    }
    assert [x for x in lines if "close in front" in x] == (
        [
            f"Vertex Spacing 0.25: {1 + cut} object(s) with surfaces close in front of part of their "
            f"faces or a light's edge across them ({named[y < 0.1, cut]}): those faces cut to 0.0625 m "
            "(their light changes across them)."
        ]
        if y < 0.1
        else []
    )
    ov.remove_own_values([wall])
    assert FINER not in wall.data.attributes and not wall.modifiers


@pytest.mark.parametrize("length, level, corners", [(0.24, 2, 64), (0.3, 2, 256), (0.24, 0, 4), (0.3, 0, 16)])
def test_a_thin_face_with_something_close_before_part_of_it_gets_finer_corners(
    monkeypatch, length, level, corners
):
    """A bottle's side: one 1.5 cm wide quad `length` m tall (x 0-0.015, facing +y) and a plate 5 cm
    in front of its lower 8 cm. near_clutter finds it in part (some of its rays meet the plate, some
    pass above); by its area (0.0036 m^2 at 0.24 m) no finer level is worth the corners (FINER 1
    adds 12, 2 adds 60 against 8 x 0.0036 / 0.0625^2 = 7 at CLUTTER_WORTH 0.5), but it is thin
    (_thin: 16 x longer than wide, narrower than the finest spacing, cut at most once at 0.25 m), so
    FINER 2 (within THIN_SHARE of BUDGET_FLOOR): at 0.24 m level 2 (Subdivide Mesh's 4 x 4: 64
    corners, its light in four rows along it), at 0.3 m level 3 (8 x 8: 256). level 0: THIN_RATIO
    off (inf: before session 34), it keeps its corners at the spacing (4; 16 at 0.3 m, level 1) and
    no FINER."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER

    if not level:
        monkeypatch.setattr(ov, "THIN_RATIO", float("inf"))
    side = ms.mesh_object(
        "Side",
        [(0, 0, 0), (0.015, 0, 0), (0.015, 0, length), (0, 0, length)],
        [[0, 3, 2, 1]],
        ms.diffuse("Grey", (RHO,) * 3),
    )
    plate = ms.mesh_object(
        "Plate",
        [(-0.2, 0.05, -0.1), (0.2, 0.05, -0.1), (0.2, 0.05, 0.08), (-0.2, 0.05, 0.08)],
        [[0, 1, 2, 3]],
        ms.diffuse("Grey plate", (RHO,) * 3),
    )
    dg = bpy.context.evaluated_depsgraph_get()
    share, area, _ = ov.near_clutter([side, plate], [side], dg, 0.25, 0.25)["Side"]
    np.testing.assert_allclose(area, 0.015 * length, rtol=1e-5)
    assert (0 < share[0] < 1) if level else share[0] == 0, share  # (not looked at: 0)
    ov.ensure_own_values([side, plate], "CORNER", dg, 0.25, log=lambda line: None)
    dg.update()
    assert len(side.evaluated_get(dg).data.loops) == corners
    a = side.data.attributes.get(FINER)
    assert (a is not None) == bool(level)
    if level:
        finer = np.empty(1, np.int32)
        a.data.foreach_get("value", finer)
        assert finer[0] == level


def test_the_group_cuts_each_face_by_its_finer():
    """The subdividing group reads the mesh's FINER per face: the grid wall's 0.2 m quads at 0.25 m
    (level 0) with FINER 1 on its first row (2 x 2 each) and 2 on the second (4 x 4) make 200 +
    10 x 12 + 10 x 60 corners, as corners_at counts them; the row between them and the rest stay
    whole, and no vertex of the finer rows lies off the wall's plane or outside its 2 x 1 m."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    wall = _grid_wall(ms)
    dg = bpy.context.evaluated_depsgraph_get()
    longest, n = ov.face_edges(wall, dg)
    finer = np.repeat([1, 2, 0, 0, 0], 10).astype(np.int8)
    ov._ensure(wall, "CORNER", 0.25)
    ov._set_finer(wall.data, finer)
    dg.update()
    me = wall.evaluated_get(dg).data
    assert len(me.loops) == ov.corners_at(longest, n, 0.25, finer) == 200 + 10 * 12 + 10 * 60
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    assert np.abs(co[:, 1]).max() < 1e-6 and co[:, 0].min() > -1e-6 and co[:, 2].max() < 1 + 1e-6


def test_a_shared_mesh_or_one_whose_modifiers_change_its_faces_gets_no_finer_faces():
    """The grid wall with the plate 5 cm before its lower 0.45 m (the faces in part, as above), its
    mesh shared by a second object (a linked duplicate), or behind a Mirror modifier (its evaluated
    faces are not the mesh's): no FINER on the mesh, no log line, and the wall (0.2 m quads under
    0.25 m) not subdivided."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER

    for how in ("shared", "mirror"):
        bpy, ms, scene = empty_scene()
        wall = _grid_wall(ms)
        plate = _plate(ms, 0.05, 0.45)
        objects = [wall, plate]
        if how == "shared":
            twin = bpy.data.objects.new("Twin", wall.data)
            twin.location.y = -3
            scene.collection.objects.link(twin)
            objects.append(twin)
        else:
            wall.modifiers.new("Mirror", "MIRROR").use_axis = (False, False, True)
        dg = bpy.context.evaluated_depsgraph_get()
        lines = []
        ov.ensure_own_values(objects, "CORNER", dg, 0.25, log=lines.append)
        assert FINER not in wall.data.attributes and not [x for x in lines if "'Grid wall'" in x], how
        assert ov.subdividing(wall) == 0.0, how


def test_a_back_panel_between_shelf_boards_gets_finer_corners():
    """A 1.2 x 1.6 m back panel, one quad, and three boards 0.3 m deep, 2 cm thick, across it (their
    ends on it, at z 0.3, 0.7 and 1.1 m): the rays along the normal from the panel's centre and the
    points 0.8 of the way to its corners and edge middles (session 31's near_clutter) all pass
    between the boards, but the tilted ones near a board meet it: the panel is in part and its one
    face takes a finer level (FINER 1: level 4 instead of 3, 1,024 corners; level 5 is not worth its
    3,840 corners more for 1.9 m^2 about a fifth in part at CLUTTER_WORTH 0.5)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    corners = [(0, 0, 0), (1.2, 0, 0), (1.2, 0, 1.6), (0, 0, 1.6)]
    panel = ms.mesh_object("Panel", corners, [[0, 3, 2, 1]], ms.diffuse("Back", (RHO,) * 3))
    boards = []
    for z in (0.3, 0.7, 1.1):
        box = [(x, yy, zz) for zz in (z, z + 0.02) for yy in (0, 0.3) for x in (0, 1.2)]
        faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
        boards.append(ms.mesh_object(f"Board {z}", box, faces, ms.diffuse("Board", (RHO,) * 3)))
    dg = bpy.context.evaluated_depsgraph_get()
    assert tuple(panel.data.polygons[0].normal) == pytest.approx((0, 1, 0))
    (share,), _, _ = ov.near_clutter([panel, *boards], [panel], dg, 0.25, 0.25)["Panel"]
    assert 0 < share < 0.5
    ov.ensure_own_values([panel, *boards], "CORNER", dg, 0.25)
    dg.update()
    assert len(panel.evaluated_get(dg).data.loops) == 4 * 4**4 and ov.subdividing(panel) == 0.25


def test_the_clutter_does_not_depend_on_the_frames_baked(tmp_path):
    """The plate moves from 5 cm before the wall (frame 1, the scene's first) to 0.5 m (frame 3 on):
    a bake of frame 4 alone subdivides the wall as a bake of frame 1 does (the corners are static,
    taken at the scene's first frame: the ten faces 2 x 2, 320 corners, as in the test above)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.bake import run_bake

    wall = _grid_wall(ms)
    plate = _plate(ms, 0.05, 0.45)
    ms.mesh_object("Lamp", *LAMP, ms.emission("Glow", (1, 1, 1), STRENGTH))
    for frame, y in ((1, 0.0), (3, 0.45)):
        plate.location.y = y
        plate.keyframe_insert("location", frame=frame)
    scene.frame_start, scene.frame_end = 1, 5
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "plate.blend"))
    got = []
    for frames in ((4, 4), (1, 1)):
        scene.frame_set(frames[0])
        scene.hr.vertex_spacing = 0.25
        run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=frames)
        dg = bpy.context.evaluated_depsgraph_get()
        got.append((ov.subdividing(wall), len(wall.evaluated_get(dg).data.loops)))
    assert got == [(0.25, 320)] * 2


def test_at_a_fine_spacing_the_large_faces_are_cut_within_the_budget(tmp_path):
    """The furnished sample at 0.1 m would make 757,408 corners, over its budget (8 x 42,676 =
    341,408): one common spacing for every object (the books' too), so the walls, floor and ceiling
    (0.23-0.24 m quads) are cut at least once each way, where the largest-first rule (before session
    31) left them uncut. Counted on the evaluated meshes after ensure_own_values (not by the budget's
    own count): the scene's corners within the budget, and each room surface at least 4 x its own."""
    bpy = load_bpy()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.scene_in import geometry_objects

    open_sample("furnished", tmp_path / "furnished")
    vl = bpy.context.scene.view_layers[0]
    dg = vl.depsgraph
    objects = geometry_objects(vl)
    own = {o.name: len(o.evaluated_get(dg).data.loops) for o in objects}
    lines = []
    ov.ensure_own_values(objects, "CORNER", dg, 0.1, log=lines.append)
    dg.update()
    now = {o.name: len(o.evaluated_get(dg).data.loops) for o in objects}
    assert sum(own.values()) == 42_676 and sum(now.values()) <= ov.budget(42_676) == 341_408
    room = ("wall_north", "wall_south", "wall_east", "wall_west", "floor", "ceiling")
    assert all(now[n] >= 4 * own[n] for n in room), {n: (own[n], now[n]) for n in room}
    assert len([x for x in lines if "corner budget" in x]) == 1


def _bars(ms, n):
    """n bars 1 x 0.08 x 0.05 m side by side (4,104 corners each at 0.1 or 0.12 m, 24 their own)."""
    return [
        ms.mesh_object(
            f"Bar{k}",
            [(x, y + 0.3 * k, z) for z in (0, 0.05) for y in (1, 1.08) for x in (0, 1.0)],
            [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]],
        )
        for k in range(n)
    ]


@pytest.mark.parametrize("limit", [100_000, 60_000, 20_000, 5_000])
def test_the_budgets_corners_are_what_the_meshes_get_and_within_the_limit(limit):
    """A 4 m one-quad wall and 40 bars 1 x 0.08 x 0.05 m (at 0.1 m: 16,384 + 40 x 4,104 corners) under budgets
    that cut it: the spacings corner_budget gives, set by ensure_own_values' modifier, make
    evaluated meshes of exactly its total, within the limit, and every object's spacing is the
    common one or up to two of its steps finer (at most 4 x apart); the largest object is cut too."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    wall = ms.mesh_object("Wall", *WALL)
    bars = _bars(ms, 40)
    objects = [wall, *bars]
    dg = bpy.context.evaluated_depsgraph_get()
    out, (own, want, got), _ = ov.corner_budget(objects, objects, 0.1, dg, limit=limit)
    assert (own, want) == (4 + 40 * 24, 16_384 + 40 * 4_104)
    assert got <= limit
    for o in objects:
        ov._ensure(o, "CORNER", out.get(o.name, 0.1) or 0.0)
    dg.update()
    assert sum(len(o.evaluated_get(dg).data.loops) for o in objects) == got
    s = [v for v in out.values() if v is not None]
    assert s and max(s) <= 4 * min(s) * (1 + 1e-6)
    if limit >= 20_000:
        assert len(wall.evaluated_get(dg).data.loops) > 4


def test_over_the_budget_the_named_objects_keep_the_spacing_while_the_others_make_room():
    """corner_budget with a clutter entry over its limit: the grid wall (0.2 m quads: 800 corners at
    0.12 m) named by near_clutter keeps 0.12 m while ten 1 m bars (4,104 corners each at 0.12 m) share
    one coarser spacing, the total within the limit; when even the bars' own corners (24 each) leave
    no room for the wall's 800, it is raised with them (not in part: all or none)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    wall = _grid_wall(ms)
    bars = _bars(ms, 10)
    objects = [wall, *bars]
    dg = bpy.context.evaluated_depsgraph_get()
    clutter = {"Grid wall": (np.ones(50), np.full(50, 0.04))}  # (_cluttered's: every face weighed 1)
    out, (own, want, got), fine = ov.corner_budget(objects, objects, 0.12, dg, limit=10_000, clutter=clutter)
    assert (own, want) == (200 + 10 * 24, 800 + 10 * 4_104) and got <= 10_000
    assert "Grid wall" not in out and all(out[b.name] is None or out[b.name] > 0.12 for b in bars)
    assert fine == {}  # (over the budget no face gets finer than the spacing)
    out, (_, _, got), _ = ov.corner_budget(
        objects, objects, 0.12, dg, limit=800 + 10 * 24 - 1, clutter=clutter
    )
    assert out["Grid wall"] is None and got <= 800 + 10 * 24 - 1


# -- the group's output = the helper's mesh while the guard holds (session 32, branch playfix) --

PROBE = "probe"  # an attribute only the helper's mesh has: shown while the group outputs that mesh


def _guarded_wall(ms, shape_key=False, uv=True):
    """The wall (a UV map unless not uv, a second material; shape_key: a shape key at 0) with its
    subdividing modifier and helper at 0.25 m (ensure_own_values), random HR_Radiance and PROBE on
    the helper's mesh; (wall, the helper's mesh)."""
    import bpy
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.playback import write_attribute

    wall = _scene(ms)
    if uv:
        wall.data.uv_layers.new(name="UVMap")
    wall.data.materials.append(ms.diffuse("Red", (0.5, 0.1, 0.1)))
    if shape_key:
        wall.shape_key_add(name="Basis")
        key = wall.shape_key_add(name="Key")
        key.data[0].co.y += 0.1
        key.value = 0.0
    dg = bpy.context.evaluated_depsgraph_get()
    ov.ensure_own_values([wall], "CORNER", dg, 0.25)
    md = wall.modifiers[-1]
    me = md[md.node_group.interface.items_tree["Values"].identifier].data
    write_attribute(me, np.random.default_rng(1).random((len(me.loops), 4), np.float32), "CORNER")
    me.attributes.new(PROBE, "FLOAT", "POINT")
    wall.update_tag()
    return wall, me


def _evaluated(obj):
    """obj's evaluated mesh: {attribute: (domain, its values' bytes)} and its materials' names."""
    import bpy

    me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    out = {}
    for a in me.attributes:
        if a.name.startswith(".a_"):  # (anonymous: Capture Attribute's seam flag, not kept in a copy)
            continue
        width = {"FLOAT_VECTOR": 3, "FLOAT_COLOR": 4, "FLOAT2": 2, "INT32_2D": 2}.get(a.data_type, 1)
        key = {"FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color", "FLOAT2": "vector"}.get(a.data_type, "value")
        kind = {"INT": np.int32, "BOOLEAN": bool, "INT32_2D": np.int32}.get(a.data_type, np.float32)
        v = np.empty(len(a.data) * width, kind)
        a.data.foreach_get(key, v)
        out[a.name] = (a.domain, v.tobytes())
    return out, [m.name for m in me.materials]


def _edit(wall, what):
    import bpy

    if what.startswith("position"):
        wall.data.vertices[2].co.x += 1e-4
    elif what == "uv":
        wall.data.uv_layers["UVMap"].uv[1].vector = (0.25, 0.75)
    elif what == "material index":
        wall.data.polygons[0].material_index = 1
    elif what == "modifier":
        wall.modifiers.new("Displace", "DISPLACE").strength = 0.1
        wall.modifiers.move(len(wall.modifiers) - 1, 0)
    elif what == "shape key":
        wall.data.shape_keys.key_blocks["Key"].value = 1.0
    wall.data.update()
    bpy.context.view_layer.update()


@pytest.mark.parametrize(
    "what", ["position", "position, no attributes", "uv", "material index", "modifier", "shape key"]
)
def test_the_group_shows_the_helpers_mesh_until_an_edit(what):
    """While the mesh the group receives is the bake's (its GUARD, the sum and variance of a hash
    per corner, is the helper's), the group's output is the helper's mesh (PROBE shows), bit for bit what the
    subdivision makes (every attribute, HR_Radiance from the helper, the materials); an edit after
    the bake (positions, UVs, a material index, a deforming modifier or a shape key below the
    group) makes the group subdivide again: the edit shows. A mesh without attributes of its own
    (no UV map): the group's GUARDS slots are empty (skipped) and the same holds."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import GUARD

    wall, me = _guarded_wall(ms, what == "shape key", uv=what != "position, no attributes")
    md = wall.modifiers[-1]
    slots = [md[ov._socket(md, f"{ov.GUARDS} {k + 1}")] for k in range(ov.GUARDED)]
    assert slots == ([""] * 4 if what == "position, no attributes" else ["UVMap"] + ["position"] * 3)
    (attrs, mats) = _evaluated(wall)
    assert PROBE in attrs and mats == ["Grey", "Red"] and GUARD in attrs
    guard = me.attributes[GUARD]
    saved = np.empty(3 * len(guard.data), np.float32)
    guard.data.foreach_get("vector", saved)
    me.attributes.remove(guard)  # the guard broken: the subdivision's own output
    wall.update_tag()
    (sub, sub_mats) = _evaluated(wall)
    del attrs[PROBE]
    assert PROBE not in sub and sub == attrs and sub_mats == mats
    me.attributes.new(GUARD, "FLOAT_VECTOR", ov.GUARD_DOMAIN).data.foreach_set("vector", saved)
    wall.update_tag()
    assert PROBE in _evaluated(wall)[0]
    _edit(wall, what)
    edited, _ = _evaluated(wall)
    assert PROBE not in edited
    name = {"uv": "UVMap", "material index": "material_index"}.get(what, "position")
    assert edited[name] != attrs.get(name), what
    assert edited[GUARD] != attrs[GUARD]


def test_helpers_hold_their_objects_materials():
    """The helper's mesh holds the object's materials (the evaluated mesh's while the guard
    holds): a slot given another material after the bake is synced by the depsgraph handler and by
    the stale check (own_values.sync_materials), so the evaluated object shows the new one; more
    attributes than the guard reads (GUARDED): no GUARD on the helper, the group subdivides."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import GUARD

    wall, me = _guarded_wall(ms)
    assert [m.name for m in me.materials] == ["Grey", "Red"]
    blue = ms.diffuse("Blue", (0.1, 0.1, 0.5))
    wall.data.materials[1] = blue
    bpy.context.view_layer.update()  # (playback.on_depsgraph_update syncs the helper)
    assert [m.name for m in me.materials] == ["Grey", "Blue"]
    assert _evaluated(wall)[1] == ["Grey", "Blue"] and PROBE in _evaluated(wall)[0]
    me.materials[1] = None  # (an edit the handler did not see)
    assert ov.sync_materials([wall]) == [wall] and ov.sync_materials([wall]) == []
    for k in range(ov.GUARDED + 1 - len(ov._guard_names(wall))):
        wall.data.attributes.new(f"extra {k}", "FLOAT", "POINT")
    ov.ensure_own_values([wall], "CORNER", bpy.context.evaluated_depsgraph_get(), 0.25)
    md = wall.modifiers[-1]
    me = md[md.node_group.interface.items_tree["Values"].identifier].data
    assert GUARD not in me.attributes
    me.attributes.new(PROBE, "FLOAT", "POINT")
    wall.update_tag()
    assert PROBE not in _evaluated(wall)[0]


def test_a_material_changed_after_the_bake_shows_and_the_check_names_it(tmp_path):
    """After a bake at 0.25 m the wall shows its helper's mesh, which holds its material; another
    material in its slot shows (the depsgraph handler syncs the helper) and the stale check names
    the wall, also when the helper was not synced before it (the check syncs first)."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)
    from hr_addon.blender.playback import check_scene

    wall = _scene(ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "wall.blend"))
    _bake(scene, 0.25)
    md = wall.modifiers[-1]
    me = md[md.node_group.interface.items_tree["Values"].identifier].data
    me.attributes.new(PROBE, "FLOAT", "POINT")
    wall.update_tag()
    assert PROBE in _evaluated(wall)[0] and _evaluated(wall)[1] == ["Grey"]
    assert check_scene(scene, force=True) == ""
    grey, blue = wall.data.materials[0], ms.diffuse("Blue", (0.1, 0.1, 0.5))
    wall.data.materials[0] = blue
    bpy.context.view_layer.update()
    assert _evaluated(wall)[1] == ["Blue"]
    assert "'Wall'" in check_scene(scene, force=True)
    wall.data.materials[0] = grey
    bpy.context.view_layer.update()
    assert check_scene(scene, force=True) == ""
    wall.data.materials[0] = blue
    me.materials[0] = grey  # (the helper not synced: an edit the handler did not see)
    assert "'Wall'" in check_scene(scene, force=True)
    assert _evaluated(wall)[1] == ["Blue"] and PROBE in _evaluated(wall)[0]


def test_a_modifier_that_sets_materials_gets_no_guard():
    """A geometry-nodes modifier below the group that sets the faces' material: the subdivided
    mesh's materials are not the object's mesh's, which the helper holds, so its helper gets no
    GUARD and the group subdivides (the modifier's material shows)."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import GUARD

    wall = _scene(ms)
    red = ms.diffuse("Red", (0.5, 0.1, 0.1))
    g = bpy.data.node_groups.new("Paint", "GeometryNodeTree")
    g.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    g.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go, paint = (g.nodes.new(k) for k in ("NodeGroupInput", "NodeGroupOutput", "GeometryNodeSetMaterial"))
    paint.inputs["Material"].default_value = red
    g.links.new(gi.outputs[0], paint.inputs["Geometry"])
    g.links.new(paint.outputs["Geometry"], go.inputs[0])
    wall.modifiers.new("Paint", "NODES").node_group = g
    ov.ensure_own_values([wall], "CORNER", bpy.context.evaluated_depsgraph_get(), 0.25)
    md = wall.modifiers[-1]
    me = md[md.node_group.interface.items_tree["Values"].identifier].data
    assert md.name == ov.N_VALUES and GUARD not in me.attributes
    me.attributes.new(PROBE, "FLOAT", "POINT")
    wall.update_tag()
    attrs, mats = _evaluated(wall)
    assert PROBE not in attrs and "Red" in mats


def test_the_guard_holds_in_the_saved_file(tmp_path):
    """The helper's .HR_Guard, its materials and the group's inputs are saved: the file opened
    again shows the helper's mesh (PROBE), with the object's materials."""
    bpy, ms, scene = empty_scene()
    _needs_the_guard(bpy)

    _guarded_wall(ms)
    path = str(tmp_path / "guarded.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    attrs, mats = _evaluated(bpy.data.objects["Wall"])
    assert PROBE in attrs and mats == ["Grey", "Red"]


# -- light shapes' outlines and concave junctions (session 33, branch outline) --------------------


def _window_on_wall(ms, x0=0.25, x1=0.75, z0=0.25, z1=0.75, name="Window"):
    """The grid wall and a light shape on it (facing +y, the wall's way) from x0 to x1, z0 to z1: its
    outline crosses the 0.2 m quads it runs through (at a quarter of them: 0.25 / 0.75)."""
    wall = _grid_wall(ms)
    verts = [(x0, 0.0, z0), (x0, 0.0, z1), (x1, 0.0, z1), (x1, 0.0, z0)]
    ms.light_shape(name, verts, [[0, 1, 2, 3]], ms.emission("Sun", (1.0, 0.9, 0.8), 4.0))
    return wall


def test_faces_a_light_shapes_outline_crosses_get_finer_corners_there_only():
    """A 0.5 m light shape on the grid wall (0.2 m quads; nothing in front of it, so near_clutter's
    rays see nothing): the faces its outline crosses, the ring of 12 around its middle four, get FINER
    2 (0.25 / 4: worth their 60 corners each at weight 1); the faces wholly inside or outside it keep
    theirs. outline_faces reads the shape's outline (lights_in.light_edges) and a shape keyed to
    move is read over the scene's frames: moved 0.4 m along x from frame 1 to 5, the faces its outline
    crosses on any frame (ring by ring across the wall) get them too."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.lights_in import light_edges
    from hr_addon.blender.names import FINER

    wall = _window_on_wall(ms)
    vl = scene.view_layers[0]
    dg = vl.depsgraph
    outlines, cones = light_edges(scene, vl)
    assert len(outlines) == 1 and len(outlines[0]) == 1 and not len(cones)
    ring = np.zeros((5, 10), bool)
    ring[1:4, 1:4] = True  # (rows from z = 0, columns from x = 0)
    ring[2, 2] = False  # (0.4-0.6: wholly inside)
    crossed = ov.outline_faces([wall], dg, outlines)["Grid wall"].reshape(5, 10)
    assert (crossed == ring).all(), crossed.astype(int)
    lines = []
    ov.ensure_own_values([wall], "CORNER", dg, 0.25, log=lines.append, outlines=outlines)
    finer = np.empty(50, np.int32)
    wall.data.attributes[FINER].data.foreach_get("value", finer)
    assert (finer.reshape(5, 10) == 2 * ring).all(), finer.reshape(5, 10)
    dg.update()
    assert len(wall.evaluated_get(dg).data.loops) == 200 + 8 * 60
    # moving: keyed from x 0.25 to 0.65, frames 1 to 5 (the wall as it was: its own faces)
    ov.remove_own_values([wall])
    dg.update()
    shape = bpy.data.objects["Window"]
    scene.frame_start, scene.frame_end = 1, 5
    for frame, x in ((1, 0.0), (5, 0.4)):
        shape.location.x = x
        shape.keyframe_insert("location", frame=frame)
    scene.frame_set(3)
    outlines, _ = light_edges(scene, vl)
    assert scene.frame_current == 3 and len(outlines) == 5  # (at frames 1 to 5)
    crossed = ov.outline_faces([wall], dg, outlines)["Grid wall"].reshape(5, 10)
    assert crossed[[0, 4]].sum() == 0 and crossed[1:4, 1:6].all() and crossed[1:4, 6:].sum() == 0, crossed


def _face_integrals(obj, step=0.2, nx=10):
    """(50,) the grid wall's shown HR_Radiance (mean of RGB) integrated over each of its 0.2 m quads:
    the evaluated polygons' area x their corners' mean, summed by the quad holding each one's centre."""
    from test_blender_helpers import shown

    bpy = load_bpy()
    me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    v = shown(obj)[:, :3].mean(1)
    n = len(me.polygons)
    area, cen, start, total = np.empty(n), np.empty(n * 3), np.empty(n, np.int64), np.empty(n, np.int64)
    me.polygons.foreach_get("area", area)
    me.polygons.foreach_get("center", cen)
    me.polygons.foreach_get("loop_start", start)
    me.polygons.foreach_get("loop_total", total)
    cen = cen.reshape(-1, 3)
    mean = np.add.reduceat(v, start) / total  # (loops are in polygon order)
    quad = (cen[:, 2] // step).astype(int) * nx + (cen[:, 0] // step).astype(int)
    return np.bincount(quad, area * mean, 50)


def test_a_light_shapes_outline_across_a_wall_reads_closer_to_a_fine_bake(tmp_path, monkeypatch):
    """The grid wall with the 0.5 m light shape on it baked (vertex output, draft) at 0.25 m with the
    outline's faces finer (FINER 2 on the ring of 12), at 0.25 m without (CLUTTER_LEVELS 0: before
    session 33 no face of it was finer, nothing stands before it) and at 0.05 m (every quad 4 x 4:
    the reference): the light integrated over each quad the outline crosses is closer to the
    reference's with the finer faces (the outline runs a quarter of the way into them: a coarse
    quad's corners read its step at the quad's edge: 0.0365 before, 0.0815 with them, 0.0815 the
    reference, as a side quad's 0.082 light); the quads wholly inside or outside read about the same
    in both."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame

    wall = _window_on_wall(ms)
    ms.mesh_object("Lamp", *LAMP, ms.emission("Glow", (1, 1, 1), STRENGTH))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "window.blend"))
    got = {}
    for key, spacing, levels in (("outline", 0.25, 2), ("before", 0.25, 0), ("fine", 0.05, 0)):
        monkeypatch.setattr(ov, "CLUTTER_LEVELS", levels)
        scene.hr.vertex_spacing = spacing
        run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 1))
        assert load_frame(scene, 1)
        got[key] = _face_integrals(wall)
    ring = np.zeros((5, 10), bool)
    ring[1:4, 1:4] = True
    ring[2, 2] = False
    ring = ring.ravel()
    err = {k: np.abs(got[k] - got["fine"]) for k in ("outline", "before")}
    assert (err["outline"][ring] < err["before"][ring]).all(), (err["outline"][ring], err["before"][ring])
    assert err["outline"][ring].sum() < 0.25 * err["before"][ring].sum()
    # the others: as before, within the draft gather's sampling (up to 7% on the faces only the lamp
    # lights, 1,000 x darker than the shape: their samples are drawn anew with the finer faces')
    np.testing.assert_allclose(got["outline"][~ring], got["before"][~ring], rtol=0.1)


def test_a_floor_along_a_wall_is_not_in_part_a_panel_under_a_board_is(monkeypatch):
    """A 2 x 1 m floor of 0.2 m quads and a wall standing on its back edge (y = 1, the floor's
    edge): the floor's faces along the wall see the wall with their tilted rays, a concave junction
    at their own edge (JUNCTION): not in part (before session 33: a share of 0.18-0.2 along the wall,
    so the room samples' floors, walls and ceilings were cut along every junction), nor the wall's
    one face, whose bottom edge the floor holds (0.034 before). A board 0.2 m deep standing on the
    floor across its middle (x 0.9-0.95, its foot inside the faces at x 0.8-1.0): those faces are in
    part (its shadow's edge may cross them)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov

    step, nx, ny = 0.2, 10, 5
    verts = [(i * step, j * step, 0.0) for j in range(ny + 1) for i in range(nx + 1)]
    at = lambda i, j: j * (nx + 1) + i  # noqa: E731
    faces = [[at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)] for j in range(ny) for i in range(nx)]
    floor = ms.mesh_object("Floor", verts, faces, ms.diffuse("Grey floor", (RHO,) * 3))
    wall = ms.mesh_object(
        "Wall",
        [(0, 1, 0), (2, 1, 0), (2, 1, 1), (0, 1, 1)],
        [[0, 1, 2, 3]],  # (facing -y: into the room)
        ms.diffuse("Grey wall", (RHO,) * 3),
    )
    dg = bpy.context.evaluated_depsgraph_get()
    found = ov.near_clutter([floor, wall], [floor, wall], dg, 0.25, 0.25)
    assert (found["Floor"][0] == 0).all() and (found["Wall"][0] == 0).all(), found
    monkeypatch.setattr(ov, "_junction", lambda *a: np.zeros(len(a[5]), bool))
    share = ov.near_clutter([floor, wall], [floor, wall], dg, 0.25, 0.25)["Floor"][0].reshape(ny, nx)
    assert (share[-1] > 0.15).all() and (share[:-1] == 0).all(), share  # (the rule off: as before)
    monkeypatch.undo()
    box = [(x, y, z) for z in (0, 0.6) for y in (0.2, 0.4) for x in (0.9, 0.95)]
    cube = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    board = ms.mesh_object("Board", box, cube, ms.diffuse("Board", (RHO,) * 3))
    dg = bpy.context.evaluated_depsgraph_get()
    share = ov.near_clutter([floor, wall, board], [floor], dg, 0.25, 0.25)["Floor"][0].reshape(ny, nx)
    part = (share > 0) & (share < 1)
    assert part[1:3, 4].all() and part[:, :3].sum() == 0 and part[:, 6:].sum() == 0, share


def _one_cone(scene):
    """(depsgraph, cones) of a scene with one Blender light and no light shape: light_edges' one cone."""
    from hr_addon.blender.lights_in import light_edges

    vl = scene.view_layers[0]
    dg = vl.depsgraph
    dg.update()
    outlines, cones = light_edges(scene, vl)
    assert not outlines and len(cones) == 1
    return dg, cones


def test_faces_a_spot_lights_footprint_edge_crosses_get_finer_corners():
    """A spot light 1 m before the grid wall aimed at its middle (x 1, z 0.5), its cone 30 degrees
    wide: a footprint about 0.54 m across whose edge crosses the ring of quads around its middle
    (near_clutter's third array: of the points of a face, some inside the cone and in its sight,
    some not); those faces alone weigh 1 and get FINER 2, the quads wholly inside or outside keep
    theirs."""
    import math

    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER

    wall = _grid_wall(ms)
    spot = bpy.data.objects.new("Spot", bpy.data.lights.new("Spot", "SPOT"))
    spot.data.energy, spot.data.spot_size = 200.0, math.radians(30)
    spot.location, spot.rotation_euler = (1.0, 1.0, 0.5), (math.radians(-90), 0, 0)  # (-z to -y)
    scene.collection.objects.link(spot)
    dg, cones = _one_cone(scene)
    np.testing.assert_allclose(cones[0, 3:6], (0, -1, 0), atol=1e-6)
    _, _, edge = ov.near_clutter([wall], [wall], dg, 0.25, 0.25, cones)["Grid wall"]
    edge = edge.reshape(5, 10)
    r = math.tan(math.radians(15))  # (the footprint's radius: 0.268 m about (1, 0.5))
    x, z = np.meshgrid(np.arange(10) * 0.2, np.arange(5) * 0.2)
    corners = [np.hypot(x + dx - 1, z + dz - 0.5) for dx in (0, 0.2) for dz in (0, 0.2)]
    inside_all = np.all([c < r for c in corners], 0)
    far = np.hypot(np.clip(1, x, x + 0.2) - 1, np.clip(0.5, z, z + 0.2) - 0.5) > r  # (nearest point out)
    assert not (edge & far).any() and not (edge & inside_all).any(), edge.astype(int)
    assert edge.sum() >= 8, edge.astype(int)
    lines = []
    ov.ensure_own_values([wall], "CORNER", dg, 0.25, log=lines.append, cones=cones)
    finer = np.empty(50, np.int32)
    wall.data.attributes[FINER].data.foreach_get("value", finer)
    assert (finer.reshape(5, 10) == 2 * edge).all(), finer.reshape(5, 10)


@pytest.mark.parametrize("kind", ["POINT", "SUN"])
def test_faces_a_point_lights_or_suns_shadow_edge_crosses_get_finer_corners(kind):
    """A point light 2 m before the grid wall (x 1, z 0.5), or a sun shining straight at it, and a
    0.3 x 0.25 m card 1 m before the wall between them: the card's shadow on the wall (0.6 x 0.5 m
    from the point light, 0.3 x 0.25 m from the sun, about (1, 0.5)) has its edges across quads. The
    card is farther than near_clutter's rays reach: only the light's shadow edge (light_edges' cone
    of a point light, cos -1; a sun's direction) can find them. Exactly the quads the shadow covers in
    part weigh 1 and get FINER 2 (session 36: the loft's shelf items under the pendant's shade,
    which only spots' cones were looked at for); those wholly in it or out of it keep theirs."""
    import math

    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.lights_in import SUN_CONE
    from hr_addon.blender.names import FINER

    wall = _grid_wall(ms)
    w, h = 0.3, 0.25
    card = ms.mesh_object(
        "Card",
        [
            (1 - w / 2, 1.0, 0.5 - h / 2),
            (1 + w / 2, 1.0, 0.5 - h / 2),
            (1 + w / 2, 1.0, 0.5 + h / 2),
            (1 - w / 2, 1.0, 0.5 + h / 2),
        ],
        [[0, 1, 2, 3]],
        ms.diffuse("Card", (RHO,) * 3),
    )
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", kind))
    light.location, light.rotation_euler = (1.0, 2.0, 0.5), (math.radians(-90), 0, 0)  # (-z to -y)
    scene.collection.objects.link(light)
    dg, cones = _one_cone(scene)
    if kind == "SUN":
        np.testing.assert_allclose(cones[0], (0, 0, 0, 0, -1, 0, SUN_CONE), atol=1e-6)
    else:
        np.testing.assert_allclose(cones[0], (1, 2, 0.5, 0, -1, 0, -1), atol=1e-6)
    found = ov.near_clutter([wall, card], [wall], dg, 0.25, 0.25, cones)["Grid wall"]
    assert (found[0] == 0).all(), found[0]  # (the card is beyond the rays' reach)
    grow = 2.0 if kind == "POINT" else 1.0  # (the shadow's size over the card's)
    x0, x1, z0, z1 = 1 - grow * w / 2, 1 + grow * w / 2, 0.5 - grow * h / 2, 0.5 + grow * h / 2
    x, z = np.meshgrid(np.arange(10) * 0.2, np.arange(5) * 0.2)
    meets = (x < x1) & (x + 0.2 > x0) & (z < z1) & (z + 0.2 > z0)
    inside = (x >= x0) & (x + 0.2 <= x1) & (z >= z0) & (z + 0.2 <= z1)
    edge = found[2].reshape(5, 10)
    assert (edge == (meets & ~inside)).all() and edge.sum() >= 6, edge.astype(int)
    ov.ensure_own_values([wall, card], "CORNER", dg, 0.25, log=[].append, cones=cones)
    finer = np.empty(50, np.int32)
    wall.data.attributes[FINER].data.foreach_get("value", finer)
    assert (finer.reshape(5, 10) == 2 * edge).all(), finer.reshape(5, 10)


def test_an_ngon_the_spacing_leaves_whole_gets_a_centre_corner_where_a_shadow_crosses_it():
    """A plate's top: a 32-gon 0.22 m across (span 0.219 m: level 0 at 0.25 m, its 32 rim corners
    only), a point light 1 m above it and a 8 cm box (a cup) standing on its rim towards the light
    (its shadow and its foot over part of the rim). The loft's Plate 1 so (session 36) read -27% in
    its direct light: three dark rim corners, which Blender's triangulation of the n-gon spreads over
    long triangles across it. Its first level (32 quads about a corner at its centre: 96 corners
    more for 0.038 m^2) is not worth its area by CLUTTER_WORTH, as a quad's would be; an n-gon's first
    level is a choice anyway, where the light changes across it: FINER 1 (before: none)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.lights_in import light_edges
    from hr_addon.blender.names import FINER

    seg, R = 32, 0.11
    t = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    disc = ms.mesh_object(
        "Plate",
        np.c_[R * np.cos(t), R * np.sin(t), np.zeros(seg)],
        [list(range(seg))],
        ms.diffuse("P", (RHO,) * 3),
    )
    box = [(x, y, z) for z in (0, 0.09) for y in (-0.04, 0.04) for x in (0.1, 0.18)]
    cube = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    cup = ms.mesh_object("Cup", box, cube, ms.diffuse("Cup", (RHO,) * 3))
    point = bpy.data.objects.new("Point", bpy.data.lights.new("Point", "POINT"))
    point.location = (0.35, 0.0, 1.0)  # (beyond the cup: its shadow falls on the plate)
    scene.collection.objects.link(point)
    vl = scene.view_layers[0]
    dg = vl.depsgraph
    dg.update()
    longest, n = ov.face_edges(disc, dg)
    assert ov.levels(longest, 0.25)[0] == 0 and n[0] == seg
    _, cones = light_edges(scene, vl)
    share, area, edge = ov.near_clutter([disc, cup], [disc], dg, 0.25, 0.25, cones)["Plate"]
    assert edge[0] and 0 < share[0] < 1, (share, edge)
    add, ok = ov._choices(longest, n, 0.25, area)
    assert add[0, 0] == 96 and not ok.any()  # (by its area alone: no level)
    ov.ensure_own_values([disc, cup], "CORNER", dg, 0.25, log=[].append, cones=cones)
    finer = np.empty(1, np.int32)
    disc.data.attributes[FINER].data.foreach_get("value", finer)
    assert finer[0] == 1


def test_an_ngon_disc_under_a_point_light_gets_corners_inside_it(tmp_path):
    """A table top's n-gon: a 64-gon disc 0.55 m in radius (5.4 cm edges, none longer than 0.25 m)
    spans 1.1 m (_ngon_span: twice its centre's distance from an edge's midpoint), so at 0.25 m it
    gets level 3 like a 1.1 m quad: Subdivide Mesh cuts it into 64 x 16 quads, corners_at's count,
    with a vertex at its centre (session 34's loft: its table top had corners on the rim only and
    read -11 to -15% under the pendant). Baked under a point light 1 m above its centre (nothing
    else in the scene: direct light only), its corners read the point light's light, h / (h^2 +
    r^2)^1.5 x rho I / pi (I = P / 4 pi) at the points the vertex layout reads (OUTPUT_INSET towards
    each face's centre, the mean over a vertex's corners): the centre 1.49 x the rim."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender.playback import load_frame
    from hr_addon.blender.scene_in import mesh_topology

    seg, R, h = 64, 0.55, 1.0
    t = np.linspace(0, 2 * np.pi, seg, endpoint=False)
    ring = np.c_[R * np.cos(t), R * np.sin(t), np.zeros(seg)]
    disc = ms.mesh_object("Disc", ring, [list(range(seg))], ms.diffuse("Top", (RHO,) * 3))
    point = bpy.data.objects.new("Point", bpy.data.lights.new("Point", "POINT"))
    point.data.energy, point.data.shadow_soft_size, point.location = 50.0, 0.0, (0, 0, h)
    scene.collection.objects.link(point)
    dg = bpy.context.evaluated_depsgraph_get()
    longest, n = ov.face_edges(disc, dg)
    np.testing.assert_allclose(longest, 2 * R * np.cos(np.pi / seg), rtol=1e-6)
    assert ov.has_coarse_edges(disc, 0.25, dg) and ov.levels(longest, 0.25)[0] == 3
    scene.hr.vertex_spacing = 0.25
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "disc.blend"))
    run_bake(scene, log=lambda *a, **k: None, quality="draft", frames=(1, 1))
    assert load_frame(scene, 1)
    me = disc.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    co, ls, lt, lv = mesh_topology(me)
    assert len(lv) == ov.corners_at(longest, n, 0.25) == seg * 4**3 and (lt == 4).all()
    r = np.hypot(co[:, 0], co[:, 1])
    assert r.min() < 1e-6  # (its centre)
    v = np.empty(len(lv) * 4, np.float32)
    me.attributes["HR_Radiance"].data.foreach_get("color", v)
    val = v.reshape(-1, 4)[:, 0].astype(np.float64)
    poly = np.repeat(np.arange(len(ls)), lt)
    centre = np.stack([np.bincount(poly, co[lv, c]) / lt for c in range(3)], 1)[poly]
    at = co[lv] + OUTPUT_INSET * (centre - co[lv])
    e = h / (h * h + (at[:, :2] ** 2).sum(1)) ** 1.5
    ref = (np.bincount(lv, e, len(co)) / np.bincount(lv, minlength=len(co)))[lv]
    ref *= RHO * cf.point_light_irradiance(point.data.energy, 1.0, 1.0) / np.pi
    # (within 0.5%, not the exact direct light's 1e-5: corner_fit shifts the cut faces' corners to
    # keep each face's light, layouts.FIT; measured 0.38%)
    np.testing.assert_allclose(val, ref, rtol=5e-3)
    assert val[r[lv] < 1e-6].mean() / val[r[lv] > R - 1e-4].mean() > 1.45


def test_faces_close_to_a_point_light_get_pieces_that_show_the_light_at_their_edge():
    """near_light_finer on the loft's lamp shade (session 37): a 28.4 cm face whose plane passes
    h = 15.7 cm from the bulb, the light's foot 15.5 cm up from its rim. The vertex output shows
    along the rim the corners' values, each read OUTPUT_INSET of the way to its piece's centre, so
    the mean of the interpolant over the strip a camera sees into the shade's mouth (its first 1.6 cm)
    is set against the exact mean of cos / d^2 over it (closed form: the integral of h / (h^2 +
    x^2)^1.5 is x / (h sqrt(h^2 + x^2))). At the spacing alone (0.25 m: the face halved) it reads
    +25% (the camera's +25% on those pixels); the rule's 2 levels finer (pieces of 3.55 cm, at most
    NEAR_LIGHT x its centre's 15.8 cm) +5%. The same face facing away, 1 m off, outside a spot's
    cone, or by an area light or a sun: none finer; facing away with both sides lit (a Solidify's
    shells): finer too."""
    from hr_addon.blender import own_values as ov

    h, foot, length, spacing = 0.157, 0.155, 0.284, 0.25
    light = np.array([0.0, 0.0, h])
    # faces in the plane z = 0 along x, the light's foot at x = foot: the rim at x = 0
    centre = np.array([[length / 2 - foot, 0, 0]] * 4) + [[0, 0, 0], [0, 0, 0], [1.0, 0, 0], [0, 0, 0]]
    normal = np.array([[0, 0, 1.0], [0, 0, -1], [0, 0, 1], [0, 0, 1]])
    longest = np.full(4, length, np.float32)
    point = np.r_[light, 0, 0, -1, -1.0]
    finer = ov.near_light_finer(longest, centre, normal, [point], spacing)
    assert finer.tolist() == [2, 0, 0, 2]
    assert ov.near_light_finer(longest, centre, normal, [point], spacing, both=True).tolist() == [2, 2, 0, 2]
    away = np.r_[light, 0, 0, 1, np.cos(np.radians(25))]  # a spot pointing up, away from the faces
    down = np.r_[light, 0, 0, -1, np.cos(np.radians(25))]  # ... pointing down: the first face in it
    assert ov.near_light_finer(longest, centre, normal, [away], spacing).tolist() == [0, 0, 0, 0]
    assert ov.near_light_finer(longest, centre, normal, [down], spacing)[0] == 2
    area, sun = np.r_[light, 0, 0, -1, 0.0], np.r_[0, 0, 0, 0, 0, -1, 2.0]  # (light_edges': not 1 / d^2)
    assert not ov.near_light_finer(longest, centre, normal, [area, sun], spacing).any()

    def light_at(x):  # cos / d^2 at x along the face from its rim
        return h / (h * h + (x - foot) ** 2) ** 1.5

    seen = 0.016

    def strip(k):  # the interpolant's mean over [0, seen] at k levels finer
        piece = length / 2 ** ov.levels(longest[:1], spacing, k)[0]
        off = OUTPUT_INSET * piece / 2
        rim = light_at(off)
        next_ = 0.5 * (light_at(piece - off) + light_at(piece + off))  # its samples in both pieces
        return rim + (next_ - rim) * seen / 2 / piece

    def integral(x):  # of cos / d^2 along the face, x from the light's foot
        return x / (h * np.sqrt(h * h + x * x))

    exact = (integral(seen - foot) - integral(-foot)) / seen
    assert strip(0) / exact - 1 == pytest.approx(0.25, abs=0.01)
    assert strip(finer[0]) / exact - 1 == pytest.approx(0.05, abs=0.01)


def test_a_solidified_face_close_to_a_point_light_gets_finer_on_both_shells():
    """The lamp shade's path through the product: a 28.4 x 4 cm quad with a Solidify (6 mm), a point
    light 15.7 cm before it (the shade's face). near_clutter leaves out an object whose modifiers
    change its faces (FINER is the mesh's); the near-light rule writes FINER 2 on the mesh's face,
    the Solidify gives it to both shells (and the rims), and the group cuts each shell's face to
    level 3 (64 quads, 4 x 4^3 corners) where the spacing alone halves it (level 1: 16 corners)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.names import FINER

    face = ms.mesh_object(
        "Shade",
        [(0, 0, 0), (0.284, 0, 0), (0.284, 0.04, 0), (0, 0.04, 0)],
        [[0, 1, 2, 3]],
        ms.diffuse("S", (RHO,) * 3),
    )
    face.modifiers.new("Solidify", "SOLIDIFY").thickness = 0.006
    light = bpy.data.objects.new("Bulb", bpy.data.lights.new("Bulb", "POINT"))
    light.location = (0.155, 0.02, 0.157)  # (on the face's front, +z)
    scene.collection.objects.link(light)
    dg, cones = _one_cone(scene)
    lines = []
    ov.ensure_own_values([face], "CORNER", dg, 0.25, log=lines.append, cones=cones)
    finer = np.empty(1, np.int32)
    face.data.attributes[FINER].data.foreach_get("value", finer)
    assert finer.tolist() == [2] and any("close to a light" in line for line in lines), lines
    dg.update()
    ev = face.evaluated_get(dg).data
    shells = [p for p in ev.polygons if abs(p.normal.z) > 0.99]  # (the rims stand on edge)
    assert len(shells) == 2 * 64 and all(abs(p.area - 0.284 * 0.04 / 64) < 1e-6 for p in shells)
