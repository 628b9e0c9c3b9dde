"""Writing HR_Radiance (playback.write_attribute / apply_arrays, scene_in.FlatExtract): the faster
path writes the values the code before it wrote. Nothing here asserts on time."""

import numpy as np

from test_blender_helpers import empty_scene


def _scene(bpy, ms):
    """A few objects: plain quads, a box, one with a modifier changing its topology, one whose
    HR_Radiance exists on the wrong domain."""
    mat = ms.diffuse("grey", (0.5, 0.5, 0.5))
    for i in range(4):
        quad = [(i, 0, 0), (i + 0.9, 0, 0), (i + 0.9, 1, 0), (i, 1, 0)]
        ms.mesh_object(f"quad{i}", quad, [[0, 1, 2, 3]], mat)
    v = [(x, y, z) for x in (0, 1) for y in (2, 3) for z in (0, 1)]
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    ms.mesh_object("box", v, faces, mat)
    sub = ms.mesh_object("sub", [(0, 4, 0), (1, 4, 0), (1, 5, 0), (0, 5, 0)], [[0, 1, 2, 3]], mat)
    sub.modifiers.new("s", "SUBSURF").levels = 1
    bpy.data.objects["quad1"].data.color_attributes.new("HR_Radiance", "FLOAT_COLOR", "POINT")


def _old_write(me, values, domain):
    """playback.write_attribute before this branch (the reference)."""
    attr = me.color_attributes.get("HR_Radiance")
    if attr is not None and (attr.domain != domain or attr.data_type != "FLOAT_COLOR"):
        me.color_attributes.remove(attr)
        attr = None
    if attr is None:
        attr = me.color_attributes.new("HR_Radiance", "FLOAT_COLOR", domain)
    attr.data.foreach_set("color", np.ascontiguousarray(values, np.float32).ravel())
    me.update_tag()


def _read(bpy, names):
    out = {}
    for n in names:
        attr = bpy.data.objects[n].data.attributes["HR_Radiance"]
        buf = np.empty(len(attr.data) * 4, np.float32)
        attr.data.foreach_get("color", buf)
        out[n] = (attr.domain, attr.data_type, buf)
    return out


def test_faster_write_gives_the_values_written_before():
    """Per object values from FlatExtract (one array, views per object) written by apply_arrays
    equal, bitwise, what Target.extract + an RGBA copy per object (the Live worker's way) wrote
    through the former write_attribute, for CORNER and POINT; the wrong-domain attribute is made
    anew; the meshes are marked as written for playback and for the given reader."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import playback, scene_in
    from hr_addon.blender.state import STATE

    _scene(bpy, ms)
    si = scene_in.collect_geometry(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    assert any(t.vert_map is not None for t in si.targets)  # the modifier's topology path is covered
    names = [t.name for t in si.targets]
    rng = np.random.default_rng(1)
    for domain in ("CORNER", "POINT"):
        n = len(si.mesh.verts) if domain == "POINT" else len(si.mesh.loop_verts)
        values = rng.random((n, 3)).astype(np.float32)
        ref = {}
        for t in si.targets:
            v = np.asarray(t.extract(values, domain), np.float32)
            ref[t.name] = np.concatenate([v, np.ones((len(v), 1), np.float32)], 1)
            _old_write(bpy.data.objects[t.name].data, ref[t.name], domain)
        before = _read(bpy, names)
        for n_ in names:  # another value in every attribute first: the new path must write them all
            playback.write_attribute(bpy.data.objects[n_].data, np.zeros_like(ref[n_]), domain)
        bpy.data.objects["quad1"].data.attributes.remove(
            bpy.data.objects["quad1"].data.attributes["HR_Radiance"]
        )
        bpy.data.objects["quad1"].data.color_attributes.new(
            "HR_Radiance", "FLOAT_COLOR", "CORNER" if domain == "POINT" else "POINT"
        )
        flat = scene_in.FlatExtract(si.targets, domain)
        new = flat.rgba(values)
        assert list(new) == names
        assert all(np.array_equal(new[k], ref[k]) for k in names)
        assert all(np.array_equal(flat(values)[k], ref[k][:, :3]) for k in names)
        STATE.writes.take(), STATE.writes.take("mine")
        assert playback.apply_arrays(scene, new, domain, reader="mine") == []
        after = _read(bpy, names)
        for k in names:
            assert after[k][:2] == (domain, "FLOAT_COLOR") == before[k][:2]
            assert np.array_equal(after[k][2], before[k][2]), k
        meshes = {bpy.data.objects[k].data.name for k in names}
        assert STATE.writes.take() == meshes and STATE.writes.take("mine") == meshes


def test_foreach_set_alone_updates_the_evaluated_mesh():
    """Where write_attribute leaves out mesh.update_tag() (playback.TAG_AFTER_SET False: Blender
    5.0), foreach_set on the attribute's data must itself make the evaluated mesh show the new
    values (two writes in turn, each read back from the evaluated mesh)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import playback

    _scene(bpy, ms)
    obj = bpy.data.objects["box"]
    n = len(obj.data.loops)
    for value in (0.25, 0.75):
        assert playback.apply_arrays(scene, {"box": np.full((n, 4), value, np.float32)}, "CORNER") == []
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        buf = np.empty(n * 4, np.float32)
        ev.attributes["HR_Radiance"].data.foreach_get("color", buf)
        assert (buf == value).all(), (bpy.app.version, playback.TAG_AFTER_SET)


def test_unaligned_values_are_written_as_aligned_ones():
    """write_attribute given a float32 view at an unaligned address (as read_npz's members are)
    writes the same values as from an aligned copy (it copies it: Blender's foreach_set would take
    it element by element)."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import playback

    _scene(bpy, ms)
    me = bpy.data.objects["box"].data
    n = len(me.loops)
    values = np.random.default_rng(2).random((n, 4)).astype(np.float32)
    raw = np.zeros(values.nbytes + 1, np.uint8)
    view = raw[1:].view(np.float32).reshape(n, 4)
    view[:] = values
    assert not view.flags.aligned and memoryview(view).format != "f"
    playback.write_attribute(me, np.zeros_like(values), "CORNER")
    playback.write_attribute(me, view, "CORNER")
    assert np.array_equal(_read(bpy, ["box"])["box"][2], values.reshape(-1))


def test_objects_kept_between_writes_are_looked_up_again_when_removed():
    """apply_arrays(objects=) (Live keeps its targets' objects between writes): the dict is filled
    by the first write; after an object is removed the next write says it is missing, writes the
    others and keeps no reference to the removed one."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import playback

    _scene(bpy, ms)
    names = ["quad0", "quad2", "box"]
    arrays = {n: np.full((len(bpy.data.objects[n].data.loops), 4), 0.5, np.float32) for n in names}
    kept = {}
    assert playback.apply_arrays(scene, arrays, "CORNER", objects=kept) == []
    assert sorted(kept) == sorted(names) and all(kept[n] == bpy.data.objects[n] for n in names)
    bpy.data.objects.remove(bpy.data.objects["quad2"])
    arrays = {n: v * 2 for n, v in arrays.items()}
    assert playback.apply_arrays(scene, arrays, "CORNER", objects=kept) == [
        "object 'quad2' of the bake is missing"
    ]
    assert sorted(kept) == ["box", "quad0"]
    got = _read(bpy, ["quad0", "box"])
    assert all((got[n][2] == 1.0).all() for n in got)


def test_rows_unchanged_since_the_last_write_are_skipped_and_the_values_stay_exact():
    """scene_in.Rows.unchanged names the targets whose rows hold the same bits in both results of
    one FlatExtract (0.0 and -0.0 differ; a target with its own array, here the modifier's, is
    never named; another FlatExtract's result: None); apply_arrays(skip=) leaves those out, marks
    only the meshes it wrote, and HR_Radiance then holds the second result bit for bit."""
    bpy, ms, scene = empty_scene()
    from hr_addon.blender import playback, scene_in
    from hr_addon.blender.state import STATE

    _scene(bpy, ms)
    si = scene_in.collect_geometry(bpy.context.view_layer, bpy.context.evaluated_depsgraph_get())
    names = [t.name for t in si.targets]
    flat = scene_in.FlatExtract(si.targets, "CORNER")
    v1 = np.random.default_rng(3).random((len(si.mesh.loop_verts), 3)).astype(np.float32)
    by = {t.name: t for t in si.targets}
    v1[by["quad2"].loops[0]] = 0.0
    v2 = v1.copy()
    v2[by["quad0"].loops[0] + 1, 2] *= 1.5
    v2[by["box"].loops[1] - 1, 0] += 1.0
    v2[by["quad2"].loops[0], 1] = -0.0
    v2[by["sub"].loops[0]] += 1.0  # (its own array: written whatever changed)
    r1, r2 = flat.rgba(v1), flat.rgba(v2)
    same = r2.unchanged(r1)
    assert same == {"quad1", "quad3"}, same
    assert r2.unchanged(r2) == set(names) - {"sub"}
    assert r2.unchanged(scene_in.FlatExtract(si.targets, "CORNER").rgba(v1)) is None
    assert r2.unchanged({k: v for k, v in r1.items()}) is None
    assert playback.apply_arrays(scene, r1, "CORNER") == []
    STATE.writes.take()
    assert playback.apply_arrays(scene, r2, "CORNER", skip=same) == []
    assert STATE.writes.take() == {bpy.data.objects[k].data.name for k in names if k not in same}
    got = _read(bpy, names)
    for k in names:
        assert np.array_equal(got[k][2].view(np.uint32), r2[k].reshape(-1).view(np.uint32)), k
