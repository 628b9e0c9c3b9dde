"""Blender (bpy) set-up shared by the bpy tests and the Cycles comparisons: the add-on registered
once per process, and the sample scenes opened from a copy (a test never writes sample_blends/)."""

import shutil
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
SAMPLES = REPO_ROOT / "sample_blends"


def load_bpy():
    import bpy

    import hr_addon

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    return bpy


def open_sample(name, directory, sub="") -> Path:
    """Copy sample_blends/<name>.blend into directory[/sub] and open it; returns the copy's path."""
    bpy = load_bpy()
    d = Path(directory) / sub if sub else Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    dst = d / f"{name}.blend"
    shutil.copy(SAMPLES / f"{name}.blend", dst)
    bpy.ops.wm.open_mainfile(filepath=str(dst), load_ui=False)
    return dst


def isolated_env(directory):
    """The environment of a Blender subprocess that touches neither ~/.config/blender nor this
    process's add-ons: a throw-away HOME and user-resource folder in `directory`, no inherited
    PYTHONPATH. Returns (env, the user-resource folder)."""
    import os

    home, resources = Path(directory) / "home", Path(directory) / "blender_user"
    home.mkdir()
    resources.mkdir()
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("BLENDER_USER_") and k not in ("PYTHONPATH", "PYTHONHOME")
    }
    env.update(
        HOME=str(home),
        BLENDER_USER_RESOURCES=str(resources),
        XDG_CONFIG_HOME=str(home / ".config"),
        PYTHONDONTWRITEBYTECODE="1",
    )
    return env, resources
