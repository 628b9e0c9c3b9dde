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
