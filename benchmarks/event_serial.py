"""Threads (issue 23, session 22): where the light events' and their outputs' serial CPU goes. On
the stored 100k room (thread_cpu.py --store's steps: per method the base parts' output, a new
window and its output, the window moved and its output), one thread, each step under cProfile
(time.thread_time) with every outermost batch map run (on one thread, inline as ever) in a thread
of its own, which the profiler does not see: its table is the serial CPU alone (what Amdahl's law
keeps on one core), by function, with whole call stacks. Per step: CPU, the maps'
batch CPU, the serial CPU (CPU - maps), then the top functions by their own and cumulative serial
time. --root runs another checkout (main's, for a before / after pair).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/event_serial.py
        [--store /work/cache/s20main] [--root CHECKOUT] [--top 25] [--steps "FE add,FE add output"]
        [--json out.json] [--no-profile]

--no-profile: the same steps without cProfile (its overhead inflates the Python-heavy parts):
CPU, map and serial CPU only.
"""

import argparse
import cProfile
import io
import json
import pstats
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/s20main")
    ap.add_argument("--root", default=str(ROOT))
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--steps", default=None, help="only these steps' tables (comma-separated)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--no-profile", action="store_true")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.root)
    from hr_addon.core import parallel  # (first: bench_gather_events puts this checkout first)
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    import hr_addon.core.events.direct  # noqa: F401 (their batch_map wrapped below)
    import hr_addon.core.gather  # noqa: F401

    sys.path.insert(1, str(ROOT / "benchmarks"))
    from bench_gather_events import load_store

    _, frame = furnished_room("100k")[1]["light_wall"]
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    pc.use_threads(s, g, 1)
    s.links.extended(s.h)

    state = dict(maps=0.0, n=0, by={})
    tl = threading.local()
    orig = parallel.batch_map

    def wrapped(fn, batches, threads=1, progress=None, poll=0.1):
        if getattr(tl, "inside", False) or parallel.in_worker():
            return orig(fn, batches, threads, progress, poll)
        got = {}
        f = sys._getframe(1)
        where = f"{Path(f.f_code.co_filename).stem}.{f.f_code.co_name}"
        batches = list(batches)

        secs = []

        def timed(*a):
            t0 = time.thread_time()
            try:
                return fn(*a)
            finally:
                secs.append(time.thread_time() - t0)

        def run():  # in a thread of its own: the profiler (this thread's) sees no batch's CPU
            tl.inside = True
            c0 = time.thread_time()
            try:
                got["out"] = orig(timed, batches, threads, progress, poll)
            except BaseException as exc:  # (re-raised in the calling thread)
                got["exc"] = exc
            got["cpu"] = time.thread_time() - c0

        t = threading.Thread(target=run)
        t.start()
        t.join()
        state["maps"] += got["cpu"]
        state["n"] += 1
        by = state["by"].setdefault(where, [0, 0, 0.0, 0.0, 0.0])
        by[0] += 1
        by[1] += len(batches)
        by[2] += got["cpu"]
        for i, cores in ((3, 2), (4, 16)):  # the map's makespan on that many cores (Amdahl, pool)
            by[i] += parallel.makespan(secs, cores) + (got["cpu"] - sum(secs))
        if "exc" in got:
            raise got["exc"]
        return got["out"]

    for name, mod in list(sys.modules.items()):
        if name.startswith("hr_addon") and getattr(mod, "batch_map", None) is orig:
            mod.batch_map = wrapped

    def window(cx):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.full(3, 20.0), "window")

    only = set(args.steps.split(",")) if args.steps else None
    out = {"hr_addon": str(Path(parallel.__file__).parents[1])}

    def step(name, fn):
        state["maps"], state["n"], state["by"] = 0.0, 0, {}
        prof = None if args.no_profile else cProfile.Profile(time.thread_time)
        c0 = time.thread_time()
        if prof is not None:
            prof.enable()
        fn()
        if prof is not None:
            prof.disable()
        serial = time.thread_time() - c0  # (the maps ran in threads of their own)
        rec = dict(cpu=serial + state["maps"], maps=state["maps"], serial=serial, n_maps=state["n"])
        rec["by_caller"] = state["by"]  # caller: [maps, batches, CPU s, model s on 2, on 16 cores]
        for i, cores in ((3, 2), (4, 16)):
            rec[f"model_{cores}"] = rec["cpu"] / (serial + sum(v[i] for v in state["by"].values()))
        out[name] = rec
        print(
            f"== {name}: {rec['cpu']:.3f} s CPU, {rec['n_maps']} maps {rec['maps']:.3f} s, serial "
            f"{rec['serial']:.3f} s; model {rec['model_2']:.2f}x on 2 cores, {rec['model_16']:.2f}x on 16",
            flush=True,
        )
        for where, (nm, nb, c, m2, m16) in sorted(state["by"].items(), key=lambda kv: -kv[1][2]):
            print(
                f"   map {where:32s} {nm:4d} maps {nb:5d} batches {c:7.3f} s, "
                f"on 2 / 16 cores {m2:7.3f} / {m16:7.3f} s"
            )
        if prof is not None and (only is None or name in only):
            for key in ("tottime", "cumulative"):
                buf = io.StringIO()
                pstats.Stats(prof, stream=buf).sort_stats(key).print_stats(args.top)
                text = buf.getvalue()
                print(text[text.find("   ncalls") :], flush=True)

    for method in ("FE", "AUTO"):
        dyn = DynamicRadiosity(s.copy(), method=method, **DynamicRadiosity.gather_options("draft"))
        lv = g
        while lv is not None:
            lv._shape_cache.clear()
            lv = lv.second
        step(f"{method} first output", lambda: g.loop_radiance(dyn))
        step(f"{method} add", lambda: dyn.add("w", window(0.7)))
        step(f"{method} add output", lambda: g.loop_radiance(dyn))
        step(f"{method} move", lambda: dyn.apply({"w": window(1.2)}))
        step(f"{method} move output", lambda: g.loop_radiance(dyn))
        out[f"{method} B"] = float(np.abs(dyn.B).sum())
    print(json.dumps({k: v for k, v in out.items() if not isinstance(v, dict)}))
    if args.json:
        Path(args.json).write_text(json.dumps(out))


if __name__ == "__main__":
    main()
