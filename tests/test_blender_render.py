"""A tiny Cycles render of two baked frames through the preview material (32x32 px, 4 samples)."""

import numpy as np
import pytest

from test_blender_helpers import load_bpy, open_sample

pytestmark = [pytest.mark.bpy, pytest.mark.cycles]


def test_render_two_frames_show_the_bake(tmp_path):
    bpy = load_bpy()
    from hr_addon.blender.bake import run_bake

    open_sample("cornell", tmp_path)
    scene = bpy.context.scene
    run_bake(scene, frames=(5, 6), quality="draft", method="FE", log=lambda *a, **k: None)
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    r = scene.render
    r.engine = "CYCLES"
    scene.cycles.samples = 4
    scene.cycles.device = "CPU"
    r.resolution_x = r.resolution_y = 32
    r.resolution_percentage = 100
    r.image_settings.file_format = "OPEN_EXR"
    r.filepath = str(tmp_path / "render_####")
    scene.frame_start, scene.frame_end = 5, 6
    bpy.ops.render.render(animation=True)  # frame_change_pre loads each frame
    px = {}
    for f in (5, 6):
        img = bpy.data.images.load(str(tmp_path / f"render_{f:04d}.exr"))
        a = np.empty(32 * 32 * 4, np.float32)
        img.pixels.foreach_get(a)
        px[f] = a.reshape(32, 32, 4)[..., :3]
    # Frame 6: the window on the green (right, +x) wall is lit; frame 5: it is not.
    assert np.all(np.isfinite(px[5])) and px[5].mean() > 0.01
    left_half = (slice(None), slice(0, 16))  # the camera looks along +y: x = 0 is on the image's left
    assert px[6][left_half].mean() > 1.2 * px[5][left_half].mean()
