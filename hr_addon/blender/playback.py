"""Radiance out: cached frames -> colour attribute HR_Radiance, and the persistent handlers.

Never silently wrong: a frame whose file is missing or damaged shows magenta (Blender's colour
for a missing texture) on the bake's objects, with a message in the panel; a scene that changed
since the bake (geometry, materials, light shapes: signatures.py against the manifest) is named
in the panel ("the scene changed since the bake (re-bake)"). The check runs when a bake is
loaded (file open, Reload, Preview, after a bake), after frame changes when something was edited
(depsgraph updates mark the scene), and half a second after an edit in the UI.
"""

import os

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..io.cache import CacheError, CacheReader, _names, changed_objects
from .names import ATTRIBUTE, N_VALUES, TAG
from .own_values import sync_materials
from .paths import bake_dir_abs, frame_texture
from .state import STATE
from .steps import advance, finish

MAGENTA = (1.0, 0.0, 1.0, 1.0)

LOCK_MESSAGE = (
    "Frames are not loaded during this render: turn on Render > Lock Interface "
    "(changing mesh data during a render is unsafe)."
)


def _log_once(scene, msg):
    """Print a message once per scene and message; the panel shows the latest one."""
    key = scene.name_full if scene is not None else ""
    if STATE.messages.get(key) != msg:
        STATE.messages[key] = msg
        print(f"HR Radiosity: {msg}", flush=True)


def status(scene):
    """What the panel shows: the load problem, then whether the scene changed since the bake."""
    return "\n".join(
        m for m in (STATE.messages.get(scene.name_full, ""), STATE.stale.get(scene.name_full, "")) if m
    )


def _log_stale(scene, msg):
    key = scene.name_full
    if STATE.stale.get(key, "") != msg:
        if msg:
            print(f"HR Radiosity: {msg}", flush=True)
        STATE.stale[key] = msg


def get_reader(directory):
    """CacheReader for `directory`, re-read when its manifest changes."""
    mpath = os.path.join(directory, "manifest.json")
    try:
        mtime = os.stat(mpath).st_mtime_ns
    except OSError:
        mtime = None
    hit = STATE.readers.get(directory)
    if hit is not None and hit[0] == mtime and mtime is not None:
        return hit[1]
    reader = CacheReader(directory)
    STATE.readers[directory] = (mtime, reader)
    return reader


def forget_readers():
    STATE.readers.clear()
    STATE.changes.clear()
    STATE.checks.clear()
    STATE.image_checks.clear()
    forget_loaded()


# -- the scene against the bake ------------------------------------------------------------------
def stale_message(scene, reader, directory, depsgraph=None, force=False):
    """'' or 'The scene changed since the bake (re-bake): ...' naming the objects (memoized until
    the scene is edited or another bake is loaded)."""
    key = _memo_key(directory)
    memo = STATE.changes.get(scene.name_full)
    if memo is not None and memo[0] == key and not force and scene.name_full not in STATE.dirty:
        return memo[1]
    STATE.dirty.discard(scene.name_full)
    msg = finish(_stale_steps(scene, reader, depsgraph))
    STATE.changes[scene.name_full] = (key, msg)
    return msg


def _memo_key(directory):
    return (directory, STATE.readers.get(directory, (None,))[0])


def _stale_steps(scene, reader, depsgraph=None):
    """The comparison of stale_message, a step (an object) at a time: a generator returning the
    message (signatures.geometry_signature_steps)."""
    m = reader.manifest
    if "geometry" not in m:
        return ""
    from . import signatures

    vl = signatures.view_layer_of(scene, m.get("view_layer"))
    try:
        same = (
            depsgraph is not None
            and depsgraph.view_layer.name == vl.name
            and depsgraph.scene.name == scene.name
        )
    except (AttributeError, ReferenceError):
        same = False
    dg = depsgraph if same else vl.depsgraph
    if sync_materials([o for o in vl.objects if o.type == "MESH"]):
        dg.update()  # (an edit the depsgraph handler did not see: the helpers' materials read)
    try:
        sigs = yield from signatures.geometry_signature_steps(vl, dg)
        parts = changed_objects(m["geometry"], sigs)
        ls = changed_objects(m.get("light_shapes", {}), signatures.light_shape_identity(vl))
    except (RuntimeError, ReferenceError, AttributeError) as exc:  # data going away (undo, file load)
        parts, ls = [f"cannot compare ({exc})"], []
    parts += [f"light shape(s) {p}" for p in ls]
    if parts:
        return "The scene changed since the bake (re-bake): " + "; ".join(parts) + "."
    return ""


def check_scene(scene, depsgraph=None, force=False):
    """Compare the scene with its bake now and update the panel's message. Returns the message."""
    STATE.checks.pop(scene.name_full, None)  # (a check spread over timer ticks: this one replaces it)
    directory = bake_dir_abs(scene)
    if not directory:
        _log_stale(scene, "")
        return ""
    try:
        reader = get_reader(directory)
    except CacheError:
        return ""
    msg = stale_message(scene, reader, directory, depsgraph, force)
    _log_stale(scene, msg)
    return msg


CHECK_SLICE = 0.04  # seconds of a stale check per UI timer tick (check_scene_slice)


class _Check:
    """A stale check in progress on the UI thread (check_scene_slice)."""

    def __init__(self, scene, directory, reader):
        self.directory = directory
        self.key = _memo_key(directory)
        self.steps = _stale_steps(scene, reader)
        self.restarts = 0


def check_scene_slice(scene, budget=None):
    """check_scene spread over UI timer ticks: compare for about `budget` seconds, then return
    (None: call again) or the message when the comparison has ended (the panel's message updated,
    as check_scene). A big scene's comparison (3,882 objects: a second) froze the UI when done in
    one call. An edit that comes while it runs (the scene marked dirty again, or an object
    removed) starts it again: the message is never of a mix of two states."""
    name = scene.name_full
    chk = STATE.checks.get(name)
    directory = bake_dir_abs(scene)
    if chk is not None and (chk.directory != directory or chk.key != _memo_key(directory)):
        chk = None
    if chk is None or name in STATE.dirty:
        if not directory:
            STATE.checks.pop(name, None)
            STATE.dirty.discard(name)
            _log_stale(scene, "")
            return ""
        try:
            reader = get_reader(directory)
        except CacheError:
            STATE.checks.pop(name, None)
            STATE.dirty.discard(name)
            return ""
        chk = STATE.checks[name] = _Check(scene, directory, reader)
        STATE.dirty.discard(name)
    try:
        _, finished, msg = advance(chk.steps, CHECK_SLICE if budget is None else budget)
        if not finished:
            return None
    except ReferenceError:  # an object went away between two slices: start again
        STATE.checks.pop(name, None)
        STATE.dirty.add(name)
        return None
    STATE.checks.pop(name, None)
    STATE.changes[name] = (chk.key, msg)
    _log_stale(scene, msg)
    return msg


def show_missing(scene, reader=None):
    """Magenta in HR_Radiance of the bake's objects (all meshes carrying it without a manifest):
    the frame shown has no valid data, and renders must not use another frame's light."""
    names = (
        list(reader.objects)
        if reader is not None
        else [o.name for o in scene.objects if o.type == "MESH" and ATTRIBUTE in o.data.color_attributes]
    )
    done = set()
    objs = objects_by_name(scene, names)
    for name in names:
        obj = objs[name]
        if obj is None or obj.type != "MESH" or obj.mode == "EDIT" or obj.data.name in done:
            continue
        me = obj.data
        attr = me.color_attributes.get(ATTRIBUTE)
        if attr is None and reader is not None and reader.domain in ("CORNER", "POINT"):
            attr = me.color_attributes.new(ATTRIBUTE, "FLOAT_COLOR", reader.domain)
        if attr is None:
            continue
        attr.data.foreach_set("color", np.tile(np.array(MAGENTA, np.float32), len(attr.data)))
        me.update_tag()
        STATE.writes.mark(me.name)
        done.add(me.name)
    return len(done)


def _texture_problem(reader, directory, frame):
    from ..io.images import image_file_problem

    f = reader.nearest(frame)
    for name, info in reader.objects.items():
        path = frame_texture(directory, info, f)
        if path is None:
            continue
        try:
            st = os.stat(path)
            key = (path, st.st_mtime_ns, st.st_size)
        except OSError:
            key = (path, None, None)
        why = STATE.image_checks.get(key)
        if why is None:
            why = image_file_problem(path, info.get("resolution"))
            if len(STATE.image_checks) > 4096:
                STATE.image_checks.clear()
            STATE.image_checks[key] = why
        if why:
            return (
                f"Radiosity cache texture '{path}' of object '{name}' is {why}: Blender shows it "
                "magenta (re-bake; a bake of any frame range re-bakes damaged frames)."
            )
    return ""


def forget_loaded():
    """Forget which cached file each scene shows (the next load_frame writes HR_Radiance again)."""
    STATE.loaded.clear()


HELPER = N_VALUES + " "  # the name prefix of own_values' helper objects

# Blender 5.0's foreach_set on attribute data tags the mesh for the depsgraph itself (tested:
# test_blender_ux's foreach_set test); an update_tag() more cost 9 ms per write of 3,882 objects.
# Older versions were not checked: they keep it.
TAG_AFTER_SET = bpy.app.version < (5, 0, 0)


def write_attribute(mesh, values, domain):
    """Write (N, 4) float32 RGBA into mesh's HR_Radiance (created / re-created as needed). Called
    once per object on every Live update and frame change (3,882 objects in the furnished room):
    as few RNA accesses as it takes (attributes[] is cheaper than color_attributes.get, a
    data_type than a domain). The caller marks the mesh as written (STATE.writes)."""
    try:
        attr = mesh.attributes[ATTRIBUTE]  # (cheaper than get() where it exists: every write but the first)
    except KeyError:
        attr = None
    if attr is None or attr.data_type != "FLOAT_COLOR" or attr.domain != domain:
        if attr is not None:
            mesh.attributes.remove(attr)
        attr = mesh.color_attributes.new(ATTRIBUTE, "FLOAT_COLOR", domain)
        if mesh.color_attributes.active_color is None:
            mesh.color_attributes.active_color = attr
    data = attr.data
    if len(data) != len(values):
        raise CacheError(
            f"Mesh '{mesh.name}' has {len(data)} {domain.lower()} elements but the "
            f"cache holds {len(values)}: the mesh changed since the bake (re-bake)."
        )
    # an aligned C-contiguous float32 array goes to foreach_set as its buffer (format 'f'), no copy;
    # an unaligned one (format '=f') Blender would read element by element, ~3x the CPU
    values = np.ascontiguousarray(values, np.float32)
    data.foreach_set("color", (values if values.flags.aligned else values.copy()).reshape(-1))
    if TAG_AFTER_SET:
        mesh.update_tag()


def linked_meshes(objects):
    """A warning (or none) naming the objects whose mesh is linked from a library: Blender does not
    let HR_Radiance be written into linked data (foreach_set fails without a word), so they would
    play back white."""
    linked = [o.name for o in objects if o.data.library is not None]
    if not linked:
        return []
    return [
        f"{len(linked)} object(s) use a mesh linked from a library ({_names(linked)}): HR_Radiance cannot be "
        "written into linked data, so they show no baked light. Make their meshes local (Object > "
        "Relations > Make Local > Selected Objects and Data), or bake textures with a HR_Lightmap UV "
        "map made in the library file."
    ]


def objects_by_name(scene, names):
    """{name: object or None} for names, from the scene's objects, else bpy.data's. One pass over
    the scene: a collection's get() searches linearly (3 s per Live update of 3,882 objects)."""
    found = {}
    for o in scene.objects:
        found.setdefault(o.name, o)
    if any(n not in found for n in names):  # (own_values' helpers are in no scene: one pass too)
        for o in bpy.data.objects:
            found.setdefault(o.name, o)
    return {n: found.get(n) for n in names}


def apply_arrays(scene, arrays, domain, reader=None, objects=None, skip=None):
    """Write {object name: values} to the objects' meshes; returns the list of problems. The
    meshes written are marked as playback's writes (STATE.writes) and, with reader, as its own
    too (a Live session's scene name), so the caller need not look the objects up again.
    objects: {name: object} the caller keeps between writes (a Live session: 3,882 objects are
    not looked up at every edit), filled here; emptied and filled again when one of them was
    removed since (ReferenceError; the caller empties it after an undo, which replaces them).
    skip: names whose HR_Radiance already holds these very values (Live: rows that did not change
    since its last write, scene_in.Rows.unchanged): checked as the others, not written again (nor
    tagged: Blender re-evaluates each written mesh, ~70 us of CPU each at the next redraw)."""
    if objects is not None:
        try:
            return _apply_arrays(scene, arrays, domain, reader, objects, skip)
        except ReferenceError:
            objects.clear()
    return _apply_arrays(scene, arrays, domain, reader, objects, skip)


def _looked_up(scene, names, objects):
    """{name: object} holding `names`' objects: `objects` (a cache the caller keeps; None: a new dict)
    with those it lacks looked up in one pass (objects_by_name) and added; one not found is looked
    up again next time."""
    objects = {} if objects is None else objects
    new = [n for n in names if n not in objects]
    if new:
        objects.update((n, o) for n, o in objects_by_name(scene, new).items() if o is not None)
    return objects


def _apply_arrays(scene, arrays, domain, reader, objects, skip=None):
    problems = []
    STATE.loaded.pop(scene.name_full, None)
    objs = _looked_up(scene, arrays, objects)
    written, feeds = [], []
    for name, values in arrays.items():
        obj = objs.get(name)
        if obj is None or obj.type != "MESH":
            problems.append(f"object '{name}' of the bake is missing")
            continue
        if obj.mode == "EDIT":
            problems.append(f"object '{name}' is in Edit Mode; not updated")
            continue
        if skip and name in skip:
            continue
        me = obj.data
        try:
            write_attribute(me, values, domain)
        except CacheError as exc:
            problems.append(str(exc))
            continue
        written.append(me.name)
        if name.startswith(HELPER):  # own_values' helper: the object it feeds is updated too, not edited
            feeds.append(obj.get(TAG, ""))
    if feeds:  # (by name, one pass: bpy.data.objects.get searches linearly, 0.3 ms each at 100k)
        fed = _looked_up(scene, feeds, objects if objects is not None else objs)
        written += [o.data.name for n in feeds if (o := fed.get(n)) is not None and o.type == "MESH"]
    STATE.writes.mark_all(written)
    if reader is not None:
        STATE.writes.mark_all(written, reader)
    return problems


def load_frame(scene, frame=None):
    """Load `frame` (default: current) of scene's bake into HR_Radiance. True on success.

    A missing or damaged frame (or cache) shows magenta and says so in the panel: the frame shown
    before is not left in place for renders to use."""
    directory = bake_dir_abs(scene)
    if not directory:
        return False
    frame = scene.frame_current if frame is None else frame
    try:
        reader = get_reader(directory)
    except CacheError as exc:
        if STATE.loaded.get(scene.name_full) != ("missing", directory):
            show_missing(scene)
            STATE.loaded[scene.name_full] = ("missing", directory)
        _log_once(scene, f"{exc} Showing magenta.")
        return False
    if reader.manifest.get("output") == "TEXTURE":  # image sequences play back by themselves
        problem = _texture_problem(reader, directory, frame)
        if problem:
            _log_once(scene, problem)
            return False
        STATE.messages.pop(scene.name_full, None)
        return True
    name = reader.frames[reader.nearest(frame)]
    key = (directory, STATE.readers.get(directory, (None,))[0], name)  # manifest mtime
    if STATE.loaded.get(scene.name_full) == key and _attributes_present(scene, reader):
        return True  # same cached file as the frame shown: HR_Radiance is already right
    if STATE.loaded.get(scene.name_full) == ("magenta", key):
        return False  # the same damaged file: already magenta, message shown
    try:
        arrays = reader.load(frame)
    except CacheError as exc:
        show_missing(scene, reader)
        STATE.loaded[scene.name_full] = ("magenta", key)
        _log_once(
            scene,
            f"{exc} Frame {frame} shows magenta (re-bake; a bake of any frame range "
            "re-bakes damaged frames).",
        )
        return False
    problems = apply_arrays(scene, arrays, reader.domain)
    if problems:
        _log_once(scene, "; ".join(problems))
        return False
    STATE.loaded[scene.name_full] = key
    STATE.messages.pop(scene.name_full, None)
    return True


def _attributes_present(scene, reader):
    objs = objects_by_name(scene, reader.objects)
    for name in reader.objects:
        obj = objs[name]
        if obj is None or obj.type != "MESH" or ATTRIBUTE not in obj.data.color_attributes:
            return False
    return True


def render_unlocked(scene):
    """True when an interactive render runs without Lock Interface (frames must not be loaded)."""
    return not bpy.app.background and not scene.render.use_lock_interface and bpy.app.is_job_running("RENDER")


def live_shown(scene):
    """True while Live Relight shows its own light on scene (live.py); renders play the bake back."""
    return scene.name_full in STATE.live_sessions and not bpy.app.is_job_running("RENDER")


@persistent
def on_frame_change_pre(scene, *args):
    if STATE.baking or not scene.hr.playback or live_shown(scene):
        return
    if render_unlocked(scene):
        _log_once(scene, LOCK_MESSAGE)  # printed once, and shown in the panel
        return
    load_frame(scene)


@persistent
def on_frame_change_post(scene, depsgraph=None):
    """After a frame change (depsgraph evaluated): compare the scene with the bake if it was
    edited since the last comparison (or never compared)."""
    if STATE.baking or not scene.hr.playback or render_unlocked(scene):
        return
    memo = STATE.changes.get(scene.name_full)
    if memo is None or scene.name_full in STATE.dirty:
        if not SPREAD:
            check_scene(scene, depsgraph)
        else:  # spread over timer ticks: a big scene's comparison takes a second (check_scene_slice)
            STATE.dirty.add(scene.name_full)
            _schedule_check(0.0)


_RELEVANT = ("Object", "Mesh", "Material", "ShaderNodeTree", "Collection", "Scene", "NodeTree", "Image")


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    """An edit may have changed what the bake depends on: mark the scene; the UI compares half a
    second later (a drag does not compare at every step). Our own HR_Radiance writes are skipped."""
    if STATE.baking or depsgraph is None:
        return
    written = STATE.writes.take()
    relevant = False
    for u in depsgraph.updates:
        idd = u.id
        kind = type(idd).__name__
        if not any(kind.endswith(k) for k in _RELEVANT):
            continue
        if kind == "Mesh" and idd.name in written and not u.is_updated_transform:
            continue
        if kind == "Object" and not u.is_updated_transform:
            data = getattr(idd, "data", None)
            if data is not None and getattr(data, "name", None) in written:
                continue
        relevant = True
        break
    if not relevant:
        return
    _sync_helpers(scene, depsgraph, written)
    for sc in bpy.data.scenes:
        if sc.hr.playback and sc.hr.bake_dir:
            STATE.dirty.add(sc.name_full)
    _schedule_check(0.5)


def _sync_helpers(scene, depsgraph, written=()):
    """The helpers of the objects an edit updated (their meshes not our writes) get their
    materials again (own_values.sync_materials: while its guard holds, an object shows its
    helper's mesh and so its materials). Returns the objects whose helper changed."""
    meshes, objects = set(), set()
    for u in depsgraph.updates:
        idd = getattr(u.id, "original", u.id)
        kind = type(idd).__name__
        if kind == "Mesh" and idd.name not in written:
            meshes.add(idd.name)
        elif kind == "Object" and idd.type == "MESH":
            objects.add(idd.name)
    if not meshes and not objects:
        return []
    edited = [o for o in scene.objects if o.type == "MESH" and (o.name in objects or o.data.name in meshes)]
    return sync_materials(edited)


SLICE_GAP, EDIT_PAUSE = 0.01, 0.5  # seconds between two slices of a check; after an edit
# The UI spreads stale checks over timer ticks; background mode has no event loop (no timers):
# there a frame change compares at once (tests and benchmarks set it to drive _deferred_check)
SPREAD = not bpy.app.background


def _schedule_check(first):
    if not bpy.app.background and not bpy.app.timers.is_registered(_deferred_check):
        bpy.app.timers.register(_deferred_check, first_interval=first)


def _deferred_check():
    """The UI's stale check, half a second after an edit, a slice per tick (check_scene_slice).
    A check that an edit interrupts waits for the edits to pause again."""
    if STATE.baking:
        return EDIT_PAUSE
    again, ended = None, False
    for sc in bpy.data.scenes:
        name = sc.name_full
        if not sc.hr.playback:
            STATE.checks.pop(name, None)
            continue
        if name in STATE.checks and name in STATE.dirty:  # edited meanwhile: wait for a pause
            STATE.checks.pop(name)
            again = min(again or EDIT_PAUSE, EDIT_PAUSE)
            continue
        if name not in STATE.dirty and name not in STATE.checks:
            continue
        try:
            if check_scene_slice(sc) is None:
                again = SLICE_GAP
            else:
                ended = True
        except ReferenceError:
            STATE.checks.pop(name, None)
    if ended:
        for win in getattr(bpy.context.window_manager, "windows", []):
            for area in win.screen.areas:
                if area.type in {"PROPERTIES", "VIEW_3D"}:
                    area.tag_redraw()
    return again


@persistent
def on_undo_redo(*args):
    forget_loaded()  # undo may bring back HR_Radiance values of another frame
    for sc in bpy.data.scenes:
        STATE.dirty.add(sc.name_full)


@persistent
def on_load_post(*args):
    forget_readers()
    STATE.messages.clear()
    STATE.stale.clear()
    STATE.dirty.clear()
    STATE.notes.clear()
    STATE.errors.clear()
    for scene in bpy.data.scenes:
        if scene.hr.playback and bake_dir_abs(scene):
            load_frame(scene)
            try:
                dg = bpy.context.evaluated_depsgraph_get() if bpy.context.scene == scene else None
            except (RuntimeError, AttributeError):
                dg = None
            check_scene(scene, dg)


def _remove(lst, fn):
    """Remove fn and stale copies of it (same module and name, e.g. after an add-on reload)."""
    for h in list(lst):
        if h is fn or (
            getattr(h, "__name__", None) == fn.__name__ and getattr(h, "__module__", None) == fn.__module__
        ):
            lst.remove(h)


def _handlers():
    h = bpy.app.handlers
    return (
        (h.frame_change_pre, on_frame_change_pre),
        (h.frame_change_post, on_frame_change_post),
        (h.depsgraph_update_post, on_depsgraph_update),
        (h.load_post, on_load_post),
        (h.undo_post, on_undo_redo),
        (h.redo_post, on_undo_redo),
    )


def register():
    for lst, fn in _handlers():
        _remove(lst, fn)
        lst.append(fn)


def unregister():
    for lst, fn in _handlers():
        _remove(lst, fn)
    if bpy.app.timers.is_registered(_deferred_check):
        bpy.app.timers.unregister(_deferred_check)
