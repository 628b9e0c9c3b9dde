"""Segment-occlusion throughput (rays/s) of every available visibility backend.

Scenes: (a) a Cornell-like box with two blocks (36 triangles), (b) the box plus tessellated spheres
(3,556 triangles), (c) the same with finer spheres (37,236 triangles). Segments join random area-weighted
points on the scene's surfaces, each moved 1e-6 x sqrt(total area) off its surface towards the other
point, as the refiner does for form-factor visibility. Build time is reported apart; the float32 backends'
lazily built numpy fallback is warmed up first. Writes benchmarks/out/rays.json.

    .venv/bin/python benchmarks/bench_rays.py [--rays 1000000] [--slow-rays 20000]
"""

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
try:  # the bpy module provides mathutils; without it the mathutils backend is just skipped
    import bpy  # noqa: F401
except ImportError:
    pass
from hr_addon.core.visibility import available_backends, make_backend  # noqa: E402
from hr_testing.scenes import box_triangles  # noqa: E402

SLOW = {"mathutils"}  # Python-loop backends get fewer rays


def cornell():
    return np.array(
        box_triangles([0, 0, 0], [5.5, 5.5, 5.5])
        + box_triangles([1.3, 0.65, 0], [2.9, 2.25, 1.65])
        + box_triangles([3.7, 2.95, 0], [5.3, 4.55, 3.3])
    )


def sphere(c, r, n):
    th, ph = np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, 2 * n + 1)
    p = np.stack(np.meshgrid(th, ph, indexing="ij"), -1)
    p = c + r * np.stack(
        [np.sin(p[..., 0]) * np.cos(p[..., 1]), np.sin(p[..., 0]) * np.sin(p[..., 1]), np.cos(p[..., 0])], -1
    )
    a, b, cc, d = p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]
    tri = np.concatenate([np.stack([a, b, cc], -2), np.stack([a, cc, d], -2)]).reshape(-1, 3, 3)
    e = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return tri[np.linalg.norm(e, axis=1) > 1e-12]  # drop the pole slivers


def spheres_scene(n_sph, n):
    rng = np.random.default_rng(1)
    parts = [cornell()] + [sphere(rng.uniform(1, 4.5, 3), rng.uniform(0.3, 0.7), n) for _ in range(n_sph)]
    return np.concatenate(parts)


def segments(tri, k, rng):
    """k segments between random area-weighted surface points, ends offset off the surfaces."""
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(n, axis=1)
    n /= area[:, None]
    ends = []
    for _ in range(2):
        i = rng.choice(len(tri), k, p=area / area.sum())
        r1, r2 = rng.random((2, k, 1))
        s = np.sqrt(r1)
        ends.append(((1 - s) * tri[i, 0] + s * (1 - r2) * tri[i, 1] + s * r2 * tri[i, 2], n[i]))
    (a, na), (b, nb) = ends
    eps = 1e-6 * np.sqrt(area.sum() / 2)
    a = a + eps * na * np.sign(np.einsum("ij,ij->i", na, b - a))[:, None]  # towards the other end
    b = b + eps * nb * np.sign(np.einsum("ij,ij->i", nb, a - b))[:, None]
    return a, b


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--slow-rays", type=int, default=20_000)
    args = ap.parse_args()
    scenes = {"cornell": cornell(), "2k": spheres_scene(8, 11), "20k": spheres_scene(10, 31)}
    rng = np.random.default_rng(0)
    results = []
    print(
        f"{'scene':8s} {'tris':>6s} {'backend':10s} {'rays':>8s} {'build s':>8s} {'rays/s':>11s} {'occl':>6s}"
    )
    for sname, tri in scenes.items():
        a, b = segments(tri, args.rays, rng)
        for name in available_backends():
            t0 = time.perf_counter()
            be = make_backend(tri, name)
            t1 = time.perf_counter()
            be.occluded(a[:1000], a[:1000] + 1e-9)  # warm-up: too short for float32, builds the lazy fallback
            r = args.slow_rays if name in SLOW else args.rays
            t2 = time.perf_counter()
            occ = be.occluded(a[:r], b[:r])
            dt = time.perf_counter() - t2
            results.append(
                dict(
                    scene=sname,
                    triangles=len(tri),
                    backend=name,
                    rays=r,
                    build_s=t1 - t0,
                    seconds=dt,
                    rays_per_s=r / dt,
                    occluded_fraction=float(occ.mean()),
                    retraced=getattr(be, "last_retraced", 0),
                )
            )
            print(
                f"{sname:8s} {len(tri):6d} {name:10s} {r:8d} {t1 - t0:8.3f} {r / dt:11.3e} {occ.mean():6.3f}",
                flush=True,
            )
    out = os.path.join(ROOT, "benchmarks", "out")
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, "rays.json"), "w") as f:
        json.dump(dict(cpu_count=os.cpu_count(), numpy=np.__version__, results=results), f, indent=1)
    print("wrote", os.path.join(out, "rays.json"))


if __name__ == "__main__":
    main()
