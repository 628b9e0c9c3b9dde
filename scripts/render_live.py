"""Render the user guide's Live Relight picture sequence (Cycles, CPU, headless).

The Cornell sample with Live Relight on: the back-wall light shape is dragged across the wall in
a few steps; after each step hr.live_update() brings HR_Radiance up to date (what the timer does
in the viewport) and the frame is rendered through the preview material (HR_Radiance into an
Emission shader, zero bounces: what you see is exactly the Live result). Writes
docs/images/live_drag.png, a strip of the steps with the time each update took.

Usage: python scripts/render_live.py [--size 240] [--quality medium] [--steps 4]
"""

import argparse
import os
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "scripts")]
from render_figures import emission_render  # noqa: E402  (the README pictures' settings)


def render(size, quality, steps, out):
    import bpy
    from PIL import Image, ImageDraw
    from hr_addon.blender import live

    tmp = tempfile.mkdtemp(prefix="hr_live_fig_")
    try:
        blend = os.path.join(tmp, "cornell.blend")
        shutil.copy(os.path.join(ROOT, "sample_blends", "cornell.blend"), blend)
        bpy.ops.wm.open_mainfile(filepath=blend)
        scene = bpy.context.scene
        scene.hr.quality = quality.upper()
        for o in scene.objects:  # a still scene: the shapes are edited, not animated
            if o.hr.is_light_shape:
                o.animation_data_clear()
        bpy.data.objects["Window"].hide_render = True
        patch = bpy.data.objects["Back Patch"]
        patch.hide_render = False
        # a larger, warmer shape than the sample's, so that its bounce light is easy to see
        me = patch.data
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3).astype(np.float64)
        c = co.mean(0)
        co = c + (co - c) * np.array([1.0, 1.0, 1.6])
        me.vertices.foreach_set("co", co.astype(np.float32).ravel())
        me.update()
        node = next(n for n in patch.data.materials[0].node_tree.nodes if n.type == "EMISSION")
        node.inputs["Color"].default_value = (1.0, 0.75, 0.45, 1.0)
        node.inputs["Strength"].default_value = 14.0
        x0, x1 = float(co[:, 0].min()), float(co[:, 0].max())
        left, right = 0.03 - x0, 0.53 - x1  # the back wall spans x = 0 .. 0.556
        emission_render(scene, size)  # the Live result's emission, nothing else
        scene.hr.live = True
        t0 = time.perf_counter()
        bpy.ops.hr.live_update()  # builds the hierarchy once
        print(
            f"Live on: {time.perf_counter() - t0:.1f} s (hierarchy build and first light state)", flush=True
        )
        tiles = []
        for i in range(steps):
            patch.location.x = left + (right - left) * i / max(steps - 1, 1)
            t0 = time.perf_counter()
            bpy.ops.hr.live_update(check_geometry=False)
            dt = time.perf_counter() - t0
            path = os.path.join(tmp, f"live_{i}.png")
            scene.render.filepath = path
            bpy.ops.render.render(write_still=True)
            img = Image.open(path).convert("RGB")
            ImageDraw.Draw(img).text((6, 4), f"step {i + 1}: {1000 * dt:.0f} ms", fill=(255, 255, 255))
            tiles.append(img)
            print(
                f"step {i + 1}: x = {patch.location.x:+.3f} m, update {1000 * dt:.0f} ms "
                f"({live.session(scene).last.report.method})",
                flush=True,
            )
        strip = Image.new("RGB", (size * len(tiles) + 4 * (len(tiles) - 1), size), (255, 255, 255))
        for i, t in enumerate(tiles):
            strip.paste(t, (i * (size + 4), 0))
        os.makedirs(os.path.dirname(out), exist_ok=True)
        strip.save(out)
        print(f"wrote {out}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=240)
    ap.add_argument("--quality", default="medium")
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "live_drag.png"))
    args = ap.parse_args()
    import hr_addon

    hr_addon.register()
    render(args.size, args.quality, args.steps, args.out)


if __name__ == "__main__":
    main()
