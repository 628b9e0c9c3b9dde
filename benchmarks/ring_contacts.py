"""The lightmap ring's rule on a real texture bake of the artist room, without baking again
(docs/accuracy.md, *Texels along contacts*, session 20, branch ring).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/ring_contacts.py \
        --texture-cache DIR --dump FILE.npz [--texel 0.035] [--name ring]

DIR: a texture bake of the room (default settings); FILE: unseen_vs_cycles.py's --dump of the same
room (reference, emission, texel gather, points per reference texel). The bake's images hold the
values of every planned texel; the ring rule reads only the inside texels' values, so each image
is rewritten here from its own inside texels (plan.ObjectTexels.image) as the bake would write it
with the rule: `point` (the island point's value: the images as baked, as a check), `copy` (the
nearest inside texel's value) and `line` (this branch: the inside texels' line carried out). Each
is read as a render reads it (unseen_vs_cycles.real_texture) and compared with Cycles per object
(over the lit objects: median, share within 5%) and with the texel gather by distance to the Room
box's edges (the floor's contacts with the walls, the Room's own corners).
JSON: benchmarks/out/<name>_contacts.json.
"""

import argparse
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, ROOT)
import numpy as np  # noqa: E402

import unseen_vs_cycles as U  # noqa: E402

RULES = ("point", "copy", "line")
COUNTS = {"texels": 0, "ring": 0, "ring_from_inside": 0}  # over the images rewritten (all rules)
BANDS = (0.0, 0.02, 0.05, 0.10, np.inf)  # distance to the Room box's nearest edge (m)


def rewrite(me, img, rule):
    """The bake's image `img` (res, res, 3) rewritten from its inside texels with the ring `rule`."""
    from hr_addon.lightmap.plan import ObjectTexels
    from hr_addon.lightmap.raster import dilation_steps, rasterise, ring_sources

    res = img.shape[0]
    me.calc_loop_triangles()
    tl = np.empty(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("loops", tl)
    uv = np.empty(len(me.loops) * 2, np.float32)
    me.uv_layers["HR_Lightmap"].uv.foreach_get("vector", uv)
    tri_uv = uv.reshape(-1, 2).astype(np.float64)[tl.reshape(-1, 3)]
    texel, tri, bary, inside = rasterise(tri_uv, res)
    edge = np.einsum("nk,nkj->nj", bary, tri_uv[tri] * res - 0.5)
    ring = ring_sources(texel, inside, edge, res)
    if rule == "copy":
        ring = ring[:3] + (np.zeros_like(ring[3]),)
    COUNTS["texels"] += len(texel)
    COUNTS["ring"] += int((~inside).sum())
    COUNTS["ring_from_inside"] += len(ring[0])
    o = ObjectTexels("", res, "", texel, inside, 0, len(texel), dilation_steps(texel, res), "", None)
    o.ring = None if rule == "point" else ring
    return o.image(img.reshape(-1, 3)[texel]).astype(np.float64)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--texture-cache", required=True)
    ap.add_argument("--dump", required=True)
    ap.add_argument("--texel", type=float, default=0.035)
    ap.add_argument("--name", default="ring")
    args = ap.parse_args()
    import bpy

    from hr_addon.blender.texture import ensure_lightmaps
    from hr_testing import artist_room as AR, cycles_ref as C

    scene, info = AR.artist_room()
    meshes = [n for n in info["meshes"] if n in bpy.data.objects]
    hr = scene.hr
    ensure_lightmaps([bpy.data.objects[n] for n in meshes], hr.texture_resolution, hr.texel_density)
    baked = U.lightmap_images(args.texture_cache)
    U.applied_copy(meshes)
    bpy.context.view_layer.update()
    rs = C.prepare(scene, texel=args.texel)
    z = np.load(args.dump)
    room = bpy.data.objects["Room"]
    corners = np.array([room.matrix_world @ v.co for v in room.data.vertices])
    lo, hi = corners.min(0), corners.max(0)
    ref = {n: z[f"{n}/ref"] + z[f"{n}/emission"] for n in rs.objects}
    gather = {n: z[f"{n}/texture"] + z[f"{n}/emission"] for n in rs.objects}
    lit = C.lit_objects({n: z[f"{n}/ref"] for n in rs.objects})
    out = {"texel": args.texel, "lit": lit, "rules": {}}
    for rule in RULES:
        images = {n: rewrite(bpy.data.objects[n].data, img, rule) for n, img in baked.items()}
        if rule == "point":
            out["point_rewrite_max_change"] = max(float(np.abs(images[n] - baked[n]).max()) for n in baked)
        real = U.real_texture(rs, images)
        if rule == "point":  # the dump's real texture, read from the same images by the benchmark
            diff = [np.abs(real[n] - z[f"{n}/real_texture"]) for n in real if f"{n}/real_texture" in z]
            out["point_vs_dump_max"] = max(float(np.nanmax(d)) for d in diff if d.size)
            U.log({n: float(np.nanmax(d)) for n, d in zip(real, diff) if d.size and np.nanmax(d) > 1e-4})
        per = {n: C.metrics(real[n], ref[n]) for n in real}
        per = {n: m for n, m in per.items() if m is not None}
        st = C.object_summary(per, lit)
        bands = {}
        for n in ("Floor", "Room"):
            p = z[f"{n}/point"]
            d = np.sort(np.minimum(p - lo, hi - p), 1)[:, 1]  # the second axis: its own face's edge
            for b0, b1 in zip(BANDS[:-1], BANDS[1:]):
                m = (d >= b0) & (d < b1) & np.isfinite(real[n]).all(1) & np.isfinite(gather[n]).all(1)
                bands[f"{n} {100 * b0:g}-{100 * b1:g} cm"] = {
                    "texels": int(m.sum()),
                    "real_over_gather": float(real[n][m].sum() / gather[n][m].sum()),
                }
        out["rules"][rule] = {
            "summary": st,
            "bias": {n: per[n]["bias"] for n in sorted(per)},
            "bands": bands,
        }
        U.log(
            f"{rule:6s} lit {st['objects']}: median {100 * st['median']:.2f}%, within 5% "
            f"{100 * st['within_5']:.0f}%, pooled bias {100 * st['pooled_bias']:+.2f}%; "
            + ", ".join(f"{k} {v['real_over_gather']:.3f} ({v['texels']})" for k, v in bands.items())
        )
    out["counts_per_rule"] = {k: v // len(RULES) for k, v in COUNTS.items()}
    U.log(out["counts_per_rule"], "point rewrite:", out["point_rewrite_max_change"], out["point_vs_dump_max"])
    with open(os.path.join(HERE, "out", f"{args.name}_contacts.json"), "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
