"""The artist-made room (hr_testing/artist_room.py) against Cycles per object, frame 1 (issues 19,
20; docs/accuracy.md, *An artist-made room*).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/unseen_vs_cycles.py \
        [--small] [--texel 0.03] [--spp 128] [--vertex-cache DIR] [--name unseen] [--vertex-spacing S]

1. Our real path: the room saved and baked by `python -m hr_addon bake FILE --frames 1` (vertex
   output, default settings) in a child process (or the frame-1 cache of such a bake, --vertex-cache);
   its HR_Radiance corner values are written onto the original meshes (a mesh shared by linked
   duplicates holds the last object's, as playback leaves it).
2. The comparison copy: every compared object made single-user and converted to a mesh (modifiers
   applied: HR_Radiance goes through them as a render sees it), the remaining Principled materials
   (instances, text, curve) without specular (Cycles' reference is diffuse); cycles_ref.prepare,
   shape_proxies at frame 1, two Cycles references (seed per object) at --spp.
3. Our side on the comparison copy (hr_testing.cycles_lights.bake_ours at the scene's quality and
   method, light shapes and Blender lights of frame 1): the texel gather at the texel centres
   (texture output, every texel) and the corner gather interpolated over the loop triangles
   (the machinery's vertex output), and the real bake's HR_Radiance through the modifiers
   (real_vertex): both vertex rows over the unburied texels (benchmarks/unburied.py).
--vertex-spacing S: the room's Vertex Spacing (own_values) set before the bake; the comparison
copy's meshes are then the subdivided ones (the modifier applied), its Cycles references their own.
Per object: the error of the mean (cycles_ref.metrics), over the lit objects
(cycles_ref.lit_objects) the median, the share within 5% and the pooled bias. JSON:
benchmarks/out/<name>_vs_cycles.json.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, ROOT)
import numpy as np  # noqa: E402

from unburied import unburied_texels, visible_texels  # noqa: E402


def log(*a):
    print(*a, flush=True)


def real_bake(path, cache, variant=None):
    """`python -m hr_addon bake path --frames 1` (the scene's settings) into cache; its CPU seconds.
    variant: bias_split.py's VARIANTS entry applied in the bake process (its --bake entry)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = ["-m", "hr_addon"] if variant is None else [os.path.join(HERE, "bias_split.py"), "--bake"]
    env = dict(os.environ, HR_BIAS27_VARIANT=variant or "")
    cmd = [
        sys.executable,
        *run,
        "bake",
        path,
        "--frames",
        "1",
        "--threads",
        "1",
        "--cache-dir",
        cache,
    ]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"the bake failed ({p.returncode}): {p.stderr[-2000:]}")
    log("\n".join(line for line in p.stdout.splitlines() if "warning" in line or "baked frames" in line))
    return (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)


def load_vertex_frame(cache, frame=1):
    """HR_Radiance (FLOAT_COLOR, CORNER) from the bake's frame file on every object it names."""
    import bpy

    z = np.load(os.path.join(cache, f"frame_{frame:06d}.npz"))
    for name in sorted(z.files):
        ob = bpy.data.objects.get(name)
        if ob is None or ob.type != "MESH":
            continue
        me = ob.data
        a = me.color_attributes.get("HR_Radiance") or me.color_attributes.new(
            "HR_Radiance", "FLOAT_COLOR", "CORNER"
        )
        a.data.foreach_set("color", np.asarray(z[name], np.float32).ravel())


def lightmap_images(cache, frame=1):
    """{object: (H, W, 3) float} of a texture bake's frame (its manifest's per-object entries)."""
    import json

    import bpy

    from hr_addon.blender.paths import frame_texture

    objs = json.load(open(os.path.join(cache, "manifest.json")))["objects"]
    out = {}
    for name, info in objs.items():
        path = frame_texture(cache, info, frame)
        if path is None or not os.path.exists(path):
            continue
        img = bpy.data.images.load(path)
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        out[name] = px.reshape(h, w, 4)[..., :3].astype(np.float64)
        bpy.data.images.remove(img)
    return out


def _bilinear(img, uv):
    """img (H, W, 3) at uv (S, 2) as Blender's Linear image texture (texel centres at + 0.5, clamped)."""
    h, w = img.shape[:2]
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]

    def at(i, j):
        return img[np.clip(j, 0, h - 1), np.clip(i, 0, w - 1)]

    return (
        at(x0, y0) * (1 - fx) * (1 - fy)
        + at(x0 + 1, y0) * fx * (1 - fy)
        + at(x0, y0 + 1) * (1 - fx) * fy
        + at(x0 + 1, y0 + 1) * fx * fy
    )


def real_texture(rs, images):
    """{name: (N, 3) per texel}: the real texture bake's image sampled through the converted mesh's
    HR_Lightmap UVs at the atlas's sub-samples (what a render of the helper material shows)."""
    import bpy

    out = {}
    for n in rs.objects:
        me = bpy.data.objects[n].data
        lay = me.uv_layers.get("HR_Lightmap")
        if lay is None or n not in images:
            log(f"  {n}: no lightmap ({'no image' if lay is not None else 'no HR_Lightmap UVs'})")
            continue
        uv = np.empty(len(me.loops) * 2, np.float32)
        lay.uv.foreach_get("vector", uv)
        uv = uv.reshape(-1, 2).astype(np.float64)
        at = rs.atlases[n]
        p = np.einsum("sk,skc->sc", at.s_bary, uv[at.s_loops])
        out[n] = at.texel_mean(_bilinear(images[n], p))
    return out


def applied_copy(names):
    """Single-user meshes with their modifiers applied (Convert to Mesh) for the objects `names`."""
    import bpy

    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for n in names:
        ob = bpy.data.objects[n]
        if ob.data.users > 1:
            ob.data = ob.data.copy()
        ob.select_set(True)
    bpy.context.view_layer.objects.active = bpy.data.objects[names[0]]
    bpy.ops.object.convert(target="MESH")
    for m in bpy.data.materials:  # what stays the user's (instances, text, curve): diffuse only
        if m.node_tree is None:
            continue
        for nd in m.node_tree.nodes:
            if nd.type == "BSDF_PRINCIPLED":
                nd.inputs["Specular IOR Level"].default_value = 0.0


def turn_like_the_bake(names):
    """Flip, in the comparison copy, the polygons of `names` that the bake's orientation check
    (core.orientation.find_reversed) turns around, before the references are made: the reference's
    materials are one-sided (black behind), the user's are not, so a painting hung facing its wall,
    which the bake turns to face the room (Cycles shows its room side lit, as the bake does), would
    otherwise face the room with a black back in the reference and reflect nothing into it.
    Returns {object: polygons flipped}."""
    import bmesh
    import bpy

    from hr_addon.blender.scene_in import collect_geometry
    from hr_addon.core.geometry import prepare_patches
    from hr_addon.core.orientation import find_reversed
    from hr_addon.core.visibility import make_backend

    vl = bpy.context.view_layer
    sin = collect_geometry(vl, vl.depsgraph)
    m = sin.mesh
    patches = prepare_patches(m)
    flip, reasons = find_reversed(patches, make_backend(patches.triangles, "auto", 1))
    polys = np.unique(patches.poly[flip]) if flip.any() else []  # each flipped patch's own polygon
    out = {}
    for p in polys:
        name = m.object_names[int(m.object_id[p])]
        if name not in names:
            continue
        s, k = int(m.loop_start[p]), int(m.loop_total[p])
        c = m.verts[m.loop_verts[s : s + k]].mean(0)
        out.setdefault(name, []).append(c)
    for name, cs in out.items():
        ob = bpy.data.objects[name]
        mw = np.array(ob.matrix_world)
        bm = bmesh.new()
        bm.from_mesh(ob.data)
        bm.faces.ensure_lookup_table()
        cen = np.array([tuple(f.calc_center_median()) for f in bm.faces])
        cen = cen @ mw[:3, :3].T + mw[:3, 3]
        pick = {int(np.argmin(np.linalg.norm(cen - c, axis=1))) for c in cs}
        bmesh.ops.reverse_faces(bm, faces=[bm.faces[i] for i in sorted(pick)])
        bm.to_mesh(ob.data)
        bm.free()
        out[name] = len(pick)
    log(f"turned like the bake (reasons {sorted(set(reasons.values()))}): {out}")
    return out


def real_vertex(rs):
    """{name: (N, 3) per texel} HR_Radiance of the converted meshes interpolated over the loop
    triangles at the atlas's sub-samples (what a render shows of the real bake)."""
    import bpy

    out = {}
    for n in rs.objects:
        me = bpy.data.objects[n].data
        a = me.color_attributes.get("HR_Radiance")
        if a is None or a.domain != "CORNER" or len(a.data) != len(me.loops):
            log(f"  {n}: no corner HR_Radiance after the conversion ({None if a is None else a.domain})")
            continue
        c = np.empty(len(me.loops) * 4, np.float32)
        a.data.foreach_get("color", c)
        c = c.reshape(-1, 4)[:, :3].astype(np.float64)
        at = rs.atlases[n]
        out[n] = at.texel_mean(np.einsum("sk,skc->sc", at.s_bary, c[at.s_loops]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--texel", type=float, default=0.03)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--vertex-cache", help="a frame-1 vertex bake of the same room (skip the real bake)")
    ap.add_argument(
        "--texture-cache", help="a texture bake of the same room (default settings): real_texture"
    )
    ap.add_argument("--name", default="unseen")
    ap.add_argument("--vertex-spacing", type=float, default=0.0, help="the room's Vertex Spacing")
    ap.add_argument("--dump", help="an .npz of per-texel values: texture, real texture, reference, points")
    ap.add_argument("--refs-only", action="store_true", help="bake (and keep) the Cycles references, stop")
    ap.add_argument(
        "--variant",
        choices=("direct",),
        help="direct: our indirect term zeroed (bias_split.py's variant, in the real bake too) against "
        "Cycles bakes with max bounces 0 (references <name>_refb0_...)",
    )
    ap.add_argument(
        "--turned",
        action="store_true",
        help="flip the copy's polygons the bake's orientation check turns (turn_like_the_bake)",
    )
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import bpy

    from hr_testing import artist_room as AR, cycles_lights, cycles_ref as C

    scene, info = AR.artist_room(small=args.small)
    scene.hr.vertex_spacing = args.vertex_spacing
    log(f"room: {info['triangles']} triangles, {len(info['meshes'])} mesh objects")
    tmp = tempfile.mkdtemp(prefix="unseen_")
    cpu_real = None
    cache = args.vertex_cache
    if cache is None:
        path = os.path.join(tmp, "room.blend")
        bpy.ops.wm.save_as_mainfile(filepath=path)
        cache = os.path.join(tmp, "cache")
        cpu_real = real_bake(path, cache, args.variant)
        log(f"real bake (frame 1, vertex): {cpu_real:.0f} s CPU")
    meshes = [n for n in info["meshes"] if n in bpy.data.objects]
    try:  # the bake's helpers (own_values, made in its own process): where its frame file puts values
        from hr_addon.blender.own_values import ensure_own_values

        objs = [bpy.data.objects[n] for n in meshes]
        ensure_own_values(objs, scene.hr.domain, bpy.context.evaluated_depsgraph_get(), args.vertex_spacing)
    except ImportError:  # (before own_values)
        pass
    load_vertex_frame(cache)
    images = {}
    if args.texture_cache:  # the bake's HR_Lightmap UVs (deterministic), carried through the modifiers
        from hr_addon.blender.texture import ensure_lightmaps

        hr = scene.hr  # the bake's sizes: its Texture Size and Texel Density
        ensure_lightmaps([bpy.data.objects[n] for n in meshes], hr.texture_resolution, hr.texel_density)
        images = lightmap_images(args.texture_cache)
    applied_copy(meshes)
    bpy.context.view_layer.update()
    turned = turn_like_the_bake(meshes) if args.turned else {}
    bpy.context.view_layer.update()
    rs = C.prepare(scene, texel=args.texel)
    shapes = C.shape_proxies(rs, 1)
    log(
        f"compared: {len(rs.objects)} objects, {sum(rs.atlases[n].n for n in rs.objects)} texels; "
        f"not compared: {rs.not_compared}"
    )
    refs, ref_cpu = [], []
    bounces = 0 if args.variant == "direct" else 64
    kind = "refb0" if args.variant == "direct" else "ref"
    for seed in (1, 2):
        # kept (git-ignored): the references cost minutes, our side can then run in a fresh process
        path = os.path.join(HERE, "out", f"{args.name}_{kind}_t{args.texel}_s{args.spp}_seed{seed}_po.npz")
        if os.path.exists(path):
            z = np.load(path)
            refs.append({n: z[n].astype(np.float64) for n in rs.objects})
            ref_cpu.append(float(z["__cpu"]))
            log(f"Cycles seed {seed}: cached, {ref_cpu[-1]:.0f} s CPU when baked")
            continue
        vals, dt, mask = C.bake(rs, args.spp, seed=seed, bounces=bounces, seed_per_object=True)
        for n in rs.objects:
            vals[n][~mask[n]] = np.nan
        refs.append(vals)
        ref_cpu.append(dt["cpu"])
        np.savez(path, __cpu=dt["cpu"], **{n: v.astype(np.float32) for n, v in vals.items()})
        log(f"Cycles seed {seed}: {dt['cpu']:.0f} s CPU")
    if args.refs_only:
        return
    ref = {n: (refs[0][n] + refs[1][n]) / 2 for n in rs.objects}
    quality = rs.scene.hr.quality
    if args.variant == "direct":  # as bias_split.patched_bake: emission + rho x direct light
        from hr_addon.core.gather.final import FinalGather

        FinalGather.indirect = lambda self, dyn: 0.0
        FinalGather._incident_by_response = lambda self, dyn: None
        FinalGather._response_parts = lambda self, dyn: None  # the vertex output's path (LoopGather)
    t0 = time.process_time()
    res, cost, binfo = cycles_lights.bake_ours(rs, quality, vertex=True, shapes=shapes)
    cpu_ours = time.process_time() - t0
    real = real_vertex(rs)
    rtex = real_texture(rs, images) if images else {}
    unb = unburied_texels(rs, 5e-5 * rs.diag)
    # the *_visible rows (ctc32): also inside solids whose T-junctions the edge test misses and
    # behind an open plane the object is sunk through (the Crate below the floor); the rows above
    # keep session 26's texels
    vis = visible_texels(rs, 5e-5 * rs.diag)
    lit = C.lit_objects(ref)
    rows = {}
    for n in rs.objects:
        e = res[n]["emission"]
        mask = unb[n]
        row = {
            "texture": C.metrics(res[n]["gather_refl"], ref[n]),
            "vertex": C.metrics(res[n]["gvertex_total"], ref[n] + e, mask),
            "real_vertex": C.metrics(real[n], ref[n] + e, mask) if n in real else None,
            "real_texture": C.metrics(rtex[n], ref[n] + e) if n in rtex else None,
            # the texture rows over the vertex rows' texels (vertex-only errors apart)
            "texture_unburied": C.metrics(res[n]["gather_refl"], ref[n], mask),
            "real_texture_unburied": C.metrics(rtex[n], ref[n] + e, mask) if n in rtex else None,
            "noise": C.noise(refs[0][n], refs[1][n])[1] / np.sqrt(2),
            "texels": rs.atlases[n].n,
            "unburied": float(mask.mean()),
            "vertex_visible": C.metrics(res[n]["gvertex_total"], ref[n] + e, vis[n]),
            "real_vertex_visible": C.metrics(real[n], ref[n] + e, vis[n]) if n in real else None,
            "texture_visible": C.metrics(res[n]["gather_refl"], ref[n], vis[n]),
            "visible": float(vis[n].mean()),
        }
        g = float(np.nanmean(res[n]["gather_refl"])) if np.isfinite(res[n]["gather_refl"]).any() else 0.0
        for k in res[n]:  # each Blender light kind's share of our texel gather's reflected light
            if k.startswith("direct_") and g > 0:
                row[f"share_{k[7:]}"] = float(np.nanmean(res[n][k])) / g
        rows[n] = {k: v for k, v in row.items() if v is not None}
    if args.dump:
        arrays = {}
        for n in rs.objects:
            at = rs.atlases[n]
            arrays[f"{n}/point"] = at.texel_mean(at.s_point)
            arrays[f"{n}/ref"] = ref[n]  # real_texture holds the emission too
            arrays[f"{n}/emission"] = res[n]["emission"]
            arrays[f"{n}/texture"] = res[n]["gather_refl"]
            if n in rtex:
                arrays[f"{n}/real_texture"] = rtex[n]
            if n in real:  # the vertex rows (their texels: unburied)
                arrays[f"{n}/real_vertex"] = real[n]
            arrays[f"{n}/vertex"] = res[n]["gvertex_total"]
            arrays[f"{n}/unburied"] = unb[n]
            arrays[f"{n}/visible"] = vis[n]
            for k in res[n]:  # each Blender light kind's reflected direct light (texel centres)
                if k.startswith("direct_"):
                    arrays[f"{n}/{k}"] = res[n][k]
        np.savez_compressed(args.dump, **arrays)
    summary = {}
    shown = (
        "texture",
        "vertex",
        "real_vertex",
        "real_texture",
        "texture_unburied",
        "real_texture_unburied",
        "vertex_visible",
        "real_vertex_visible",
        "texture_visible",
    )
    for var in shown:
        per = {n: r[var] for n, r in rows.items() if var in r}
        if not per:
            continue
        st = C.object_summary(per, lit)
        summary[var] = st
        worst = sorted((n for n in lit if n in per), key=lambda n: -per[n]["mre"])[:6]
        log(
            f"{var:12s} {st['objects']} lit objects: median {100 * st['median']:.1f}%, within 5% "
            f"{100 * st['within_5']:.0f}%, pooled bias {100 * st['pooled_bias']:+.2f}%, median signed "
            f"{100 * st['median_signed']:+.1f}%; worst: "
            + ", ".join(f"{n} {100 * per[n]['bias']:+.1f}%" for n in worst)
        )
    for n in sorted(rows):
        r = rows[n]
        log(
            f"  {n:26s} texels {r['texels']:6d} lit {n in lit!s:5s} noise {100 * r['noise']:.2f}% "
            + " ".join(
                f"{v} {100 * r[v]['bias']:+6.1f}%"
                for v in ("texture", "vertex", "real_vertex", "real_texture")
                if v in r
            )
        )
    dump = {
        "room": info,
        "texel": args.texel,
        "spp": args.spp,
        "quality": quality,
        "config": binfo["config"],
        "lights": binfo["lights"],
        "lit": lit,
        "summary": summary,
        "objects": rows,
        "not_compared": rs.not_compared,
        "variant": args.variant,
        "turned": turned,
        "cpu_seconds": {
            "real_bake_frame1": cpu_real,
            "ours_on_copy": cpu_ours,
            "cycles_refs": ref_cpu,
            **cost,
        },
    }
    C.write_json(os.path.join(HERE, "out", f"{args.name}_vs_cycles.json"), dump)


if __name__ == "__main__":
    main()
