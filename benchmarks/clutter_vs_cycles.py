"""The clutter room (hr_testing/clutter.py: clutter sunk into clutter, a 64-segment pillar near two
walls) against Cycles per object, as tests/test_cycles_clutter.py at finer settings: texels of
TEXEL, Cycles at SPP, two seeds (their mean the reference, their spread its noise); ours the bake's
path (cycles_lights.bake_ours, FE, final gather on) at draft and medium:

- texture: the texel gather, every texel;
- vertex: the corner gather (LoopGather) interpolated over the loop triangles, fully visible
  texels (no sub-sample inside another solid: clutter.visible_texels);
- vertex_unmoved: the same with the corners' buried samples left where they are
  (gather/layouts.UNCOVER empty: the output before the samples were moved);
- vertex_nofit: the corners' samples averaged, not shifted (layouts.FIT False: before branch vfit);
- vertex_other: the faces' shifts on the other set of faces than corner_fit.EVERY's (every face,
  or the cut ones alone);
- leaves: the hierarchy's leaves (reflected), every texel.

    .venv/bin/python benchmarks/clutter_vs_cycles.py [--spp 256] [--texel 0.02]

Prints ours / Cycles - 1 per object and variant, the reference's noise, CPU seconds; writes
benchmarks/out/clutter_vs_cycles.json.
"""

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
import numpy as np  # noqa: E402

from hr_testing import clutter as CL, cycles_lights, cycles_ref as C  # noqa: E402
from hr_testing.blend import mesh_scene  # noqa: E402


COLUMNS = ("texture", "vertex", "vertex_other", "vertex_nofit", "vertex_unmoved", "leaves")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--texel", type=float, default=0.02)
    ap.add_argument("--json", default="clutter_vs_cycles.json", help="under benchmarks/out/")
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from hr_addon.core.gather import layouts

    mesh, info = CL.clutter_room()
    scene = mesh_scene(mesh)
    rs = C.prepare(scene, texel=args.texel, only=CL.COMPARED)
    refs, cyc_cpu = [], []
    for seed in (1, 2):
        vals, dt, mask = C.bake(rs, args.spp, seed=seed)
        for n in rs.objects:
            vals[n][~mask[n]] = np.nan
        refs.append(vals)
        cyc_cpu.append(dt["cpu"])
    ref = {n: (refs[0][n] + refs[1][n]) / 2 for n in rs.objects}
    visible = {n: CL.visible_texels(rs.atlases[n], n, info["solids"]) for n in rs.objects}
    texels = {n: rs.atlases[n].n for n in rs.objects}
    print(
        f"clutter room: {info['triangles']} triangles; texel {args.texel} m: {texels}; Cycles {args.spp} spp "
        f"x 2 seeds, CPU {cyc_cpu[0]:.1f} + {cyc_cpu[1]:.1f} s",
        flush=True,
    )
    noise = {n: cycles_lights._noise_of_mean([refs[0][n], refs[1][n]]) for n in rs.objects}
    txt = ", ".join(f"{n} {100 * v:.2f}%" for n, v in noise.items())
    print("  reference noise of an object mean: " + txt)
    dump = {
        "every": layouts.corner_fit.EVERY,
        "spp": args.spp,
        "texel": args.texel,
        "texels": texels,
        "cycles_cpu_s": cyc_cpu,
        "noise": noise,
    }
    moves = layouts.UNCOVER
    for q in ("DRAFT", "MEDIUM"):
        layouts.UNCOVER, layouts.FIT = (), False
        c0 = time.process_time()
        before = cycles_lights.bake_ours(rs, q, method="FE", vertex=True)[0]
        layouts.UNCOVER, layouts.FIT = moves, False
        nofit = cycles_lights.bake_ours(rs, q, method="FE", vertex=True)[0]
        layouts.FIT, every = True, layouts.corner_fit.EVERY
        layouts.corner_fit.EVERY = not every
        other = cycles_lights.bake_ours(rs, q, method="FE", vertex=True)[0]
        layouts.corner_fit.EVERY = every
        c1 = time.process_time()
        res, cost, _ = cycles_lights.bake_ours(rs, q, method="FE", vertex=True)
        c2 = time.process_time()
        rows = {}
        for n in rs.objects:
            vis = visible[n]
            rows[n] = {
                "texture": C.metrics(res[n]["gather_refl"], ref[n])["bias"],
                "vertex": C.metrics(res[n]["gvertex_total"], ref[n], vis)["bias"],
                "vertex_unmoved": C.metrics(before[n]["gvertex_total"], ref[n], vis)["bias"],
                "vertex_nofit": C.metrics(nofit[n]["gvertex_total"], ref[n], vis)["bias"],
                "vertex_other": C.metrics(other[n]["gvertex_total"], ref[n], vis)["bias"],
                "leaves": C.metrics(res[n]["leaf_refl"], ref[n])["bias"],
                "visible": float(vis.mean()),
            }
        print(
            f"{q.lower()} FE: ours CPU {c2 - c1:.1f} s (build {cost['build_s']:.1f}, texel gather "
            f"{cost['texel_precompute_s']:.1f}, loop gather {cost['loop_precompute_s']:.1f}; unmoved run "
            f"{c1 - c0:.1f} s, of it the unmoved, unfitted and other runs)"
        )
        head = ("object", "visible", "texture", "vertex", "other", "nofit", "unmoved", "leaves")
        print(f"  {head[0]:14s} " + " ".join(f"{h:>8s}" for h in head[1:]))
        for n, r in rows.items():
            print(
                f"  {n:14s} {100 * r['visible']:7.0f}% " + " ".join(f"{100 * r[k]:+7.2f}%" for k in COLUMNS)
            )
        dump[q.lower()] = {"objects": rows, "cost": cost}
    C.write_json(os.path.join(HERE, "out", args.json), dump)


if __name__ == "__main__":
    main()
