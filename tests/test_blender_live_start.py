"""Live Relight's start and stop spread over timer ticks (live_session.start / stop with spread=True,
the UI's default): the preview's materials wired and the scene read a slice per tick, the restore at
stop the same way. Background mode has no event loop: live._tick() is called here as Blender's
timer would, with SLICE 0 (one step per tick), and edits fire the depsgraph handler through
view_layer.update(), as tests/test_blender_live.py does."""

import numpy as np
import pytest

from test_blender_helpers import attribute, load_bpy, open_sample


def _open(tmp_path, monkeypatch):
    bpy = load_bpy()
    open_sample("cornell", tmp_path)
    scene = bpy.context.scene
    scene.hr.method = "FE"
    scene.hr.quality = "DRAFT"
    for o in scene.objects:
        if o.hr.is_light_shape:
            o.animation_data_clear()
            o.hide_render = False
    from hr_addon.blender import live_session

    monkeypatch.setattr(live_session, "SLICE", 0.0)  # one step per tick
    return bpy, scene


def _state(bpy):
    """What Live may change in the file: each material's nodes and active output, each object's
    material slots and colour attributes."""
    mats = {}
    for m in bpy.data.materials:
        tree = m.node_tree
        nodes = sorted(n.name for n in tree.nodes) if tree is not None else []
        active = (
            [n.name for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output] if tree else []
        )
        links = sorted((lk.from_node.name, lk.to_node.name) for lk in tree.links) if tree else []
        mats[m.name] = (nodes, active, links)
    objs = {
        o.name: (
            [s.material.name if s.material else None for s in o.material_slots],
            sorted(a.name for a in o.data.color_attributes),
        )
        for o in bpy.data.objects
        if o.type == "MESH"
    }
    return mats, objs


def _shown(bpy, sess):
    return {n: attribute(bpy.data.objects[n]).copy() for n in sess.targets}


def _prepare(live, sess, limit=10000):
    """Tick until the preparation is over; the panel's lines meanwhile."""
    texts = []
    for _ in range(limit):
        if sess.preparing is None:
            return texts
        live._tick()
        texts.append(sess.text())
    raise AssertionError("the preparation did not end")


def _result(live, sess):
    assert sess.worker.flush(timeout=600)
    live._tick()  # the result written
    assert sess.last is not None and not sess.error, sess.text()


def _stop(live, scene):
    live.stop(scene)
    for _ in range(10000):
        if not live.restoring(scene):
            return
        live._tick()
    raise AssertionError("the restore did not end")


def _one_call(bpy, live, scene):
    """HR_Radiance of Live started in one call (scripts), then Live off."""
    sess = live.start(scene, threaded=False, spread=False)
    assert sess.preparing is None
    assert sess.worker.flush(timeout=600)
    live._tick()
    shown = _shown(bpy, sess)
    live.stop(scene)
    return shown


def test_a_spread_start_prepares_over_ticks_and_shows_what_one_call_shows(tmp_path, monkeypatch):
    bpy, scene = _open(tmp_path, monkeypatch)
    from hr_addon.blender import live

    before = _state(bpy)
    sess = live.start(scene, threaded=False, spread=True)
    assert sess.preparing is not None and sess.worker.generation == 0  # nothing done in start()
    texts = _prepare(live, sess)
    n_obj = len(sess.targets)
    assert len(texts) > n_obj  # a step per material, per object
    assert "Live Relight: preparing 1 / 5 materials (the preview's nodes)" in texts
    assert f"Live Relight: preparing {n_obj} / {n_obj} objects" in texts
    assert sess.worker.generation == 1 and sess.reads == 1
    _result(live, sess)
    spread = _shown(bpy, sess)
    _stop(live, scene)
    assert _state(bpy) == before  # the preview's nodes and HR_Radiance gone again (no bake)
    one = _one_call(bpy, live, scene)
    assert spread.keys() == one.keys()
    for name in one:
        np.testing.assert_array_equal(spread[name], one[name], err_msg=name)


@pytest.mark.parametrize("phase", ["materials", "objects"])
@pytest.mark.parametrize("how", ["stop", "toggle"])
def test_stopping_while_it_prepares_leaves_nothing_behind(tmp_path, monkeypatch, phase, how):
    bpy, scene = _open(tmp_path, monkeypatch)
    from hr_addon.blender import live, preview

    before = _state(bpy)
    assert not preview.has_preview()
    sess = live.start(scene, threaded=False, spread=True)
    for _ in range(1000):  # into the phase, a step or two done
        live._tick()
        done, of, what = sess.prepared
        if what.startswith(phase) and 1 <= done < of:
            break
    else:
        raise AssertionError(f"never in {phase}: {sess.prepared}")
    assert preview.has_preview()  # a part is wired
    if how == "stop":
        assert live.stop(scene) == "no HR_Radiance (there is no bake)"
    else:  # the panel's checkbox: the timer ends Live
        scene.hr.live = False
        live._tick()
    assert not live.is_live(scene) and not scene.hr.live
    assert sess.worker.generation == 0  # no build was asked for
    for _ in range(1000):
        if not live.restoring(scene):
            break
        live._tick()
    assert not live.restoring(scene)
    assert _state(bpy) == before
    assert not preview.has_preview()


def test_edits_while_it_prepares_are_in_the_result(tmp_path, monkeypatch):
    """A light shape's edit is read at the preparation's last step (no new read); an edit of the
    geometry during the read starts the read again. Either way the result is Live's of the edited
    scene, started in one call."""
    bpy, scene = _open(tmp_path, monkeypatch)
    from hr_addon.blender import live

    unedited = _one_call(bpy, live, scene)
    window, block = bpy.data.objects["Window"], bpy.data.objects["short_block"]
    vl = bpy.context.view_layer

    def into_the_read(sess, at=2):
        for _ in range(1000):
            live._tick()
            done, of, what = sess.prepared
            if what == "objects" and done >= at:
                return
        raise AssertionError(sess.prepared)

    # a light shape moved while the scene is read: no second read, the move is in the result
    sess = live.start(scene, threaded=False, spread=True)
    into_the_read(sess)
    window.location.y += 0.06
    vl.update()  # the depsgraph handler
    _prepare(live, sess)
    assert sess.reads == 1
    _result(live, sess)
    moved = _shown(bpy, sess)
    assert any(not np.array_equal(moved[n], unedited[n]) for n in moved)
    _stop(live, scene)
    for name, v in _one_call(bpy, live, scene).items():
        np.testing.assert_array_equal(moved[name], v, err_msg=name)

    # the geometry edited while the scene is read: read again; the light shape's edit too
    sess = live.start(scene, threaded=False, spread=True)
    into_the_read(sess, at=3)
    block.location.x += 0.05
    vl.update()
    window.location.y -= 0.03
    vl.update()
    _prepare(live, sess)
    assert sess.reads == 2
    _result(live, sess)
    edited = _shown(bpy, sess)
    _stop(live, scene)
    fresh = _one_call(bpy, live, scene)
    assert any(not np.array_equal(edited[n], moved[n]) for n in edited)
    for name, v in fresh.items():
        np.testing.assert_array_equal(edited[name], v, err_msg=name)


def test_update_finishes_a_spread_start_at_once(tmp_path, monkeypatch):
    """hr.live_update() is synchronous: a start still preparing over ticks is finished in the call."""
    bpy, scene = _open(tmp_path, monkeypatch)
    from hr_addon.blender import live

    sess = live.start(scene, threaded=False, spread=True)
    live._tick()
    assert sess.preparing is not None
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    assert sess.preparing is None and sess.last is not None and sess.reads == 1
    _stop(live, scene)
