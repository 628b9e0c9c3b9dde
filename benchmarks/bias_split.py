"""Issue 19's -1.5% common to every output, split (branch bias27, docs/gather.md): camera_compare's
furnished views with the product's bake changed one way at a time, against the same Cycles
references (or a direct-light-only Cycles reference for --variant direct).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bias_split.py --variant NAME \
        [--views furnished_wide,furnished_close] [--outputs texture] [--texel 0.02] [--spp 128]
        [--work DIR] [--frame N] [--tag TAG]

Variants (VARIANTS): the bake is `python -m hr_addon bake` run through this file (`--bake`), which
applies the variant's change in the bake process before the command runs:
- direct: the final gather's indirect term zeroed (FinalGather.indirect -> 0, no response
  parts): every output is emission + rho x its exact direct light; compared against a Cycles
  render with no bounces (max bounces 0: direct light only), --direct-spp per seed, seeds 1, 2.
- rays512, rays256: 512 / 256 hemisphere rays per output sample (draft's 128).
- levels1: one level (the hits read the transport's leaves; draft's two levels and 4 iterations);
  levels1medium: the same on the medium transport.
- iter12: two levels, 12 iterations (draft's 4).
- medium: --quality medium (the transport's medium preset with the gather's, 32 shadow rays).
- shadow64: 64 shadow rays per sample and emitter (draft's 16).
- second32: the second level's samples 32 shadow rays each (draft's 16 // 4 -> 8).
- coveredmean: hemisphere hits where the contact test covers them read their leaf's mean
  (covered_hits="shown") instead of 0.
- shadow003, shadow01: the draft transport's shadow_feps 0.003 / 0.01 (GATHER_TRANSPORT's 0.03;
  branch ind28: V's darkness, benchmarks/transport_split.py).
- none: the product's bake unchanged (the baseline beside the others on the same code).
- rafterinside (hr_testing/loft.py only, a diagnostic: docs/accuracy.md, session 38, branch
  loftdx38): points strictly inside the loft's two rafters (the ceiling under their sunk 2 cm)
  covered (Hierarchy.dark), as the product's contact test does not find them: the second level's
  samples there no longer read ~0 into the ceiling's leaf means and near hits.
- tail: the second level's passes read at their limit (FinalGather._tail, the geometric series of
  the last change) in every evaluation, not only with a light shape's gathered light (main
  before branch bias27; since its commit the default, so a no-op).
Each variant's bake and renders go to camera_work/furnished/<output>[_texel]_<variant>/ and
camera_work/<view>[_texel..]_<variant>/; JSON benchmarks/out/camera_bias27_<variant>.json (the
compare() figures as camera_compare writes them).
"""

import argparse
import json
import os
import subprocess
import sys


HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

VARIANTS = {
    "direct": dict(patch="direct"),
    "rays512": dict(gather=dict(rays=512)),
    "rays256": dict(gather=dict(rays=256)),
    "levels1": dict(gather=dict(levels=1, iterations=0)),
    "levels1medium": dict(gather=dict(levels=1, iterations=0), args=["--quality", "medium"]),
    "iter12": dict(gather=dict(iterations=12)),
    "medium": dict(args=["--quality", "medium"]),
    "shadow64": dict(gather=dict(shadow_rays=64)),
    "tail": dict(patch="tail"),
    "second32": dict(gather=dict(second_shadow_rays=32)),
    "coveredmean": dict(gather=dict(covered_hits="shown")),
    "shadow003": dict(transport=dict(shadow_feps=0.003)),
    "shadow01": dict(transport=dict(shadow_feps=0.01)),
    "rafterinside": dict(patch="rafterinside"),
    "none": dict(),
}


def rafter_inside(points):
    """(N,) True where world points lie strictly inside one of hr_testing/loft.py's two rafters (x
    within its 12 cm, from 2 cm above the slope it is sunk into to 14 cm below it)."""
    import math

    import numpy as np

    from hr_testing import loft

    a = math.radians(loft.TURN)
    q = np.asarray(points, float).reshape(-1, 3) - np.asarray(loft.ORIGIN)
    x = q[:, 0] * math.cos(a) + q[:, 1] * math.sin(a)
    y = -q[:, 0] * math.sin(a) + q[:, 1] * math.cos(a)
    cos = loft.YK / math.hypot(loft.YK, loft.HH - loft.HL)  # the slope's
    d = (loft.HL + y * (loft.HH - loft.HL) / loft.YK - q[:, 2]) * cos  # below the slope
    rx = (np.abs(x - 1.2) < 0.06 - 1e-4) | (np.abs(x - 4.6) < 0.06 - 1e-4)
    return rx & (y > 0) & (y < loft.YK) & (d > -0.02 + 1e-4) & (d < 0.14 - 1e-4)


def patched_bake(argv):
    """Run `python -m hr_addon bake argv` with the variant in HR_BIAS27_VARIANT applied."""
    v = VARIANTS[os.environ["HR_BIAS27_VARIANT"]]
    from hr_addon.blender import settings

    for q in settings.GATHER:
        settings.GATHER[q].update(v.get("gather", {}))
    if "transport" in v:  # the draft transport's preset (RefineParams.for_gather), one field changed
        from hr_addon.core import params

        params.GATHER_TRANSPORT["draft"].update(v["transport"])
    if v.get("patch") == "direct":
        from hr_addon.core.gather.final import FinalGather

        FinalGather.indirect = lambda self, dyn: 0.0
        FinalGather._incident_by_response = lambda self, dyn: None
        FinalGather._response_parts = lambda self, dyn: None  # the vertex output's path (LoopGather)
    if v.get("patch") == "rafterinside":
        from hr_addon.core.hierarchy import Hierarchy

        dark = Hierarchy.dark

        def covered(self, leaf, points, threads=None, boxes=None):
            return dark(self, leaf, points, threads, boxes) | rafter_inside(points)

        Hierarchy.dark = covered
    if v.get("patch") == "tail":
        from hr_addon.core.gather.final import FinalGather

        levels = FinalGather._levels

        def _levels(self, V, direct, tail=False, *a, **k):  # the passes' limit (their tail) everywhere
            return levels(self, V, direct, True, *a, **k)

        FinalGather._levels = _levels
    from hr_addon.__main__ import main

    sys.exit(main(argv))


def main():
    import camera_compare as cc

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--variant", required=True, choices=sorted(VARIANTS))
    p.add_argument("--views", default="furnished_wide,furnished_close")
    p.add_argument("--outputs", default="texture")
    p.add_argument("--texel", type=float, default=0.02, help="0: the bake's own Texel Density")
    p.add_argument("--spp", type=int, default=128)
    p.add_argument("--direct-spp", type=int, default=32)
    p.add_argument("--work", help="camera_compare's work folder (its --work)")
    p.add_argument("--frame", type=int, help="this frame instead of the views' own (camera_compare --frame)")
    p.add_argument("--tag", help="the JSON's name: camera_<tag>.json (bias27_<variant>)")
    a = p.parse_args()
    var = VARIANTS[a.variant]
    tag = a.tag or f"bias27_{a.variant}"
    if a.work:
        cc.WORK = a.work

    def bake(scene, frame, output):
        d = os.path.join(
            cc.WORK,
            scene,
            output
            + (f"_{a.texel}" if output == "texture" and a.texel else "")
            + f"_{a.variant}"
            + (f"_f{frame}" if frame != 1 else ""),
        )
        saved = os.path.join(d, "baked.blend")
        if os.path.exists(saved):
            return saved, json.load(open(saved + ".json")).get("cpu")
        os.makedirs(d, exist_ok=True)
        src = os.path.join(d, f"{scene}.blend")
        import shutil

        shutil.copy(cc.source_blend(scene), src)
        if output == "texture" and a.texel:  # --texel 0: the bake's own Texel Density
            cc.lightmap_sizes(src, a.texel)
        cmd = [
            sys.executable,
            os.path.abspath(__file__),
            "--bake",
            "bake",
            src,
            "--frames",
            f"{frame}-{frame}",
        ]
        cmd += ["--quality", "draft", "--output", output, "--threads", "1", "--save", saved]
        cmd += var.get("args", [])
        c0 = cc.cpu(True)
        cc.log(" ".join(cmd[1:]))
        env = dict(os.environ, HR_BIAS27_VARIANT=a.variant)
        r = subprocess.run(cmd, cwd=cc.ROOT, capture_output=True, text=True, env=env)
        print(r.stdout[-1500:], r.stderr[-1500:], flush=True)
        if r.returncode:
            raise RuntimeError(f"bake failed ({r.returncode})")
        dt = cc.cpu(True) - c0
        json.dump({"cpu": dt}, open(saved + ".json", "w"))
        return saved, dt

    def reference_direct(view, names, spp, seed, path):
        from hr_testing import cycles_ref as C
        from hr_testing.blend import load_bpy

        bpy = load_bpy()
        bpy.ops.wm.open_mainfile(filepath=cc.source_blend(view["scene"]), load_ui=False)
        scene = bpy.context.scene
        rs = C.prepare(scene, only=())
        C.shape_proxies(rs, view["frame"])
        cc.set_camera(bpy, scene, view)
        cc.pass_indices(bpy, names)
        return cc.render(bpy, scene, path, spp, seed, 0)

    path = os.path.join(cc.OUT, f"camera_{tag}.json")
    dump = json.load(open(path)) if os.path.exists(path) else {"views": {}}
    for vn0 in a.views.split(","):
        view = cc.VIEWS[vn0]
        if a.frame and a.frame != view["frame"]:
            view = dict(view, frame=a.frame)
            vn0 = f"{vn0}_f{a.frame}"
        names = cc.geometry_names(view)
        wd = os.path.join(cc.WORK, vn0)
        vn = f"{vn0}_{a.variant}"
        bakes = {k: bake(view["scene"], view["frame"], k) for k in a.outputs.split(",")}
        r, cpu_s = {"names": names}, {}
        wo = os.path.join(cc.WORK, vn)
        os.makedirs(wo, exist_ok=True)
        for i, seed in enumerate(cc.SEEDS):
            if a.variant == "direct":
                exr = os.path.join(wd, f"ref_direct_s{a.direct_spp}_seed{seed}.exr")
                if not os.path.exists(exr):
                    dt = reference_direct(view, names, a.direct_spp, seed, exr)[2]
                    json.dump({"cpu": dt}, open(exr + ".json", "w"))
                    cc.log(f"[{vn}] Cycles direct only {a.direct_spp} spp seed {seed}: {dt:.0f} s CPU")
            else:
                exr = os.path.join(wd, f"ref_s{a.spp}_seed{seed}.exr")
            r[f"ref{i + 1}"] = cc.read_render(exr)
            cpu_s[f"ref_seed{seed}"] = json.load(open(exr + ".json"))["cpu"]
        for k, (saved, bake_cpu) in bakes.items():
            exr = os.path.join(wo, f"ours_{k}.exr")
            if not os.path.exists(exr):
                dt = cc.ours(view, names, saved, cc.OURS_SPP, exr)[2]
                json.dump({"cpu": dt}, open(exr + ".json", "w"))
                cc.log(f"[{vn}] ours ({k}) rendered: {dt:.0f} s CPU")
            r[k] = cc.read_render(exr)
            cpu_s[f"ours_{k}_render"] = json.load(open(exr + ".json"))["cpu"]
            cpu_s[f"bake_{k}"] = bake_cpu
        res = cc.compare(vn, r)
        res.update(view=view, variant=a.variant, cpu_seconds=cpu_s)
        cc.save_view(vn, r, bakes, names, res, dump, path)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--bake":
        patched_bake(sys.argv[2:])
    else:
        main()
