"""Render baked frames of the sample scenes for the README (Cycles, CPU, headless).

Each sample is baked with the extension's own pipeline into a temporary copy, shown through the
preview material (the baked radiance into an Emission shader), and rendered with zero bounces: what
you see is exactly the HR_Radiance the bake wrote. Writes docs/images/<scene>.png, a strip of frames.

Usage: python scripts/render_figures.py [scene ...] [--size 240] [--quality medium]
"""

import argparse
import os
import shutil
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

# Frames to show per sample (within its frame range): chosen to show the light events of each
# animation.
FRAMES = {
    "cornell": [1, 7, 13, 21],
    "curtain": [1, 6, 12],
    "searchbeam": [1, 6, 12],
    "moonlight": [1, 6, 12],
    "office": [1, 4, 8],
    "policespot": [1, 6, 11, 16, 21, 26],  # the spot turns 60 degrees between pictures
    "daylight": [1, 7, 13, 19, 25],  # morning, mid-morning, noon, afternoon, evening
}


def emission_render(scene, size):
    """Cycles on the CPU, 8 samples, no bounces: camera rays see the preview material's emission (the
    baked radiance), nothing else; a size x size PNG."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.cycles.max_bounces = 0
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "AgX"
    scene.render.image_settings.file_format = "PNG"


def render_scene(name, size, quality, out_dir):
    import bpy
    from hr_addon.blender.bake import run_bake
    from hr_addon.blender import playback, preview
    from PIL import Image, ImageDraw

    tmp = tempfile.mkdtemp(prefix="hr_fig_")
    try:
        blend = os.path.join(tmp, f"{name}.blend")
        shutil.copy(os.path.join(ROOT, "sample_blends", f"{name}.blend"), blend)
        bpy.ops.wm.open_mainfile(filepath=blend)
        scene = bpy.context.scene
        run_bake(scene, log=lambda *a, **k: None, quality=quality)
        meshes = [o for o in scene.objects if o.type == "MESH" and not o.hr.is_light_shape]
        preview.add_preview(meshes)
        for o in scene.objects:  # the light shapes are not geometry of the solution
            if o.type == "MESH" and o.hr.is_light_shape:
                o.hide_render = True
                o.animation_data_clear()
        emission_render(scene, size)
        tiles = []
        for f in FRAMES[name]:
            scene.frame_set(f)
            playback.load_frame(scene, f)
            path = os.path.join(tmp, f"{name}_{f:03d}.png")
            scene.render.filepath = path
            bpy.ops.render.render(write_still=True)
            img = Image.open(path).convert("RGB")
            ImageDraw.Draw(img).text((6, 4), f"frame {f}", fill=(255, 255, 255))
            tiles.append(img)
        strip = Image.new("RGB", (size * len(tiles) + 4 * (len(tiles) - 1), size), (255, 255, 255))
        for i, t in enumerate(tiles):
            strip.paste(t, (i * (size + 4), 0))
        os.makedirs(out_dir, exist_ok=True)
        strip.save(os.path.join(out_dir, f"{name}.png"))
        print(f"wrote {os.path.join(out_dir, name + '.png')}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=list(FRAMES))
    ap.add_argument("--size", type=int, default=240)
    ap.add_argument("--quality", default="medium")
    args = ap.parse_args()
    import hr_addon

    hr_addon.register()
    for name in args.scenes:
        render_scene(name, args.size, args.quality, os.path.join(ROOT, "docs", "images"))


if __name__ == "__main__":
    main()
