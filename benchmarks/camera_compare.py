"""Accuracy as issue 19's product owner measures it: Cycles renders of a scene from a camera, compared
per object in the image (docs/accuracy.md, "Per object from a camera").

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/camera_compare.py \
        [--views furnished_close,furnished_wide,clutter,cornell] [--spp 256] [--tag camera] [--texel 0.02]
        [--outputs vertex,texture] [--subdivide 0.25]

(docs/accuracy.md's runs: --spp 128 for the furnished views, with and without --texel 0.02, and
--spp 32 for clutter and cornell; about 5 CPU minutes per 128-spp reference render.)

Per view (VIEWS: a scene, its frame, a camera, a resolution):
1. Reference: a Cycles render of the scene itself, the references' materials (cycles_ref.prepare:
   Diffuse BSDF roughness 0 + Emission, black back faces: one-sided emitters; light shapes as
   cycles_ref.shape_proxies), path traced, 64 bounces, no clamping, Standard view, Blender's default
   pixel filter (Blackman-Harris 1.5 px), one thread, two seeds; each object's pass_index set, the
   Object Index pass read with the combined pass from a 32-bit float multilayer EXR.
2. Ours through the product's path: `python -m hr_addon bake` of a copy of the scene at draft
   quality, default settings otherwise (final gather on), once with vertex output (the default)
   and once with texture output (--output texture: lightmaps sized by the bake's Texel Density;
   --texel T: every object a Lightmap Size for texels of about T metres instead, lightmap_sizes,
   as session 19 measured before the Texel Density); the saved copy opened, the frame loaded and
   shown as the product shows it (the Preview Bake operator: HR_Radiance as Emission, or the baked
   image sequences on the helper materials), rendered by Cycles from the same camera, same
   resolution and filter, no bounces (emission only), OURS_SPP samples for the anti-aliasing.
3. Per object (index pass): mean over its pixels; objects with fewer than MIN_PIXELS pixels left
   out; error ours / Cycles - 1 (cycles_ref.metrics: mean over RGB), over the lit objects
   (cycles_ref.lit_objects); also over the objects' interior pixels (no 8-neighbour of another
   object: anti-aliased edges out). The reference's own noise: |seed 1 - seed 2| / 2 per object.

Writes benchmarks/out/camera_<tag>.json (per view: the summaries, every object's figures, the
worst objects as (name, error, pixels), CPU seconds), and per view benchmarks/out/camera_<view>/
(PNGs of Cycles, ours and the error maps; the renders as .npz). Work files (copies, bakes, EXRs and
their CPU seconds) go to benchmarks/out/camera_work/ and are reused when present (--fresh: ours
made again; the Cycles references, ~7 min CPU a seed and view, are kept: delete them by hand),
so a second run only compares. Times are CPU seconds (this process and its children).
`--figure furnished_close` writes docs/images/camera_furnished_close.png from the PNGs; `--pair VIEW`
docs/images/camera_VIEW_pair.png (Cycles beside ours, vertex output: the README's picture).
`--vertex-spacing S` bakes the vertex output with the product's Vertex Spacing S (own_values).
`--frame N` measures frame N instead of the views' own (the furnished window shape shows from frame 3):
references, bakes and JSON entries named VIEW_fN.
`--subdivide S` bakes a copy whose faces are cut until no edge is longer than S metres (linear,
the shape unchanged: `subdivide`), against the same references: the vertex output's upper bound
when its values sit at vertices that fine (branch vsub, session 21).
`--views unseen_a,unseen_b`: hr_testing/two_rooms.py's room, a scene nobody tuned on (session 31,
branch unseen; its light shapes from frame 3: --frame 3); `--views loft_a,loft_b`: hr_testing/loft.py's
room (session 34, branch unseen3; its skylight's blind closed at frame 1, half open at frame 3).
`--quality Q` bakes at Q instead of draft
(work folders and JSON entries VIEW..._Q); `--work DIR` keeps copies, bakes and references in DIR
instead of camera_work/ (the unseen runs: /work/cache/unseen, outside git).
"""

import argparse
import json
import os
import resource
import shutil
import struct
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
from hr_testing.loft import VIEWS as LOFT_VIEWS  # noqa: E402
from hr_testing.two_rooms import VIEWS as TWO_ROOMS_VIEWS  # noqa: E402

OUT = os.path.join(HERE, "out")
WORK = os.path.join(OUT, "camera_work")

MIN_PIXELS = 50
OURS_SPP = 64  # emission only: converges the anti-aliasing, cheap
SEEDS = (1, 2)
FILTER = ("BLACKMAN_HARRIS", 1.5)  # Blender's default pixel filter
# texture output: per-object lightmap sizes for texels of about this many metres (lightmap_sizes,
# --texel); none: the product's own sizing (Texel Density, since session 19's branch texsize)
TEXEL = {}
SUBDIVIDE = {}  # --subdivide: scene -> spacing in metres of the baked copy's vertices
BAKE_ARGS = []  # --vertex-spacing: the bake's options (and its work folder's suffix)
VARIANT = []  # --variant: a name for the vertex bake's work folder and JSON entry
# scene: sample_blends/<name>.blend or "clutter" (hr_testing.clutter, built here); camera: None (the
# sample's own) or (location, target, lens mm)
VIEWS = {
    "furnished_wide": dict(scene="furnished", frame=1, camera=None, res=(640, 480)),
    "furnished_close": dict(
        scene="furnished", frame=1, camera=((2.0, 3.1, 1.05), (2.0, 4.75, 0.95), 24), res=(640, 480)
    ),
    "clutter": dict(
        scene="clutter", frame=1, camera=((0.35, 0.3, 1.75), (2.2, 2.2, 0.6), 24), res=(640, 480)
    ),
    "cornell": dict(scene="cornell", frame=1, camera=None, res=(400, 400)),
}
# hr_testing/two_rooms.py's room (session 31, branch unseen): --views unseen_a,unseen_b
VIEWS.update(
    {v: dict(scene="two_rooms", frame=1, camera=cam, res=(640, 480)) for v, cam in TWO_ROOMS_VIEWS.items()}
)
# hr_testing/loft.py's room (session 34, branch unseen3): --views loft_a,loft_b
VIEWS.update({v: dict(scene="loft", frame=1, camera=cam, res=(640, 480)) for v, cam in LOFT_VIEWS.items()})
FLIP_REF = []  # --flip-ref: objects whose faces the references reverse
QUALITY = ["draft"]  # --quality: the bakes' quality (its work folders and JSON entries named _<quality>)


def log(msg, t0=[time.perf_counter()]):
    print(f"{time.perf_counter() - t0[0]:7.1f}s {msg}", flush=True)


def cpu(children=False):
    r = resource.getrusage(resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


# --------------------------------------------------------------------------------------------
# scenes, bakes
# --------------------------------------------------------------------------------------------


def source_blend(scene):
    """The scene's .blend in WORK (a copy of the sample, or the clutter room built and saved)."""
    from hr_testing.blend import load_bpy, mesh_scene

    path = os.path.join(WORK, scene, f"{scene}.blend")
    if os.path.exists(path):
        return path
    os.makedirs(os.path.dirname(path), exist_ok=True)
    if scene == "clutter":
        from hr_testing.clutter import clutter_room

        bpy = load_bpy()
        mesh_scene(clutter_room()[0])
        bpy.ops.wm.save_as_mainfile(filepath=path)
    elif scene in ("two_rooms", "loft"):
        from hr_testing.loft import loft_scene
        from hr_testing.two_rooms import two_rooms_scene

        bpy = load_bpy()
        (two_rooms_scene if scene == "two_rooms" else loft_scene)()
        bpy.ops.wm.save_as_mainfile(filepath=path)
    else:
        shutil.copy(os.path.join(ROOT, "sample_blends", f"{scene}.blend"), path)
    return path


def lightmap_sizes(path, texel):
    """Give every object of the .blend at path a Lightmap Size (Object > HR Radiosity) for texels
    of about `texel` metres, 16 to the default 128, and save it. The furnished room's 851 objects
    at the default 128 x 128 each are 7.4 million texels: the bake stopped at 10 GB (MemoryError)."""
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    from hr_addon.blender.scene_in import mesh_topology
    from hr_addon.lightmap import TextureError
    from hr_addon.lightmap.charts import pack_lightmap

    for ob in bpy.context.scene.objects:
        if ob.type != "MESH":
            continue
        co, ls, lt, lv = mesh_topology(ob.data)
        co = co * np.array(ob.matrix_world.to_scale())
        area = sum(p.area for p in ob.data.polygons) * np.prod(ob.matrix_world.to_scale()) ** (2 / 3)
        # the charts fill about half of the square (margins, shelf packing); curved objects' many
        # one-polygon charts need more (their margins): the size doubled until they fit
        res = int(np.clip(np.ceil(np.sqrt(2 * area) / texel), 16, 128))
        while res < 128:
            try:
                pack_lightmap(co, ls, lt, lv, res)
                break
            except TextureError:
                res = min(2 * res, 128)
        ob.hr.lightmap_resolution = res
    bpy.ops.wm.save_mainfile()


def subdivide(path, spacing):
    """Cut every edge of the .blend at path longer than `spacing` metres (world space) in halves,
    again until none is, and save it: planar faces stay where they were (linear, no smoothing),
    a quad with its four edges cut becomes four quads. Meshes shared by objects: cut once, by the
    first user's transform."""
    import bmesh
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    done = set()
    for ob in bpy.context.scene.objects:
        if ob.type != "MESH" or ob.data.name in done:
            continue
        done.add(ob.data.name)
        bm = bmesh.new()
        bm.from_mesh(ob.data)
        M = np.array(ob.matrix_world)[:3, :3]
        while True:
            long = [e for e in bm.edges if np.linalg.norm(M @ (e.verts[0].co - e.verts[1].co)) > spacing]
            if not long:
                break
            bmesh.ops.subdivide_edges(bm, edges=long, cuts=1, use_grid_fill=True)
        bm.to_mesh(ob.data)
        bm.free()
    bpy.ops.wm.save_mainfile()


def bake(scene, frame, output):
    """`python -m hr_addon bake` of a copy of the scene (draft, default settings, --output output).
    Returns (the saved copy, CPU seconds of the bake process, kept beside the copy)."""
    d = os.path.join(
        WORK,
        scene,
        output
        + (f"_{TEXEL[scene]}" if output == "texture" and scene in TEXEL else "")
        + (f"_sub{SUBDIVIDE[scene]}" if scene in SUBDIVIDE else "")
        + (f"_vs{BAKE_ARGS[1]}" if BAKE_ARGS and output == "vertex" else "")
        + (f"_{VARIANT[0]}" if VARIANT and output == "vertex" else "")
        + (f"_{QUALITY[0]}" if QUALITY[0] != "draft" else "")
        + (f"_f{frame}" if frame != 1 else ""),  # --frame: its own bake
    )
    saved = os.path.join(d, "baked.blend")
    if os.path.exists(saved):
        return saved, json.load(open(saved + ".json")).get("cpu")  # None: not timed
    os.makedirs(d, exist_ok=True)
    src = os.path.join(d, f"{scene}.blend")
    shutil.copy(source_blend(scene), src)
    if output == "texture" and scene in TEXEL:
        lightmap_sizes(src, TEXEL[scene])
    if scene in SUBDIVIDE:
        subdivide(src, SUBDIVIDE[scene])
    cmd = [sys.executable, "-m", "hr_addon", "bake", src, "--frames", f"{frame}-{frame}"]
    cmd += ["--quality", QUALITY[0], "--output", output, "--threads", "1", "--save", saved]
    cmd += BAKE_ARGS if output == "vertex" else []
    log(" ".join(cmd[1:]))
    with open(os.path.join(d, "bake.log"), "w+") as out:  # the bake's own rusage: os.wait4
        p = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, text=True)
        _, status, ru = os.wait4(p.pid, 0)
        out.seek(0)
        print(out.read()[-4000:], flush=True)
    if status:
        raise RuntimeError(f"bake failed ({status})")
    dt = ru.ru_utime + ru.ru_stime
    json.dump({"cpu": dt, "peak_rss_gb": ru.ru_maxrss / 1e6}, open(saved + ".json", "w"))
    return saved, dt


# --------------------------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------------------------


def read_exr(path):
    """{channel: (H, W) float32} of an uncompressed scanline OpenEXR, single- or multi-part
    (Blender's multilayer EXR with codec NONE: one part per pass in some files), rows as stored:
    the top row first."""
    data = open(path, "rb").read()
    assert struct.unpack_from("<i", data, 0)[0] == 20000630
    flags = struct.unpack_from("<i", data, 4)[0]
    assert not flags & 0xA00, "tiled or deep EXR"
    multi = bool(flags & 0x1000)
    pos, parts = 8, []
    while True:  # headers: name \0 type \0 size value ... \0; multi-part: a list ending in \0
        attrs = {}
        while data[pos] != 0:
            e = data.index(b"\0", pos)
            e2 = data.index(b"\0", e + 1)
            size = struct.unpack_from("<i", data, e2 + 1)[0]
            attrs[data[pos:e].decode()] = data[e2 + 5 : e2 + 5 + size]
            pos = e2 + 5 + size
        pos += 1
        parts.append(attrs)
        if not multi or data[pos] == 0:
            break
    pos += multi
    types = {0: "<u4", 1: "<f2", 2: "<f4"}
    out = {}
    for attrs in parts:
        assert attrs["compression"][0] == 0, "compressed EXR"
        chans, cl, q = [], attrs["channels"], 0
        while cl[q] != 0:
            e = cl.index(b"\0", q)
            chans.append((cl[q:e].decode(), struct.unpack_from("<i", cl, e + 1)[0]))
            q = e + 17
        x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"])
        W, H = x1 - x0 + 1, y1 - y0 + 1
        part = {c: np.empty((H, W), np.float32) for c, _ in chans}
        for off in struct.unpack_from(f"<{H}Q", data, pos):
            off += 4 * multi  # a multi-part chunk starts with its part number
            y = struct.unpack_from("<i", data, off)[0] - y0
            p = off + 8
            for c, t in chans:
                dt = np.dtype(types[t])
                part[c][y] = np.frombuffer(data, dt, W, p)
                p += W * dt.itemsize
        pos += 8 * H
        out.update(part)
    return out


def set_camera(bpy, scene, view):
    cam = view["camera"]
    if cam is not None:
        from hr_testing.blend import look_from

        look_from(scene, "camera_compare", *cam)
    r = scene.render
    r.resolution_x, r.resolution_y = view["res"]
    r.resolution_percentage = 100


def pass_indices(bpy, names):
    for i, n in enumerate(names):
        bpy.data.objects[n].pass_index = i + 1


def render(bpy, scene, path, spp, seed, bounces):
    """Render the scene's camera into a float multilayer EXR at path; returns (rgb (H, W, 3), object
    index (H, W) int, CPU seconds)."""
    from hr_testing.cycles_ref import configure_cycles

    configure_cycles(scene, spp, seed, threads=1, bounces=bounces)
    c = scene.cycles
    c.pixel_filter_type, c.filter_width = FILTER
    scene.view_settings.look = "None"
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    scene.render.film_transparent = False
    bpy.context.view_layer.use_pass_object_index = True
    im = scene.render.image_settings
    if hasattr(im, "media_type"):  # Blender 5: the multilayer formats are a media type
        im.media_type = "MULTI_LAYER_IMAGE"
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.color_depth = "32"
    im.exr_codec = "NONE"
    scene.render.filepath = path
    scene.render.use_file_extension = False
    c0 = cpu()
    bpy.ops.render.render(write_still=True)
    dt = cpu() - c0
    return read_render(path) + (dt,)


def read_render(path):
    """(rgb (H, W, 3), object index (H, W) int) of a render's multilayer EXR, rows top first."""
    ch = read_exr(path)
    comb = next(k for k in ch if k.endswith("Combined.R"))[:-1]
    rgb = np.stack([ch[comb + k] for k in "RGB"], -1)
    ob = ch[next(k for k in ch if k.endswith(("Object Index.X", "IndexOB.X")))]
    assert np.all(ob == np.round(ob)), "object index pass not integral"
    return rgb.astype(np.float64), ob.astype(np.int64)


def _remove_ours(work):
    """Everything under work but the Cycles references (ref_*)."""
    for d, dirs, files in os.walk(work, topdown=False):
        for f in files:
            if not f.startswith("ref_"):
                os.remove(os.path.join(d, f))
        for sub in dirs:
            if not os.listdir(os.path.join(d, sub)):
                os.rmdir(os.path.join(d, sub))


def reference(view, names, spp, seed, path):
    """Cycles' render of the scene with the references' one-sided Diffuse materials."""
    from hr_testing import cycles_ref as C
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=source_blend(view["scene"]), load_ui=False)
    scene = bpy.context.scene
    for name in FLIP_REF:  # --flip-ref: these objects' faces reversed, as the bake turns them
        bpy.data.objects[name].data.flip_normals()
    rs = C.prepare(scene, only=())  # every object: one-sided reference materials, no atlas
    shapes = C.shape_proxies(rs, view["frame"])
    set_camera(bpy, scene, view)
    pass_indices(bpy, names)
    out = render(bpy, scene, path, spp, seed, 64)
    return out + (sorted(shapes),)


def ours(view, names, saved, spp, path):
    """The product's display of its bake (Preview Bake) rendered by Cycles, emission only."""
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=saved, load_ui=False)
    scene = bpy.context.scene
    scene.frame_set(view["frame"])
    assert bpy.ops.hr.load_frame() == {"FINISHED"}
    assert bpy.ops.hr.add_preview() == {"FINISHED"}
    set_camera(bpy, scene, view)
    pass_indices(bpy, names)
    return render(bpy, scene, path, spp, 0, 0)


def geometry_names(view):
    from hr_testing.blend import load_bpy
    from hr_addon.blender.scene_in import geometry_objects

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=source_blend(view["scene"]), load_ui=False)
    return sorted(o.name for o in geometry_objects(bpy.context.view_layer))


# --------------------------------------------------------------------------------------------
# per object
# --------------------------------------------------------------------------------------------


def interior(ob):
    """Pixels whose 8 neighbours show the same object (anti-aliased edges excluded)."""
    p = np.pad(ob, 1, mode="edge")
    H, W = ob.shape
    same = np.ones_like(ob, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            same &= p[dy : dy + H, dx : dx + W] == ob
    return same


def per_object(img, ob, names, mask=None):
    """{name: (n, 3) pixels} of the objects with at least MIN_PIXELS pixels (in mask)."""
    out = {}
    keep = np.ones(ob.shape, bool) if mask is None else mask
    for i, n in enumerate(names):
        m = (ob == i + 1) & keep
        if m.sum() >= MIN_PIXELS:
            out[n] = img[m]
    return out


def compare(view_name, r):
    """Per-object figures of one view. r: the renders {ref1, ref2, vertex, texture: (rgb, ob)}."""
    from hr_testing import cycles_ref as C

    names = r["names"]
    (a, oa), (b, ob_) = r["ref1"], r["ref2"]
    ob = oa
    assert (oa == ob_).mean() > 0.999, "the two seeds' index passes differ"
    outs = [k for k in ("vertex", "texture") if k in r]
    for k in outs:
        # the index pass takes one sample's hit per pixel: agree where the hit is sure
        log(f"  index pass agreement ref / {k}: {(r[k][1] == ob).mean():.4f}")
    ref = (a + b) / 2
    res = {"objects": {}, "pixels": int(ob.size)}
    pa, pb = per_object(a, ob, names), per_object(b, ob, names)
    pref = per_object(ref, ob, names)
    lit = C.lit_objects({n: v for n, v in pref.items()})
    small = [n for i, n in enumerate(names) if 0 < (ob == i + 1).sum() < MIN_PIXELS]
    res.update(lit=lit, seen=len(pref), left_out_small=len(small), min_pixels=MIN_PIXELS)
    noise = {}
    for n in pref:
        ma, mb = pa[n].mean(0), pb[n].mean(0)
        noise[n] = float(np.mean(np.abs(ma - mb) / np.maximum(ma + mb, 1e-12)))  # |a - b| / 2 / mean
    res["ref_noise_median"] = float(np.median([noise[n] for n in lit]))
    res["ref_noise_p90"] = float(np.percentile([noise[n] for n in lit], 90))
    inner = interior(ob)
    summary = {}
    for k in outs:
        for part, mask in (("", None), ("_interior", inner)):
            po = per_object(r[k][0], ob, names, mask)
            pr = per_object(ref, ob, names, mask)
            per = {n: C.metrics(po[n], pr[n]) for n in pr}
            for n, m in per.items():
                res["objects"].setdefault(n, {})[k + part] = {
                    key: m[key] for key in ("mre", "bias", "texels")
                }
            ll = [n for n in lit if n in per]
            groups = (
                ("all", ll),
                ("books", [n for n in ll if "_book" in n]),
                ("others", [n for n in ll if "_book" not in n]),
            )
            for g, sel in groups:
                if sel:
                    st = C.object_summary(per, sel)
                    summary[f"{k}{part}|{g}"] = st
                    log(
                        f"  {view_name} {k + part:17s} {g:6s} {st['objects']:3d} lit objects: median "
                        f"{100 * st['median']:.2f}%, within 5% {100 * st['within_5']:.0f}%, pooled bias "
                        f"{100 * st['pooled_bias']:+.2f}%, median signed {100 * st['median_signed']:+.2f}%"
                    )
    for n in pref:
        res["objects"][n]["pixels"] = int(len(pref[n]))
        res["objects"][n]["ref_noise"] = noise[n]
        res["objects"][n]["mean_ref"] = pref[n].mean(0).tolist()
    res["summary"] = summary
    # the image's light, interior pixels and anti-aliased edges apart: sum ours / sum Cycles - 1
    shown = ob > 0
    res["edge_share"] = float((~inner & shown).sum() / shown.sum())
    res["pixel_bias"] = {
        k: {
            part: float(r[k][0][m].sum() / ref[m].sum() - 1)
            for part, m in (("interior", inner & shown), ("edges", ~inner & shown))
        }
        for k in outs
    }
    for k in outs:  # the worst lit objects, for a look at the images
        worst = sorted((n for n in lit if k in res["objects"][n]), key=lambda n: -res["objects"][n][k]["mre"])
        res[f"worst_{k}"] = [
            (n, res["objects"][n][k]["bias"], res["objects"][n][k]["texels"]) for n in worst[:12]
        ]
    log(
        f"  {view_name}: {len(pref)} objects of >= {MIN_PIXELS} px ({len(small)} smaller left out), "
        f"{len(lit)} lit; reference noise median {100 * res['ref_noise_median']:.2f}%, "
        f"p90 {100 * res['ref_noise_p90']:.2f}%"
    )
    return res


# the texel measure of the same bake settings (furnished_vs_cycles.py, branch bookvx, in main):
# per object over texels, texture output at the texel centres, vertex output over unburied texels
TEXEL_JSON = os.path.join(OUT, "furnished_vs_cycles_bookvx.json")
TEXEL_VARS = {"texture": "refl_gather", "vertex": "total_gvertex_unburied"}


def texel_side(res):
    """The texel measure's per-object errors over the objects this view compares (lit in both),
    beside the camera's: which objects, or how they are measured, makes the difference."""
    from hr_testing import cycles_ref as C

    if not os.path.exists(TEXEL_JSON):
        return None
    tj = json.load(open(TEXEL_JSON))
    out = {}
    for k, var in TEXEL_VARS.items():
        if not any(k in o for o in res["objects"].values()):
            continue
        tex = {n: o[var] for n, o in tj["objects"].items() if var in o}
        both = [n for n in res["lit"] if n in tex and n in tj["lit"]]
        for g, sel in (("all", both), ("books", [n for n in both if "_book" in n])):
            if not sel:
                continue
            out[f"{k}|{g}"] = row = {"objects": len(sel)}
            for side, per in (
                ("texel", tex),
                ("camera", {n: res["objects"][n][k] for n in sel}),
                (
                    "camera_interior",
                    {
                        n: res["objects"][n][k + "_interior"]
                        for n in sel
                        if k + "_interior" in res["objects"][n]
                    },
                ),
            ):
                ss = [n for n in sel if n in per]
                st = C.object_summary({n: dict(per[n], mean_ours=[0], mean_ref=[1]) for n in ss}, ss)
                row[side] = {q: st[q] for q in ("objects", "median", "within_5", "median_signed")}
            log(
                f"  same {len(sel)} objects ({k}, {g}): "
                + ", ".join(
                    f"{side} median {100 * v['median']:.2f}% ({100 * v['within_5']:.0f}% within 5%)"
                    for side, v in row.items()
                    if side != "objects"
                )
            )
        for n in both:
            res["objects"][n][f"texel_{k}"] = {"mre": tex[n]["mre"], "bias": tex[n]["bias"]}
    return out


def pictures(view_name, r, ob):
    """PNGs: Cycles, ours (vertex, texture), each at the same exposure, and the error maps
    ours / Cycles - 1 (blue -20% ... red +20%, black: below 2% of the exposure's white in Cycles)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = os.path.join(OUT, f"camera_{view_name}")
    os.makedirs(d, exist_ok=True)
    ref = (r["ref1"][0] + r["ref2"][0]) / 2
    g = ref.mean(-1)
    scale = min(np.percentile(g, 99), 4 * np.median(g))  # an emitter in view: the room's exposure

    def srgb(x):
        x = np.clip(x / scale, 0, 1)
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)

    plt.imsave(os.path.join(d, "cycles.png"), srgb(ref))
    for k in ("vertex", "texture"):
        if k not in r:
            continue
        plt.imsave(os.path.join(d, f"ours_{k}.png"), srgb(r[k][0]))
        g, gr = r[k][0].mean(-1), ref.mean(-1)
        err = np.where(gr > 0.02 * scale, g / np.maximum(gr, 1e-12) - 1, np.nan)
        cm = plt.get_cmap("coolwarm").copy()
        cm.set_bad("black")
        plt.imsave(os.path.join(d, f"error_{k}.png"), np.ma.masked_invalid(err), cmap=cm, vmin=-0.2, vmax=0.2)


def figure(view_name, path):
    """Cycles, ours (vertex output) and the error maps of both outputs, half size, 2 x 2: the
    picture docs/accuracy.md shows (error maps as pictures() draws them)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = os.path.join(OUT, f"camera_{view_name}")
    tiles = [
        ("cycles", "Cycles (2 seeds)"),
        ("ours_vertex", "ours, vertex output"),
        ("error_vertex", "vertex / Cycles - 1 (blue -20%, red +20%)"),
        ("error_texture", "texture / Cycles - 1"),
    ]
    fig, axes = plt.subplots(2, 2, figsize=(6.6, 5.3))
    for ax, (name, title) in zip(axes.ravel(), tiles):
        ax.axis("off")
        ax.imshow(plt.imread(os.path.join(d, f"{name}.png"))[::2, ::2], interpolation="nearest")
        ax.set_title(title, fontsize=9)
    fig.tight_layout(pad=0.3)
    fig.canvas.draw()
    from PIL import Image

    # 128 colours: the noisy error maps otherwise make a 640 kB file
    rgb = Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3])
    rgb.quantize(128, dither=Image.Dither.NONE).save(path, optimize=True)


def pair_figure(view_name, path):
    """Cycles beside ours (vertex output), full size, at the same exposure (pictures()): the README's
    picture of a view (`--pair VIEW`)."""
    from PIL import Image, ImageDraw, ImageFont

    d = os.path.join(OUT, f"camera_{view_name}")
    tiles = [(Image.open(os.path.join(d, f"{n}.png")).convert("RGB"), t) for n, t in PAIR]
    w, h = tiles[0][0].size
    out = Image.new("RGB", (2 * w + 6, h), (255, 255, 255))
    font = ImageFont.load_default(size=18)
    for i, (img, title) in enumerate(tiles):
        draw = ImageDraw.Draw(img)
        box = draw.textbbox((10, 8), title, font=font)
        draw.rectangle((box[0] - 5, box[1] - 4, box[2] + 5, box[3] + 4), fill=(0, 0, 0))
        draw.text((10, 8), title, fill=(255, 255, 255), font=font)
        out.paste(img, (i * (w + 6), 0))
    out.quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
    log(f"wrote {path}")


PAIR = [("cycles", "Cycles, 2 x 128 spp"), ("ours_vertex", "ours: vertex output (the default)")]


def save_view(vn, r, outputs, names, res, dump, path):
    """A view's pictures, its renders (renders.npz) and its entry in the JSON at path."""
    from hr_testing.cycles_ref import write_json

    pictures(vn, r, r["ref1"][1])
    np.savez_compressed(
        os.path.join(OUT, f"camera_{vn}", "renders.npz"),
        ref1=r["ref1"][0].astype(np.float32),
        ref2=r["ref2"][0].astype(np.float32),
        **{k: r[k][0].astype(np.float32) for k in outputs},
        index=r["ref1"][1].astype(np.int32),
        names=np.array(names),
    )
    dump["views"][vn] = res
    write_json(path, dump)
    log(f"[{vn}] written {path}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--views", default=",".join(VIEWS))
    p.add_argument("--spp", type=int, default=256, help="Cycles samples per seed of the reference")
    p.add_argument("--tag", default="camera")
    p.add_argument(
        "--fresh", action="store_true", help="bake and render ours again (the Cycles references are kept)"
    )
    p.add_argument(
        "--texel",
        type=float,
        help="texture output: every object a Lightmap Size for texels of about this many metres "
        "(session 19's runs: 0.04, 0.02) instead of the bake's own Texel Density",
    )
    p.add_argument("--outputs", default="vertex,texture", help="the outputs baked and compared")
    p.add_argument(
        "--subdivide",
        type=float,
        help="bake a copy with no edge longer than this many metres (linear subdivision, subdivide)",
    )
    p.add_argument(
        "--variant",
        help="a name for the vertex bake's own work files and JSON entry (a variant of the code or its "
        "environment: the same spacing baked again)",
    )
    p.add_argument("--vertex-spacing", help="the vertex bake's --vertex-spacing (the product's subdivision)")
    p.add_argument(
        "--frame",
        type=int,
        help="this frame instead of the views' own (references, bakes and JSON entries of their own)",
    )
    p.add_argument(
        "--flip-ref",
        help="objects whose faces the references reverse (faces built facing away, which the bake turns "
        "around and one-sided references show black: the two rooms' doorway); references and JSON "
        "entries VIEW_flip",
    )
    p.add_argument("--quality", default="draft", help="the bakes' quality (draft, medium, high)")
    p.add_argument(
        "--work",
        help="the work folder (copies, bakes, the Cycles references) instead of benchmarks/out/camera_work",
    )
    p.add_argument(
        "--figure", metavar="VIEW", help="only the docs' picture of VIEW (docs/images/camera_VIEW.png)"
    )
    p.add_argument(
        "--pair",
        metavar="VIEW",
        help="only Cycles beside ours (vertex output) of VIEW's PNGs (docs/images/camera_VIEW_pair.png)",
    )
    p.add_argument("--pair-spp", type=int, help="--pair: the references' samples per seed named in its title")
    a = p.parse_args()
    if a.pair_spp:
        PAIR[0] = ("cycles", f"Cycles, 2 x {a.pair_spp} spp")
    if a.pair:
        return pair_figure(a.pair, os.path.join(ROOT, "docs", "images", f"camera_{a.pair}_pair.png"))
    if a.figure:
        return figure(a.figure, os.path.join(ROOT, "docs", "images", f"camera_{a.figure}.png"))
    global WORK
    if a.work:
        WORK = a.work
    QUALITY[0] = a.quality
    if a.fresh and os.path.isdir(WORK):
        _remove_ours(WORK)
    os.makedirs(WORK, exist_ok=True)
    path = os.path.join(OUT, f"camera_{a.tag}.json")
    dump = json.load(open(path)) if os.path.exists(path) else {"views": {}}
    dump.update(ours_spp=OURS_SPP, filter=FILTER, min_pixels=MIN_PIXELS, seeds=SEEDS)
    for vn in a.views.split(","):
        view = VIEWS[vn]
        if a.frame and a.frame != view["frame"]:
            view = dict(view, frame=a.frame)
            vn = f"{vn}_f{a.frame}"
        names = geometry_names(view)
        if a.flip_ref:
            FLIP_REF[:] = a.flip_ref.split(",")
            vn = f"{vn}_flip"
        wd = os.path.join(WORK, vn)  # the references' renders
        if a.texel:
            TEXEL[view["scene"]] = a.texel
            vn = f"{vn}_texel{a.texel}"  # its own renders of ours and JSON entry
        if a.vertex_spacing:
            BAKE_ARGS[:] = ["--vertex-spacing", a.vertex_spacing]
            vn = f"{vn}_vs{a.vertex_spacing}"
        if a.subdivide:
            SUBDIVIDE[view["scene"]] = a.subdivide
            vn = f"{vn}_sub{a.subdivide}"
        if a.variant:
            VARIANT[:] = [a.variant]
            vn = f"{vn}_{a.variant}"
        if a.quality != "draft":
            vn = f"{vn}_{a.quality}"
        bakes = {k: bake(view["scene"], view["frame"], k) for k in a.outputs.split(",")}
        r, cpu_s = {"names": names}, {}
        wo = os.path.join(WORK, vn)
        os.makedirs(wo, exist_ok=True)
        for i, seed in enumerate(SEEDS):
            exr = os.path.join(wd, f"ref_s{a.spp}_seed{seed}.exr")
            if not os.path.exists(exr):
                rgb, ob, dt, shapes = reference(view, names, a.spp, seed, exr)
                json.dump({"cpu": dt, "shapes": shapes}, open(exr + ".json", "w"))
                log(f"[{vn}] Cycles {a.spp} spp seed {seed}: {dt:.0f} s CPU, light shapes {shapes}")
            r[f"ref{i + 1}"] = read_render(exr)
            info = json.load(open(exr + ".json"))
            cpu_s[f"ref_seed{seed}"] = info["cpu"]
        for k, (saved, bake_cpu) in bakes.items():
            exr = os.path.join(wo, f"ours_{k}.exr")
            if not os.path.exists(exr):
                dt = ours(view, names, saved, OURS_SPP, exr)[2]
                json.dump({"cpu": dt}, open(exr + ".json", "w"))
                log(f"[{vn}] ours ({k}) rendered: {dt:.0f} s CPU")
            r[k] = read_render(exr)
            cpu_s[f"ours_{k}_render"] = json.load(open(exr + ".json"))["cpu"]
            cpu_s[f"bake_{k}"] = bake_cpu
        res = compare(vn, r)
        res.update(view=view, ref_spp=a.spp, cpu_seconds=cpu_s)
        if view["scene"] == "furnished":
            res["texel_measure"] = texel_side(res)
        save_view(vn, r, bakes, names, res, dump, path)


if __name__ == "__main__":
    main()
