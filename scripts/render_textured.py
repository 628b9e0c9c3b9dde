"""Textured surfaces, before and after (docs/images/textured_albedo.png, docs/accuracy.md).

The textured room (make_samples.textured_room: a checker Image Texture on the floor's Principled
Base Color) baked as Baked Textures and rendered through the helper material (Emission of the
lightmap, zero bounces: what the bake stores), next to a Cycles path-traced render of the same
scene (one-sided Diffuse reference materials, hr_testing/cycles_ref.py):
  1. before: outgoing radiance with the average albedo (the output before this change: the texture
     modulation switched off for this bake only),
  2. after: outgoing radiance modulated per texel by the texture (the default mode),
  3. after: Irradiance (lightmap) mode, the helper material multiplying by the floor's base colour,
  4. Cycles path tracing.
Prints the relative RMSE of each against the path-traced render (float pixels, the emitter left
out). Cycles CPU, Standard view transform; about two minutes on two cores.

Usage: python scripts/render_textured.py [--size 240] [--spp 256] [--res 128]
"""

import argparse
import os
import shutil
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "scripts")]


def _render(bpy, scene, path, spp, bounces):
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.device, c.samples, c.use_denoising, c.seed = "CPU", spp, False, 0
    c.max_bounces = c.diffuse_bounces = bounces
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path, check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1, :, :3].astype(np.float64)  # row 0 at the top


def _tile(img, label):
    """A linear float image as an 8-bit sRGB PIL image with a label."""
    from PIL import Image, ImageDraw

    from hr_addon.io.images import linear_to_srgb

    im = Image.fromarray((np.clip(linear_to_srgb(np.clip(img, 0, 1)), 0, 1) * 255 + 0.5).astype(np.uint8))
    ImageDraw.Draw(im).text((6, 4), label, fill=(255, 255, 255))
    return im


def _against(img, ref):
    """(relative pixel RMSE, relative mean error) of img against ref, the emitter (>= 1) left out."""
    keep = ref.max(-1) < 1.0
    d = (img - ref)[keep]
    return float(np.sqrt(np.mean(d**2)) / ref[keep].mean()), float(img[keep].mean() / ref[keep].mean() - 1)


def _reference_materials(bpy, objs):
    """One-sided Diffuse (+ Emission) copies of what our reader reads; the floor's colour is the
    same image through the same UV map."""
    from hr_testing import cycles_ref as C

    for name, ob in objs.items():
        ref = C.reference_material(f"REF_{name}", ob.data.materials[0], textured=name == "floor")
        ob.material_slots[0].link = "OBJECT"
        ob.material_slots[0].material = ref


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=240)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--res", type=int, default=128, help="lightmap size")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "textured_albedo.png"))
    args = ap.parse_args()
    import bpy
    from PIL import Image

    import make_samples as ms
    from hr_addon.blender import texture
    from hr_addon.blender.bake import run_bake

    scene = ms.reset()
    objs = ms.textured_room()
    ms.camera((0.35, 0.35, 1.8), (2.0, 2.3, 0.35), lens=16)
    scene.render.resolution_x, scene.render.resolution_y = args.size, args.size * 3 // 4
    scene.render.resolution_percentage = 100
    tmp = tempfile.mkdtemp(prefix="hr_tex_")
    try:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.join(tmp, "room.blend"))
        panels = {}

        def bake_and_render(key, mode, flat=False):
            keep = texture._albedo_specs
            if flat:  # the output before this change: every material at its average colour
                texture._albedo_specs = lambda obj, warned, cache: []
            try:
                run_bake(
                    scene,
                    log=lambda *a, **k: None,
                    frames=(1, 1),
                    quality="medium",
                    output="TEXTURE",
                    resolution=args.res,
                    radiance_mode=mode,
                )
            finally:
                texture._albedo_specs = keep
            texture.add_material(scene)
            panels[key] = _render(bpy, scene, os.path.join(tmp, f"{key}.exr"), 16, 0)
            texture.remove_material()

        bake_and_render("before: average albedo", "RADIANCE", flat=True)
        bake_and_render("after: outgoing radiance", "RADIANCE")
        bake_and_render("after: irradiance x base colour", "IRRADIANCE")
        scene.hr.playback = False  # the reference materials are not the baked scene
        _reference_materials(bpy, objs)
        ref = _render(bpy, scene, os.path.join(tmp, "cycles.exr"), args.spp, 64)
        panels[f"Cycles path traced, {args.spp} spp"] = ref
        for k, img in list(panels.items())[:-1]:
            rel, bias = _against(img, ref)
            print(f"{k}: relative RMSE {rel:.3f}, mean {bias:+.3%} against the path-traced render")
        tiles = [_tile(img, k) for k, img in panels.items()]
        w, h = tiles[0].size
        strip = Image.new("RGB", (w * 2 + 4, h * 2 + 4), (255, 255, 255))
        for i, t in enumerate(tiles):
            strip.paste(t, ((i % 2) * (w + 4), (i // 2) * (h + 4)))
        os.makedirs(os.path.dirname(args.out), exist_ok=True)
        strip.save(args.out)
        print(f"wrote {args.out}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
