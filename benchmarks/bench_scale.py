"""Scale benchmark: hierarchy build on furnished rooms of ~2k to ~1M triangles, with and without
clustering, plus light events on the built system. Prints a table, writes JSON and a chart.

    .venv/bin/python benchmarks/bench_scale.py [--sizes 2k,10k,20k,100k,1M] [--plain 2k,20k]
                                               [--quality draft] [--events 100k] [--out benchmarks/out]

Every run is a separate process, so its peak memory (ru_maxrss) is its own. Timings are wall
seconds on this machine, plus the build's CPU seconds (user + system), which other jobs sharing
the cores distort much less than wall time. With --gather the rooms are built and solved as the
bake builds them with the final gather on (RefineParams.for_gather, DynamicRadiosity.gather_options).
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def run_one(size, cluster, quality, events):
    """Child process: build, solve, optionally time an FE and an AUTO event; print one JSON line."""
    import dataclasses

    import numpy as np

    from hr_testing.furnished import furnished_room
    from hr_testing import shapes as S
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    mesh, info = furnished_room(size)
    # with the final gather, the bake's transport: coarser links, solves to the output's tolerance
    gathered = int(os.environ.get("HR_GATHER_RAYS", "0")) > 0
    preset = RefineParams.for_gather(quality) if gathered else RefineParams.preset(quality)
    params = dataclasses.replace(preset, cluster=cluster)
    opts = DynamicRadiosity.gather_options(quality) if gathered else {}
    cpu = lambda: sum(resource.getrusage(resource.RUSAGE_SELF)[:2])  # user + system seconds
    peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # GB so far (Linux: kB)
    peaks = {}  # the process's high-water mark after each phase: which one raised it
    t0, c0 = time.perf_counter(), cpu()
    # progress to stderr: the parent keeps the last line when it stops a run at its time limit
    s = RadiositySystem(
        mesh,
        params,
        progress=lambda p: print(f"{p.message} [{p.elapsed:.0f} s]", file=sys.stderr, flush=True),
    )
    build, build_cpu = time.perf_counter() - t0, cpu() - c0
    build_rss = peak()  # before the solve and events
    s.solve()
    peaks["solve"] = peak()
    r = s.build.refine
    out = dict(
        size=size,
        cluster=cluster,
        quality=quality,
        triangles=info["triangles"],
        polygons=info["polygons"],
        objects=info["objects"],
        build_s=build,
        links=len(s.links),
        far_links=s.links.n_far,
        corrections=s.links.n_corrections,
        nodes=s.h.n,
        rays=r["rays"],
        cluster_pairs=r.get("cluster_pairs", 0),
        patch_pairs=r["pairs_tested"],
        solve_s=s.report.seconds,
        iterations=s.report.iterations,
        energy_error=s.report.energy_error,
        t_vis=r["t_vis"],
        t_ff=r["t_ff"],
        t_refine=r["t_refine"],
        t_clusters=r.get("t_clusters", 0.0),
        build_peak_gb=build_rss,
        build_cpu_s=build_cpu,
    )
    if events:
        _, frame = info["light_wall"]
        window = LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )
        for method in ("FE", "AUTO"):
            dyn = DynamicRadiosity(s.copy(), method=method, **opts)
            t1, c1 = time.perf_counter(), cpu()
            rep = dyn.add("w", window)
            out[f"{method.lower()}_event_s"] = time.perf_counter() - t1
            out[f"{method.lower()}_event_cpu_s"] = cpu() - c1
            out[f"{method.lower()}_iterations"] = rep.iterations
            peaks[f"{method.lower()}_event"] = peak()
            del dyn
    rays = int(os.environ.get("HR_GATHER_RAYS", "0"))
    if rays:  # the final gather at the mesh's corners (hr_addon.core.gather.LoopGather)
        from hr_addon.core.gather import LoopGather

        _, frame = info["light_wall"]
        window = LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(0.7, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )
        # the system itself, as a bake has one (copies above: the events start from the same base)
        dyn = DynamicRadiosity(s, method="FE", **opts)
        dyn.add("w", window)
        peaks["gather_system"] = peak()
        c1 = cpu()
        levels = int(os.environ.get("HR_GATHER_LEVELS", "1"))
        its = int(os.environ.get("HR_GATHER_ITERATIONS", "0"))
        srays = int(os.environ.get("HR_GATHER_SHADOW_RAYS", "32"))
        g = LoopGather(dyn, rays=rays, shadow_rays=srays, levels=levels, iterations=its)
        out.update(
            gather_levels=levels,
            gather_iterations=its,
            gather_rays=rays,
            gather_shadow_rays=srays,
            gather_samples=g.n,
            gather_precompute_cpu_s=cpu() - c1,
        )
        out["gather_weights_mb"] = g.weights_bytes / 1e6
        out["gather_nnz"] = int(len(g.w))
        peaks["gather_precompute"] = peak()
        c1 = cpu()
        g.loop_radiance(dyn)
        out["gather_first_evaluate_cpu_s"] = cpu() - c1  # direct light of every emitter
        peaks["gather_first_evaluate"] = peak()
        c1 = cpu()
        g.loop_radiance(dyn)
        out["gather_evaluate_cpu_s"] = cpu() - c1  # a frame with no emitter changed: the matvec
        dyn.apply({"w": LightShape(window.rings, np.array([10.0, 20.0, 30.0]), "window")})
        c1 = cpu()
        g.loop_radiance(dyn)
        out["gather_colour_edit_evaluate_cpu_s"] = cpu() - c1
        moved = LightShape(
            S.on_plane(S.rect(0.9, 0.7, centre=(1.2, 0.6), angle=0.2), frame), np.full(3, 20.0), "window"
        )
        c1 = cpu()
        dyn.apply({"w": moved})
        out["fe_moved_apply_cpu_s"] = cpu() - c1  # the light event of the move (FE), before the gather
        c1 = cpu()
        g.loop_radiance(dyn)
        out["gather_moved_shape_evaluate_cpu_s"] = cpu() - c1  # the moved shape's direct light
        peaks["gather_moved"] = peak()
        del dyn, g
    out["peak_rss_gb"] = peak()
    out["peak_after_gb"] = peaks
    print(json.dumps(out), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="2k,10k,20k,100k,1M")
    ap.add_argument("--plain", default="2k,20k", help="sizes also built without clustering (all patch pairs)")
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--events", default="100k", help="sizes on which FE and AUTO events are timed")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    ap.add_argument("--timeout", type=float, default=1800, help="seconds per run before it is stopped")
    ap.add_argument("--table", action="store_true", help="print the markdown table of the JSON and stop")
    ap.add_argument("--gather", type=int, default=0, help="also time the final gather with this many rays")
    ap.add_argument("--gather-levels", type=int, default=1, help="1, 2 (the two-level gather), 3, ...")
    ap.add_argument(
        "--gather-iterations", type=int, default=0, help="two levels: passes among the gather samples"
    )
    ap.add_argument(
        "--gather-shadow-rays", type=int, default=32, help="shadow rays per emitter (bakes: 16 at draft)"
    )
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.gather:
        os.environ["HR_GATHER_RAYS"] = str(args.gather)
        os.environ["HR_GATHER_LEVELS"] = str(args.gather_levels)
        os.environ["HR_GATHER_ITERATIONS"] = str(args.gather_iterations)
        os.environ["HR_GATHER_SHADOW_RAYS"] = str(args.gather_shadow_rays)
    if args.child:
        size, cluster, events = args.child
        return run_one(size, cluster == "1", args.quality, events == "1")
    if args.table:
        print(table(json.loads((Path(args.out) / f"scale_{args.quality}.json").read_text())))
        return
    os.makedirs(args.out, exist_ok=True)
    runs = [(s, True) for s in args.sizes.split(",") if s] + [(s, False) for s in args.plain.split(",") if s]
    results = []
    for size, cluster in runs:
        ev = cluster and size in args.events.split(",")
        cmd = [
            sys.executable,
            __file__,
            "--quality",
            args.quality,
            "--child",
            size,
            "1" if cluster else "0",
            "1" if ev else "0",
        ]
        rss0 = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
        except subprocess.TimeoutExpired as e:
            rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            last = (e.stderr or b"").decode(errors="replace").strip().splitlines()[-1:] or ["no progress"]
            results.append(
                dict(
                    size=size,
                    cluster=cluster,
                    quality=args.quality,
                    timeout_s=args.timeout,
                    peak_rss_gb=rss / 1e6 if rss > rss0 else None,
                    last_progress=last[0],
                )
            )
            print(f"{size} cluster={cluster}: stopped after {args.timeout:.0f} s at '{last[0]}'", flush=True)
            continue
        if p.returncode != 0:
            print(f"{size} cluster={cluster}: failed\n{p.stderr[-2000:]}", flush=True)
            continue
        res = json.loads(p.stdout.strip().splitlines()[-1])
        results.append(res)
        ev_txt = (
            f", FE event {res['fe_event_s']:.2f} s, AUTO event {res['auto_event_s']:.2f} s"
            if "fe_event_s" in res
            else ""
        )
        if "gather_rays" in res:
            print(
                "   final gather: "
                + ", ".join(f"{k} {v:.3g}" for k, v in res.items() if k.startswith("gather"))
            )
        print(
            f"{size:>5} {'clusters' if cluster else 'all pairs':>9}: {res['triangles']:,} triangles, "
            f"build {res['build_s']:.1f} s ({res['build_cpu_s']:.1f} s CPU), "
            f"{res['links']:,} links ({res['far_links']:,} far), "
            f"{res['links'] / res['triangles']:.1f} per triangle, "
            f"peak {res['peak_rss_gb']:.2f} GB, "
            f"solve {res['solve_s']:.1f} s ({res['iterations']} it){ev_txt}",
            flush=True,
        )
    path = Path(args.out) / f"scale_{args.quality}{'_gather' if args.gather else ''}.json"
    # runs of other sizes measured earlier stay (each entry is one process of one run)
    old = json.loads(path.read_text()) if path.exists() else []
    new = {(r["size"], r["cluster"]) for r in results}
    results = [r for r in old if (r["size"], r["cluster"]) not in new] + results
    path.write_text(json.dumps(results, indent=1))
    if args.gather:
        print(f"wrote {path}")
        return
    plot(results, ROOT / "benchmarks" / "scale.png")
    print(table(results))
    print(f"wrote {path} and benchmarks/scale.png")


def table(results):
    """Markdown table of the runs in the JSON (README, docs/scale.md)."""
    L = [
        "| triangles | linking | build (wall) | build (CPU) | links | links / triangle | far links | "
        "peak memory, build | solve (iterations) | FE / AUTO event |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (not r["cluster"], r.get("triangles", float("inf")))):
        kind = "clusters" if r["cluster"] else "all pairs"
        if "build_s" not in r:
            L.append(
                f"| ~{r['size']} | {kind} | "
                f"stopped after {r['timeout_s']:.0f} s ({r['last_progress']}) | | | | | "
                f"{r['peak_rss_gb'] or 0:.1f} GB | | |"
            )
            continue
        ev = f"{r['fe_event_s']:.1f} s / {r['auto_event_s']:.1f} s" if "fe_event_s" in r else ""
        cpu = f"{r['build_cpu_s']:.1f} s" if "build_cpu_s" in r else ""
        mem = f"{r['build_peak_gb']:.2f} GB" if "build_peak_gb" in r else ""
        L.append(
            f"| {r['triangles']:,} | {kind} | {r['build_s']:.1f} s | {cpu} | {r['links']:,} | "
            f"{r['links'] / r['triangles']:.1f} | {r['far_links']:,} | {mem} | "
            f"{r['solve_s']:.1f} s ({r['iterations']}) | {ev} |"
        )
    return "\n".join(L)


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    done = [r for r in results if "build_s" in r]
    key = "build_cpu_s" if done and all("build_cpu_s" in r for r in done) else "build_s"
    for cluster, style, label in ((True, "o-", "clusters"), (False, "s--", "all patch pairs")):
        rs = sorted(
            (r for r in results if r["cluster"] == cluster and "build_s" in r), key=lambda r: r["triangles"]
        )
        if not rs:
            continue
        tri = [r["triangles"] for r in rs]
        axes[0].loglog(tri, [r[key] for r in rs], style, label=label)
        axes[1].loglog(tri, [r["links"] for r in rs], style, label=label)
    for ax, what in zip(axes, ("build CPU time (s)" if key == "build_cpu_s" else "build time (s)", "links")):
        ax.set_xlabel("triangles (furnished room)")
        ax.set_ylabel(what)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    axes[0].set_title("Hierarchy build at draft quality")
    axes[1].set_title("Links")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
