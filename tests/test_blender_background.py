"""The interactive bake's background worker (hr_addon/blender/background.py) driven like the
modal operator does: start(), poll() in a loop, cancel(). In tests the worker is
`python -m hr_addon bake` (the bpy module has no Blender binary)."""

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, open_sample, shown

pytestmark = pytest.mark.bpy


def _wait(job, until=lambda job: False, limit=600):
    """poll() the job every 20 ms until it ends or until(job); the limit only bounds a hang."""
    t0 = time.monotonic()
    while job.poll():
        if until(job):
            return True
        assert time.monotonic() - t0 < limit, f"background bake still running: {job.status}"
        time.sleep(0.02)
    return False


def _cache_snapshot(d):
    """The bake's files. Not the scene precompute: no part of the bake, a cancel after the build
    keeps the new one the build stored."""
    return {p.name: p.read_bytes() for p in Path(d).iterdir() if p.name != "precompute.hrpc"}


def test_background_bake_reports_progress_and_loads_result(tmp_path):
    bpy = load_bpy()
    path = open_sample("searchbeam", tmp_path)
    from hr_addon.blender import background
    from hr_addon.io.cache import CacheReader

    scene = bpy.context.scene
    scene.frame_set(7)
    mtime = path.stat().st_mtime_ns
    job = background.BackgroundBake(scene, method="FE", quality="draft").start()
    assert background.running() and background.active() is job
    assert job.proc.pid > 0 and (job.tmp / path.name).is_file()  # the worker bakes a saved copy
    stages = []
    _wait(job, until=lambda j: stages.append(j.finish_stage if j.finishing else "") and False)
    assert job.state == "done", (job.error, job.status)
    # the result loaded a step per poll(): the frame, then the comparison (a slice per poll)
    assert "loading the current frame" in stages and "comparing the scene with the bake" in stages
    assert not background.running()
    # progress went through the status file: the build, then frames 1..12 with a time estimate
    stages = {s for _, s, _, _ in job.seen}
    assert {"build", "frame"} <= stages, job.seen
    fractions = [f for f, _, _, _ in job.seen]
    assert any(0 < f < 1 for f in fractions) and fractions == sorted(fractions), fractions
    assert any(fr is not None and 1 <= fr <= 12 for _, _, fr, _ in job.seen)
    assert any(eta is not None and eta >= 0 for _, st, _, eta in job.seen if st == "frame")
    assert "rays: embree" in job.summary, job.summary
    # the result is in the scene's cache folder and the current frame is shown
    cache = tmp_path / "hr_cache" / "searchbeam"
    reader = CacheReader(cache)
    assert sorted(reader.frames) == list(range(1, 13)) and reader.manifest["rays"] == "embree"
    assert scene.hr.bake_dir == "//hr_cache/searchbeam/" and job.loaded
    want = reader.load(7)
    for name, values in want.items():
        np.testing.assert_array_equal(attribute(bpy.data.objects[name]), values)
    assert path.stat().st_mtime_ns == mtime  # the user's file was not written
    assert not job.tmp.exists()  # the copy and status file are gone
    assert sorted(p.name for p in cache.parent.iterdir()) == ["searchbeam"]


@pytest.mark.slow
@pytest.mark.parametrize("wait", [True, False])
def test_background_cancel_keeps_previous_bake(tmp_path, wait):
    """Cancel keeps the previous bake. wait=False is the Cancel button's: cancel() returns at once
    (the UI does not wait for the worker to stop) and the job ends at a later poll()."""
    bpy = load_bpy()
    open_sample("searchbeam", tmp_path)
    from hr_addon.blender import background
    from hr_addon.blender.bake import run_bake

    scene = bpy.context.scene
    run_bake(scene, log=lambda *a, **k: None, frames=(1, 3), method="FE", quality="draft")
    cache = tmp_path / "hr_cache" / "searchbeam"
    before = _cache_snapshot(cache)
    scene.frame_set(2)
    before_values = shown(bpy.data.objects["wall_x0"])  # (through its HR Radiance modifier: 0.25 m)
    # NAIVE at medium quality rebuilds per frame: slow enough to be cancelled mid-way
    job = background.BackgroundBake(scene, method="NAIVE", quality="medium", frames=(1, 12)).start()
    assert _wait(job, until=lambda j: j.status.get("stage") == "frame"), job.status
    job.cancel(wait=wait)
    if not wait:
        assert job.cancelling and background.running()  # a new bake cannot start yet
        assert job.text().startswith("Cancelling")
        assert not _wait(job)
    assert job.state == "cancelled" and not background.running()
    assert job.proc.poll() is not None
    assert _cache_snapshot(cache) == before
    assert sorted(p.name for p in cache.parent.iterdir()) == ["searchbeam"]  # partial bake removed
    assert not job.tmp.exists()
    assert scene.hr.bake_dir == "//hr_cache/searchbeam/"
    np.testing.assert_array_equal(shown(bpy.data.objects["wall_x0"]), before_values)
    assert not job.poll()


def test_background_failure_is_reported(tmp_path):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    from hr_addon.blender import background

    job = background.BackgroundBake(
        bpy.context.scene, output="texture", frames=(-2, 1), quality="draft"
    ).start()
    _wait(job)
    assert job.state == "failed"
    assert "frame numbers >= 0" in job.error, job.error
    assert not (tmp_path / "hr_cache" / "cornell").exists()


def test_background_start_refuses_unsaved_file():
    bpy = load_bpy()
    from hr_addon.blender import background
    from hr_addon.blender.scene_in import SceneError

    bpy.ops.wm.read_factory_settings(use_empty=False)
    with pytest.raises(SceneError, match="Save the .blend file first"):
        background.BackgroundBake(bpy.context.scene).start()
    assert not background.running()


def test_status_file_reader_is_robust(tmp_path):
    from hr_addon.blender.jobstatus import StatusWriter, read_status

    p = tmp_path / "status.json"
    assert read_status(p) is None  # missing
    w = StatusWriter(p, cache_dir="/x")
    s = read_status(p)
    assert s["state"] == "running" and s["fraction"] == 0.0 and s["pid"] == os.getpid()
    w.write(fraction=0.25, eta=float("nan"))  # NaN is written as JSON NaN: read back as unknown
    assert read_status(p)["eta"] is None and read_status(p)["fraction"] == 0.25
    text = p.read_text()
    p.write_text(text[: len(text) // 2])  # a torn write (not possible with replace, but)
    assert read_status(p) is None
    p.write_text(json.dumps({"version": 99, "state": "done"}))
    assert read_status(p) is None
    p.write_text(json.dumps({"version": 1, "state": "exploded"}))
    assert read_status(p) is None
    p.write_text(json.dumps({"version": 1, "state": "running", "fraction": 7, "eta": "soon"}))
    assert read_status(p) is None
    p.write_text(json.dumps({"version": 1, "state": "running", "fraction": 7, "eta": 3}))
    assert read_status(p)["fraction"] == 1.0 and read_status(p)["eta"] == 3.0
