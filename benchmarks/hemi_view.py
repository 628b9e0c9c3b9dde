"""What a point of the loft sees over its hemisphere, Cycles against our bake (issue 19, the loft's
Rafter 0, docs/accuracy.md, session 38, branch loftdx38): camera_compare's reference / ours renders
from a 180-degree equisolid fisheye camera (every pixel the same solid angle) at a point (room frame)
looking along a normal; the cosine-weighted mean of each render is the incident light there (/ pi).

    nice -n 19 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/hemi_view.py --work WORK \
        --at X,Y,Z --normal NX,NY,NZ [--ours BAKED.blend] [--spp 256] [--seed 1] [--res 200] --out OUT
(WORK: camera_compare's work folder holding loft/loft.blend; OUT.npz: rgb, index, names)
"""

import argparse
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))

import camera_compare as CC  # noqa: E402


def weights(res):
    """(res, res) cos(theta) of an equisolid 180-degree fisheye's pixels inside its circle, else 0."""
    c = (np.arange(res) + 0.5) / res * 2 - 1
    r = np.hypot(*np.meshgrid(c, c))  # r = sin(theta / 2) / sin(pi / 4)
    s = np.clip(r * math.sin(math.pi / 4), 0, 1)
    return np.where(r <= 1, 1 - 2 * s * s, 0.0)  # cos(theta) = 1 - 2 sin^2(theta / 2)


def main():
    from hr_testing.loft import TURN, _world

    p = argparse.ArgumentParser()
    p.add_argument("--work", required=True)
    p.add_argument("--at", required=True)
    p.add_argument("--normal", required=True)
    p.add_argument("--ours")
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--res", type=int, default=200)
    p.add_argument("--out", required=True)
    a = p.parse_args()
    CC.WORK = a.work
    at = np.array([float(v) for v in a.at.split(",")])
    n = np.array([float(v) for v in a.normal.split(",")])
    cam, tgt = _world(tuple(at)), _world(tuple(at + n))
    view = dict(scene="loft", frame=1, camera=(cam, tgt, 35.0), res=(a.res, a.res))
    set_camera = CC.set_camera

    def fisheye(bpy, scene, view):
        set_camera(bpy, scene, view)
        c = scene.camera.data
        c.type = "PANO"
        c.panorama_type = "FISHEYE_EQUISOLID"
        c.fisheye_fov = math.pi
        c.sensor_fit = "HORIZONTAL"
        c.sensor_width = c.sensor_height = c.fisheye_lens * 4 * math.sin(math.pi / 4)
        c.clip_start = 1e-4

    CC.set_camera = fisheye
    names = CC.geometry_names(view)
    if a.ours:
        rgb, ob, dt = CC.ours(view, names, a.ours, 64, a.out + ".exr")
    else:
        rgb, ob, dt = CC.reference(view, names, a.spp, a.seed, a.out + ".exr")[:3]
    w = weights(a.res)
    E = (rgb * w[..., None]).sum((0, 1)) / w.sum()
    print("turn", TURN, "incident / pi (rgb)", E, "cpu", dt, flush=True)
    rgb, ob = rgb.astype(np.float32), ob.astype(np.int32)
    np.savez_compressed(a.out, rgb=rgb, index=ob, names=np.array(names), E=E)


if __name__ == "__main__":
    main()
