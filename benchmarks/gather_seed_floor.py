"""The seed noise of the gathered vertex output, on a stored build (bench_gather_events.py --cache):
the stored gather's top-level rows (the corners' and the extra samples') retraced with other
seeds, the second level kept, and the output after bench_gather_events.py's FE window add and
move per object: each seed against the stored rows' output (what any change of the corners'
random streams moves by) and the stored rows and dumps of other stores of the same system
(bench_gather_events.py --dump) against the seeds' mean (a reference with less noise); and each
realisation of the stored code (its rows, each seed) against the mean of as many of the others: the
spread of an unchanged code's error against such a mean (the floor). One run.

--second: the second level's rows retraced too (its seed the top's + 7919, as FinalGather makes
it; the probe's rows that the second level reuses and the fine leaves' alike), on the stored
layout (the fine leaves the stored probe chose, every sample's rays as stored): the floor for a
change of the second level's random streams (its fine leaves' rays, final.FINE_RAYS).

    .venv/bin/python benchmarks/gather_seed_floor.py /work/cache/STORE [--seeds 1,2,3] [--second] \
        [--against NAME=DUMP.npz ...] [--json OUT.json] [--check] [--runs RUNS.npz]
"""

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from bench_gather_events import load_store  # noqa: E402
from compare_gather_dumps import difference, line, per_object  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402
from hr_testing import shapes as S  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("store")
ap.add_argument("--size", default="100k", help="the furnished room the store holds (its light wall)")
ap.add_argument("--seeds", default="1,2,3")
ap.add_argument("--second", action="store_true", help="reseed the second level's rows too")
ap.add_argument("--check", action="store_true", help="first retrace with the stored seeds: the stored rows?")
ap.add_argument("--against", action="append", default=[], help="NAME=DUMP.npz of the same system")
ap.add_argument("--json", default=None)
ap.add_argument(
    "--runs",
    default=None,
    help="npz: the stored rows' and the seeds' per-object outputs, "
    "written when traced, read instead of tracing when the file exists",
)
args = ap.parse_args()

s, g, _ = load_store(Path(args.store) / pc.FILENAME)
pc.use_threads(s, g, 1)
g.iterations = 4
if getattr(g, "stats", {}).get("second_reads"):  # (its sample_rays are the rest of the corners' rays)
    sys.exit("a store whose corners read the second level (branch pc60): use one without")
_, frame = furnished_room(args.size)[1]["light_wall"]
obj = np.asarray(s.mesh.object_id)[np.repeat(np.arange(len(s.mesh.loop_start)), s.mesh.loop_total)]
STEPS = ("FE_add", "FE_move")


def window(cx):
    rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
    return LightShape(rect, np.full(3, 20.0), "window")


def outputs(G):
    """{step: per-object means} of gather G after the FE window's add and move."""
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    G.loop_radiance(dyn)
    dyn.add("w", window(0.7))
    out = {"FE_add": per_object(G.loop_radiance(dyn), obj)}
    dyn.apply({"w": window(1.2)})
    out["FE_move"] = per_object(G.loop_radiance(dyn), obj)
    return out


def retraced(G, seed):
    """G's rows traced anew with `seed` (as FinalGather's precompute: the covered samples trace
    nothing, each sample its stored rays), in place on a copy."""
    G.seed, G._trace = seed, ~G.dark
    G.indptr, G.cols, G.w, G.wu, G.wv = G.merge([G.gather_batch(a, b) for a, b in G.batches(G.rays)])
    del G._trace
    G._responses, G._responses_of = {}, None
    for k in ("_loop_parts", "_loop_rows", "_cols_read"):
        G.__dict__.pop(k, None)
    return G


def reseeded(seed):
    """g with its top-level rows traced anew with `seed`, the near hits remapped onto the second
    level's samples; with --second the second level's rows too (seed + 7919, its near hits
    remapped onto its own fine samples: FinalGather's near_layout (off, None))."""
    used, start = g._second_map[0], g._second_start
    fine = np.diff(start) > np.diff(start).min()
    off = np.full(g.n_hr, -1, np.int64)
    off[used[fine]] = start[:-1][fine]
    G = retraced(copy.copy(g), seed)
    if args.second:
        G2 = G.second = retraced(copy.copy(g.second), g.second.seed - g.seed + seed)
        G2._remap_near(off, None)
    G._remap_near(off, G.second.dark)
    return G


if args.check:  # the stored seeds must give the stored rows back, bit for bit
    c0 = time.process_time()
    G = reseeded(g.seed)
    for name, a, b in (("top", g, G), ("second", g.second, G.second)):
        same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("indptr", "cols", "w"))
        print(f"check {name}: rows {'equal' if same else 'DIFFER'} ({time.process_time() - c0:.1f} s CPU)")
    del G
if args.runs and Path(args.runs).exists():  # (traced before: --against other dumps)
    d = np.load(args.runs)
    runs = {}
    for key in d.files:
        r, k = key.rsplit(":", 1)
        runs.setdefault(r, {})[k] = d[key]
else:
    runs = {"stored": outputs(g)}
    for seed in map(int, args.seeds.split(",")):
        c0 = time.process_time()
        runs[f"seed{seed}"] = outputs(reseeded(seed))
        print(f"seed {seed}: {time.process_time() - c0:.1f} s CPU", flush=True)
    if args.runs:
        np.savez(args.runs, **{f"{r}:{k}": v for r, out in runs.items() for k, v in out.items()})
for spec in args.against:
    name, path = spec.split("=", 1)
    d = np.load(path)
    runs[name] = {k: per_object(d[k], obj) for k in STEPS}
seeds = [k for k in runs if k.startswith("seed")]
res = {}
for k in STEPS:
    mean = np.mean([runs[r][k] for r in seeds], 0)
    for r in runs:
        if r.startswith("seed"):
            res[f"{r}_vs_stored_{k}"] = difference(runs["stored"][k], runs[r][k])
        else:
            res[f"{r}_vs_seed_mean_{k}"] = difference(mean, runs[r][k])
    # the floor itself: each of the stored rows and the seeds (realisations of the same code)
    # against the mean of as many others (len(seeds) of the rest): how far a realisation of
    # unchanged code lies from such a mean, the spread a changed code's dump is judged against
    real = ["stored", *seeds]
    if len(real) > 2:
        for r in real:
            others = [runs[o][k] for o in real if o != r][: len(seeds)]
            res[f"{r}_vs_others_mean_{k}"] = difference(np.mean(others, 0), runs[r][k])
for k, r in res.items():
    print(line(k, r))
if args.json:
    Path(args.json).write_text(json.dumps(res, indent=1))
