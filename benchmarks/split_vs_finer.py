"""Vertex Spacing: the bake with the hierarchy on the user's mesh (dec25's split, the default) against
the hierarchy on the finer mesh (before dec25), per object: the direct incident light and the
radiance the gather gives at the objects' corners (docs/accuracy.md, session 23, branch def26).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/split_vs_finer.py \
        sample_blends/furnished.blend split|finer OUT.json [--cache-dir DIR]

Bakes frame 1 of a copy of the file's scene as it is (its Vertex Spacing, draft, one thread;
`finer`: own_values.before_subdivision off, so the hierarchy is built on the subdivided mesh) and
writes per object {name: [mean direct irradiance (3), mean radiance (3), corners]} at the bake's
output corners (FinalGather.direct_and_emission's D through loop_values; loop_radiance)."""

import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def main():
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("blend")
    ap.add_argument("mode", choices=("split", "finer"))
    ap.add_argument("out")
    ap.add_argument("--cache-dir", default=None)
    a = ap.parse_args()
    from hr_testing import blend

    bpy = blend.load_bpy()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(a.blend), load_ui=False)
    from hr_addon.blender import bake as bake_mod
    from hr_addon.blender import own_values

    got = {}
    frame_values = bake_mod._Bake.frame_values

    def spy(self, snap, dyn, final, *args, **kw):
        out = frame_values(self, snap, dyn, final, *args, **kw)
        D, _ = final.direct_and_emission(dyn)
        direct = final.loop_values(np.asarray(D, float), "CORNER")
        total = np.asarray(final.loop_radiance(dyn, "CORNER"), float)
        for t in snap.scene_in.targets:
            x, y = t.extract(direct, "CORNER"), t.extract(total, "CORNER")
            got[t.name] = [np.mean(x, 0).tolist(), np.mean(y, 0).tolist(), len(x)]
        return out

    bake_mod._Bake.frame_values = spy
    if a.mode == "finer":
        own_values.before_subdivision = lambda *args, **kw: {}
    cache = a.cache_dir or os.path.join(os.path.dirname(os.path.abspath(a.out)), f"cache_{a.mode}")
    res = bake_mod.run_bake(
        bpy.context.scene, log=lambda *x, **k: None, frames=(1, 1), threads=1, cache_dir=cache
    )
    json.dump({"patches": int(res.build_report.patches), "objects": got}, open(a.out, "w"))
    print(f"{a.mode}: {res.build_report.patches} patches, {len(got)} objects -> {a.out}")


if __name__ == "__main__":
    main()
