"""Where a light event's time goes on a stored room, by stage: the FE / AUTO window added and moved
(as bench_gather_events.py's), then --sweep more steps of a 24-step sweep's 2.2 cm (the host
visibility stores warm: hostvis_tiles.py --sweep's later steps), each with its gathered output
(loop_radiance); CPU seconds (process time, inclusive) per stage and gather level from wrappers on
the classes, the host visibility's (hostvis.py: `light`, its `visible` read, the segments traced by
`_fill`, the ratio, the form factors) and the rays traced, the response's operator applications one
by one (with their sources' nonzero share), optional cProfile and dumps. The draft preset's defaults
(today "zero": no response; --warm TOL sets FinalGather.WARM_TOL, off by default: a moved shape's
passes then start from its last limit where warm_moves, DynamicRadiosity's default, as Live's; --dyn
"dict(warm_moves=False)" gives a bake's passes from nothing); each method starts from empty host
visibility stores and shape caches at every level (the slot samples' facing copy too), as a fresh
process would. The window is a moving shape (LightShape.moves: a keyed sweep's, whose direct light the
product reads from the host visibility; session 31 evsweep: since hvmove the benchmark's window was
still, its light by shadow rays); --still for that.

    .venv/bin/python benchmarks/event_stages.py STORE [--methods FE,AUTO] [--sweep 1] \\
        [--dyn "dict(gather_responses='tail')"] [--dump out.npz] [--profile out.txt] [--json out.json]

--gather "dict(SEIDEL_MIN_PASSES=4, SEIDEL_TAIL_SHARE=0.05)" sets FinalGather's class settings first (an
A/B of a knob from one tree; session 37, ev37).

Medium (a store built with --quality medium): --dyn "DynamicRadiosity.gather_options('medium')"
(its options replace the draft's; the store carries the gather's own rays and shadow rays).

--tail-shares 0.02,0.03,...: instead, the second level's passes from nothing against their limit:
the FE window added, moved and swept one step, its gathered output with FinalGather.TAIL_SHARE at
each value, per object against the passes run to TAIL_PASSES with a share of --limit (the same
estimator's limit; --limit-passes at most); the passes taken and the output's CPU (the host
visibility and shape light warm after the first variant: only the passes differ).

STORE: a folder of bench_gather_events.py --cache (the furnished 100k room, draft, --transport gather).
"""

import argparse
import dataclasses
import functools
import json
import os
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402

STAGES = (
    "_read",
    "_seidel_pass",
    "_levels",
    "_leaf_means",
    "_near_rows",
    "_tail",
    "_dmix",
    "_facing_part",
    "_response_parts",
)
HOST = ("light", "visible", "_fill", "_new_part", "_ratio", "block", "layout")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument("--methods", default="FE,AUTO")
    ap.add_argument("--dyn", default="dict()", help="DynamicRadiosity options over gather_options('draft')")
    ap.add_argument("--sweep", type=int, default=1, help="steps of 0.5 / 23 m after the move")
    ap.add_argument("--still", action="store_true", help="the window as a still shape (shadow rays)")
    ap.add_argument("--tail-shares", default=None, help="the passes' stopping rule instead (module doc)")
    ap.add_argument("--limit", type=float, default=1e-4, help="--tail-shares: the reference's share")
    ap.add_argument("--limit-passes", type=int, default=16, help="--tail-shares: its passes at most")
    ap.add_argument("--warm", type=float, default=None, help="FinalGather.WARM_TOL (module doc)")
    ap.add_argument("--gather", default="dict()", help="FinalGather settings: dict(SEIDEL_MIN_PASSES=4)")
    ap.add_argument("--json", default=None, help="the steps' figures and stages (or --tail-shares' results)")
    ap.add_argument("--dump", default=None, help="npz of the gathered output after each event")
    ap.add_argument("--profile", default=None, help="a cProfile summary of the events here")
    ap.add_argument("--profile-step", default=None, help="with --profile: only this step (e.g. FE_sweep1)")
    args = ap.parse_args(argv)
    if args.tail_shares:
        return tail_shares(args)

    from bench_gather_events import _write_profile, stored_room
    from hostvis_tiles import count_rays
    from hr_addon.core import solver
    from hr_addon.core.events import DynamicRadiosity, solves
    from hr_addon.core.events import direct as ev_direct
    from hr_addon.core.gather import direct as g_direct
    from hr_addon.core.gather.direct import DirectLight
    from hr_addon.core.gather.final import FinalGather
    from hr_addon.core.gather.hostvis import HostVisibility

    cpu = time.process_time
    if args.warm is not None:
        FinalGather.WARM_TOL = args.warm
    for k, v in eval(args.gather).items():
        setattr(FinalGather, k, v)
    s, g, window = stored_room(args.store)
    if not args.still:  # a keyed sweep's window moves: the product reads the host visibility for it
        window = functools.partial(_moving, window)
    times, calls, gathers = defaultdict(float), Counter(), []

    def level(lv):
        return "top" if lv is g else "second" if lv is g.second else "slot copy"

    slot = getattr(g, "_slot", None)
    levels = (g, g.second) + ((slot["f"],) if slot is not None else ())

    def wrap(cls, name, key):
        f = getattr(cls, name)

        @functools.wraps(f)
        def timed(self, *a, **k):
            c0 = cpu()
            out = f(self, *a, **k)
            times[key(self, name)] += cpu() - c0
            calls[key(self, name)] += 1
            if name == "gather":
                gathers.append((cpu() - c0, a[0].shape[0], float(np.count_nonzero(a[0]) / max(a[0].size, 1))))
            return out

        setattr(cls, name, timed)

    for name in STAGES:
        wrap(FinalGather, name, lambda lv, n: f"{n} {level(lv)}")
    wrap(DirectLight, "_shape", lambda lv, n: f"{n} {level(lv)}")
    for name in HOST:
        wrap(HostVisibility, name, lambda H, n: f"host {n} {level(H.lv)}")
    ff = ev_direct.shape_form_factors  # (hostvis imports it from events.direct at each call)

    @functools.wraps(ff)
    def form_factors(*a, **k):
        c0 = cpu()
        out = ff(*a, **k)
        times["shape_form_factors (any level)"] += cpu() - c0
        calls["shape_form_factors (any level)"] += 1
        return out

    ev_direct.shape_form_factors = g_direct.shape_form_factors = form_factors
    counted = count_rays(s.backend)
    wrap(solves.Solves, "solve", lambda _, n: "response solve")
    wrap(solver.Operator, "gather", lambda _, n: "operator gather (nested: a grey one's channel)")

    opts = dict(DynamicRadiosity.gather_options("draft"), **eval(args.dyn))
    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile(cpu)
    dumps = {}
    out = dict(store=str(args.store), options=opts, load_average=os.getloadavg()[0], steps={})
    for method in args.methods.split(","):
        dyn = DynamicRadiosity(s.copy(), method=method, **opts)
        for lv in levels:  # (each method pays for its shape's direct light and its rays)
            lv._shape_cache.clear()
            lv.__dict__.pop("_host_stores", None)
        g.loop_radiance(dyn)  # the base parts, untimed
        steps = [("add", lambda: dyn.add("w", window(0.7))), ("move", lambda: dyn.apply({"w": window(1.2)}))]
        for k in range(1, args.sweep + 1):
            steps.append((f"sweep{k}", lambda k=k: dyn.apply({"w": window(1.2 + k * 0.5 / 23)})))
        for step, ev in steps:
            times.clear()
            calls.clear()
            gathers.clear()
            on = prof is not None and args.profile_step in (None, f"{method}_{step}")
            if on:
                prof.enable()
            n0 = counted[0]
            c0 = cpu()
            ev()
            c1 = cpu()
            v = g.loop_radiance(dyn)
            c2 = cpu()
            if on:
                prof.disable()
            dumps[f"{method}_{step}"] = v
            print(
                f"{method} {step}: event {c1 - c0:.3f} s + output {c2 - c1:.3f} s CPU "
                f"(second-level passes {g.stats.get('tail_passes')}"
                f"{' warm' if g.stats.get('warm_passes') else ''}, {counted[0] - n0:,} rays)",
                flush=True,
            )
            out["steps"][f"{method}_{step}"] = dict(
                event_cpu_s=round(c1 - c0, 4),
                output_cpu_s=round(c2 - c1, 4),
                passes=g.stats.get("tail_passes"),
                warm=bool(g.stats.get("warm_passes")),
                rays=counted[0] - n0,
                stages={k: [round(times[k], 4), calls[k]] for k in sorted(times)},
                operator_applications=[[round(t, 4), c, round(z, 4)] for t, c, z in gathers],
            )
            for k in sorted(times):
                print(f"   {k:52s} {times[k]:.3f} s  x{calls[k]}", flush=True)
            if gathers:
                print(
                    "   operator applications (s, channels, nonzero share): "
                    + ", ".join(f"({t:.3f}, {c}, {z:.3f})" for t, c, z in gathers),
                    flush=True,
                )
    if args.dump:
        np.savez(args.dump, **dumps)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    if prof is not None:
        _write_profile(prof, args.profile)


def _moving(window, cx):
    """window(cx) flagged as moving (LightShape.moves)."""
    return dataclasses.replace(window(cx), moves=True)


def tail_shares(args):
    """--tail-shares (module doc)."""
    from bench_gather_events import stored_room
    from compare_gather_dumps import difference, per_object
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.gather.final import FinalGather

    cpu = time.process_time
    s, g, window = stored_room(args.store)
    if not args.still:
        window = functools.partial(_moving, window)
    m = s.mesh
    obj = np.asarray(m.object_id)[np.repeat(np.arange(len(m.loop_start)), m.loop_total)]
    opts = DynamicRadiosity.gather_options("draft")
    steps = {"add": 0.7, "move": 1.2, "sweep1": 1.2 + 0.5 / 23}
    out, ref = {}, {}
    FinalGather.TAIL_PASSES = args.limit_passes
    for share in [args.limit] + [float(x) for x in args.tail_shares.split(",")]:
        FinalGather.TAIL_SHARE = share
        dyn = DynamicRadiosity(s.copy(), method="FE", **opts)
        g.loop_radiance(dyn)  # the base parts
        row = {}
        for k, (step, cx) in enumerate(steps.items()):
            if k == 0:
                dyn.add("w", window(cx))
            else:
                dyn.apply({"w": window(cx)})
            c0 = cpu()
            v = per_object(np.asarray(g.loop_radiance(dyn), np.float64), obj)
            row[step] = dict(output_cpu_s=round(cpu() - c0, 3), passes=int(g.stats.get("tail_passes", 0)))
            if share == args.limit:
                ref[step] = v
            else:
                row[step].update(difference(ref[step], v))
            r = row[step]
            print(
                f"share {share:g} {step}: {r['passes']} passes, output {r['output_cpu_s']:.3f} s"
                + (
                    f"; against the limit median {100 * r['median']:.3f}%, p95 {100 * r['p95']:.3f}%, "
                    f"worst {100 * r['worst']:.2f}%, bias {100 * r['bias']:+.3f}%"
                    if "median" in r
                    else ""
                ),
                flush=True,
            )
        out[str(share)] = row
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
