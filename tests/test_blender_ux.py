"""Bake UX: operator polls, Preview without a bake, Delete Bake, the Lock Interface message in the
panel, playback that does not rewrite HR_Radiance for frames mapping to the same cached file,
descriptive labels, and the build's progress reaching the headless bake's output."""

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, open_sample

pytestmark = pytest.mark.bpy


def _bake(**kw):
    import bpy
    from hr_addon.blender.bake import run_bake

    kw.setdefault("quality", "draft")
    return run_bake(bpy.context.scene, log=lambda *a, **k: None, **kw)


def test_preview_and_cache_operators_need_a_bake(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    ops = (bpy.ops.hr.add_preview, bpy.ops.hr.load_frame, bpy.ops.hr.delete_bake, bpy.ops.hr.clear_bake)
    for op in ops:
        assert not op.poll()
    with pytest.raises(RuntimeError, match="bake first"):
        bpy.ops.hr.add_preview()
    assert not bpy.ops.hr.remove_preview.poll()  # nothing to remove
    assert not bpy.ops.hr.cancel_bake.poll()  # nothing running
    assert bpy.ops.hr.bake.poll()
    _bake(frames=(1, 2), method="FE")
    assert all(op.poll() for op in ops)
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    assert bpy.ops.hr.remove_preview.poll()


def test_bake_poll_refuses_unsaved_file():
    bpy = load_bpy()
    bpy.ops.wm.read_factory_settings(use_empty=False)
    assert not bpy.ops.hr.bake.poll()


def test_delete_bake_removes_the_files(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    _bake(frames=(5, 7), method="FE")
    cache = tmp_path / "hr_cache" / "cornell"
    assert (cache / "manifest.json").is_file()
    other = tmp_path / "hr_cache" / "notes.txt"
    other.write_text("not ours")
    scene = bpy.context.scene
    scene.frame_set(6)
    assert "HR_Radiance" in bpy.data.objects["floor"].data.color_attributes
    # EXEC: the confirmation is invoke()'s; the scene precompute goes too (kept by default:
    # test_blender_precompute)
    assert bpy.ops.hr.delete_bake(keep_precompute=False) == {"FINISHED"}
    assert not cache.exists()
    assert other.read_text() == "not ours"  # only the bake's own files go
    assert scene.hr.bake_dir == "" and not scene.hr.playback
    assert "HR_Radiance" not in bpy.data.objects["floor"].data.color_attributes
    assert not bpy.ops.hr.delete_bake.poll()


def test_delete_refuses_a_folder_that_is_not_a_bake(tmp_path):
    load_bpy()
    from hr_addon.io.cache import CacheError
    from hr_addon.blender.ops import delete_cache_files

    d = tmp_path / "precious"
    d.mkdir()
    (d / "frame_000001.npz").write_bytes(b"mine")
    with pytest.raises(CacheError):
        delete_cache_files(str(d))
    assert (d / "frame_000001.npz").read_bytes() == b"mine"


def test_delete_keeps_a_users_files_inside_the_cache_folder(tmp_path):
    load_bpy()
    from hr_addon.blender.ops import delete_cache_files
    from hr_addon.io.cache import CacheWriter

    d = tmp_path / "cache"
    w = CacheWriter(d, {"a": {"mesh": "a", "count": 1}}, "CORNER", "s")
    w.write(1, {"a": np.ones((1, 3))})
    w.commit()
    (d / "mine.txt").write_text("mine")
    (d / "textures").mkdir()
    (d / "textures" / "wood.png").write_bytes(b"png")
    assert delete_cache_files(str(d)) == 3  # frame, manifest, marker
    assert sorted(str(p.relative_to(d)) for p in d.rglob("*")) == [
        "mine.txt",
        "textures",
        "textures/wood.png",
    ]


def test_playback_skips_rewriting_same_cached_file(tmp_path, monkeypatch):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import playback

    _bake(frames=(1, 24), method="FE")  # files for frames 1, 6, 13, 21 only
    scene = bpy.context.scene
    writes = []
    original = playback.write_attribute
    monkeypatch.setattr(
        playback, "write_attribute", lambda me, v, d: (writes.append(me.name), original(me, v, d))
    )
    scene.frame_set(6)
    n = len(writes)
    assert n > 0
    shown = attribute(bpy.data.objects["back"])
    for f in (7, 8, 12):  # all map to frame_000006.npz
        scene.frame_set(f)
    assert len(writes) == n
    np.testing.assert_array_equal(attribute(bpy.data.objects["back"]), shown)
    scene.frame_set(13)  # another file
    assert len(writes) == 2 * n
    # removing the attribute (or undo) makes the next frame change write it again
    me = bpy.data.objects["back"].data
    me.color_attributes.remove(me.color_attributes["HR_Radiance"])
    scene.frame_set(14)
    assert len(writes) == 3 * n and "HR_Radiance" in me.color_attributes


def test_lock_interface_message_in_panel(tmp_path, monkeypatch):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import playback

    _bake(frames=(1, 7), method="FE")
    scene = bpy.context.scene
    scene.frame_set(1)
    monkeypatch.setattr(playback, "render_unlocked", lambda s: True)  # a render without Lock Interface
    before = attribute(bpy.data.objects["right_green"])
    scene.frame_set(6)
    assert playback.status(scene) == playback.LOCK_MESSAGE  # what the panel shows
    np.testing.assert_array_equal(attribute(bpy.data.objects["right_green"]), before)  # not loaded
    monkeypatch.setattr(playback, "render_unlocked", lambda s: False)
    scene.frame_set(7)
    assert playback.status(scene) == ""


def test_descriptive_labels():
    bpy = load_bpy()
    props = bpy.types.Scene.bl_rna.properties["hr"].fixed_type.properties
    assert props["feps"].name == "Link threshold (Feps)"
    assert props["aeps"].name == "Smallest element (Aeps)"


def test_headless_bake_prints_build_progress_and_rays(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender.bake import run_bake

    lines = []
    seen = []
    res = run_bake(
        bpy.context.scene,
        log=lambda m, **k: lines.append(m),
        status=seen.append,
        frames=(1, 3),
        method="FE",
        quality="medium",
    )
    build = [p for p in seen if p.stage == "build"]
    assert len(build) >= 2 and all(0 <= p.fraction <= 0.5 for p in build), [p.fraction for p in build]
    assert any(ln.startswith("HR Radiosity: Building the hierarchy: ") for ln in lines), lines
    assert res.rays == "embree" and lines[-1].endswith("rays: embree)"), lines[-1]


def test_invoke_in_background_mode_bakes_synchronously(tmp_path):
    """No event loop in `blender -b` / the bpy module: the button's INVOKE bakes in this process."""
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import background

    scene = bpy.context.scene
    scene.hr.use_frame_range = True
    scene.hr.frame_start = scene.hr.frame_end = 6
    scene.hr.quality = "DRAFT"
    assert bpy.ops.hr.bake("INVOKE_DEFAULT") == {"FINISHED"}
    assert background.active() is None
    assert (tmp_path / "hr_cache" / "cornell" / "manifest.json").is_file()


def test_without_embreex_the_bake_says_numpy(tmp_path, monkeypatch):
    """A platform without a wheel: the numpy tracer, and the summary and manifest say so."""
    import sys

    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    for name in [m for m in sys.modules if m == "embreex" or m.startswith("embreex.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex -> ImportError
    lines = []
    from hr_addon.blender.bake import run_bake
    from hr_addon.io.cache import CacheReader

    res = run_bake(bpy.context.scene, log=lambda m, **k: lines.append(m), frames=(1, 1), quality="draft")
    assert res.rays == "numpy" and "embreex not available" in res.rays_note
    assert "rays: numpy (embreex not available" in lines[-1], lines[-1]
    m = CacheReader(tmp_path / "hr_cache" / "cornell").manifest
    assert m["rays"] == "numpy" and "embreex not available" in m["rays_note"]


class _Event:
    def __init__(self, type, timer=None):
        self.type, self.timer = type, timer


def test_modal_bake_passes_every_event_through(tmp_path):
    """The modal operator never consumes an event (the UI stays usable) and only polls on its own
    timer; when the worker ends it reports and finishes. Driven with stand-ins for the window
    manager (there is no event loop in background mode)."""
    load_bpy()
    from types import SimpleNamespace
    from hr_addon.blender.ops import FINISH_TICK, HR_OT_bake

    class Job:
        def __init__(self):
            self.polls, self.state, self.warnings, self.summary = 0, "running", ["w1"], "baked frames 1-2 ..."
            self.finishing = False

        def poll(self):
            self.polls += 1
            self.finishing = self.polls == 2  # the result loading, a step per tick
            if self.polls == 3:
                self.state = "done"
            return self.state == "running"

        def text(self):
            return "50% · frame 1 (1/2)"

    timer, other_timer, fast_timer = object(), object(), object()
    reports, status = [], []
    workspace = SimpleNamespace(status_text_set=status.append)
    wm = SimpleNamespace(
        windows=[SimpleNamespace(workspace=workspace, screen=SimpleNamespace(areas=[]))],
        event_timer_remove=lambda t: reports.append(("timer removed", t is timer)),
        event_timer_add=lambda step, window=None: reports.append(("timer added", step)) or fast_timer,
    )
    context = SimpleNamespace(window_manager=wm, window=None)
    op = SimpleNamespace(
        _job=Job(), _timer=timer, _fast=False, report=lambda kind, msg: reports.append((sorted(kind)[0], msg))
    )
    for ev in ("MOUSEMOVE", "LEFTMOUSE", "ESC", "SPACE", "WHEELUPMOUSE", "A"):
        assert HR_OT_bake.modal(op, context, _Event(ev)) == {"PASS_THROUGH"}
    assert HR_OT_bake.modal(op, context, _Event("TIMER", other_timer)) == {"PASS_THROUGH"}
    assert op._job.polls == 0
    assert HR_OT_bake.modal(op, context, _Event("TIMER", timer)) == {"PASS_THROUGH"}
    assert HR_OT_bake.modal(op, context, _Event("TIMER", timer)) == {"PASS_THROUGH"}
    assert status == ["HR Radiosity: 50% · frame 1 (1/2)"] * 2
    # while the result loads (a step per tick) the timer runs faster
    assert reports == [("timer removed", True), ("timer added", FINISH_TICK)] and op._timer is fast_timer
    assert HR_OT_bake.modal(op, context, _Event("TIMER", timer)) == {"PASS_THROUGH"}  # the old one: ignored
    assert op._job.polls == 2
    assert HR_OT_bake.modal(op, context, _Event("TIMER", fast_timer)) == {"FINISHED"}
    assert status[-1] is None and reports[2] == ("timer removed", False)
    assert ("WARNING", "w1") in reports and ("INFO", "HR Radiosity: baked frames 1-2 ...") in reports


def test_ray_backend_name_from_the_build_report():
    load_bpy()
    from types import SimpleNamespace
    from hr_addon.blender.bake import ray_backend_name

    assert ray_backend_name(SimpleNamespace(backend=SimpleNamespace(name="embree"))) == "embree"
    assert ray_backend_name(SimpleNamespace(build=SimpleNamespace(backend="NumpyBackend"))) == "numpy"


def _unregistered(cls, **attrs):
    """An object standing in for an operator instance of cls (bpy makes those only when it runs
    one): cls's methods bound to it, its class attributes readable, attrs set."""
    import inspect
    from types import MethodType, SimpleNamespace

    op = SimpleNamespace(**attrs)
    for name, value in inspect.getmembers(cls):
        if name.startswith("__") or name in attrs:
            continue
        setattr(op, name, MethodType(value, op) if inspect.isfunction(value) else value)
    return op


def test_preview_button_wires_a_slice_of_materials_per_tick(tmp_path, monkeypatch):
    """The Preview button (invoke) wires the materials over timer ticks, Remove Preview's unwires
    them (3,641 materials of the furnished 100k room took 30 s CPU in one call: every node named is
    a pass over all IDs); the preview is the one execute() makes; scripts and background mode keep
    execute()."""
    from types import SimpleNamespace

    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import ops, playback, preview
    from hr_addon.blender.bake import run_bake

    scene = bpy.context.scene
    run_bake(scene, log=lambda *a, **k: None, frames=(1, 1), quality="draft")
    monkeypatch.setattr(playback, "SPREAD", True)  # as in the UI (no event loop here: ticks by hand)
    monkeypatch.setattr(ops, "PREVIEW_SLICE", 0.0)  # a material per tick
    timers, removed, reports = [], [], []
    wm = SimpleNamespace(
        windows=[],
        event_timer_add=lambda step, window=None: timers.append(object()) or timers[-1],
        event_timer_remove=removed.append,
        modal_handler_add=lambda op: None,
    )
    context = SimpleNamespace(scene=scene, view_layer=bpy.context.view_layer, window_manager=wm, window=None)
    op = _unregistered(ops.HR_OT_add_preview, report=lambda kind, msg: reports.append((sorted(kind)[0], msg)))
    op.execute = lambda ctx: pytest.fail("the button wires over timer ticks")
    assert ops.HR_OT_add_preview.invoke(op, context, _Event("LEFTMOUSE")) == {"RUNNING_MODAL"}
    assert not preview.has_preview() and len(timers) == 1
    assert ops.HR_OT_add_preview.modal(op, context, _Event("MOUSEMOVE")) == {"PASS_THROUGH"}
    ticks = 0
    while (got := ops.HR_OT_add_preview.modal(op, context, _Event("TIMER", timers[0]))) == {"PASS_THROUGH"}:
        ticks += 1
    assert got == {"FINISHED"} and removed == timers
    from hr_addon.blender.scene_in import geometry_objects

    mats = {s.material for o in geometry_objects(bpy.context.view_layer) for s in o.material_slots}
    assert ticks >= len(mats) - 1
    assert reports[0][0] == "INFO" and f"{len(mats)} material(s)" in reports[0][1], reports
    wired = {m.name: sorted((n.name, n.bl_idname) for n in m.node_tree.nodes) for m in mats}
    assert all(preview.N_OUT in m.node_tree.nodes for m in mats)
    # named in the button's last step (each name costs Blender a relations update: not one per tick)
    assert all(m.node_tree.nodes[preview.N_ATTR].attribute_name == preview.ATTRIBUTE for m in mats)
    assert scene.name_full in ops.STATE.dirty  # the stale check follows on playback's timer
    # Remove Preview's button: a slice per tick too
    op = _unregistered(ops.HR_OT_remove_preview, report=op.report)
    assert ops.HR_OT_remove_preview.invoke(op, context, _Event("LEFTMOUSE")) == {"RUNNING_MODAL"}
    ticks = 0
    while (got := ops.HR_OT_remove_preview.modal(op, context, _Event("TIMER", timers[1]))) == {
        "PASS_THROUGH"
    }:
        ticks += 1
    assert got == {"FINISHED"} and removed == timers and ticks >= len(mats) - 1
    assert not preview.has_preview() and reports[-1] == (
        "INFO",
        f"Preview removed from {len(mats)} material(s)",
    )
    assert bpy.ops.hr.add_preview() == {"FINISHED"}  # execute(): the same nodes
    assert wired == {m.name: sorted((n.name, n.bl_idname) for n in m.node_tree.nodes) for m in mats}
