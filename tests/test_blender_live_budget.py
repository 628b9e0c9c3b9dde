"""Live's per-update write budget for a drag's previews (live_session._within_budget, docs/live.md,
session 29): a preview writes at most sess.write_budget objects, those whose values changed most
against what HR_Radiance holds; the others are measured again at the next update; the exact
update (the refine), strength and colour edits write everything, bit for bit as without a budget.
Driven as test_blender_live.py does (background mode: hr.live_update(), _reconcile / _deliver)."""

import numpy as np

from test_blender_helpers import attribute
from test_blender_live import _emission_node, _live, _open, _update


def _held(bpy, names):
    return {n: attribute(bpy.data.objects[n]).reshape(-1).view(np.uint32).copy() for n in names}


def _bits(rows, names):
    return {n: np.asarray(rows[n], np.float32).reshape(-1).view(np.uint32) for n in names}


def _same(a, b):
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def _drag(bpy, scene, live, sess, window, steps, written=None):
    """Drag steps as the timer delivers them (previews); written: a list that gets, per step, the
    names the write did not skip."""
    vl = bpy.context.view_layer
    for _ in range(steps):
        window.location.y += 0.02
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        assert sess.worker.flush(refine=False)
        live._deliver(sess, scene)
        vl.update()  # (Live's own writes: they do not drop sess.written)
        assert sess.last.preview and sess.written is not None
        # what the session records is what HR_Radiance holds, bit for bit
        assert _same(_held(bpy, sess.targets), _bits(sess.written, sess.targets))
        if written is not None:
            written.append(set(sess.targets) - (_skips[-1] or set()))


_skips = []


def _record_skips(monkeypatch):
    from hr_addon.blender import playback

    _skips.clear()
    apply = playback.apply_arrays
    monkeypatch.setattr(
        playback, "apply_arrays", lambda *a, skip=None, **k: _skips.append(skip) or apply(*a, skip=skip, **k)
    )


def _start(tmp_path, budget):
    from hr_addon.blender.live_worker import PREVIEW

    bpy, scene = _open(tmp_path, "FE")
    scene.hr.live = True
    _update(bpy)
    live, sess = _live(bpy)
    sess.worker.preview = PREVIEW
    sess.write_budget = budget
    return bpy, scene, live, sess, bpy.data.objects["Window"]


def test_a_budgeted_preview_writes_at_most_the_budget_and_the_rest_later(tmp_path, monkeypatch):
    from hr_addon.blender import live_session

    monkeypatch.setattr(live_session, "PREVIEW_WRITE_THRESHOLD", 0.0)  # every changed object competes
    _record_skips(monkeypatch)
    bpy, scene, live, sess, window = _start(tmp_path, 2)
    written = []
    _drag(bpy, scene, live, sess, window, 4, written)
    assert all(len(w) <= 2 for w in written) and len(sess.targets) > 4
    # objects the first preview changed but left out were written by a later one, and every object
    # the drag changed has been written at least once within 4 updates of 2
    left = set(sess.targets) - written[0]
    assert left & set().union(*written[1:])
    assert sess.behind and sess.written is not sess.last.values
    # what lags is what a write of the full preview would still change
    rel = sess.last.values.change(sess.written)
    keys = sess.last.values.extract.span_keys
    lagging = {keys[i] for i in np.flatnonzero(rel > 0)}
    assert lagging and not lagging & written[-1]


def test_the_exact_update_after_a_budgeted_drag_is_the_unbudgeted_ones(tmp_path, monkeypatch):
    """HR_Radiance after the refine that ends a drag written within a budget of 1 is bit for bit
    what the same drag without a budget leaves (Live turned off and on again, the window back at
    the start); before the refine the budget had left objects behind the preview."""
    bpy, scene, live, sess, window = _start(tmp_path, 1)
    start = tuple(window.location)
    _drag(bpy, scene, live, sess, window, 3)
    assert sess.behind
    assert not _same(_held(bpy, sess.targets), _bits(sess.last.values, sess.targets))
    assert sess.worker.flush()
    live._deliver(sess, scene)
    assert not sess.last.preview and not sess.behind and sess.written is sess.last.values
    budgeted = _held(bpy, sess.targets)
    scene.hr.live = False
    _update(bpy)
    bpy, scene, live, sess, window = _start(tmp_path / "b", None)  # (the file again: the window at start)
    assert tuple(window.location) == start
    _drag(bpy, scene, live, sess, window, 3)
    assert sess.written is sess.last.values  # no budget: every changed object written
    assert sess.worker.flush()
    live._deliver(sess, scene)
    assert _same(budgeted, _held(bpy, sess.targets))


def test_strength_and_colour_edits_are_written_whole_during_a_drag(tmp_path, monkeypatch):
    """A strength or colour change while a budgeted preview is shown (the preview stays, scaled)
    writes every object: HR_Radiance holds the result bit for bit."""
    bpy, scene, live, sess, window = _start(tmp_path, 1)
    _drag(bpy, scene, live, sess, window, 2)
    assert sess.behind
    node = _emission_node(bpy.data.materials["Window Light"], "BSDF_PRINCIPLED")  # the dragged shape's
    strength, colour = node.inputs["Emission Strength"], node.inputs["Emission Color"]
    vl = bpy.context.view_layer
    for edit in (
        lambda: setattr(strength, "default_value", strength.default_value * 1.5),
        lambda: setattr(colour, "default_value", (1.0, 0.6, 0.4, 1.0)),
    ):
        edit()
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        assert sess.worker.flush(refine=False)
        live._deliver(sess, scene)
        assert sess.last.preview and {e.kind for e in sess.last.report.events} == {"emission"}
        assert not sess.behind and sess.written is sess.last.values
        assert _same(_held(bpy, sess.targets), _bits(sess.last.values, sess.targets))


def test_once_the_drag_pauses_the_rest_of_the_preview_is_written_a_budget_at_a_time(tmp_path, monkeypatch):
    """With no new result (the timer's ticks while the refine is computed) a session behind its
    preview writes the next budget's worth of it once CATCH_UP_AFTER has passed since its last
    write, not while an edit is pending (dirty), until HR_Radiance holds the preview."""
    from hr_addon.blender import live_session

    monkeypatch.setattr(live_session, "PREVIEW_WRITE_THRESHOLD", 0.0)
    _record_skips(monkeypatch)
    bpy, scene, live, sess, window = _start(tmp_path, 1)
    _drag(bpy, scene, live, sess, window, 2)
    assert sess.behind
    n = len(_skips)
    assert not live._deliver(sess, scene) and len(_skips) == n  # too soon after the write
    sess.wrote_at -= live_session.CATCH_UP_AFTER
    sess.dirty = True
    assert not live._deliver(sess, scene) and len(_skips) == n  # an edit is pending: it comes first
    sess.dirty = False
    for _ in range(len(sess.targets)):
        if not sess.behind:
            break
        sess.wrote_at -= live_session.CATCH_UP_AFTER
        assert live._deliver(sess, scene)
        assert len(set(sess.targets) - _skips[-1]) <= 1
        assert _same(_held(bpy, sess.targets), _bits(sess.written, sess.targets))
    assert not sess.behind and sess.last.preview
    assert _same(_held(bpy, sess.targets), _bits(sess.last.values, sess.targets))
