"""Threads (issue 23): a furnished room's phases with 1 and 2 threads, each run in its own
process pinned with taskset (-c 0 for 1 thread, -c 0,1 for 2); wall time per phase and the
speed-up, and each run's CPU time over its wall time (the cores it kept busy). A control run, 1
thread allowed on both cores (taskset -c 0,1), separates the threads' gain from what a second
core gives a single thread on a shared machine. Phases: build (RadiositySystem), the FE base
solve, the gather precompute (LoopGather, two levels + 4 iterations, 128 rays, the bake's draft
transport), the first output (direct light of the static emitters + the gather), one FE event (a
new window) and its output, one AUTO event and its output. The values of all runs are compared
too (they must be equal).

The 1-thread runs also profile (core.parallel.profiled): the CPU seconds of every batch of the
threaded maps, and so of what stays serial per phase. From those, Amdahl's law with the pool's own
schedule (parallel.makespan) models each phase on N cores: serial CPU + the batches' makespan on N
workers. CPU time hardly depends on the load of a shared machine, unlike wall time; the model
assumes a batch takes as long on any core (no memory bandwidth limit: an upper bound).

    .venv/bin/python benchmarks/bench_threads.py [--size 20k] [--runs 1@0,1@0-1,2@0-1] [--json out.json]
        [--system DIR] [--solve-only] [--build-only]

--system DIR keeps the built system in DIR (sys_<size>_<quality>.npz + .json, io.precompute_graph's
capture) and loads it in later runs: the build phase is then the load (the 100k room's build takes
5-7 minutes a run). --solve-only runs the solver's phases alone: the FE base solve, the FE event
and the AUTO event (no gather, no output); their values are the node radiance B. --build-only runs
the build alone (its values: the links and the hierarchy's areas).
"""

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

PHASE_KEYS = ("samples", "links", "cpu", "batches", "profiled", "loaded")  # a run's entries that are no phase


def child(size, threads, quality, dump, system=None, solve_only=False, build_only=False):
    from hr_addon.core import parallel

    prof = parallel.profiled() if threads == 1 else contextlib.nullcontext([])
    with prof as maps:
        return _phases(size, threads, quality, dump, maps, system, solve_only, build_only)


def _system(mesh, size, quality, threads, folder):
    """(RadiositySystem, loaded?): built, or loaded from / saved to `folder` (--system)."""
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_addon.io.precompute import use_threads
    from hr_addon.io.precompute_graph import capture, restore

    stem = Path(folder or ".") / f"sys_{size}_{quality}"
    if folder and stem.with_suffix(".json").exists():
        arrays = dict(np.load(stem.with_suffix(".npz")))
        s, _ = restore(arrays, json.loads(stem.with_suffix(".json").read_text()))
        use_threads(s, None, threads)
        return s, True
    s = RadiositySystem(mesh, RefineParams.for_gather(quality), threads=threads)
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        arrays, graph = capture(s)
        np.savez(stem.with_suffix(".npz"), **arrays)
        stem.with_suffix(".json").write_text(json.dumps(graph))
    return s, False


def _phases(size, threads, quality, dump, maps, system=None, solve_only=False, build_only=False):
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.gather import LoopGather

    wall = time.perf_counter
    mesh, info = furnished_room(size)
    _, frame = info["light_wall"]
    window = LightShape(
        S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
    )
    dkw = DynamicRadiosity.gather_options(quality)
    out, values = {}, {}

    cpu, batches = {}, {}

    def phase(name, fn):
        t0, c0, m0 = wall(), time.process_time(), len(maps)
        r = fn()
        out[name] = wall() - t0
        cpu[name] = time.process_time() - c0
        batches[name] = maps[m0:]  # the CPU seconds of the batches of each threaded map
        print(f"  {name:22s} {out[name]:7.2f} s", file=sys.stderr, flush=True)
        return r

    s, out["loaded"] = phase("build", lambda: _system(mesh, size, quality, threads, system))
    if build_only:
        L = s.links
        values.update(a=L.a, b=L.b, f_ab=L.f_ab, f_ba=L.f_ba, vis=L.vis, area=s.h.view("area"))
        values.update(far_a=L.far.a, far_b=L.far.b, far_vis=L.far.vis)
        out["samples"], out["links"], out["cpu"], out["batches"] = 0, len(L), cpu, batches
        out["profiled"] = threads == 1
        if dump:
            np.savez(dump, **values)
        return out
    dyn = phase("FE base solve", lambda: DynamicRadiosity(s.copy(), method="FE", **dkw))
    if solve_only:
        values["first"] = dyn.B.copy()
        phase("FE event", lambda: dyn.add("w", window))
        values["FE"] = dyn.B.copy()
        dyn2 = DynamicRadiosity(s.copy(), method="AUTO", **dkw)
        phase("AUTO event", lambda: dyn2.add("w", window))
        values["AUTO"] = dyn2.B.copy()
        out["samples"], out["links"], out["cpu"], out["batches"] = 0, len(s.links), cpu, batches
        out["profiled"] = threads == 1
        if dump:
            np.savez(dump, **values)
        return out
    gkw = dict(rays=128, shadow_rays=16 if quality == "draft" else 32, levels=2, iterations=4)
    g = phase("gather precompute", lambda: LoopGather(dyn, threads=threads, **gkw))
    values["first"] = phase("first output", lambda: g.loop_radiance(dyn))
    phase("FE event", lambda: dyn.add("w", window))
    values["FE"] = phase("FE output", lambda: g.loop_radiance(dyn))
    dyn2 = DynamicRadiosity(s.copy(), method="AUTO", **dkw)
    lv = g
    while lv is not None:  # the shape's direct light is part of each method's event cost
        lv._shape_cache.clear()
        lv = lv.second
    g.loop_radiance(dyn2)  # the base parts of this DynamicRadiosity
    phase("AUTO event", lambda: dyn2.add("w", window))
    values["AUTO"] = phase("AUTO output", lambda: g.loop_radiance(dyn2))
    out["samples"], out["links"], out["cpu"], out["batches"] = g.n, len(s.links), cpu, batches
    out["profiled"] = threads == 1
    if dump:
        np.savez(dump, **values)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="20k")
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--runs", default="1@0,1@0-1,2@0-1", help="threads@cpus (taskset -c)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--system", default=None, help="folder to keep / load the built system in")
    ap.add_argument("--solve-only", action="store_true", help="the solver's phases alone")
    ap.add_argument("--build-only", action="store_true", help="the build alone")
    ap.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--dump", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        only = dict(solve_only=args.solve_only, build_only=args.build_only)
        print(json.dumps(child(args.size, args.child, args.quality, args.dump, args.system, **only)))
        return
    runs, dumps = {}, {}
    for run in args.runs.split(","):
        t, cpus = run.split("@")
        dumps[run] = f"/tmp/bench_threads_{os.getpid()}_{len(dumps)}.npz"
        cmd = ["taskset", "-c", cpus, sys.executable, __file__, "--size", args.size, "--quality"]
        cmd += [args.quality, "--child", t, "--dump", dumps[run]]
        cmd += (["--system", args.system] if args.system else []) + (
            ["--solve-only"] if args.solve_only else []
        )
        cmd += ["--build-only"] if args.build_only else []
        print(f"{t} thread(s), taskset -c {cpus}, load {os.getloadavg()[0]:.2f}", flush=True)
        r = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, check=True)
        runs[run] = json.loads(r.stdout.strip().splitlines()[-1])
    ks = list(runs)
    first, last = ks[0], ks[-1]
    names = [k for k in runs[first] if k not in PHASE_KEYS]
    print(f"\n{args.size} room, {runs[first]['samples']:,} samples, {runs[first]['links']:,} links; wall s")
    head = f"{'phase':22s}" + "".join(f"{'thr ' + k:>12s}" for k in ks) + f"{'speed-up':>10s}"
    if len(ks) > 2:
        head += f"{'vs ' + ks[-2]:>12s}"
    print(head)
    tot = {k: sum(runs[k][n] for n in names) for k in ks}
    for n in [*names, "total"]:
        v = {k: tot[k] if n == "total" else runs[k][n] for k in ks}
        row = f"{n:22s}" + "".join(f"{v[k]:12.2f}" for k in ks) + f"{v[first] / v[last]:10.2f}"
        if len(ks) > 2:
            row += f"{v[ks[-2]] / v[last]:12.2f}"
        print(row)
    # CPU / wall of each run: how many cores a run kept busy (2 threads on a loaded machine: the
    # share of a phase that ran in parallel, whatever the wall time lost to other jobs)
    print("CPU s / wall s per run:")
    for n in names:
        print(f"{n:22s}" + "".join(f"{runs[k]['cpu'][n] / runs[k][n]:12.2f}" for k in ks))
    amdahl = {k: amdahl_table(runs[k], names) for k in ks if runs[k]["profiled"]}
    for k, table in amdahl.items():
        print(f"Amdahl model from the profile of run {k} (CPU s; threaded share; modelled speed-up):")
        print(f"{'phase':22s}{'CPU s':>9s}{'serial s':>10s}{'threaded':>10s}{'2 cores':>9s}{'16 cores':>9s}")
        for n, r in table.items():
            print(
                f"{n:22s}{r['cpu']:9.2f}{r['serial']:10.2f}{r['share']:10.2f}"
                f"{r['speedup'][2]:9.2f}{r['speedup'][16]:9.2f}"
            )
    loaded = [np.load(dumps[k]) for k in ks]
    equal = {f: all(bool(np.array_equal(loaded[0][f], x[f])) for x in loaded[1:]) for f in loaded[0].files}
    print("values equal across runs:", equal)
    for p in dumps.values():
        os.remove(p)
    if args.json:
        Path(args.json).write_text(json.dumps(dict(size=args.size, runs=runs, equal=equal, amdahl=amdahl)))


def amdahl_table(run, names, cores=(2, 4, 8, 16)):
    """Per phase of a profiled 1-thread run: CPU s, its serial part (outside the threaded maps),
    the threaded share and the modelled speed-up on each core count (serial + the maps' makespan)."""
    from hr_addon.core.parallel import makespan

    out = {}
    names = [*names, "total"]
    for n in names:
        maps = [m for k in names[:-1] for m in run["batches"][k]] if n == "total" else run["batches"][n]
        cpu = sum(run["cpu"][k] for k in names[:-1]) if n == "total" else run["cpu"][n]
        par = sum(map(sum, maps))
        serial = max(cpu - par, 0.0)
        out[n] = dict(
            cpu=cpu,
            serial=serial,
            share=par / cpu if cpu > 0 else 0.0,
            speedup={c: cpu / (serial + sum(makespan(m, c) for m in maps)) for c in cores},
        )
    return out


if __name__ == "__main__":
    main()
