"""A box sunk into a floor plane: what its side faces' corners below the floor show.

The artist room's Crate (a 0.5 m cube sunk 5 cm into the floor) read +7.6% against Cycles with the
finer corners' samples at inset 0.5 and -10.7% at 0.36 (docs/accuracy.md, vx27). This reproduces
it on a plane, a cube and a point light: at the default Vertex Spacing each side's lower finer face
spans the floor line; its lower corners' samples lie at 12.5 x inset - 5 cm against the floor
(inset 0.5: 1.25 cm above it; 0.36: 0.5 cm below). Below it, `layouts._buried` did not call them
buried before session 24's bur27 (only about half their probe rays hit the floor's back face: the
rest escape below it, and buried needed 3/4 back faces), so they stayed, gathered almost nothing,
and their corners read 0: the visible part of the face shaded to black at the floor (a false
contact shadow 20 cm tall). Now they are moved above the floor (lower corners 0.000 -> 0.251).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/sunk_box.py [--insets 0.5,0.36]

Prints, per inset, the lower side faces' corner values (red) and the mean of the corners below
the floor against those on the middle line (local z 0). One process per inset (the precompute is
keyed by the code's files, not by a constant changed at run time: each run bakes in its own folder).
"""

import argparse
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def one(inset, folder):
    import numpy as np

    sys.path.insert(0, ROOT)
    from hr_addon.core.gather import layouts

    layouts.OUTPUT_INSET = inset
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy = load_bpy()
    scene = bpy.context.scene
    scene.frame_start = scene.frame_end = 1
    bpy.ops.mesh.primitive_plane_add(size=4, location=(0, 0, 0))
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(0.3, 0.2, 0.2))  # 5 cm below the floor
    cube = bpy.context.object
    light = bpy.data.lights.new("Light", "POINT")
    light.energy = 200
    lo = bpy.data.objects.new("Light", light)
    lo.location = (1.5, -1.0, 2.0)
    scene.collection.objects.link(lo)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, "sunk_box.blend"))
    from hr_addon.blender.bake import run_bake

    run_bake(scene, log=lambda *a, **k: None, frames=(1, 1), quality="draft")
    me = cube.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    att = me.attributes["HR_Radiance"]
    v = np.empty(len(att.data) * 4, np.float32)
    att.data.foreach_get("color", v)
    red = v.reshape(-1, 4)[:, 0]
    below, line = [], []
    for p in me.polygons:
        if abs(p.normal[2]) < 0.5 and p.center[2] < 0:  # a side's lower row (local z)
            z = [me.vertices[me.loops[i].vertex_index].co[2] for i in p.loop_indices]
            vals = [float(red[i]) for i in p.loop_indices]
            print(
                f"inset {inset}: face at {tuple(round(c, 3) for c in p.center)}: corners",
                [round(x, 4) for x in vals],
            )
            below += [x for x, h in zip(vals, z) if h < -0.2]
            line += [x for x, h in zip(vals, z) if abs(h) < 1e-6]
    print(
        f"inset {inset}: corners below the floor {np.mean(below):.4f}, on the middle line {np.mean(line):.4f}"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--insets", default="0.5,0.36")
    ap.add_argument("--one", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--folder", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one is not None:
        return one(a.one, a.folder)
    for inset in a.insets.split(","):
        with tempfile.TemporaryDirectory() as folder:
            subprocess.run([sys.executable, __file__, "--one", inset, "--folder", folder], check=True)


if __name__ == "__main__":
    main()
