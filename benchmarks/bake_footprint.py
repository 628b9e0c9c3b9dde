"""Where Cycles' Diffuse/Emit bake samples each texel, against the footprint the comparisons assume
(core.gather.bakepoints: the middle half of the texel, uniform over its part inside the
centre's triangle; before 2026-12-03 folded into it by mirror repeat, as Cycles 3.x did). On the
Cornell back wall (texel 1/56 of the diagonal, cycles_ref's atlas), two seeds:
- Position bake at --spp: each texel's mean sample against the footprint's mean, in texels along
  the texel's sides (mean, spread, and the two seeds' correlation: a placement error that is the
  same at every seed does not show in the seeds' spread);
- Emit bake of a clamped linear ramp (width one texel) across the wall, x + kz = c for each
  (c, k) of RAMPS: Cycles' texel against the ramp's exact mean over the footprint (32 x 32
  points) on the texels it crosses, root mean square and worst, the seeds' spread, and the
  texel centres' value for scale.

Run: .venv/bin/python benchmarks/bake_footprint.py [--spp 1024]   (about 1 min; writes
benchmarks/out/bake_footprint.json)"""

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
RAMPS = ((0.30, 0.0), (0.40, 1.0), (0.20, 0.3))  # (c, k): the ramp's foot x + k z = c (m)
WIDTH = 0.017  # m, about one texel


def _bake(rs, ob, kind, spp, seed):
    import bpy

    from hr_testing import cycles_ref as C

    at, img = rs.atlases[ob.name], rs.images[ob.name]
    C.configure_cycles(rs.scene, spp, seed=seed)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob
    C.clear_image(img)
    bpy.ops.object.bake(type=kind, margin=0, use_clear=False, target="IMAGE_TEXTURES")
    px = np.empty(at.width * at.height * 4, np.float32)
    img.pixels.foreach_get(px)
    cen = np.flatnonzero(at.s_centre)
    return px.reshape(at.height, at.width, 4)[at.ty, at.tx, :3].astype(float)[at.s_texel[cen]]


def _ramp_material(image, c, k):
    """Emission strength clamp((x + k z - c) / WIDTH, 0, 1), and the bake's target image node."""
    import bpy

    m = bpy.data.materials.new("ramp")
    if bpy.app.version < (5, 0, 0):
        m.use_nodes = True
    t = m.node_tree
    t.nodes.clear()
    n = t.nodes.new
    geo, sep, mz, add, sub, div = (
        n("ShaderNodeNewGeometry"),
        n("ShaderNodeSeparateXYZ"),
        *(n("ShaderNodeMath") for _ in range(4)),
    )
    mz.operation, add.operation, sub.operation, div.operation = "MULTIPLY", "ADD", "SUBTRACT", "DIVIDE"
    mz.inputs[1].default_value, sub.inputs[1].default_value, div.inputs[1].default_value = k, c, WIDTH
    div.use_clamp = True
    em, out = n("ShaderNodeEmission"), n("ShaderNodeOutputMaterial")
    for a, b in (
        (geo.outputs["Position"], sep.inputs[0]),
        (sep.outputs["Z"], mz.inputs[0]),
        (sep.outputs["X"], add.inputs[0]),
        (mz.outputs[0], add.inputs[1]),
        (add.outputs[0], sub.inputs[0]),
        (sub.outputs[0], div.inputs[0]),
        (div.outputs[0], em.inputs["Strength"]),
        (em.outputs[0], out.inputs["Surface"]),
    ):
        t.links.new(a, b)
    tex = n("ShaderNodeTexImage")
    tex.image = image
    t.nodes.active = tex
    return m


def main(spp):
    import bpy

    from hr_addon.core.gather.bakepoints import texel_points
    from hr_testing import cycles_ref as C
    from hr_testing.blend import load_bpy, open_sample

    load_bpy()
    open_sample("cornell", tempfile.mkdtemp())
    rs = C.prepare(bpy.context.scene, texel_rel=1 / 56)
    ob = bpy.data.objects["back"]
    at = rs.atlases["back"]
    cen = np.flatnonzero(at.s_centre)
    axes = at.s_axes[cen]
    k = 32
    f = (np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2) + 0.5) / k
    pts = texel_points(at.s_point[cen], axes, at.s_tri[cen], np.broadcast_to(f, (len(cen),) + f.shape))
    ours = (at.s_point[cen] + (spp - 1) * pts.mean(1)) / spp  # Cycles' first sample is the centre
    offs = []
    for seed in (1, 2):
        p = _bake(rs, ob, "POSITION", spp, seed)
        p /= 1.0 if abs(np.sum(p * ours) / np.sum(ours * ours) - 1) < 0.02 else spp  # 5.0: summed
        d = p - ours
        offs.append(np.stack([(d * axes[:, i]).sum(1) / (axes[:, i] ** 2).sum(1) for i in (0, 1)], 1))
    a, b = offs
    res = {
        "spp": spp,
        "texels": len(cen),
        "offset_mean_uv": a.mean(0).round(4).tolist(),
        "offset_spread_uv": a.std(0).round(4).tolist(),
        "seeds_correlation_uv": [round(float(np.corrcoef(a[:, i], b[:, i])[0, 1]), 3) for i in (0, 1)],
        "ramps": [],
    }
    print(
        f"position, {len(cen)} texels, {spp} spp: mean sample - footprint's mean, texels: "
        f"mean u {a[:, 0].mean():+.4f} v {a[:, 1].mean():+.4f}, spread u {a[:, 0].std():.4f} "
        f"v {a[:, 1].std():.4f}; seeds' correlation u {np.corrcoef(a[:, 0], b[:, 0])[0, 1]:.3f} "
        f"v {np.corrcoef(a[:, 1], b[:, 1])[0, 1]:.3f}",
        flush=True,
    )
    slots = list(ob.material_slots)
    for c, kz in RAMPS:
        m = _ramp_material(rs.images["back"], c, kz)
        for s in slots:
            s.material = m
        v = [_bake(rs, ob, "EMIT", spp, seed)[:, 0] for seed in (1, 2)]
        exact = np.clip((pts[..., 0] + kz * pts[..., 2] - c) / WIDTH, 0, 1).mean(1)
        centre = np.clip((at.s_point[cen, 0] + kz * at.s_point[cen, 2] - c) / WIDTH, 0, 1)
        r = (exact > 1e-3) & (exact < 1 - 1e-3)
        cy = (v[0] + v[1]) / 2

        def rms(x):
            return float(np.sqrt(np.mean(x[r] ** 2)))

        res["ramps"].append(
            {
                "c": c,
                "k": kz,
                "texels": int(r.sum()),
                "cycles_vs_exact_rms": round(rms(cy - exact), 4),
                "cycles_vs_exact_worst": round(float(np.abs(cy - exact)[r].max()), 4),
                "seeds_spread": round(rms((v[0] - v[1]) / 2), 4),
                "centres_vs_exact_rms": round(rms(centre - exact), 4),
            }
        )

        print(
            f"emit ramp x + {kz:g} z = {c:g} m, {r.sum()} texels: "
            f"Cycles - exact mean rms {rms(cy - exact):.4f} "
            f"(worst {np.abs(cy - exact)[r].max():.4f}), seeds' spread {rms((v[0] - v[1]) / 2):.4f}, "
            f"texel centres - exact mean {rms(centre - exact):.4f} (of the ramp's height 1)",
            flush=True,
        )
    return res


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    a = sys.argv[1:]
    out = main(int(a[a.index("--spp") + 1]) if "--spp" in a else 1024)
    with open(Path(__file__).resolve().parent / "out" / "bake_footprint.json", "w") as fh:
        json.dump(out, fh, indent=1)
