"""Shared helpers for the tests/test_blender_*.py files (no tests here).

bpy (Blender as a Python module) is one global state per process: the add-on is registered
once, each test starts from factory settings or opens a copy of a sample .blend in tmp_path.
"""

import importlib.util
import sys

import numpy as np
import pytest

from hr_testing import blend
from hr_testing.blend import REPO_ROOT, SAMPLES, open_sample  # noqa: F401  (the tests import them from here)

PYTHON = sys.executable


def load_bpy():
    pytest.importorskip("bpy")
    return blend.load_bpy()


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


def saved_room(tmp_path_factory, name, build):
    """build() -> (scene, info) made in a fresh file, saved as <tmp>/<name>.blend: (path, info)."""
    bpy = load_bpy()
    _, info = build()
    path = tmp_path_factory.mktemp(name) / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path, info


def texture_means(cache, reader, names, frame):
    """Each object's mean RGB over its baked texture of `frame` (every pixel finite)."""
    bpy = load_bpy()
    from hr_addon.blender.paths import frame_texture

    means = {}
    for name in names:
        img = bpy.data.images.load(frame_texture(str(cache), reader.objects[name], frame))
        px = np.empty(img.size[0] * img.size[1] * 4, np.float32)
        img.pixels.foreach_get(px)
        bpy.data.images.remove(img)
        assert np.isfinite(px).all(), name
        means[name] = float(px.reshape(-1, 4)[:, :3].mean())
    return means


def scale_scene(scene, factor):
    """Parent every mesh of `scene` to a new empty "Scale" scaled by `factor` (a unit-dependence test)."""
    bpy = load_bpy()
    root = bpy.data.objects.new("Scale", None)
    scene.collection.objects.link(root)
    for o in list(scene.objects):
        if o is not root and o.type == "MESH":
            o.parent = root
    root.scale = (factor,) * 3


def attribute(obj, name="HR_Radiance"):
    """(N, 4) float32 values of a colour attribute."""
    attr = obj.data.color_attributes[name]
    v = np.empty(len(attr.data) * 4, np.float32)
    attr.data.foreach_get("color", v)
    return v.reshape(-1, 4)


def shown(obj, name="HR_Radiance"):
    """(N, 4) float32 values of a colour attribute on obj's evaluated mesh: what a render shows,
    through the modifiers (Vertex Spacing's HR Radiance modifier reads its helper's values)."""
    bpy = load_bpy()
    me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    attr = me.attributes[name]
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
