"""Cornell box lit by a Blender light in place of its emitter (issue 20) against Cycles
(hr_testing/cycles_lights.py): reflected radiance per surface, Cycles against our final gather.

Run: .venv/bin/python benchmarks/cycles_lights.py [POINT|AREA|SPOT|SUN|SUN_HOLE|WORLD|WORLD_ENV ...] [--spp N]
     [--indirect]  (Cycles' direct light + our "Indirect only" values against the full Cycles bake)
     [--leaf-points N]  (the second level's N x N gather samples per HR leaf, default 2)
     [--gather-seed N] [--rays N]  (the final gather's seed, default 0, and hemisphere rays per
     texel, default 128: the spread over seeds is the gather's own noise)
     [--seeds 1,2,...]  (the reference: their mean; default 1,2)
     [--cache]  (Cycles' bakes kept in benchmarks/out/cycles_lights_cache/, git-ignored: a re-run
     with the same light, spp and seed reads them)
Prints one JSON line per light kind; the test tests/test_cycles_lights.py runs a smaller version."""

import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from hr_testing.cycles_lights import run  # noqa: E402

if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    args = sys.argv[1:]
    spp = 32
    if "--spp" in args:
        i = args.index("--spp")
        spp = int(args[i + 1])
        del args[i : i + 2]
    seeds = (1, 2)
    if "--seeds" in args:
        i = args.index("--seeds")
        seeds = tuple(int(v) for v in args[i + 1].split(","))
        del args[i : i + 2]
    cache = (
        str(Path(__file__).resolve().parent / "out" / "cycles_lights_cache") if "--cache" in args else None
    )
    gather = dict(levels=2, iterations=4)
    if "--leaf-points" in args:  # the second level's gather samples per HR leaf side (default 2)
        i = args.index("--leaf-points")
        gather["leaf_points"] = int(args[i + 1])
        del args[i : i + 2]
    for opt, key in (("--gather-seed", "seed"), ("--rays", "rays")):
        if opt in args:
            i = args.index(opt)
            gather[key] = int(args[i + 1])
            del args[i : i + 2]
    indirect = "--indirect" in args  # the "Indirect only (for EEVEE)" composite too
    args = [a for a in args if a not in ("--indirect", "--cache")]
    for kind in args or ["POINT"]:
        print(
            "RESULT "
            + json.dumps(run(kind, spp, seeds=seeds, gather=gather, indirect=indirect, cache_dir=cache)),
            flush=True,
        )
