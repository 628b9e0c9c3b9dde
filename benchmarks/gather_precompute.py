"""The vertex output's gather precompute (LoopGather + precompute.prepare, as a bake builds and
stores it) on a stored build's system and base solution (bench_gather_events.py --cache), with the
code of the checkout given: CPU seconds, one run. For comparing checkouts on the same system.

    .venv/bin/python benchmarks/gather_precompute.py /work/cache/STORE [--root CHECKOUT] \
        [--set layouts.SPLIT=False] [--set final.FinalGather.BATCH_RAYS=1<<17] [--threads N] \
        [--serial] [--profile FILE [--whole]] [--digest FILE] [--check FILE] \
        [--json FILE] [--write DIR] [--output]

--serial: the CPU seconds of the threaded maps' batches (core.parallel.profiled, threads 1) and so
the serial part, with Amdahl's model on 2 and 16 cores as docs/threads.md's (bench_threads.py).
--profile: a cProfile of the serial code (its clock stands still inside every threaded map), its
60 largest cumulative entries written to FILE: where the serial part is (--whole: of everything).
--digest: a SHA-256 per stored array of the captured precompute (io.precompute_graph.capture),
written to FILE as JSON: two checkouts or thread counts store the same bits if the files match.
--check: compare this run's digests with FILE (another run's --digest): prints whether every
captured array is bitwise the same and names those that differ.
--write: write the stored system with this gather as a new store into DIR (not the one read), for
bench_gather_events.py --cache DIR (its events and --dump on this checkout's gather).
--output: gather on the stored gather's output layout (a Blender bake's precompute.hrpc: the vertex
output on the Vertex Spacing mesh's corners, as the bake gathers), not on the system's own corners.
"""

import argparse
import contextlib
import cProfile
import hashlib
import json
import os
import pstats
import sys
import time
from pathlib import Path

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("store", help="folder of a stored build (bench_gather_events.py --cache)")
ap.add_argument("--root", default=str(Path(__file__).resolve().parent.parent), help="checkout timed")
ap.add_argument("--set", action="append", default=[], help="module.NAME=value in hr_addon.core.gather")
ap.add_argument("--threads", type=int, default=1)
ap.add_argument("--serial", action="store_true", help="the serial part and Amdahl's model (threads 1)")
ap.add_argument("--profile", default=None, help="write a cProfile summary of the serial code here")
ap.add_argument("--whole", action="store_true", help="--profile: of the whole run, the maps' batches too")
ap.add_argument("--digest", default=None, help="write the stored arrays' SHA-256 here (JSON)")
ap.add_argument("--check", default=None, help="compare the arrays' SHA-256 with this --digest file")
ap.add_argument("--json", default=None, help="append this run's figures to this JSON list")
ap.add_argument("--write", default=None, help="write the system and this gather as a store here")
ap.add_argument("--output", action="store_true", help="on the stored gather's output layout (a bake's)")
args = ap.parse_args()
sys.path.insert(0, args.root)
sys.path.insert(0, os.path.join(args.root, "benchmarks"))

from bench_gather_events import load_store  # noqa: E402
from hr_addon.core import gather, parallel  # noqa: E402
from hr_addon.core.events import DynamicRadiosity  # noqa: E402
from hr_addon.io import precompute as pc  # noqa: E402

for kv in args.set:  # module.NAME or module.Class.NAME under hr_addon.core.gather
    name, value = kv.split("=", 1)
    *path, attr = name.split(".")
    target = gather
    for part in path:
        target = getattr(target, part)
    setattr(target, attr, eval(value))
s, g, header = load_store(Path(args.store) / pc.FILENAME)
pc.use_threads(s, g, args.threads)
layout = dict(output=g.output, smooth_angle=g.smooth_angle) if args.output else {}
del g
dyn = DynamicRadiosity(s, method="FE", **DynamicRadiosity.gather_options("draft"))
prof = None
if args.profile and args.whole:
    prof = cProfile.Profile(time.process_time)
elif args.profile:
    # a clock of the serial CPU only: it stands still inside every outermost batch map (each
    # module's imported name wrapped), so every function's time is its serial part
    mapping, inside, skipped, frozen = parallel.batch_map, [0], [0.0], [0.0]

    def clock():
        return frozen[0] if inside[0] else time.process_time() - skipped[0]

    def unprofiled(*a, **k):
        if not inside[0]:
            frozen[0], t0 = clock(), time.process_time()
        inside[0] += 1
        try:
            return mapping(*a, **k)
        finally:
            inside[0] -= 1
            if not inside[0]:
                skipped[0] += time.process_time() - t0

    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("hr_addon") and getattr(mod, "batch_map", None) is mapping:
            mod.batch_map = unprofiled
    prof = cProfile.Profile(clock)
with parallel.profiled() if args.serial else contextlib.nullcontext([]) as maps:
    c0 = time.process_time()
    if prof:
        prof.enable()
    kw = dict(rays=128, levels=2, iterations=4, threads=args.threads, shadow_rays=16)
    g = gather.LoopGather(dyn, **kw, **layout)
    pc.prepare(g)
    if prof:
        prof.disable()
    cpu = time.process_time() - c0
print(
    f"{args.root}: gather precompute {cpu:.2f} s CPU, {args.threads} thread(s), {g.n:,} samples, "
    f"load {os.getloadavg()[0]:.2f}"
)
run = dict(root=args.root, threads=args.threads, cpu=cpu, samples=int(g.n), load=os.getloadavg()[0])
if args.serial:
    par = sum(map(sum, maps))
    model = {c: cpu / (cpu - par + sum(parallel.makespan(m, c) for m in maps)) for c in (2, 16)}
    print(
        f"threaded maps {par:.2f} s in {len(maps)} maps, serial {cpu - par:.2f} s "
        f"({(cpu - par) / cpu:.1%}); model {model[2]:.2f}x on 2 cores, {model[16]:.2f}x on 16"
    )
    run.update(threaded=par, maps=len(maps), serial=cpu - par, model={str(c): v for c, v in model.items()})
if args.json:
    p = Path(args.json)
    p.write_text(json.dumps([*(json.loads(p.read_text()) if p.exists() else []), run], indent=1))
if args.write:
    if Path(args.write).resolve() == Path(args.store).resolve():
        sys.exit("--write: not into the store read")
    want = {k: header[k] for k in ("format_version", "extension", "code", "settings", "objects")}
    info = {**header.get("info", {}), "gather_precompute_cpu_s": cpu}
    pc.write(args.write, *pc.capture(s, g), want, info=info)
if prof:
    with open(args.profile, "w") as fh:
        pstats.Stats(prof, stream=fh).sort_stats("cumulative").print_stats(60)
        pstats.Stats(prof, stream=fh).sort_stats("tottime").print_stats(40)
if args.digest or args.check:
    from hr_addon.io.precompute_graph import capture

    def sha(a):
        return hashlib.sha256(str((a.dtype, a.shape)).encode() + a.tobytes()).hexdigest()

    arrays, _ = capture(s, g)
    got = {k: sha(a) for k, a in arrays.items()}
    if args.digest:
        Path(args.digest).write_text(json.dumps(got, indent=0))
    if args.check:
        ref = json.loads(Path(args.check).read_text())
        differ = sorted(k for k in set(ref) | set(got) if ref.get(k) != got.get(k))
        print(f"{len(got)} arrays against {args.check}: bitwise equal: {not differ}; differ: {differ[:20]}")
