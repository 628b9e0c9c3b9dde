"""Scene in: evaluated meshes -> MeshInput, light-shape objects -> rings (hr_addon/blender/scene_in.py)."""

import numpy as np
import pytest

from test_blender_helpers import empty_scene, open_sample

pytestmark = pytest.mark.bpy

QUAD = ([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [[0, 1, 2, 3]])


@pytest.fixture
def env():
    return empty_scene()


def _collect(bpy):
    from hr_addon.blender.scene_in import collect_geometry

    vl = bpy.context.view_layer
    return collect_geometry(vl, vl.depsgraph)


def _normals(mi):
    from hr_addon.core.geometry import newell

    out = []
    for s, n in zip(mi.loop_start, mi.loop_total):
        v = newell(mi.verts[mi.loop_verts[s : s + n]][None])[0]
        out.append(v / np.linalg.norm(v))
    return np.array(out)


def test_world_space_materials_and_filters(env):
    bpy, ms, scene = env
    red = ms.diffuse("Red", (0.6, 0.1, 0.1))
    lamp = ms.emission("Lamp", (1, 1, 1), 3.0)
    a = ms.mesh_object("A", *QUAD, red, location=(0, 0, 2))
    a.data.materials.append(lamp)
    a.data.polygons[0].material_index = 1
    ms.mesh_object("B", *QUAD, None, location=(5, 0, 0))  # no material: grey
    ms.mesh_object("Hidden", *QUAD, red).hide_render = True
    ms.mesh_object("Excluded", *QUAD, red).hr.exclude = True
    ms.mesh_object("Shape", *QUAD, lamp).hr.is_light_shape = True
    col = bpy.data.collections.new("Off")
    scene.collection.children.link(col)
    off = bpy.data.objects.new("InOff", bpy.data.meshes["A"].copy())
    col.objects.link(off)
    col.hide_render = True
    si = _collect(bpy)
    assert si.mesh.object_names == ["A", "B"]
    assert [t.name for t in si.targets] == ["A", "B"]
    assert np.allclose(si.mesh.verts[:4, 2], 2.0) and np.allclose(si.mesh.verts[4:, 0] - [0, 1, 1, 0], 5)
    assert np.allclose(si.mesh.reflectance, [[0, 0, 0], [0.8, 0.8, 0.8]])
    assert np.allclose(si.mesh.emission, [[3, 3, 3], [0, 0, 0]])


def test_modifiers_scale_and_mirror(env):
    bpy, ms, scene = env
    v, p = ms.grid([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], 2)
    a = ms.mesh_object("Mirrored", v, p, None)
    a.scale = (-2, 1, 1)  # negative determinant: winding is reversed back
    si = _collect(bpy)
    assert np.allclose(_normals(si.mesh), [0, 0, 1])
    assert np.isclose(si.mesh.verts[:, 0].min(), -2)
    t = si.targets[0]
    vals = np.arange(len(si.mesh.loop_verts) * 3, dtype=np.float32).reshape(-1, 3)
    out = t.extract(vals, "CORNER")
    # The value of input loop j lands on the evaluated loop it came from.
    assert np.array_equal(out[t.loop_perm], vals)
    a.scale = (1, 1, 1)
    mod = a.modifiers.new("Sub", "SUBSURF")
    mod.levels = 1
    si = _collect(bpy)
    assert len(si.mesh.loop_start) == 16  # evaluated: 4 quads -> 16
    assert any("topology" in w for w in si.warnings)
    t = si.targets[0]
    out = t.extract(np.ones((len(si.mesh.loop_verts), 3), np.float32), "CORNER")
    assert out.shape == (16, 3)  # back on the original mesh's 16 corners


def test_no_meshes(env):
    bpy, ms, scene = env
    from hr_addon.blender.scene_in import SceneError

    ms.mesh_object("Shape", *QUAD, None).hr.is_light_shape = True
    with pytest.raises(SceneError, match="No mesh objects"):
        _collect(bpy)


def _outline(ms, bpy, verts, polys):
    from hr_addon.blender.lights_in import mesh_outlines
    from hr_addon.blender.scene_in import read_mesh

    ob = ms.mesh_object("S", verts, polys, None)
    em = read_mesh(ob, bpy.context.view_layer.depsgraph)
    return mesh_outlines(em)


def _signed_area(r, n=(0, 0, 1)):
    from hr_addon.core.geometry import newell

    return float(newell(np.asarray(r)[None])[0] @ n) / 2


def test_coplanar_polygons_merge_into_outlines(env):
    bpy, ms, scene = env
    v, p = ms.grid([(0, 0, 0), (3, 0, 0), (3, 3, 0), (0, 3, 0)], 3)
    groups = _outline(ms, bpy, v, p)
    assert len(groups) == 1 and len(groups[0][1]) == 1
    ring = groups[0][1][0]
    assert len(ring) == 4 and np.isclose(_signed_area(ring), 9)  # collinear points dropped, CCW
    # Drop the centre quad: outer ring + one hole (clockwise).
    holes = _outline(ms, bpy, v, [q for i, q in enumerate(p) if i != 4])
    assert len(holes) == 1
    outer, hole = holes[0][1]
    assert np.isclose(_signed_area(outer), 9) and np.isclose(_signed_area(hole), -1)
    # Two separate quads and one at another height stay separate.
    sep = _outline(
        ms,
        bpy,
        [
            (0, 0, 0),
            (1, 0, 0),
            (1, 1, 0),
            (0, 1, 0),
            (2, 0, 0),
            (3, 0, 0),
            (3, 1, 0),
            (2, 1, 0),
            (1, 0, 1),
            (2, 0, 1),
            (2, 1, 1),
            (1, 1, 1),
        ],
        [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]],
    )
    assert [len(g[1]) for g in sep] == [1, 1, 1]


def _shapes(bpy, scene, frame):
    from hr_addon.blender.lights_in import collect_light_shapes
    from hr_addon.core.events import LightShape

    scene.frame_set(frame)
    vl = bpy.context.view_layer
    return collect_light_shapes(vl, vl.depsgraph, LightShape)


def test_cornell_light_shapes_per_frame(tmp_path):
    open_sample("cornell", tmp_path)
    import bpy

    ms = __import__("make_samples")
    scene = bpy.context.scene
    assert _shapes(bpy, scene, 1) == {}
    s6 = _shapes(bpy, scene, 6)
    assert sorted(s6) == ["Window:0", "Window:1", "Window:2", "Window:3"]
    rgb, strength = ms.WINDOW_EMISSION
    for s in s6.values():
        assert np.allclose(s.emission, np.array(rgb) * strength)
        (ring,) = s.rings
        assert np.all(ring[:, 0] == 0.0)  # exactly on the green wall plane x = 0
        assert np.isclose(_signed_area(ring, (1, 0, 0)), ms.WINDOW_PANE**2, rtol=1e-5)  # faces +x
    s13 = _shapes(bpy, scene, 13)
    assert sorted(s13) == sorted(list(s6) + ["Back Patch:0"])
    back = s13["Back Patch:0"]
    assert np.all(back.rings[0][:, 1] == np.float32(ms.BACK_Y))
    assert np.allclose(back.emission, np.array(ms.PATCH_EMISSION[0]) * ms.PATCH_EMISSION[1])
    assert sorted(_shapes(bpy, scene, 21)) == ["Back Patch:0"]
    scene_objs = [o.name for o in scene.objects if o.hr.is_light_shape]
    assert sorted(scene_objs) == ["Back Patch", "Window"]


def test_keyframed_transform_and_strength(tmp_path):
    open_sample("curtain", tmp_path)
    import bpy

    scene = bpy.context.scene
    w = {f: np.ptp(_shapes(bpy, scene, f)["Curtain Gap:0"].rings[0][:, 1]) for f in (1, 12)}
    assert np.isclose(w[1], 0.1, rtol=1e-5) and np.isclose(w[12], 1.2, rtol=1e-5)
    assert all(np.all(_shapes(bpy, scene, f)["Curtain Gap:0"].rings[0][:, 0] == 0) for f in (1, 5))
    open_sample("searchbeam", tmp_path)
    scene = bpy.context.scene
    xs = [_shapes(bpy, scene, f)["Searchbeam:0"].rings[0][:, 0].mean() for f in (1, 12)]
    assert np.allclose(xs, [0.8, 3.2], atol=1e-5)
    open_sample("moonlight", tmp_path)
    scene = bpy.context.scene
    em = [_shapes(bpy, scene, f)["Moonlight:0"].emission[2] for f in (1, 6)]
    assert np.allclose(em, [0.5, 4.0])


@pytest.mark.parametrize("sample", ["cornell", "moonlight", "curtain", "searchbeam", "office"])
def test_sample_light_shapes_face_like_their_surface(sample, tmp_path):
    """Every polygon of every light shape in the sample scenes lies on a surface and faces the way
    it does (the user guide's rule). The core accepts either winding (it emits on the surface's
    side), so a wrong one changes no bake; but a one-sided Cycles emitter made from such a shape
    (the Cycles comparison) lights the inside of the wall, as 'Back Patch', 'Searchbeam' and the
    office screens did while make_samples.py wound them into their surfaces."""
    from hr_addon.blender.scene_in import collect_geometry, light_shape_objects, read_mesh
    from hr_addon.core.geometry import newell

    open_sample(sample, tmp_path)
    import bpy

    vl = bpy.context.view_layer
    mesh = collect_geometry(vl, vl.depsgraph).mesh
    polys = [mesh.verts[mesh.loop_verts[s : s + k]] for s, k in zip(mesh.loop_start, mesh.loop_total)]
    qn = np.array([newell(q) for q in polys])
    qn /= np.linalg.norm(qn, axis=1, keepdims=True)
    centre = np.array([q.mean(0) for q in polys])
    shapes = light_shape_objects(vl, include_hidden=True)
    assert shapes
    for ob in shapes:
        em = read_mesh(ob, vl.depsgraph)
        for s, k in zip(em.loop_start, em.loop_total):
            ring = em.verts[em.loop_verts[s : s + k]]
            n = newell(ring) / np.linalg.norm(newell(ring))
            on = (np.abs(qn @ n) > 0.999) & (np.abs((ring[None] - centre[:, None]) @ n).max(1) < 1e-4)
            assert on.any(), f"{sample}: a polygon of '{ob.name}' lies on no surface"
            assert (qn[on] @ n > 0).all(), f"{sample}: '{ob.name}' faces into its surface"


@pytest.mark.parametrize("modifier", ["BEVEL", "SOLIDIFY"])
@pytest.mark.parametrize("scale", [1.0, -1.0])
def test_modifiers_keep_each_face_its_own_light(env, modifier, scale):
    """A box whose modifiers change its topology: each original corner takes the value of the
    evaluated corner of the face turned like its own (the top's corners the top's light), not the
    mean of the faces meeting at its vertex (a bevelled chair seat read -18% against Cycles,
    benchmarks/unseen_vs_cycles.py); mirrored by a negative scale too."""
    bpy, ms, scene = env
    v = [(x, y, z) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
    faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    box = ms.mesh_object("Box", v, faces, None)
    box.scale = (scale, 1, 1)
    m = box.modifiers.new("M", modifier)
    if modifier == "BEVEL":
        m.width = 0.1
    elif modifier == "SOLIDIFY":
        m.thickness = 0.05
    si = _collect(bpy)
    t = si.targets[0]
    assert t.vert_map is not None and t.loop_map is not None
    # the evaluated corners' value: 1 on faces looking up, 0 elsewhere (the top lit, the sides dim)
    up = _normals(si.mesh)[:, 2] > 0.99
    vals = np.repeat(up.astype(np.float32), si.mesh.loop_total)[:, None].repeat(3, 1)
    out = t.extract(vals, "CORNER")[:, 0]
    me = box.data
    top = np.repeat(np.array([p.normal.z > 0.99 for p in me.polygons]), [p.loop_total for p in me.polygons])
    assert np.array_equal(out, top.astype(np.float32))


def _fold(parts):
    mesh = parts[0]
    for p in parts[1:]:
        mesh = mesh.concat(p)
    return mesh


def _assert_same_mesh(got, want):
    for f in ("verts", "loop_start", "loop_total", "loop_verts", "reflectance", "emission", "object_id"):
        a, b = getattr(got, f), getattr(want, f)
        assert a.dtype == b.dtype and np.array_equal(a, b), f
    assert got.object_names == want.object_names
    for f in ("tri_loops", "face_group", "flat"):
        a, b = getattr(got, f), getattr(want, f)
        assert (a is None) == (b is None), f
        if a is not None:
            assert a.dtype == b.dtype and np.array_equal(a, b), f


def test_flat_shaded_faces_are_read_as_flat(env):
    """MeshInput.flat (session 33, branch vtxroom): the polygons a render shades flat (sharp_face),
    per polygon in the joined mesh; none flat: None (as before)."""
    bpy, ms, scene = env
    grey = ms.diffuse("Grey", (0.5,) * 3)
    a = ms.mesh_object("A", *QUAD, grey)
    b = ms.mesh_object(
        "B",
        [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2, 1, 0)],
        [[0, 1, 2, 3], [1, 4, 5, 2]],
        grey,
        location=(0, 3, 0),
    )
    for ob in (a, b):
        ob.data.shade_smooth()
    assert _collect(bpy).mesh.flat is None
    b.data.polygons[1].use_smooth = False
    si = _collect(bpy)
    assert si.mesh.object_names == ["A", "B"]
    assert si.mesh.flat.tolist() == [False, False, True]


def test_parts_joined_in_one_pass_equal_the_concat_fold(tmp_path, monkeypatch):
    """collect_geometry joins the objects' parts in one pass (scene_in._joined_parts): folding
    MeshInput.concat copied the growing mesh again per object (3,881 objects: seconds of Live's
    start on the UI thread at 100k). The same arrays, dtypes included: the furnished sample's parts
    and parts with and without loop triangles and face groups."""
    from hr_addon.blender import scene_in
    from hr_addon.core.geometry import MeshInput

    open_sample("furnished", tmp_path)
    import bpy

    seen, real = [], scene_in._joined_parts
    monkeypatch.setattr(scene_in, "_joined_parts", lambda parts: seen.append(list(parts)) or real(parts))
    _collect(bpy)
    assert len(seen) == 1 and len(seen[0]) > 800
    rng = np.random.default_rng(3)

    def part(k, tri, face, flat=False):
        polys = [[0, 1, 2, 3], [1, 4, 2]]
        m = MeshInput.from_polygons(rng.random((5, 3)), polys, rng.random((2, 3)), object_names=[f"o{k}"])
        m.tri_loops = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]], np.int32) if tri else None
        m.face_group = np.array([0, 0], np.int32) if face else None
        m.flat = np.array([True, False]) if flat else None
        return m

    made = [
        part(k, tri, face, k == 3) for k, (tri, face) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1), (0, 0)])
    ]
    for parts in seen + [made, made[:1], made[:2], [made[0], made[4]], made[2:]]:
        _assert_same_mesh(real(parts), _fold(parts))
