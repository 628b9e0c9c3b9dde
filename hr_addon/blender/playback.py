"""Radiance out: cached frames -> colour attribute HR_Radiance, and the persistent handlers."""
import os

import bpy
import numpy as np
from bpy.app.handlers import persistent

from .cache import CacheError, CacheReader

ATTRIBUTE = "HR_Radiance"

# Set while a bake runs: the bake moves through frames itself, playback must not interfere.
state = {"baking": False, "messages": {}, "readers": {}}


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
        arrays = reader.load(frame)
    except CacheError as exc:
        _log_once(scene, f"{exc}")
        return False
    problems = apply_arrays(scene, arrays, reader.domain)
    if problems:
        _log_once(scene, "; ".join(problems))
        return False
    state["messages"].pop(scene.name_full, None)
    return True


_warned_lock = set()


@persistent
def on_frame_change_pre(scene, *args):
    if state["baking"] or not scene.hr.playback:
        return
    if not bpy.app.background and not scene.render.use_lock_interface \
            and bpy.app.is_job_running("RENDER"):
        if scene.name_full not in _warned_lock:
            _warned_lock.add(scene.name_full)
            print("HR Radiosity: enable Render > Lock Interface to render the baked radiance "
                  "(changing mesh data during a render is unsafe); frame not loaded.", flush=True)
        return
    load_frame(scene)


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


def register():
    for lst, fn in ((bpy.app.handlers.frame_change_pre, on_frame_change_pre),
                    (bpy.app.handlers.load_post, on_load_post)):
        _remove(lst, fn)
        lst.append(fn)


def unregister():
    _remove(bpy.app.handlers.frame_change_pre, on_frame_change_pre)
    _remove(bpy.app.handlers.load_post, on_load_post)
