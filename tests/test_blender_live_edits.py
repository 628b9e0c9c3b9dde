"""A strength or colour edit in Live writes only the objects whose values changed by more than
sess.edit_threshold (live_session._within_threshold, docs/live.md, session 33); the rest are written
exactly once no new result follows (CATCH_UP_AFTER) or at hr.live_update(): the settled HR_Radiance
is the result bit for bit. Driven as test_blender_live_budget.py does (background mode)."""

import numpy as np

from test_blender_live import _emission_node, _live, _open, _update
from test_blender_live_budget import _bits, _held, _record_skips, _same, _skips


def _start(tmp_path):
    bpy, scene = _open(tmp_path, "FE")
    scene.hr.live = True
    _update(bpy)
    live, sess = _live(bpy)
    strength = _emission_node(bpy.data.materials["Patch Light"], "EMISSION").inputs["Strength"]
    return bpy, scene, live, sess, strength


def _times(socket, k):
    return lambda: setattr(socket, "default_value", socket.default_value * k)


def _result_of(bpy, scene, live, sess, edit):
    """The worker's result for edit (taken: _deliver_once hands it over)."""
    edit()
    vl = bpy.context.view_layer
    vl.update()
    live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
    assert sess.worker.flush(refine=False)
    _, r = sess.worker.take()
    assert r is not None and not r.error and {e.kind for e in r.report.events} == {"emission"}
    return r


def _deliver_once(live, sess, scene, r):
    """_deliver with r as the worker's newest result."""
    take = sess.worker.take
    sess.worker.take = lambda: (None, r)
    try:
        return live._deliver(sess, scene)
    finally:
        sess.worker.take = take


def test_an_edit_writes_what_changed_visibly_and_the_rest_when_it_settles(tmp_path, monkeypatch):
    """The patch light's strength edited: the objects whose change is above the threshold are
    written, the others keep their bits (and the session knows it: sess.written is what
    HR_Radiance holds); once no new result came for CATCH_UP_AFTER the rest is written, and
    HR_Radiance is the result bit for bit, as a write of it whole."""
    from hr_addon.blender import live_session

    _record_skips(monkeypatch)
    bpy, scene, live, sess, strength = _start(tmp_path)
    before = _held(bpy, sess.targets)
    r = _result_of(
        bpy, scene, live, sess, lambda: setattr(strength, "default_value", strength.default_value * 1.3)
    )
    keys = r.values.extract.span_keys
    rel = r.values.change(sess.written)
    sess.edit_threshold = float(np.median(rel))  # (half the room's objects under it: a mix)
    above = {keys[i] for i in np.flatnonzero(rel > sess.edit_threshold)}
    assert 0 < len(above) < len(keys)
    assert _deliver_once(live, sess, scene, r)
    assert set(sess.targets) - _skips[-1] == above
    held = _held(bpy, sess.targets)
    assert _same(held, _bits(sess.written, sess.targets))
    assert _same({n: held[n] for n in above}, _bits(r.values, above))
    left = set(keys) - above
    assert _same({n: held[n] for n in left}, {n: before[n] for n in left})
    assert sess.behind and sess.last is r
    n = len(_skips)
    assert not live._deliver(sess, scene) and len(_skips) == n  # too soon: a next edit may come
    sess.wrote_at -= live_session.CATCH_UP_AFTER
    assert live._deliver(sess, scene)
    assert not sess.behind and sess.written is r.values
    assert set(sess.targets) - _skips[-1] <= left  # only what the edit left out
    assert _same(_held(bpy, sess.targets), _bits(r.values, sess.targets))


def test_edits_below_the_threshold_wait_and_live_update_makes_them_exact(tmp_path, monkeypatch):
    """Two strength edits of the patch light by 0.05% each: no object changes by 1/512 of its
    level, none is written (each edit is measured against what HR_Radiance shows, not against the
    last result); hr.live_update() then writes HR_Radiance exactly. A 1.5x edit is written whole
    (every object that changed is above the threshold)."""
    _record_skips(monkeypatch)
    bpy, scene, live, sess, strength = _start(tmp_path)
    shown = _held(bpy, sess.targets)
    for _ in range(2):
        r = _result_of(
            bpy,
            scene,
            live,
            sess,
            lambda: setattr(strength, "default_value", strength.default_value * 1.0005),
        )
        assert _deliver_once(live, sess, scene, r)
        assert _skips[-1] == set(sess.targets) and sess.behind
        assert _same(_held(bpy, sess.targets), shown)
    assert not _same(shown, _bits(r.values, sess.targets))
    _update(bpy)
    assert not sess.behind and sess.last is r
    assert _same(_held(bpy, sess.targets), _bits(r.values, sess.targets))
    r = _result_of(
        bpy, scene, live, sess, lambda: setattr(strength, "default_value", strength.default_value * 1.5)
    )
    assert _deliver_once(live, sess, scene, r)
    assert not sess.behind and _same(_held(bpy, sess.targets), _bits(r.values, sess.targets))
