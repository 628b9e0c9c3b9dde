"""Peak traced memory (tracemalloc) and CPU of output.radiance_at(smooth=True) ("at", what
cycles_ref.Ours.evaluate runs for the texture output at medium AUTO) or texels.radiance_per_leaf
("leaf", a bake's texture output without the final gather) on the numpy furnished 20k room at
medium (gather preset), at M points spread over the patches by area. Run it under a memory cap:
  ulimit -v 4000000; python benchmarks/aumem_radiance_at.py at|leaf M [TAG]
Saves the values to /tmp/aumem_WHAT_M_TAG.npy, to compare two code versions bitwise."""

import resource
import sys
import time
import tracemalloc

import numpy as np

from hr_addon.core.output import patch_neighbours, radiance_at
from hr_addon.core.params import RefineParams
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.texels import radiance_per_leaf
from hr_testing.furnished import furnished_room

s = RadiositySystem(furnished_room("20k")[0], RefineParams.for_gather("medium"))
s.solve()
h, B = s.h, s.B
K = len(h.patches.nv)
rng = np.random.default_rng(1)


def points(M):
    """Uniform points on the patches (quads as two triangles), patches drawn by area."""
    area = h.area[:K]
    k = rng.choice(K, M, p=area / area.sum())
    c = h.corners[k]
    a, b = rng.random(M), rng.random(M)
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    tri2 = (h.nv[k] == 4) & (rng.random(M) < 0.5)
    p0 = c[:, 0]
    p1 = np.where(tri2[:, None], c[:, 2], c[:, 1])
    p2 = np.where(tri2[:, None], c[:, 3], c[:, 2])
    return k, p0 + a[:, None] * (p1 - p0) + b[:, None] * (p2 - p0)


print("nodes", h.n, "neighbour table width", patch_neighbours(h).shape[1], flush=True)
what, M = sys.argv[1], int(sys.argv[2])
k, p = points(M)
tracemalloc.start()
c0 = time.process_time()
out = radiance_at(h, B, k, p, smooth=True) if what == "at" else radiance_per_leaf(h, B, k, p)
peak = tracemalloc.get_traced_memory()[1]
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3  # MB (Linux: kB)
print(
    f"{what} M={M}: peak traced {peak / 1e6:.0f} MB ({peak / M / 1e3:.1f} kB/point), "
    f"{time.process_time() - c0:.1f} s CPU, maxrss {rss:.0f} MB",
    flush=True,
)
np.save(f"/tmp/aumem_{what}_{M}_{sys.argv[3] if len(sys.argv) > 3 else 'x'}.npy", out)
