"""Shared helpers for the tests/test_blender_*.py files (no tests here).

bpy (Blender as a Python module) is one global state per process: the add-on is registered
once, each test starts from factory settings or opens a copy of a sample .blend in tmp_path.
"""

import importlib.util
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
SAMPLES = REPO_ROOT / "sample_blends"
PYTHON = sys.executable


def load_bpy():
    bpy = pytest.importorskip("bpy")
    import hr_addon

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    return bpy


def make_samples_module():
    """scripts/make_samples.py as a module (scene-building helpers)."""
    if "make_samples" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "make_samples", REPO_ROOT / "scripts" / "make_samples.py"
        )
        mod = importlib.util.module_from_spec(spec)
        sys.modules["make_samples"] = mod
        spec.loader.exec_module(mod)
    return sys.modules["make_samples"]


def empty_scene():
    bpy = load_bpy()
    ms = make_samples_module()
    scene = ms.reset()
    return bpy, ms, scene


def open_sample(name, tmp_path, sub="") -> Path:
    """Copy sample_blends/<name>.blend into tmp_path[/sub] and open it; returns the copy's path."""
    bpy = load_bpy()
    d = Path(tmp_path) / sub if sub else Path(tmp_path)
    d.mkdir(parents=True, exist_ok=True)
    dst = d / f"{name}.blend"
    shutil.copy(SAMPLES / f"{name}.blend", dst)
    bpy.ops.wm.open_mainfile(filepath=str(dst), load_ui=False)
    return dst


def attribute(obj, name="HR_Radiance"):
    """(N, 4) float32 values of a colour attribute."""
    attr = obj.data.color_attributes[name]
    v = np.empty(len(attr.data) * 4, np.float32)
    attr.data.foreach_get("color", v)
    return v.reshape(-1, 4)


def read_image(path):
    """(H, W, 3) float32 pixels of an image file as Blender decodes it (row 0 at the bottom; PNGs
    linearised from sRGB): the independent reader of our EXR and PNG writers."""
    bpy = load_bpy()
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        W, H = img.size
        px = np.empty(W * H * img.channels, np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(H, W, img.channels)[..., :3].copy()
    finally:
        bpy.data.images.remove(img)
