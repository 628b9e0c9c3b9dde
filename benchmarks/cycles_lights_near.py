"""The Cornell box of benchmarks/cycles_lights.py where session 36's light rules could act in the
texture output (hr_testing/cycles_lights.run with add_light wrapped for the new kinds; the Cycles
cache key hashes add_light's source, so the wrapper's kinds get bakes of their own):

- POINT_HIGH: the point light (20 W, radius 0) 5 cm under the ceiling (0.50 m up), to bring the
  ceiling's HR leaves within lights.NEAR of it (node_incident's points by nearness; they stay
  below it at medium and draft: the largest half-diagonal / distance 0.45);
- POINT_R: the point light as cycles_lights' (0.40 m up, 7 cm over the tall block) with a 0.05 m
  radius: the output's full shadow rays for a sized light (gather/direct.py, session 36).

Any of cycles_lights' kinds is accepted too: with --quality the same cached Cycles bakes against
another quality's solution.

Run: .venv/bin/python benchmarks/cycles_lights_near.py KIND... [--spp 1024] [--seeds 1,2]
     [--quality medium] [--shadow-rays N]  (the gather's shadow rays per sample, default 32)
Cycles' bakes are cached as cycles_lights.py --cache does (benchmarks/out/cycles_lights_cache/).
Prints one RESULT JSON line per kind (docs/lights.md, session 37, branch cor37)."""

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import hr_testing.cycles_lights as CL  # noqa: E402

_base = CL.add_light


def add_light(kind):
    ob = _base("POINT")
    if kind == "POINT_HIGH":
        ob.location = (0.278, 0.2795, 0.50)
    elif kind == "POINT_R":
        ob.data.shadow_soft_size = 0.05
    return ob


def _opt(args, name, conv, default):
    if name not in args:
        return default
    i = args.index(name)
    v = conv(args[i + 1])
    del args[i : i + 2]
    return v


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    args = sys.argv[1:]
    quality = _opt(args, "--quality", str, "medium")  # the Cycles bakes do not depend on it
    shadow = _opt(args, "--shadow-rays", int, None)
    gather = None if shadow is None else dict(levels=2, iterations=4, shadow_rays=shadow)
    spp = _opt(args, "--spp", int, 1024)
    seeds = _opt(args, "--seeds", lambda s: tuple(int(v) for v in s.split(",")), (1, 2))
    cache = str(Path(__file__).resolve().parent / "out" / "cycles_lights_cache")
    for kind in args:
        CL.add_light = add_light if kind in ("POINT_HIGH", "POINT_R") else _base
        r = CL.run(kind, spp, seeds=seeds, quality=quality, gather=gather, cache_dir=cache)
        r["quality"], r["gather"] = quality, gather
        print("RESULT " + json.dumps(r), flush=True)
