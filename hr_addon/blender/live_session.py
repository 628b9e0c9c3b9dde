"""Live Relight's sessions (Scene.hr.live): edit a light shape, see HR_Radiance follow.

A session per scene keeps one hierarchy in memory (built once, off the UI thread, with progress)
and turns every light-shape edit into light events on it: move, scale, rotate, reshape in Edit
Mode, strength or colour, hide_render, new or removed shapes. Blender data is read and written on
the main thread only: live.py's depsgraph handler marks the session dirty, its timer reads the
light shapes (_reconcile), hands the full set to the worker (live_worker.py: numpy only, its own
thread, edits coalesced) and writes each finished result into HR_Radiance (_deliver); the previous
result stays on screen until then. Participating geometry or settings that change (signatures.py,
as the bake's stale check) rebuild the hierarchy, and the panel says why.

`update()` (operator hr.live_update) is the synchronous entry point: it reads the current state of
everything, applies what changed since the last update (whether or not a handler fired) and
returns when HR_Radiance is current. In background mode it is how Live is driven: there is no
event loop, so no timer and no thread.

Live never runs together with a bake: it refuses to start while one runs, and a bake that starts
ends it (the bake-start hook of state.py). Turning it off restores the baked playback (or removes
HR_Radiance when there is no bake).
"""

import time
from collections import deque

import numpy as np

import bpy

from ..core.events import LightShape
from .state import STATE
from . import names, paths, playback, preview, signatures, texture
from .settings import precompute_key
from .settings import BakeConfig, live_mode, solver_setup
from ..io.cache import changed_objects
from .live_worker import BuildSpec, LiveWorker
from .lights_in import (
    collect_light_shapes,
    collect_lights,
    light_objects,
    lights_signature,
    moving_shapes,
    shapes_signature,
)
from .scene_in import FlatExtract, SceneError, collect_geometry_steps, geometry_objects, light_shape_objects
from .steps import advance, finish


class LiveError(SceneError):
    """Live Relight cannot do what was asked (one-line reason)."""


BAKE_RUNNING = (
    "A radiosity bake is running: Live Relight cannot start until it has finished (or is cancelled)."
)
TICK, IDLE_POLL, GEOMETRY_SETTLE, WATCH = 0.02, 0.5, 0.25, 1.0  # seconds
SLICE = 0.04  # seconds of a build's preparation (or of a stop's restore) per timer tick
_RESTORING = {}  # {scene name: the steps of a stop's restore still to run} (over timer ticks)
# a drag's preview writes at most this many objects, those whose values changed most by more than the
# threshold (relative to the object's level), against what HR_Radiance shows (docs/live.md, session 29)
PREVIEW_WRITE_BUDGET = 500
PREVIEW_WRITE_THRESHOLD = 1e-3
# a strength or colour edit writes only the objects whose values changed by more than this (relative
# to the object's level: below one 8-bit display step); the others are written exactly once no new
# result came for CATCH_UP_AFTER (docs/live.md, session 33)
EDIT_WRITE_THRESHOLD = 1 / 512
CATCH_UP_AFTER = 0.25  # s without a new result after a budgeted write: the drag paused, write on


def message(scene):
    return STATE.live_messages.get(scene.name_full, "") if scene is not None else ""


def session(scene):
    return STATE.live_sessions.get(scene.name_full) if scene is not None else None


def is_live(scene):
    return session(scene) is not None


class Session:
    def __init__(self, scene, view_layer, threaded, spread=False):
        self.scene_name = scene.name_full
        self.view_layer_name = view_layer.name
        self.worker = LiveWorker(threaded)
        # the UI's sessions prepare a build (the preview's materials, the scene read) and restore at
        # stop over timer ticks (live._tick advances `preparing`); scripts, tests: in one call
        self.spread = spread
        self.preparing = None  # the steps of the build being prepared (_build_steps), None: none
        self.prepared = (0, 0, "")  # (done, of, what) for the panel while preparing
        self.before = None  # the steps of a previous session's restore, run before the first build
        self.take_off = False  # a baked-texture preview to take off before the first build
        self.preparing_reason = ""  # the reason of the build being prepared
        self.wired = []  # names of the objects whose materials the preview was wired for
        self.reads = 0  # scene reads begun over timer ticks (an edit meanwhile starts one again)
        self.settings = None  # settings of the last build request
        self.geometry = None  # geometry signatures of the last build request
        self.geo_names = None  # names of the geometry objects then
        self.geo_materials = set()  # their materials (a depsgraph update of one may change the light)
        self.shape_meshes = set()  # mesh data of the light shapes (their edits are light events)
        self.shape_objects = []  # names of the light-shape objects (all, hidden ones too)
        self.moving = frozenset()  # the names of those that move (lights_in.moving_shapes)
        self.shape_materials = set()  # their materials
        self.light_objects = []  # names of the Blender lights (all, hidden ones too)
        self.full_read = True  # an update other than of known light shapes: read everything
        self.domain = "CORNER"
        self.targets = []  # object names that get HR_Radiance
        self.objects = {}  # {name: object} of the targets, looked up once (playback.apply_arrays)
        self.reason = ""  # why the hierarchy is (being) built
        self.serial = 0
        self.requested_sig = None  # light state handed to the worker last
        self.shown_sig = None  # light state whose result is in HR_Radiance
        self.last = None  # the Result shown
        self.error = ""  # the current light state cannot be computed (the last valid one shows)
        self.problems = ""  # writing HR_Radiance failed for some objects
        self.fatal = ""
        self.notes = []  # warnings of the geometry read and of the build
        self.light_notes = []  # warnings of the current light state
        self.dirty = True  # something may have changed: read the light shapes again
        self.geometry_dirty = 0.0  # time of the last update that may have changed the geometry (0: none)
        self.force_write = False  # HR_Radiance must be written again (undo, render)
        self.written = None  # the values HR_Radiance holds (the last write's, Rows), None: unknown
        self.write_budget = PREVIEW_WRITE_BUDGET  # objects a drag's preview writes at most (None: all)
        self.edit_threshold = EDIT_WRITE_THRESHOLD  # an emission edit's skip (None: exact writes)
        self.behind = False  # the last write left changes out (a budgeted preview, a thresholded edit)
        self.wrote_at = 0.0  # time.monotonic() of the last write
        self.preview_change = ""  # what preview.show_radiance changed (undone when Live ends)
        self.texture_objects = []  # objects whose baked-texture preview Live took off (restored)
        self.last_poll = 0.0
        self.render_note = ""  # said once per render (see on_frame_change_pre)
        self.latencies = deque(maxlen=500)  # seconds from a light-state request to HR_Radiance written
        self.updates = 0

    # -- what the panel shows --------------------------------------------------------------------
    @property
    def building(self):
        w = self.worker
        return w.generation > w.built and w.phase not in ("failed", "closed")

    def text(self):
        w = self.worker
        if self.fatal:
            return f"Live Relight stopped: {self.fatal}"
        if self.preparing is not None:
            done, of, what = self.prepared
            return (
                f"Live Relight: preparing {done} / {of} {what}" if of else f"Live Relight: preparing ({what})"
            )
        if self.building:
            pct = f"{100 * w.fraction:.0f}%"
            eta = "" if w.eta != w.eta else f", about {w.eta:.0f} s left"
            return f"Live: building the hierarchy ({self.reason}): {pct}{eta}"
        if self.error:
            return f"Live: {self.error} Showing the light of the last valid state."
        if self.last is None:
            return "Live: computing"
        r = self.last
        ms = 1000 * (r.t_apply + r.t_output)
        if r.preview:  # a drag's cheaper estimate (live_worker.PREVIEW): the exact light follows
            return f"Live: preview ({ms:.0f} ms); the exact light follows when the edits pause"
        if w.pending or self.dirty:
            return "Live: updating (showing the previous state until the new one is ready)"
        n = len(r.report.events) if r.report is not None else 0
        return (
            f"Live: up to date, exact; last update {ms:.0f} ms ({n} light event(s), {w.spec.method}; "
            f"hierarchy {w.precompute})"
        )


def _scene_of(sess):
    scene = bpy.data.scenes.get(sess.scene_name)
    if scene is None:
        return None, None
    vl = scene.view_layers.get(sess.view_layer_name) or scene.view_layers[0]
    return scene, vl


def _depsgraph(scene, view_layer):
    """The evaluated depsgraph of scene / view_layer, up to date."""
    ctx = bpy.context
    try:
        if ctx.scene == scene and ctx.view_layer == view_layer:
            return ctx.evaluated_depsgraph_get()
    except (AttributeError, RuntimeError, ReferenceError):
        pass
    dg = view_layer.depsgraph
    dg.update()
    return dg


def _settings(scene):
    hr = scene.hr
    custom = (float(hr.feps), float(hr.aeps)) if hr.quality == "CUSTOM" else ()
    mode = live_mode(hr.radiance_mode)
    return (hr.method, hr.quality, custom, hr.domain, bool(hr.contacts), bool(hr.final_gather), mode)


def _describe_settings(old, new):
    names = ("method", "quality", "thresholds", "domain", "contacts", "final gather", "values")
    return (
        ", ".join(f"{n} {str(b).lower()}" for n, a, b in zip(names, old, new) if a != b and n != "thresholds")
        or "thresholds"
    )


# -- start, stop -----------------------------------------------------------------------------------
def start(scene, view_layer=None, threaded=None, spread=None):
    """Start Live on scene (no-op if it runs). Raises LiveError with the reason when it cannot.
    spread (the UI's default): the build's preparation (the preview's materials, the scene read)
    runs a time slice per timer tick (live._tick, Session.preparing); else in this call."""
    sess = session(scene)
    if sess is not None:
        return sess
    if STATE.bake_running():
        _refuse(scene, BAKE_RUNNING)
    view_layer = view_layer or (
        bpy.context.view_layer if bpy.context.scene == scene else scene.view_layers[0]
    )
    if not geometry_objects(view_layer):
        _refuse(scene, "No mesh objects to compute radiosity on (all hidden, excluded or light shapes).")
    STATE.live_messages.pop(scene.name_full, None)
    threaded = (not bpy.app.background) if threaded is None else threaded
    spread = (not bpy.app.background) if spread is None else spread
    sess = Session(scene, view_layer, threaded, spread)
    # a stop's restore still running (Live turned off and on again): finished first (_build_steps)
    sess.before = _RESTORING.pop(scene.name_full, (None, None))[1]
    sess.take_off = True
    STATE.live_sessions[scene.name_full] = sess
    scene.hr.live = True
    try:
        _reconcile(sess, scene, view_layer, check_geometry=True)
    except Exception:
        stop(scene, spread=False)
        raise
    if sess.preparing is None:
        print(f"HR Radiosity: Live Relight on ({sess.reason})", flush=True)
    return sess


def _refuse(scene, why):
    scene.hr.live = False
    STATE.live_messages[scene.name_full] = why
    raise LiveError(why)


def stop(scene, restore=True, spread=None):
    """End Live on scene. restore: the baked playback again (or no HR_Radiance without a bake).
    spread (None: the session's Session.spread): the restore runs a time slice per timer tick
    (_RESTORING, live._tick), else in this call. A build being prepared stops where it is: the
    restore undoes what it had wired. Returns what was (or is being) restored ('' when Live was
    not on)."""
    sess = STATE.live_sessions.pop(scene.name_full, None)
    if scene.hr.live:
        scene.hr.live = False
    if sess is None:
        return ""
    sess.worker.close()
    if sess.preparing is not None:
        sess.preparing.close()
        sess.preparing = None
    before, sess.before = sess.before, None  # a previous session's restore not run yet
    if not restore:
        if before is not None:
            _RESTORING[scene.name_full] = (sess, before)
        return ""
    what, steps = _restore_plan(sess, scene)
    if before is not None:
        steps = _chain(before, steps)
    if sess.spread if spread is None else spread:
        _RESTORING[scene.name_full] = (sess, steps)
        return what
    finish(steps)
    return what


def _chain(*steps):
    for s in steps:
        yield from s


def restore_tick(seconds=None):
    """Advance the stops' restores by a time slice each (the timer). True while some are left."""
    seconds = SLICE if seconds is None else seconds
    for name, (sess, steps) in list(_RESTORING.items()):
        scene = bpy.data.scenes.get(name)
        if scene is None:
            _RESTORING.pop(name)
            continue
        try:
            _, done, _ = advance(steps, seconds)
        except ReferenceError:  # an object went meanwhile: plan again from what is there now
            _RESTORING[name] = (sess, _restore_plan(sess, scene)[1])
            continue
        except Exception as exc:  # noqa: BLE001  (a timer must not raise: say so, go on)
            print(f"HR Radiosity: Live Relight: restoring after Live failed: {exc}", flush=True)
            done = True
        if done:
            _RESTORING.pop(name, None)
    return bool(_RESTORING)


def restoring(scene=None):
    """A stop's restore is still running on scene (None: on any scene; over timer ticks)."""
    return bool(_RESTORING) if scene is None else scene.name_full in _RESTORING


def drop_restores():
    _RESTORING.clear()


def finish_restores():
    """Run every pending restore to its end (the add-on is disabled)."""
    while restore_tick(seconds=float("inf")):
        pass


def stop_all(restore=False):
    for name in list(STATE.live_sessions):
        scene = bpy.data.scenes.get(name)
        if scene is not None:
            stop(scene, restore, spread=False)
        else:
            STATE.live_sessions.pop(name).worker.close()


def end_for_bake(scene):
    """A bake starts: it shows its own result when it finishes, so Live ends (without restoring)."""
    if is_live(scene):
        stop(scene, restore=False)
        STATE.live_messages[scene.name_full] = "Live Relight turned off for the bake."
        print("HR Radiosity: Live Relight turned off for the bake", flush=True)
        return True
    return False


STATE.on_bake_start(end_for_bake)  # a bake ends Live: it shows its own result when it has finished


def _take_off_textures(sess, scene, view_layer):
    """A baked-texture preview makes way for HR_Radiance (put back by _restore; _build shows
    HR_Radiance through the preview nodes)."""
    objs = geometry_objects(view_layer)
    if texture.is_texture_bake(scene):
        from .texture import _helper

        sess.texture_objects = [o.name for o in objs if any(_helper(s) for s in o.material_slots)]
        if sess.texture_objects:
            texture.remove_material(objs)


def _restore_plan(sess, scene):
    """(what is restored, its steps): the preview's nodes undone a material at a time, then the
    baked playback loaded, or HR_Radiance removed (and the baked textures put back)."""
    targets = set(sess.targets)
    wired = [n for n in sess.wired if n not in targets]  # (a stop while it prepared, faceless ones)
    objs = [
        o
        for o in playback.objects_by_name(scene, sess.targets + wired).values()
        if o is not None and o.type == "MESH"
    ]
    has_bake = bool(paths.bake_dir_abs(scene))
    load = has_bake and scene.hr.playback and not texture.is_texture_bake(scene)
    if load:
        what = "the baked playback"
    elif sess.texture_objects:
        what = "the baked textures"
    else:
        what = "the baked playback" if has_bake else "no HR_Radiance (there is no bake)"
    return what, _restore_steps(sess, scene, objs, load)


def _restore_steps(sess, scene, objs, load):
    yield from preview.undo_show_radiance_steps(scene, objs, sess.preview_change)
    if load:
        playback.forget_loaded()
        playback.load_frame(scene)
        return
    for i, o in enumerate(objs):
        attr = o.data.color_attributes.get(names.ATTRIBUTE)
        if attr is not None:
            o.data.color_attributes.remove(attr)
        if i % 64 == 63:
            yield
    if sess.texture_objects:
        try:
            texture.add_material(scene, [o for o in objs if o.name in sess.texture_objects])
        except Exception as exc:  # noqa: BLE001  (the cache may be gone: say so, go on)
            print(f"HR Radiosity: the baked-texture preview could not be restored: {exc}", flush=True)


# -- reading the scene -----------------------------------------------------------------------------
def _read_shapes(sess, view_layer, depsgraph, fast=False):
    """The active light shapes (and Blender lights), their digest and warnings. fast: only known
    light shapes, their materials or lights' data were edited since the last read (the depsgraph
    handler says so): read those (no walk over every object of the scene)."""
    warnings = []
    known = [bpy.data.objects.get(n) for n in sess.shape_objects + sess.light_objects] if fast else None
    if known is not None and all(o is not None for o in known):
        known, lamps = known[: len(sess.shape_objects)], known[len(sess.shape_objects) :]
        shapes = collect_light_shapes(view_layer, depsgraph, LightShape, warnings, known, sess.moving)
    else:
        lamps, objs = _shape_names(sess, view_layer)
        shown = [o for o in objs if not o.hide_render]
        shapes = collect_light_shapes(view_layer, depsgraph, LightShape, warnings, shown, sess.moving)
    sig = shapes_signature(shapes)
    # Blender lights (issue 20) ride along in the same dict under "light:" keys (core.lights.Light
    # values); the worker hands them to DynamicRadiosity.apply as its lights
    from ..core.lights import Light

    lights = collect_lights(view_layer, depsgraph, Light, warnings, objects=lamps)
    if lights:
        sig += lights_signature(lights)
        shapes = {**shapes, **lights}
    return shapes, sig, warnings


def _shape_names(sess, view_layer):
    """(Blender lights, light-shape objects), hidden ones too; the session's names of them and of
    their meshes and materials (the depsgraph handler tells their edits from the geometry's)."""
    lamps = light_objects(view_layer, include_hidden=True)  # (as the shapes: shown on a later frame)
    sess.light_objects = [o.name for o in lamps]
    objs = light_shape_objects(view_layer, include_hidden=True)
    sess.shape_objects = [o.name for o in objs]
    # which move, from the scene as a bake reads them (not from the user's drags: Live's exact light
    # is a bake's of the same state; docs/live.md, session 30 hvmove)
    sess.moving = moving_shapes(objs)
    sess.shape_meshes = {o.data.name for o in objs}
    sess.shape_materials = {
        s.material.name_full for o in objs for s in o.material_slots if s.material is not None
    }
    return lamps, objs


def _build(sess, scene, view_layer, depsgraph, reason):
    """Read the geometry and hand the worker a build (_build_steps): in this call, or over timer
    ticks for the UI's sessions (Session.spread: live._tick advances Session.preparing)."""
    steps = _build_steps(sess, scene, view_layer, reason)
    if sess.spread:
        sess.preparing, sess.prepared = steps, (0, 0, "starting")
        sess.preparing_reason = reason
        return
    finish(steps)


def _prepare(sess, scene, view_layer, seconds=None):
    """Advance the build's preparation by a time slice (the timer). A failure of the first build's
    ends Live (as start() did when it prepared in one call), a later one is the session's error."""
    seconds = SLICE if seconds is None else seconds
    try:
        advance(sess.preparing, seconds)
    except ReferenceError:  # an object read was removed meanwhile: prepare again
        sess.preparing = _build_steps(sess, scene, view_layer, sess.preparing_reason)
    except Exception as exc:  # noqa: BLE001  (a timer must not raise)
        sess.preparing = None
        if sess.settings is None:
            print(f"HR Radiosity: Live Relight: {exc}", flush=True)
            stop(scene)
            STATE.live_messages[scene.name_full] = str(exc)
        else:
            sess.error = str(exc)


def _finish_preparing(sess):
    """The build's preparation to its end in this call (update(): synchronous)."""
    while sess.preparing is not None:
        scene, vl = _scene_of(sess)
        _prepare(sess, scene, vl, seconds=float("inf"))
        if sess.error:
            raise LiveError(sess.error)
        if session(scene) is not sess:
            raise LiveError(message(scene) or "Live Relight stopped")


def _changed_meanwhile(sess):
    """An edit since the scene read began that the read may have missed (the depsgraph handler's
    marks: geometry, a material, an object added or removed, the settings); light-shape edits
    are not (they are read at the end). Only over timer ticks: in one call nobody edits between
    the steps (and the read's own depsgraph updates must not start it again)."""
    return sess.spread and bool(sess.geometry_dirty or sess.full_read)


def _build_steps(sess, scene, view_layer, reason):
    """_build's work as steps (steps.py): the preview's nodes wired a material at a time, the scene
    read an object at a time (scene_in.collect_geometry_steps), then the light shapes read and the
    build handed to the worker, which sets the solver up and computes the precompute key
    (BuildSpec.prepare: numpy, off the UI thread). Edits made meanwhile: light shapes are read at
    the last step, so their edits are in it; an edit the read may have missed (_changed_meanwhile)
    starts the read again from the wiring's check."""
    if sess.before is not None:  # the previous session's restore (Live off and on again) first
        sess.prepared = (0, 0, "the last session's preview undone")
        yield from sess.before
        sess.before = None
    if sess.take_off:
        sess.take_off = False
        _take_off_textures(sess, scene, view_layer)
        yield
    while True:
        cfg = BakeConfig.resolve(scene.hr)
        objs = geometry_objects(view_layer)
        _shape_names(sess, view_layer)
        # the preview nodes show HR_Radiance as Live writes it (outgoing radiance or Indirect only)
        change = preview.radiance_change(objs, cfg.live_mode)
        sess.preview_change = sess.preview_change or change  # (set first: a stop undoes a part)
        sess.wired = [o.name for o in objs]
        n_mat = len({s.material.name_full for o in objs for s in o.material_slots if s.material})
        for k, _ in enumerate(preview.show_radiance_steps(objs, cfg.live_mode, change)):
            sess.prepared = (k + 1, n_mat, "materials (the preview's nodes)")
            yield
        # the bake's split (snapshot.read_snapshot): with the final gather, the objects a bake's
        # HR Radiance modifier subdivides (Vertex Spacing) give the hierarchy the mesh the modifier
        # receives and the output their finer corners (core.gather.OutputLayout)
        transport_too = cfg.gather is not None
        if any(texture._helper_slots(o) for o in objs):  # (Live took the baked textures off)
            with texture.source_materials(objs):
                dg = _depsgraph(scene, view_layer)
                scene_in = collect_geometry(view_layer, dg, transport=transport_too)
            break
        dg = _depsgraph(scene, view_layer)  # (evaluates the wiring: the handler's marks come now)
        read = collect_geometry_steps(view_layer, dg, transport=transport_too)
        next(read)  # the depsgraph's update
        if transport_too:  # the objects before their subdivision: the read's own depsgraph updates
            next(read)  # (own_values.before_subdivision sets the spacing to 0 and back, evaluated)
        sess.geometry_dirty, sess.full_read = 0.0, False
        sess.reads += 1
        sess.prepared = (0, len(objs), "objects")
        scene_in = None
        while scene_in is None:
            yield
            if _changed_meanwhile(sess):  # (the handler ran between the ticks)
                break
            try:
                k = next(read)
            except StopIteration as done:
                scene_in = done.value
            else:
                if k:
                    sess.prepared = (k, len(objs), "objects")
        if scene_in is not None:
            _depsgraph(scene, view_layer)  # an edit not evaluated yet: the handler marks it now
            if not _changed_meanwhile(sess):
                break
        read.close()
        print("HR Radiosity: Live: the scene changed while it was read: reading it again", flush=True)
    _request_build(sess, scene, view_layer, cfg, objs, scene_in, reason)
    sess.dirty = False  # (the shapes were read just now, the geometry since the last edit)
    sess.geometry_dirty, sess.full_read, sess.last_poll = 0.0, False, time.monotonic()
    if sess.preparing is not None:
        sess.preparing = None
        print(f"HR Radiosity: Live Relight: prepared, building ({reason})", flush=True)


def collect_geometry(view_layer, depsgraph, transport=False):
    return finish(collect_geometry_steps(view_layer, depsgraph, transport=transport))


def _solver_and_key(transport, params, gather, output):
    """BuildSpec.prepare: the solver's setup and the precompute key, on the worker thread (numpy:
    the mesh's isolated objects, its digest; the code digest)."""

    def prepare(spec):
        spec.params, spec.min_area_rel, far = solver_setup(transport, params)
        spec.precompute = precompute_key(transport, spec.params, gather, output=output)
        return [far] if far else []

    return prepare


def _request_build(sess, scene, view_layer, cfg, objs, scene_in, reason):
    transport = scene_in.mesh if scene_in.transport is None else scene_in.transport
    output = None if scene_in.transport is None else (scene_in.mesh, scene_in.transport_poly)
    targets = list(scene_in.targets)
    extract = FlatExtract(targets, cfg.domain)  # every object's values as slices of one array
    spec = BuildSpec(
        transport,
        None,  # params, min_area_rel, precompute: the worker's prepare()
        cfg.method,
        None,
        cfg.domain,
        extract,
        reason,
        len(transport.loop_start),
        cfg.gather,
        cfg.live_threads,
        paths.default_cache_dir(scene),
        None,
        cfg.live_mode,
        cfg.solve_options if cfg.gather is not None else None,
        output,
        prepare=_solver_and_key(transport, cfg.params, cfg.gather, output),
    )
    sess.settings = _settings(scene)
    sess.geometry = scene_in.signatures
    sess.geo_names = [o.name for o in objs]
    sess.geo_materials = {
        s.material.name_full for o in objs for s in o.material_slots if s.material is not None
    }
    sess.domain = cfg.domain
    sess.targets = [t.name for t in targets]
    sess.objects = {}
    sess.written = None
    sess.notes = list(scene_in.warnings)  # (+ the far objects' note: the worker's build messages)
    sess.reason = reason
    sess.error = sess.fatal = ""
    shapes, sig, warnings = _read_shapes(sess, view_layer, _depsgraph(scene, view_layer))
    sess.light_notes = warnings
    sess.serial += 1
    sess.requested_sig = sig
    sess.worker.request_build(spec, sess.serial, sig, shapes)


def _geometry_change(sess, view_layer, depsgraph, full):
    """'' or what changed in the participating geometry since the last build."""
    names = [o.name for o in geometry_objects(view_layer)]
    if not full and names == sess.geo_names:
        return ""
    new = signatures.geometry_signatures(view_layer, depsgraph)
    if new == sess.geometry:
        sess.geo_names = names
        return ""
    return "; ".join(changed_objects(sess.geometry, new)) or "the geometry changed"


def _reconcile(sess, scene, view_layer, check_geometry, fast=False):
    """Hand the worker what changed: a rebuild (settings or geometry), else the light state.
    check_geometry: compare every participating object with the hierarchy's geometry (else only
    which objects take part). fast: only known light shapes changed (the depsgraph said so):
    read just those. Depsgraph updates that fire while it reads the scene are of what it has
    read: it clears the session's marks at the end."""
    try:
        _reconcile_now(
            sess, scene, view_layer, check_geometry, fast and not check_geometry and not sess.full_read
        )
    finally:
        sess.dirty = False
        if check_geometry:
            sess.geometry_dirty = 0.0
        if not fast:
            sess.full_read = False
            sess.last_poll = time.monotonic()


def _reconcile_now(sess, scene, view_layer, check_geometry, fast):
    dg = _depsgraph(scene, view_layer)
    if fast and _settings(scene) == sess.settings and sess.worker.phase != "failed":
        return _request(sess, view_layer, dg, fast=True)
    if sess.settings is None:
        return _build(sess, scene, view_layer, dg, "first build")
    if _settings(scene) != sess.settings:
        return _build(
            sess,
            scene,
            view_layer,
            dg,
            f"settings changed: {_describe_settings(sess.settings, _settings(scene))}",
        )
    change = _geometry_change(sess, view_layer, dg, check_geometry)
    if change:
        print(f"HR Radiosity: Live: the geometry changed ({change}): rebuilding the hierarchy", flush=True)
        return _build(sess, scene, view_layer, dg, f"geometry changed: {change}")
    if sess.worker.phase == "failed" and not sess.fatal:
        return _build(sess, scene, view_layer, dg, "rebuilding after a failure")
    _request(sess, view_layer, dg)


def _request(sess, view_layer, dg, fast=False):
    """Read the light state; hand it to the worker when it differs from the last one asked for."""
    shapes, sig, warnings = _read_shapes(sess, view_layer, dg, fast=fast)
    sess.light_notes = warnings
    if sig != sess.requested_sig:
        sess.serial += 1
        sess.requested_sig = sig
        sess.worker.request(sess.serial, sig, shapes)


def _budgeted(sess, r):
    """A drag's preview (a shape moved or reshaped; the exact result follows) is written within
    sess.write_budget; exact results, strength and colour edits are written whole."""
    return (
        sess.write_budget is not None
        and r.preview
        and r.kind == "frame"
        and r.report is not None
        and any(e.kind == "reshape" for e in r.report.events)
    )


def _emission_edit(sess, r):
    """A strength or colour edit's result (its events all "emission"), written within
    sess.edit_threshold; HR_Radiance is made exact when no new result follows (_deliver)."""
    return (
        sess.edit_threshold is not None
        and r.kind == "frame"
        and r.report is not None
        and bool(r.report.events)
        and all(e.kind == "emission" for e in r.report.events)
    )


def _within_threshold(values, written, threshold):
    """(skip, what HR_Radiance then holds, behind) for a write of values (Rows) over written (the
    Rows HR_Radiance holds) of only the objects whose change (Rows.change) is above threshold;
    behind: some object left out does not hold values' bits."""
    same = values.unchanged(written)
    if same is None:
        return None, values, False  # (not the same layout: write all)
    keys = values.extract.span_keys
    if not len(keys):
        return same, values, False
    take = values.change(written) > threshold
    skip = {keys[i] for i in np.flatnonzero(~take)}
    behind = bool(skip - same)
    return skip, values.merged(written, take) if behind else values, behind


def _within_budget(values, written, budget):
    """(skip, what HR_Radiance then holds, behind) for a budgeted write of values (Rows) over
    written (the Rows HR_Radiance holds): the `budget` objects whose values changed most
    (Rows.change), none whose change is at most PREVIEW_WRITE_THRESHOLD; the others keep what they
    show and are measured again against it at the next write (behind: some of them changed by more
    than the threshold). Blender re-evaluates every written mesh before the next redraw (~65 us of
    CPU each; the furnished 100k room's 3,882 meshes: 0.27-0.31 s)."""
    fx = values.extract
    if (
        fx is None
        or getattr(written, "extract", None) is not fx
        or written.buffer.shape != values.buffer.shape
    ):
        return values.unchanged(written), values, False  # (not the same layout: None, write all)
    keys = fx.span_keys
    if not len(keys):
        return set(), values, False
    rel = values.change(written)
    take = rel > PREVIEW_WRITE_THRESHOLD
    behind = int(take.sum()) > budget
    if behind:
        take[:] = False
        take[np.argpartition(-rel, budget)[:budget]] = True
    return {keys[i] for i in np.flatnonzero(~take)}, values.merged(written, take), behind


def _deliver(sess, scene, exact=False):
    """Write the worker's newest result into HR_Radiance. True if something was written or changed.
    exact: no emission edit's threshold, and what the last one left out written now
    (hr.live_update(): HR_Radiance current when it returns)."""
    b, r = sess.worker.take()
    changed = False
    if b is not None:
        changed = True
        sess.notes += [m for m in b.messages if m not in sess.notes]
        if b.fatal:
            sess.fatal = f"the hierarchy build failed: {b.error}"
            print(f"HR Radiosity: Live: {sess.fatal}", flush=True)
    if r is None:
        if sess.force_write and sess.last is not None and sess.last.values is not None:
            r = sess.last
        elif sess.behind and (exact or not sess.dirty and time.monotonic() - sess.wrote_at >= CATCH_UP_AFTER):
            # the drag or edit paused: the next budget's worth of the preview shown, or what a
            # strength or colour edit left out (exact: sess.last is not a new result)
            r = sess.last
        else:
            return changed
    forced, sess.force_write = sess.force_write, False
    if r.error:
        if sess.error != r.error:
            print(f"HR Radiosity: Live: {r.error}", flush=True)
        sess.error = r.error
        return True
    # the objects whose values are the same bits as in the last write, when nothing else may
    # have written HR_Radiance since (undo, a render: forced; another mesh edit: live.py's
    # handler drops sess.written): not written again (a drag's preview: ~40% of the 100k room's)
    same, written, behind = None, r.values, False
    if not forced and sess.written is not None and hasattr(r.values, "unchanged"):
        if _budgeted(sess, r):
            same, written, behind = _within_budget(r.values, sess.written, sess.write_budget)
        elif not exact and r is not sess.last and _emission_edit(sess, r):
            same, written, behind = _within_threshold(r.values, sess.written, sess.edit_threshold)
        else:
            same = r.values.unchanged(sess.written)
    problems = playback.apply_arrays(
        scene, r.values, sess.domain, reader=sess.scene_name, objects=sess.objects, skip=same
    )
    sess.written = None if problems else written
    sess.behind, sess.wrote_at = behind and not problems, time.monotonic()
    sess.problems = "; ".join(problems)
    sess.error = ""
    if r is not sess.last and r.kind != "refine":
        sess.latencies.append(time.perf_counter() - r.requested)
        sess.updates += 1
    sess.last = r
    sess.shown_sig = r.sig
    return True


# -- the synchronous entry point ---------------------------------------------------------------------
def update(scene, view_layer=None, check_geometry=True):
    """Make HR_Radiance current for Live on scene (operator hr.live_update): start Live if
    Scene.hr.live is on and it does not run, end it if Scene.hr.live is off, else read every light
    shape and the geometry, compute and write. check_geometry False: compare only which objects
    take part and the objects the depsgraph reported as changed (not every object: on a big
    scene that comparison costs more than a light event). Returns (session or None, what it did).
    Raises LiveError when the current state cannot be shown."""
    sess = session(scene)
    if not scene.hr.live:
        if sess is None:
            return None, "Live Relight is off (Scene.hr.live)"
        what = stop(scene)
        return None, f"Live Relight off: {what}"
    if STATE.bake_running():
        stop(scene, restore=False)
        _refuse(scene, BAKE_RUNNING)
    if sess is None:
        sess = start(scene, view_layer)
    elif sess.preparing is None:  # (else the UI's start, a slice per tick: the rest now)
        s, vl = _scene_of(sess)
        _reconcile(sess, s, vl, check_geometry or bool(sess.geometry_dirty))
    _finish_preparing(sess)
    if not sess.worker.flush(timeout=None):
        raise LiveError("the Live Relight worker stopped")
    _deliver(sess, scene, exact=True)
    if sess.fatal:
        msg = sess.fatal
        stop(scene)
        _refuse(scene, msg)
    if sess.error:
        raise LiveError(sess.error)
    if sess.problems:
        raise LiveError(f"HR_Radiance could not be written: {sess.problems}")
    return sess, "HR_Radiance is current"
