"""Radiance out: cached frames -> colour attribute HR_Radiance, and the persistent handlers."""
import os

import bpy
import numpy as np
from bpy.app.handlers import persistent

from .cache import CacheError, CacheReader

ATTRIBUTE = "HR_Radiance"

# Set while a bake runs: the bake moves through frames itself, playback must not interfere.
state = {"baking": False, "messages": {}, "readers": {}, "loaded": {}}

LOCK_MESSAGE = ("Frames are not loaded during this render: turn on Render > Lock Interface "
                "(changing mesh data during a render is unsafe).")


def _log_once(scene, msg):
    """Print a message once per scene and message; the panel shows the latest one."""
    key = scene.name_full if scene is not None else ""
    if state["messages"].get(key) != msg:
        state["messages"][key] = msg
        print(f"HR Radiosity: {msg}", flush=True)


def status(scene):
    return state["messages"].get(scene.name_full, "")


def default_cache_dir(scene):
    """Cache directory for scene's settings and the current .blend (None: relative, unsaved)."""
    folder = scene.hr.cache_folder or "//hr_cache/"
    if folder.startswith("//") and not bpy.data.filepath:
        return None
    stem = os.path.splitext(os.path.basename(bpy.data.filepath))[0] if bpy.data.filepath else "untitled"
    if len(bpy.data.scenes) > 1:
        stem += "_" + bpy.path.clean_name(scene.name)
    return os.path.join(os.path.abspath(bpy.path.abspath(folder)), stem)


def bake_dir_abs(scene):
    """The scene's bake: Scene.hr.bake_dir, else a bake found at the default location (a
    command-line bake that did not save the .blend)."""
    d = scene.hr.bake_dir
    if d:
        return os.path.abspath(bpy.path.abspath(d))
    if not scene.hr.playback:
        return ""
    d = default_cache_dir(scene)
    return d if d and os.path.isfile(os.path.join(d, "manifest.json")) else ""


def get_reader(directory):
    """CacheReader for `directory`, re-read when its manifest changes."""
    mpath = os.path.join(directory, "manifest.json")
    try:
        mtime = os.stat(mpath).st_mtime_ns
    except OSError:
        mtime = None
    hit = state["readers"].get(directory)
    if hit is not None and hit[0] == mtime and mtime is not None:
        return hit[1]
    reader = CacheReader(directory)
    state["readers"][directory] = (mtime, reader)
    return reader


def forget_readers():
    state["readers"].clear()
    forget_loaded()


def forget_loaded():
    """Forget which cached file each scene shows (the next load_frame writes HR_Radiance again)."""
    state["loaded"].clear()


def write_attribute(mesh, values, domain):
    """Write (N, 4) float32 RGBA into mesh's HR_Radiance (created / re-created as needed)."""
    attr = mesh.color_attributes.get(ATTRIBUTE)
    if attr is not None and (attr.domain != domain or attr.data_type != "FLOAT_COLOR"):
        mesh.color_attributes.remove(attr)
        attr = None
    if attr is None:
        attr = mesh.color_attributes.new(ATTRIBUTE, "FLOAT_COLOR", domain)
        if mesh.color_attributes.active_color is None:
            mesh.color_attributes.active_color = attr
    if len(attr.data) != len(values):
        raise CacheError(f"Mesh '{mesh.name}' has {len(attr.data)} {domain.lower()} elements but the "
                         f"cache holds {len(values)}: the mesh changed since the bake (re-bake).")
    attr.data.foreach_set("color", np.ascontiguousarray(values, np.float32).ravel())
    mesh.update_tag()


def apply_arrays(scene, arrays, domain):
    """Write {object name: values} to the objects' meshes; returns the list of problems."""
    problems = []
    state["loaded"].pop(scene.name_full, None)
    for name, values in arrays.items():
        obj = scene.objects.get(name) or bpy.data.objects.get(name)
        if obj is None or obj.type != "MESH":
            problems.append(f"object '{name}' of the bake is missing")
            continue
        if obj.mode == "EDIT":
            problems.append(f"object '{name}' is in Edit Mode; not updated")
            continue
        try:
            write_attribute(obj.data, values, domain)
        except CacheError as exc:
            problems.append(str(exc))
    return problems


def load_frame(scene, frame=None):
    """Load `frame` (default: current) of scene's bake into HR_Radiance. True on success."""
    directory = bake_dir_abs(scene)
    if not directory:
        return False
    frame = scene.frame_current if frame is None else frame
    try:
        reader = get_reader(directory)
        if reader.manifest.get("output") == "TEXTURE":   # image sequences play back by themselves
            state["messages"].pop(scene.name_full, None)
            return True
        name = reader.frames[reader.nearest(frame)]
        key = (directory, state["readers"].get(directory, (None,))[0], name)   # manifest mtime
        if state["loaded"].get(scene.name_full) == key and _attributes_present(scene, reader):
            return True          # same cached file as the frame shown: HR_Radiance is already right
        arrays = reader.load(frame)
    except CacheError as exc:
        _log_once(scene, f"{exc}")
        return False
    problems = apply_arrays(scene, arrays, reader.domain)
    if problems:
        _log_once(scene, "; ".join(problems))
        return False
    state["loaded"][scene.name_full] = key
    state["messages"].pop(scene.name_full, None)
    return True


def _attributes_present(scene, reader):
    for name in reader.objects:
        obj = scene.objects.get(name) or bpy.data.objects.get(name)
        if obj is None or obj.type != "MESH" or ATTRIBUTE not in obj.data.color_attributes:
            return False
    return True


def render_unlocked(scene):
    """True when an interactive render runs without Lock Interface (frames must not be loaded)."""
    return (not bpy.app.background and not scene.render.use_lock_interface
            and bpy.app.is_job_running("RENDER"))


@persistent
def on_frame_change_pre(scene, *args):
    if state["baking"] or not scene.hr.playback:
        return
    if render_unlocked(scene):
        _log_once(scene, LOCK_MESSAGE)     # printed once, and shown in the panel
        return
    load_frame(scene)


@persistent
def on_undo_redo(*args):
    forget_loaded()    # undo may bring back HR_Radiance values of another frame


@persistent
def on_load_post(*args):
    forget_readers()
    state["messages"].clear()
    for scene in bpy.data.scenes:
        if scene.hr.playback and bake_dir_abs(scene):
            load_frame(scene)


def _remove(lst, fn):
    """Remove fn and stale copies of it (same module and name, e.g. after an add-on reload)."""
    for h in list(lst):
        if h is fn or (getattr(h, "__name__", None) == fn.__name__
                       and getattr(h, "__module__", None) == fn.__module__):
            lst.remove(h)


def _handlers():
    h = bpy.app.handlers
    return ((h.frame_change_pre, on_frame_change_pre), (h.load_post, on_load_post),
            (h.undo_post, on_undo_redo), (h.redo_post, on_undo_redo))


def register():
    for lst, fn in _handlers():
        _remove(lst, fn)
        lst.append(fn)


def unregister():
    for lst, fn in _handlers():
        _remove(lst, fn)
