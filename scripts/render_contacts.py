"""Contacts, side by side with Cycles (docs/images/contacts_cornell.png, docs/accuracy.md).

The Cornell sample at frame 1 (ceiling light only) baked at medium quality as Baked Textures and
rendered through the helper material (Emission of the lightmap, zero bounces: what the bake
stores), next to a Cycles path-traced render of the same scene (one-sided Diffuse + Emission
reference materials, hr_testing/cycles_ref.py), their relative difference with a scale bar, and
a close-up of the short block's foot: the bake without contact handling (Scene setting Contacts
off: the floor under the block lit, the band beside it too dark), with it, and Cycles.
Prints the relative RMSE of each bake against the path-traced render (float pixels, the light
left out). Cycles CPU, Standard view transform; about four minutes on two cores.

Usage: python scripts/render_contacts.py [--size 320] [--spp 512] [--res 256]
"""

import argparse
import os
import shutil
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "scripts")]

from render_textured import _against, _render, _tile  # noqa: E402  (same settings and measures)


def _reference_materials(bpy, scene):
    from hr_testing import cycles_ref as C

    for ob in scene.objects:
        if ob.type != "MESH":
            continue
        if ob.hr.is_light_shape:
            ob.hide_render = True  # frame 1: no light shape is on
            continue
        ref = C.reference_material(f"REF_{ob.name}", ob.data.materials[0])
        ob.material_slots[0].link = "OBJECT"
        ob.material_slots[0].material = ref


def _close_up(bpy, scene):
    """A camera low over the floor, looking at the short block's foot."""
    from mathutils import Vector

    ob = scene.objects["short_block"]
    pts = np.array([ob.matrix_world @ Vector(c) for c in ob.bound_box])
    target = np.array([pts[:, 0].min() + 0.02, pts[:, 1].min() + 0.02, 0.0])
    cam = bpy.data.cameras.new("CloseUp")
    cam.lens = 35
    c = bpy.data.objects.new("CloseUp", cam)
    scene.collection.objects.link(c)
    c.location = target + np.array([-0.07, -0.16, 0.09])
    c.rotation_euler = Vector(target - np.array(c.location)).to_track_quat("-Z", "Y").to_euler()
    return c


def _box_blur(img, r):
    """Mean over (2r+1)^2 pixels (edges: the pixels inside), per channel."""
    out = img
    for ax in (0, 1):
        c = np.cumsum(np.pad(out, [(r + 1, r) if a == ax else (0, 0) for a in range(out.ndim)]), ax)
        n = out.shape[ax]
        hi, lo = np.take(c, np.arange(n) + 2 * r + 1, ax), np.take(c, np.arange(n), ax)
        ones = np.cumsum(np.pad(np.ones(n), (r + 1, r)))
        cnt = (ones[np.arange(n) + 2 * r + 1] - ones[np.arange(n)]).reshape(
            [-1 if a == ax else 1 for a in range(out.ndim)]
        )
        out = (hi - lo) / cnt
    return out


def _diff_tile(ours, ref, keep, scale, Image, ImageDraw, r=4):
    """(ours - ref) / ref on a blue-white-red ramp, +-scale, with a scale bar. Both images are
    averaged over 9 x 9 pixels first: the path tracer's noise would hide any bias."""
    ours, ref = _box_blur(ours.mean(-1), r), _box_blur(ref.mean(-1), r)
    # away from the light, the background and silhouettes (a relative difference of near-black
    # pixels, or of edges anti-aliased differently, means nothing)
    keep = keep & (ref > 0.05 * np.median(ref[keep]))
    keep = keep & (_box_blur(keep.astype(float), r) > 0.999)
    d = np.where(keep, (ours - ref) / np.maximum(ref, 1e-6), 0.0)
    t = np.clip(d / scale, -1, 1)[..., None]
    white = np.ones(3)
    rgb = np.where(
        t > 0,
        white + t * (np.array([0.8, 0.1, 0.1]) - white),
        white - t * (np.array([0.1, 0.2, 0.8]) - white),
    )
    rgb[~keep] = 0.5
    h, w = d.shape
    bar = np.linspace(-1, 1, w)[None, :, None].repeat(14, 0)
    bar_rgb = np.where(
        bar > 0,
        white + bar * (np.array([0.8, 0.1, 0.1]) - white),
        white - bar * (np.array([0.1, 0.2, 0.8]) - white),
    )
    im = Image.fromarray((np.concatenate([rgb, bar_rgb]) * 255 + 0.5).astype(np.uint8))
    dr = ImageDraw.Draw(im)
    dr.text((6, 4), "(ours - Cycles) / Cycles, 9 x 9 px means", fill=(0, 0, 0))
    dr.text((2, h), f"-{scale:.0%}", fill=(0, 0, 0))
    dr.text((w // 2 - 4, h), "0", fill=(0, 0, 0))
    dr.text((w - 30, h), f"+{scale:.0%}", fill=(0, 0, 0))
    return im


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--res", type=int, default=256, help="lightmap size")
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "images", "contacts_cornell.png"))
    args = ap.parse_args()
    import bpy
    from PIL import Image, ImageDraw

    import hr_addon
    from hr_addon.blender import texture
    from hr_addon.blender.bake import run_bake

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    tmp = tempfile.mkdtemp(prefix="hr_contacts_")
    try:
        src = os.path.join(tmp, "cornell.blend")
        shutil.copy(os.path.join(ROOT, "sample_blends", "cornell.blend"), src)
        bpy.ops.wm.open_mainfile(filepath=src)
        scene = bpy.context.scene
        scene.frame_set(1)
        scene.render.resolution_x, scene.render.resolution_y = args.size, args.size * 3 // 4
        scene.render.resolution_percentage = 100
        main_cam = scene.camera
        close = _close_up(bpy, scene)
        shots = {}

        def bake_and_render(key, contacts, views):
            run_bake(
                scene,
                log=lambda *a, **k: None,
                frames=(1, 1),
                quality="medium",
                output="TEXTURE",
                resolution=args.res,
                contacts=contacts,
            )
            texture.add_material(scene)
            for view, cam in views:
                scene.camera = cam
                shots[(key, view)] = _render(bpy, scene, os.path.join(tmp, f"{key}_{view}.exr"), 16, 0)
            texture.remove_material()

        bake_and_render("without contacts", False, [("close", close)])
        bake_and_render("with contacts", True, [("full", main_cam), ("close", close)])
        scene.hr.playback = False  # the reference materials are not the baked scene
        _reference_materials(bpy, scene)
        for view, cam in (("full", main_cam), ("close", close)):
            scene.camera = cam
            shots[("cycles", view)] = _render(
                bpy, scene, os.path.join(tmp, f"cycles_{view}.exr"), args.spp, 64
            )
        for (key, view), img in shots.items():
            if key == "cycles":
                continue
            rel, bias = _against(img, shots[("cycles", view)])
            print(f"{key}, {view} view: relative RMSE {rel:.3f}, mean {bias:+.2%} against path tracing")
        ours, ref = shots[("with contacts", "full")], shots[("cycles", "full")]
        keep = ref.max(-1) < 1.0
        top = [
            _tile(ours, "HR bake, medium (texture output)"),
            _tile(ref, f"Cycles path traced, {args.spp} spp"),
            _diff_tile(ours, ref, keep, 0.2, Image, ImageDraw),
        ]
        gain = 2.0  # the close-ups one stop brighter, all three alike
        bottom = [
            _tile(gain * shots[(k, "close")], f"block foot: {t} (+1 stop)")
            for k, t in (
                ("without contacts", "contacts off"),
                ("with contacts", "contacts on"),
                ("cycles", "Cycles"),
            )
        ]
        w, h = top[0].size
        hd = top[2].size[1]
        sheet = Image.new("RGB", (3 * w + 8, hd + h + 4), (255, 255, 255))
        for i, t in enumerate(top):
            sheet.paste(t, (i * (w + 4), 0))
        for i, t in enumerate(bottom):
            sheet.paste(t, (i * (w + 4), hd + 4))
        os.makedirs(os.path.dirname(args.out), exist_ok=True)
        sheet.save(args.out)
        print(f"wrote {args.out}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
