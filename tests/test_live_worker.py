"""Live Relight's worker (hr_addon/blender/live_worker.py, no bpy): the hierarchy built off the
calling thread, light states computed in order, edits coalesced, superseded builds cancelled.

The worker thread is held at a known point with threading.Event (never with sleeps or timings),
so what is asserted does not depend on the machine's speed."""

import threading

import numpy as np
import pytest

from hr_addon.blender.live_worker import PREVIEW, RESPONSE_TOL, BuildSpec, LiveWorker
from hr_testing import scenes
from hr_testing import shapes as S
from hr_addon.core.events import DynamicRadiosity, LightShape
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

COARSE = RefineParams(feps=0.1, aeps=4e-3, shadow_feps=0.02, veps=0.02)


def _shape(x, em=(8.0, 7.0, 5.0)):
    return {
        "w": LightShape(
            S.on_plane(S.rect(0.1, 0.08, centre=(x, 0.3)), S.CORNELL_GREEN_WALL), np.array(em, float), "w"
        )
    }


def _spec(mesh):
    return BuildSpec(mesh, COARSE, "FE", 1e-5, "CORNER", lambda v: {"all": v})


@pytest.fixture(scope="module")
def mesh():
    return scenes.cornell_box()


def _reference(mesh, shapes):
    """What a DynamicRadiosity with Live's settings computes (tests/test_events.py and
    tests/test_blender_live.py compare those with the batch settings and a bake)."""
    dyn = DynamicRadiosity(
        RadiositySystem(mesh, COARSE),
        method="FE",
        min_area_rel=1e-5,
        response_tol=RESPONSE_TOL,
        response_float32=True,
    )
    dyn.apply(shapes)
    return dyn.loop_radiance("CORNER")


def _assert_close(values, ref):
    """A move starts from the shape's previous response, so after one the result equals a fresh
    computation to the solver's tolerance, not to rounding (the criterion of tests/test_blender_live.py)."""
    np.testing.assert_allclose(values, ref, rtol=1e-4, atol=1e-6 * float(ref.max()))


def _hold(worker):
    """Make the worker's next apply() wait until the returned event is set; `entered` is set
    when it is waiting."""
    entered, release = threading.Event(), threading.Event()
    real = worker.dyn.apply

    def held(shapes, lights=None, **kw):
        entered.set()
        assert release.wait(60), "the test never released the worker"
        worker.dyn.apply = real
        return real(shapes, lights, **kw)

    worker.dyn.apply = held
    return entered, release


def test_unthreaded_worker_computes_on_flush(mesh):
    w = LiveWorker(threaded=False)
    w.request_build(_spec(mesh), 1, "a", _shape(0.2))
    assert w.pending and w.take() == (None, None)  # nothing happens before flush()
    assert w.flush()
    b, r = w.take()
    assert b is not None and not b.error and r is not None and r.serial == 1 and r.sig == "a"
    np.testing.assert_array_equal(r.values["all"][:, :3], _reference(mesh, _shape(0.2)))
    assert (r.values["all"][:, 3] == 1).all()  # RGBA, alpha 1
    w.request(2, "b", _shape(0.3))
    w.flush()
    _, r = w.take()
    _assert_close(r.values["all"][:, :3], _reference(mesh, _shape(0.3)))
    assert [e.kind for e in r.report.events] == ["reshape"]  # a move: remove + add
    assert w.computed == 2 and w.builds == 1


def test_edits_during_a_computation_are_coalesced(mesh):
    w = LiveWorker(threaded=True)
    try:
        w.request_build(_spec(mesh), 1, "s1", _shape(0.15))
        assert w.flush(timeout=600)
        _, first = w.take()
        assert first.serial == 1 and w.computed == 1
        entered, release = _hold(w)
        w.request(2, "s2", _shape(0.2))
        assert entered.wait(60)  # the worker computes state 2 ...
        for i, x in enumerate((0.25, 0.3, 0.35, 0.4)):  # ... while four more edits arrive
            w.request(3 + i, f"s{3 + i}", _shape(x))
        assert w.take() == (None, None)  # nothing new yet: the old result stays shown
        release.set()
        assert w.flush(timeout=600)
        _, r = w.take()
        # state 2 (already started) and the newest (6); states 3, 4, 5 were never computed
        assert w.computed == 3 and r.serial == 6 and r.sig == "s6"
        _assert_close(r.values["all"][:, :3], _reference(mesh, _shape(0.4)))
    finally:
        w.close()


def test_results_of_a_replaced_hierarchy_are_dropped(mesh):
    w = LiveWorker(threaded=True)
    try:
        w.request_build(_spec(mesh), 1, "a", _shape(0.2))
        assert w.flush(timeout=600)
        w.take()
        entered, release = _hold(w)
        w.request(2, "b", _shape(0.3))
        assert entered.wait(60)
        other = scenes.cornell_box(light=False)  # the geometry changed meanwhile
        w.request_build(_spec(other), 3, "c", _shape(0.3))
        release.set()
        assert w.flush(timeout=600)
        b, r = w.take()
        assert b is not None and w.builds == 2
        assert r.serial == 3 and r.generation == w.generation  # state 2 (old hierarchy) was dropped
        np.testing.assert_allclose(
            r.values["all"][:, :3], _reference(other, _shape(0.3)), rtol=1e-5, atol=1e-7
        )
    finally:
        w.close()


def test_invalid_shape_is_reported_and_state_kept(mesh):
    w = LiveWorker(threaded=False)
    w.request_build(_spec(mesh), 1, "a", _shape(0.2))
    w.flush()
    _, good = w.take()
    bow = S.on_plane(np.array([[0.1, 0.1], [0.3, 0.3], [0.3, 0.1], [0.1, 0.3]]), S.CORNELL_GREEN_WALL)
    w.request(2, "bad", {"w": LightShape(bow, np.ones(3), "Bowtie")})
    w.flush()
    _, r = w.take()
    assert r.values is None and "Bowtie" in r.error and "crosses itself" in r.error
    w.request(3, "a", _shape(0.2))  # back to the valid state: same light as before
    w.flush()
    _, r = w.take()
    np.testing.assert_allclose(r.values["all"], good.values["all"], rtol=1e-6, atol=1e-8)


def test_close_cancels_a_running_build(mesh):
    w = LiveWorker(threaded=True)
    w.request_build(_spec(mesh), 1, "a", _shape(0.2))
    w.close()
    w.thread.join(600)
    assert not w.thread.is_alive()
    assert w.dyn is None and w.builds == 0 and w.phase == "closed" and w.take() == (None, None)


def test_a_drag_shows_previews_then_the_exact_light(mesh):
    """With previews (the UI's threaded worker; set here on an unthreaded one), each drag step is
    a preview; flush() refines, giving bitwise what a worker without previews shows for the
    states it computed exactly (the start and the end of the drag)."""
    w = LiveWorker(threaded=False, preview=PREVIEW)
    ref = LiveWorker(threaded=False)
    assert ref.preview is None  # unthreaded: exact at once unless told
    for x in (w, ref):
        x.request_build(_spec(mesh), 1, "a", _shape(0.2))
        x.flush()
    _, start = w.take()
    assert not start.preview and not w.previewing  # the first state: added, then refined at once
    for i, x in enumerate((0.24, 0.28, 0.32)):
        w.request(2 + i, f"s{i}", _shape(x))
        assert w.flush(refine=False)
        _, r = w.take()
        assert r.preview and r.kind == "frame" and w.previewing and w.pending
    w.flush()
    _, r = w.take()
    assert not r.preview and r.kind == "refine" and r.serial == 4 and not w.pending
    ref.take()
    ref.request(4, "s2", _shape(0.32))
    ref.flush()
    _, exact = ref.take()
    np.testing.assert_array_equal(r.values["all"], exact.values["all"])
    assert w.computed == 4 and ref.computed == 2  # refines are not light states of their own
