"""The gather's hemisphere hits with and without the float64 re-test of hits away from the
segment's ends (visibility first_hit's `sure`, FinalGather.SURE_HITS): CPU seconds of
first_hit_within (two runs each, the second counts), the share of hits that skip the re-test and
the rays whose hit changes. Rays: 64 cosine rays from 40,000 random points on the furnished
room's polygons (fan-triangulated), Embree.

    .venv/bin/python benchmarks/sure_hits.py [SIZE] [SURE]
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hr_testing.furnished import furnished_room  # noqa: E402
from hr_addon.core import visibility as V  # noqa: E402
from hr_addon.core.gather.sampling import cosine_directions  # noqa: E402
from hr_addon.core.geometry import isolated_objects  # noqa: E402


def main(size="100k", sure=1e-4):
    mesh, _ = furnished_room(size)
    ls, lt, lv = (np.asarray(x) for x in (mesh.loop_start, mesh.loop_total, mesh.loop_verts))
    fan = [np.stack([s, s + k, s + k + 1], 1) for k in range(1, lt.max() - 1) for s in [ls[lt > k + 1]]]
    tri = np.asarray(mesh.verts)[lv[np.concatenate(fan)]]
    be = V.make_backend(tri, "embree")
    rng = np.random.default_rng(0)
    T = rng.integers(0, len(tri), 40_000)
    u = rng.random((len(T), 2))
    u[u.sum(1) > 1] = 1 - u[u.sum(1) > 1]
    a, b, c = tri[T, 0], tri[T, 1], tri[T, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    org = np.repeat(a + u[:, :1] * (b - a) + u[:, 1:] * (c - a) + 1e-6 * n, 64, 0)
    d = cosine_directions(n, np.arange(len(T)), 64, 0).reshape(-1, 3)
    reach = 4 * float(np.sqrt(isolated_objects(mesh).main_area))
    tmax = 2 * np.linalg.norm(tri.reshape(-1, 3).max(0) - tri.reshape(-1, 3).min(0)) + 1
    res, cpu = {}, {}
    for s in (None, sure, None, sure):
        c0 = time.process_time()
        res[s] = V.first_hit_within(be, org, d, reach, tmax, s)
        cpu[s] = time.process_time() - c0
    (p0, t0), (p1, t1) = res[None], res[sure]
    h = p0 >= 0
    print(
        f"{len(org):,} rays, reach {reach:.1f}: first_hit_within {cpu[None]:.2f} -> {cpu[sure]:.2f} s CPU; "
        f"hits skipping the re-test {np.mean((t0[h] > sure * reach) & (t0[h] < (1 - sure) * reach)):.1%}; "
        f"another triangle {np.sum(p0 != p1)} rays, t off by > 1e-4 {np.sum(np.abs(t0[h] - t1[h]) > 1e-4)}"
    )


if __name__ == "__main__":
    main(*(sys.argv[1:2] or ["100k"]), *[float(x) for x in sys.argv[2:3]])
