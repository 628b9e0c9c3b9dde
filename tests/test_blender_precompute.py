"""The scene precompute in the product (issue 22 phase 2): the bake loads it when it is valid,
rebuilds it naming the cause when it is not, and a re-bake after a light-shape keyframe edit gives
a cold bake's values; Delete Bake keeps or deletes it; Rebuild discards it (blender/bake.py,
ops.py, io/precompute.py)."""

import os

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, open_sample

pytestmark = pytest.mark.bpy


def _bake(**kw):
    import bpy
    from hr_addon.blender.bake import run_bake

    kw.setdefault("quality", "draft")
    kw.setdefault("frames", (6, 6))
    return run_bake(bpy.context.scene, log=lambda *a, **k: None, **kw)


def _values(bpy, frame=6):
    bpy.context.scene.frame_set(frame)
    return {
        o.name: attribute(o).copy()
        for o in bpy.context.scene.objects
        if o.type == "MESH" and "HR_Radiance" in o.data.color_attributes
    }


def _cache(tmp_path):
    return tmp_path / "hr_cache" / "cornell"


def test_rebake_after_light_keyframe_loads_and_equals_cold(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    first = _bake(method="FE")
    assert not first.precompute_loaded and first.precompute == ["precompute built: no precompute yet"]
    assert (_cache(tmp_path) / "precompute.hrpc").is_file()
    assert "precompute built: no precompute yet" in first.summary()
    # its events' host visibility kept for the next bake (session 30 hvkeep; speed only)
    assert any(n.startswith("host visibility segments stored (") for n in first.notes), first.notes
    before = _values(bpy)

    win = bpy.data.objects["Window"]  # a light-shape edit: the window slides along its wall
    win.location.y += 0.03
    win.keyframe_insert("location", frame=6)
    warm = _bake(method="FE")
    assert warm.precompute_loaded, warm.precompute
    assert warm.precompute[0].startswith("precompute loaded (built ") and " ago" in warm.precompute[0]
    assert warm.summary().find("precompute loaded") > 0 and warm.gather_seconds == 0
    assert warm.precompute[1].startswith("host visibility segments loaded ("), warm.precompute
    got = _values(bpy)

    cold = _bake(method="FE", rebuild=True)  # the same light on a precompute built from nothing
    # (and no kept segments: Rebuild builds without reading them)
    assert not cold.precompute_loaded and cold.precompute == ["precompute rebuilt: rebuild asked"]
    ref = _values(bpy)
    assert set(got) == set(ref) and len(ref) > 5
    for name in ref:  # the same arrays through the same operations: bit for bit (docs/precompute.md)
        assert np.array_equal(got[name], ref[name]), name
    assert not np.array_equal(got["right_green"], before["right_green"])  # the edit shows

    # any frame range and any method: the method is light, not part of the precompute
    for method, frames in (("AUTO", (12, 14)), ("AR", (1, 2)), ("NAIVE", (21, 21))):
        res = _bake(method=method, frames=frames)
        assert res.precompute_loaded, (method, res.precompute)


def _set_base_color(mat, rgb):
    for n in mat.node_tree.nodes:
        if n.type == "BSDF_PRINCIPLED":
            n.inputs["Base Color"].default_value = (*rgb, 1.0)
            return
    raise AssertionError(f"no Principled BSDF in {mat.name}")


def test_changes_rebuild_and_name_their_cause(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    assert not _bake().precompute_loaded
    assert _bake().precompute_loaded

    bpy.data.objects["back"].location.y += 0.01  # a moved wall
    res = _bake()
    assert res.precompute == ["precompute rebuilt: object 'back' moved or changed shape"], res.precompute
    assert _bake().precompute_loaded

    _set_base_color(bpy.data.objects["tall_block"].material_slots[0].material, (0.3, 0.3, 0.3))
    res = _bake()
    assert not res.precompute_loaded
    (msg,) = res.precompute
    assert msg.startswith("precompute rebuilt: object ") and "'tall_block'" in msg, msg
    assert msg.endswith("changed reflectance (material)"), msg
    assert _bake().precompute_loaded

    res = _bake(quality="custom", feps=0.02)  # a changed Feps (the custom quality's own setting)
    assert not res.precompute_loaded and res.precompute[0].startswith("precompute rebuilt: ")
    assert "feps " in res.precompute[0] and "-> 0.02" in res.precompute[0], res.precompute
    assert _bake(quality="custom", feps=0.02).precompute_loaded
    res = _bake(quality="custom", feps=0.03)
    assert res.precompute == ["precompute rebuilt: feps 0.02 -> 0.03"], res.precompute


def test_a_brighter_static_emitter_rebuilds_and_equals_a_cold_bake(tmp_path):
    """The stored base solution (the static emitters' light) is never stale: a changed emission
    strength of the ceiling light rebuilds the precompute, naming the object, and the new light
    shows, bit for bit as a bake with the precompute rebuilt from nothing."""
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    _bake(method="FE")
    before = _values(bpy)
    mat = bpy.data.objects["light"].material_slots[0].material
    strength = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Emission Strength"]
    strength.default_value *= 1.5
    res = _bake(method="FE")
    assert res.precompute == ["precompute rebuilt: object 'light' changed emission (material)"], (
        res.precompute
    )
    got = _values(bpy)
    assert _bake(method="FE").precompute_loaded
    assert all(np.array_equal(_values(bpy)[k], got[k]) for k in got)  # loaded: the same values
    cold = _bake(method="FE", rebuild=True)
    assert not cold.precompute_loaded
    ref = _values(bpy)
    assert all(np.array_equal(got[k], ref[k]) for k in ref)
    # the new light shows: brighter by less than the lamp's 1.5 (the window lights frame 6 too)
    assert got["back"][:, :3].mean() > 1.1 * before["back"][:, :3].mean()


def test_damaged_precompute_is_named_and_rebuilt(tmp_path):
    load_bpy()
    open_sample("cornell", tmp_path)
    _bake()
    path = _cache(tmp_path) / "precompute.hrpc"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # truncated (a full disk, a copy cut short)
    res = _bake()
    assert not res.precompute_loaded
    assert res.precompute[0].startswith("precompute rebuilt: 'precompute.hrpc' is damaged or truncated")
    from hr_addon.io import precompute as pc

    pc.read(path)  # written again, whole: every array passes its checksum
    assert _bake().precompute_loaded


def test_delete_bake_keeps_or_deletes_the_precompute_and_rebuild_discards_it(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender.panels import precompute_text

    d = _cache(tmp_path)
    assert precompute_text(bpy.context.scene) == "No scene precompute: the next bake builds it"
    _bake()
    assert precompute_text(bpy.context.scene).startswith("Scene precompute: ")
    assert " MB, built " in precompute_text(bpy.context.scene)

    assert bpy.ops.hr.delete_bake("EXEC_DEFAULT") == {"FINISHED"}  # default: keep it
    assert sorted(os.listdir(d)) == [".hr_radiosity", "precompute.hrhv", "precompute.hrpc"]  # (+ segments)
    assert _bake().precompute_loaded  # the next bake skips the build

    assert bpy.ops.hr.delete_bake("EXEC_DEFAULT", keep_precompute=False) == {"FINISHED"}
    assert not d.exists()

    _bake()
    assert bpy.ops.hr.rebuild_precompute("EXEC_DEFAULT") == {"FINISHED"}
    assert not (d / "precompute.hrpc").exists() and (d / "manifest.json").is_file()  # the bake stays
    res = _bake()
    assert res.precompute == ["precompute built: no precompute yet"]


def test_delete_bake_leaves_a_foreign_precompute_named_file(tmp_path):
    """A bake never deletes what it did not write: a directory of that name is left alone."""
    load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender.ops import delete_cache_files

    d = _cache(tmp_path)
    _bake()
    (d / "precompute.hrpc").unlink()
    os.makedirs(d / "precompute.hrpc")  # the user's folder, in the cache folder
    res = _bake()
    assert any("Precompute not stored" in w for w in res.warnings), res.warnings
    delete_cache_files(str(d), keep_precompute=False)
    assert (d / "precompute.hrpc").is_dir()


def test_live_loads_the_bakes_precompute_and_never_writes_it(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import live

    scene = bpy.context.scene
    scene.hr.quality = "DRAFT"
    path = _cache(tmp_path) / "precompute.hrpc"
    sess = live.start(scene, threaded=False)  # no precompute yet: Live builds, and stores nothing
    try:
        assert sess.worker.flush(timeout=600)
        assert sess.worker.precompute == "built (no precompute: no precompute yet)"
        assert not path.exists()
    finally:
        live.stop(scene)
    _bake()  # vertex output, draft: the key Live uses too
    stamp = path.stat().st_mtime_ns
    sess = live.start(scene, threaded=False)
    try:
        assert sess.worker.flush(timeout=600)
        assert sess.worker.precompute == "precompute loaded", sess.worker.precompute
        assert path.stat().st_mtime_ns == stamp
    finally:
        live.stop(scene)
