"""Where a scene's bake lives: the default cache folder and the folder of the current bake."""

import os

import bpy


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


def blend_relative(path):
    """`path` relative to the saved .blend ("//..."), else as it is (unsaved, other drive)."""
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(path)
        except ValueError:  # other drive (Windows)
            pass
    return path


def frame_texture(directory, info, frame):
    """Path of an object's lightmap image at `frame` in a texture bake (its manifest entry
    `info`), or None when the object has none."""
    tex = info.get("texture")
    return os.path.join(directory, *(tex % frame).split("/")) if tex else None
