"""Which kernels release the GIL (issue 23, docs/threads.md): each kernel is run K times on one
thread, then the same K calls on 2 threads; speed-up = serial wall / threaded wall (2.0: the
GIL is released for the whole call; 1.0: held). Repeated `--repeat` times (the machine is shared).

    .venv/bin/python benchmarks/gil_probe.py [--size 20k] [--repeat 3] [--json out.json]
"""

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def _speedup(fn, k, threads):
    t0 = time.perf_counter()
    for _ in range(k):
        fn()
    serial = time.perf_counter() - t0
    per = [k // threads + (i < k % threads) for i in range(threads)]

    def run(n):
        for _ in range(n):
            fn()

    ts = [threading.Thread(target=run, args=(n,)) for n in per]
    t0 = time.perf_counter()
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    return serial, time.perf_counter() - t0


def kernels(size):
    from hr_testing.furnished import furnished_room
    from hr_addon.core.gather import FinalGather, LoopGather, _csr_matvec, cosine_directions
    from hr_addon.core.geometry import prepare_patches
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_addon.core.visibility import NumpyBackend, make_backend

    mesh, _ = furnished_room(size)
    pt = prepare_patches(mesh)
    emb = make_backend(pt.triangles, "embree")
    rng = np.random.default_rng(0)
    lo, hi = pt.triangles.reshape(-1, 3).min(0), pt.triangles.reshape(-1, 3).max(0)
    n = 1 << 18
    a = lo + rng.random((n, 3)) * (hi - lo)
    b = lo + rng.random((n, 3)) * (hi - lo)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    reach = float(np.linalg.norm(hi - lo))
    npb = NumpyBackend(pt.triangles)
    # warm the lazy parts (float64 rows, the numpy fallback) before threads share the backend
    emb.occluded(a[:1000], b[:1000])
    emb.first_hit(a[:1000], d[:1000], reach)
    nn = 1 << 14
    out = {
        "embree occluded (262k segments)": lambda: emb.occluded(a, b),
        "embree first_hit (262k rays)": lambda: emb.first_hit(a, d, reach),
        "embree raw scene.run INTERSECT (262k rays)": lambda: emb._scene.run(
            (a - emb.center).astype(np.float32), d.astype(np.float32), query="INTERSECT", output=1
        ),
        "numpy grid occluded (16k segments)": lambda: npb.occluded(a[:nn], b[:nn]),
    }
    # numpy kernels of the gather, on sizes like its batches
    m = 1 << 22
    x = rng.random(m).astype(np.float32)
    cols = rng.integers(0, 1 << 18, m)
    V = rng.random((1 << 18, 3)).astype(np.float32)
    starts = np.sort(rng.choice(m, m // 50, replace=False))
    starts[0] = 0
    keys = rng.integers(0, 1 << 40, 1 << 21)
    A = rng.random((1000, 1000))
    out.update(
        {
            "np.add.reduceat float32 (1M x 3 -> 21k rows)": lambda: np.add.reduceat(
                V[cols[: m // 4]], starts[starts < m // 4], axis=0
            ),
            "fancy index V[cols] (4M x 3 float32)": lambda: V[cols],
            "elementwise x * x + x (4M float32)": lambda: x * x + x,
            "np.unique int64 (2M, sort)": lambda: np.unique(keys, return_counts=True),
            "argsort int64 (2M)": lambda: np.argsort(keys, kind="stable"),
            "matmul 1000 x 1000 float64": lambda: A @ A,
            "cosine_directions (8k samples x 128)": lambda: cosine_directions(
                d[:8192], np.arange(8192), 128, 0
            ),
        }
    )
    s = RadiositySystem(furnished_room("2k")[0], RefineParams.for_gather("draft"))
    g = LoopGather(s, rays=64, shadow_rays=16)
    em = g.static_emitters()[0][0]
    V2 = np.random.default_rng(1).random((g.n_hr, 3))
    out.update(
        {
            f"FinalGather.gather_batch (2k room, {min(g.n, 4096)} samples x 64 rays)": lambda: g.gather_batch(
                0, min(g.n, 4096)
            ),
            f"FinalGather.direct_batch (2k room, {g.n} samples, 16 shadow rays)": lambda: g.direct_batch(
                em, 0, g.n
            ),
            "_csr_matvec (2k room weights)": lambda: _csr_matvec(
                g.indptr, g.leaf_columns(), g.w, V2, rays=g.row_rays
            ),
        }
    )
    del FinalGather
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="20k")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--k", type=int, default=4, help="calls per measurement")
    ap.add_argument("--only", default=None, help="substring of the kernels to run")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    res = {}
    print(f"cores {os.cpu_count()}, affinity {sorted(os.sched_getaffinity(0))}, load {os.getloadavg()}")
    for name, fn in kernels(args.size).items():
        if args.only and args.only not in name:
            continue
        fn()  # warm
        sp = []
        for _ in range(args.repeat):
            s, p = _speedup(fn, args.k, 2)
            sp.append((s, p, s / p))
        res[name] = sp
        print(
            f"{name:70s} serial {np.median([x[0] for x in sp]):7.3f} s  2 threads "
            f"{np.median([x[1] for x in sp]):7.3f} s  speed-up {' '.join(f'{x[2]:.2f}' for x in sp)}",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
