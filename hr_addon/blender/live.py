"""Live Relight in the UI: the timer that drives the sessions (live_session.py) and the
handlers that mark them dirty (depsgraph updates, frame changes, undo, renders, file loads).

The public face of Live for operators, panels and scripts: start() (which also starts the
timer), stop(), update(), is_live(), message(), session().
"""

import time

import bpy
from bpy.app.handlers import persistent

from . import paths, playback
from .live_session import (
    BAKE_RUNNING,
    GEOMETRY_SETTLE,
    IDLE_POLL,
    TICK,
    WATCH,
    LiveError,
    _deliver,
    _prepare,
    _reconcile,
    _scene_of,
    drop_restores,
    finish_restores,
    is_live,
    message,
    restore_tick,
    restoring,
    session,
    stop,
    stop_all,
    update,
)
from .live_session import start as _start_session
from .scene_in import SceneError
from .state import STATE

__all__ = [
    "BAKE_RUNNING",
    "LiveError",
    "is_live",
    "message",
    "restoring",
    "session",
    "start",
    "stop",
    "stop_all",
    "update",
]


def start(scene, view_layer=None, threaded=None, spread=None):
    """Start Live on scene (live_session.start) and the timer that drives it."""
    sess = _start_session(scene, view_layer, threaded, spread)
    _ensure_timer()
    return sess


# -- the UI: handlers and the timer -------------------------------------------------------------------
def _redraw():
    wm = bpy.context.window_manager
    for win in getattr(wm, "windows", []):
        for area in win.screen.areas:
            if area.type in {"PROPERTIES", "VIEW_3D"}:
                area.tag_redraw()


def _ensure_timer(first=0.0):
    """Run the timer in `first` seconds (sooner if it was due later; inside the timer, it returns
    its own next interval)."""
    if bpy.app.background or STATE.in_tick:
        return
    if bpy.app.timers.is_registered(_tick):
        if first > 0:
            return
        bpy.app.timers.unregister(_tick)
    bpy.app.timers.register(_tick, first_interval=first, persistent=True)


def _tick():
    """Main thread, every TICK s while something is pending (IDLE_POLL s otherwise)."""
    STATE.in_tick = True
    try:
        return _tick_body()
    finally:
        STATE.in_tick = False


def _tick_body():
    if STATE.baking:
        return IDLE_POLL
    now = time.monotonic()
    redraw = restore_tick()  # the stops' restores, a slice each
    for scene in list(bpy.data.scenes):
        if scene.hr.live and not is_live(scene):
            try:
                start(scene)
            except (SceneError, ValueError, RuntimeError) as exc:
                print(f"HR Radiosity: Live Relight: {exc}", flush=True)
                STATE.live_messages[scene.name_full] = str(exc)
                if scene.hr.live:
                    scene.hr.live = False
            redraw = True
    for name, sess in list(STATE.live_sessions.items()):
        scene, vl = _scene_of(sess)
        if scene is None:
            STATE.live_sessions.pop(name).worker.close()
            continue
        if not scene.hr.live:
            what = stop(scene)
            print(f"HR Radiosity: Live Relight off: {what}", flush=True)
            redraw = True
            continue
        if sess.preparing is not None and not STATE.bake_running():
            _prepare(sess, scene, vl)  # the build's preparation, a slice per tick
            redraw = True
            continue
        if sess.fatal:
            continue
        if STATE.bake_running():
            stop(scene, restore=False)
            STATE.live_messages[scene.name_full] = "Live Relight turned off for the bake."
            redraw = True
            continue
        building = sess.building
        wrote = _deliver(sess, scene)
        redraw |= wrote or building
        settle = sess.geometry_dirty and now - sess.geometry_dirty >= GEOMETRY_SETTLE
        # the idle poll not in the tick that wrote HR_Radiance: its depsgraph would evaluate every
        # written mesh here (200-300 ms at 100k) where Blender's redraw evaluates them anyway
        poll = now - sess.last_poll >= IDLE_POLL and not wrote
        if sess.dirty or settle or poll:
            try:
                _reconcile(sess, scene, vl, check_geometry=bool(settle), fast=not (settle or poll))
            except (SceneError, ValueError, RuntimeError) as exc:
                sess.error = str(exc)
            redraw = True
    if redraw:
        _redraw()
    if restoring():
        return TICK
    if not STATE.live_sessions:
        return WATCH  # keeps watching Scene.hr.live (a script may set it: no depsgraph update)
    busy = any(
        s.worker.pending
        or s.dirty
        or s.geometry_dirty
        or s.force_write
        or s.behind
        or s.preparing is not None
        for s in STATE.live_sessions.values()
    )
    return TICK if busy else IDLE_POLL / 2


_GEOMETRY_KINDS = ("Image", "NodeTree")  # images (averaged colours) and node groups


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    """Mark the session dirty (the timer reads the scene); our own HR_Radiance writes are skipped."""
    if STATE.baking or depsgraph is None:
        return
    if scene.hr.live != is_live(scene):
        _ensure_timer()  # Scene.hr.live set by a script: the timer starts / ends Live
    sess = session(scene)
    if sess is None:
        return
    own = STATE.writes.take(reader=sess.scene_name)
    dirty = geometry = full = False
    for u in depsgraph.updates:
        idd = u.id
        kind = type(idd).__name__
        if kind == "Mesh":
            if idd.name in own:  # (a mesh's update says is_updated_transform too)
                continue
            dirty = True
            if idd.name in sess.shape_meshes and not u.is_updated_geometry:
                continue  # its material's strength or colour (its data, HR_Radiance, did not change)
            sess.written = None  # (a light shape's mesh too: its own HR_Radiance may have changed)
            if idd.name not in sess.shape_meshes:
                geometry = full = True
        elif kind == "Object":
            ob = getattr(idd, "original", idd)
            data = getattr(ob, "data", None)
            if not u.is_updated_transform and data is not None and getattr(data, "name", None) in own:
                continue
            dirty = True
            if ob.name not in sess.shape_objects:
                full = True  # visibility and the set of objects: the name check of a full read
            if (
                (u.is_updated_geometry or u.is_updated_transform)
                and not ob.hr.is_light_shape
                and ob.type not in {"CAMERA", "LIGHT", "SPEAKER", "LIGHT_PROBE"}
            ):
                geometry = True
        elif kind.endswith("Material"):
            dirty = True
            name = getattr(idd, "original", idd).name_full
            geometry |= name in sess.geo_materials
            full |= name not in sess.shape_materials
        elif kind.endswith("Light") or kind == "World":  # a light's data; the sky (Blender < 5 can
            dirty = True  # colour a World without a node tree: then no NodeTree update comes)
        elif kind.endswith("NodeTree") and getattr(idd, "is_embedded_data", False):
            dirty = True  # a material's own tree: its Material is in the updates too
        elif kind.endswith(_GEOMETRY_KINDS):
            dirty = geometry = full = True
        elif kind in ("Scene", "Collection", "Action"):  # (keys added: which shapes move, a full read)
            dirty = full = True
    if geometry:
        sess.geometry_dirty = time.monotonic()
        sess.written = None  # an object that is not Live's write changed: write every object again
    sess.full_read |= full or geometry
    if dirty or geometry:
        sess.dirty = sess.dirty or dirty
        _ensure_timer()


@persistent
def on_frame_change_post(scene, *args):
    sess = session(scene)
    if sess is not None and not STATE.baking:
        sess.dirty = True
        _ensure_timer()


@persistent
def on_undo_redo(*args):
    """Undo brings back HR_Radiance values (and Scene.hr.live) of another moment: write again."""
    for name, sess in STATE.live_sessions.items():
        scene = bpy.data.scenes.get(name)
        if scene is not None and not scene.hr.live:
            scene.hr.live = True  # Live is a session, not an undo step
        sess.force_write = sess.dirty = True
        sess.geometry_dirty = time.monotonic()
        sess.objects.clear()  # undo replaced the objects: references to the old ones must go
        sess.written = None
    if STATE.live_sessions:
        _ensure_timer()


@persistent
def on_frame_change_pre(scene, *args):
    """During an animation render Live steps aside (playback loads the bake, playback.live_shown).
    Without a bake every frame would render the Live light of the moment: say so, once per render."""
    if is_live(scene) and bpy.app.is_job_running("RENDER") and not paths.bake_dir_abs(scene):
        sess = session(scene)
        if not sess.render_note:
            sess.render_note = (
                "Live Relight: an animation render shows the Live light of the moment on every "
                "frame (there is no bake to play back): bake to render the light of each frame."
            )
            print(f"HR Radiosity: {sess.render_note}", flush=True)


@persistent
def on_render_done(*args):
    """An animation render played the bake back (Live steps aside while rendering): write again."""
    for sess in STATE.live_sessions.values():
        sess.force_write = sess.dirty = True
        sess.render_note = ""
    if STATE.live_sessions:
        _ensure_timer()


@persistent
def on_load_pre(*args):
    stop_all(restore=False)
    drop_restores()  # (the file's data goes away)


@persistent
def on_load_post(*args):
    """Live is a session, not saved state: a file saved with Live on opens with it off."""
    STATE.live_messages.clear()
    for scene in bpy.data.scenes:
        if scene.hr.live:
            scene.hr.live = False


def _handlers():
    h = bpy.app.handlers
    return (
        (h.depsgraph_update_post, on_depsgraph_update),
        (h.frame_change_pre, on_frame_change_pre),
        (h.frame_change_post, on_frame_change_post),
        (h.undo_post, on_undo_redo),
        (h.redo_post, on_undo_redo),
        (h.render_complete, on_render_done),
        (h.render_cancel, on_render_done),
        (h.load_pre, on_load_pre),
        (h.load_post, on_load_post),
    )


def register():
    for lst, fn in _handlers():
        playback._remove(lst, fn)
        lst.append(fn)
    _ensure_timer(WATCH)


def unregister():
    workers = [s.worker for s in STATE.live_sessions.values()]
    stop_all(restore=False)
    finish_restores()  # (a stop's restore still running: the preview's nodes undone)
    for w in workers:  # do not leave a thread computing in an add-on that is going away
        w.join(10.0)
    for lst, fn in _handlers():
        playback._remove(lst, fn)
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
