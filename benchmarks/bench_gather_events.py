"""Light events with the final gather on, on a furnished room: build, gather precompute, FE and
AUTO events (a new window, a moved window, a colour edit), each until the gathered output is
ready; CPU seconds (time.process_time) and wall seconds, one run. Optionally a cProfile of the
events and a dump of the gathered output for comparing transport settings (coarse vs fine).

    .venv/bin/python benchmarks/bench_gather_events.py --size 100k --quality draft \
        [--transport gather] [--params 'dict(feps=0.1)'] [--response-tol 1e-4] \
        [--profile out.txt] [--dump out.npz] [--json out.json] [--threads N] [--cache DIR] \
        [--texels RES]

--cache DIR: build the system, its base solution and the gather once and keep them there as a
scene precompute (io/precompute.py); later runs load them (without checking the code version:
for timing the events of code that does not change what is stored) and cost only the events.

--texels RES: texture output instead of the mesh's corners: the room's polygons packed into one
RES x RES lightmap (lightmap.charts.pack_lightmap), every object's texels of it gathered by
TexturePlan.final_gather (texel_gather: texel areas, edge texels); the events end when
TexturePlan.radiance is ready. With --cache the stored system is used, the texel gather built.

--transport gather: the transport settings used when the final gather is on
(RefineParams.for_gather / DynamicRadiosity's gather options); default: today's presets.
"""

import argparse
import dataclasses
import json
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def set_constants(items):
    """module.NAME=value (or module.Class.NAME=value) under hr_addon.core, set before the build
    (issue 19, build60: farlinks.SECOND_TRACE=False)."""
    import importlib

    for kv in items:
        name, value = kv.split("=", 1)
        mod, *path, attr = name.split(".")
        target = importlib.import_module(f"hr_addon.core.{mod}")
        for part in path:
            target = getattr(target, part)
        if not hasattr(target, attr):
            raise SystemExit(f"--set {kv}: hr_addon.core.{name} does not exist")
        setattr(target, attr, eval(value))


def load_store(path):
    """(system, gather, header) of a stored build; a store from before near hits (230d7a5) gets
    its second level's start (k points per leaf) derived."""
    from hr_addon.io import precompute as pc

    arrays, header = pc.read(path)
    s, g = pc.restore(arrays, header["graph"])
    lv = g
    while lv is not None and lv.second is not None:
        if not hasattr(lv, "_second_start"):
            used = lv._second_map[0]
            lv._second_start = np.arange(len(used) + 1) * (lv.second.n // max(len(used), 1))
        lv = lv.second
    return s, g, header


def stored_room(store):
    """(system, gather, window) of the furnished 100k room stored by --cache in folder `store`, the
    solver's far-link terms made; window(cx, em=20.0): the benchmark's window LightShape at cx."""
    from hr_addon.core.events import LightShape
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    s, g, _ = load_store(Path(store) / pc.FILENAME)
    s.links.extended(s.h)
    _, info = furnished_room("100k")
    _, frame = info["light_wall"]

    def window(cx, em=20.0):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.broadcast_to(np.asarray(em, float), (3,)).copy(), "window")

    return s, g, window


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="20k")
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--transport", default="classic", choices=("classic", "gather"))
    ap.add_argument("--params", default="dict()", help="RefineParams overrides (a Python dict)")
    ap.add_argument("--response-tol", type=float, default=None)
    ap.add_argument("--response-steps", type=int, default=None, help="responses: GMRES steps from zero")
    ap.add_argument("--no-steps", action="store_true", help="responses to response_tol (before the steps)")
    ap.add_argument("--f32", action="store_true", help="responses gather in float32")
    ap.add_argument("--rays", type=int, default=128)
    ap.add_argument("--shadow-rays", type=int, default=None)
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--methods", default="FE,AUTO")
    ap.add_argument("--profile", default=None, help="write a cProfile summary of the events here")
    ap.add_argument(
        "--profile-steps",
        default=None,
        help="with --profile: only these steps (e.g. FE_move,AUTO_add), each its own cProfile in "
        "process time, written to PROFILE.STEP.txt",
    )
    ap.add_argument("--dump", default=None, help="npz of the gathered output after each event")
    ap.add_argument("--json", default=None)
    ap.add_argument("--threads", type=int, default=1, help="core.parallel's threads (0: every core)")
    ap.add_argument("--cache", default=None, help="folder of a stored build (see the module doc)")
    ap.add_argument("--dyn", default="dict()", help="DynamicRadiosity option overrides (a Python dict)")
    ap.add_argument("--texels", type=int, default=0, help="texture output at RES x RES (module doc)")
    ap.add_argument("--set", action="append", default=[], help="module.NAME=value under hr_addon.core")
    args = ap.parse_args(argv)
    set_constants(args.set)

    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.gather import LoopGather
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_addon.io import precompute as pc

    cpu, wall = time.process_time, time.perf_counter
    mesh, info = furnished_room(args.size)
    q = args.quality
    base = RefineParams.preset(q)
    dkw = {}
    if args.transport == "gather":
        base = RefineParams.for_gather(q)
        dkw = DynamicRadiosity.gather_options(q)
    params = dataclasses.replace(base, **eval(args.params))
    if args.response_tol is not None:
        dkw["response_tol"] = args.response_tol
    if args.response_steps is not None:
        dkw["response_steps"] = args.response_steps
    if args.no_steps:
        dkw.pop("response_steps", None)
    if args.f32:
        dkw["response_float32"] = True
    dkw.update(eval(args.dyn))
    out = dict(size=args.size, quality=q, transport=args.transport, params=dataclasses.asdict(params))
    out["set"] = list(args.set)
    out["threads"], out["load_average"] = args.threads, os.getloadavg()[0]
    out["dyn_options"] = dict(dkw)
    gkw = dict(rays=args.rays, levels=args.levels, iterations=args.iterations, threads=args.threads)
    # the bake's settings (hr_addon/blender/settings.py GATHER): 16 shadow rays at draft, 32 above
    gkw["shadow_rays"] = args.shadow_rays or (16 if q == "draft" else 32)
    stored = Path(args.cache) / pc.FILENAME if args.cache else None
    g = None
    if stored is not None and stored.exists():
        s, g, header = load_store(stored)
        pc.use_threads(s, g, args.threads)
        g.iterations = args.iterations  # (the store's: 4; more for a converged reference)
        out.update(header["info"])
        out["loaded"] = str(stored)
        # the solver's far-link terms: stored since branch pcio (about 0 here); a store of older
        # code lacks them and a re-bake's first event would pay them: here once before the events
        c0 = cpu()
        s.links.extended(s.h)
        out["terms_after_load_cpu_s"] = cpu() - c0
        print(f"loaded {stored}", flush=True)
    else:
        c0 = cpu()
        s = RadiositySystem(mesh, params, threads=args.threads)
        out["build_cpu_s"] = cpu() - c0
        out["build_peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
        if stored is not None:
            c0 = cpu()
            # the base solution (kept on the system) and the gather, as a bake stores them
            g = LoopGather(DynamicRadiosity(s, method="FE", **dkw), **gkw)
            pc.prepare(g)
            meta = {k: out[k] for k in ("build_cpu_s", "build_peak_gb")}
            meta["gather_precompute_cpu_s"] = cpu() - c0
            want = pc.expected(mesh, params, gather=gkw, quality=q)
            pc.write(args.cache, *pc.capture(s, g), want, info=meta)
    if args.texels:
        g = None  # the texel gather is built below (the stored one is the corners')
    out["links"], out["nodes"] = len(s.links), s.h.n
    print(f"build {out.get('build_cpu_s', 0):.1f} s CPU, {out['links']:,} links, {s.h.n:,} nodes", flush=True)
    _, frame = info["light_wall"]
    plan = texture_plan(s, args.texels) if args.texels else None
    if plan is not None:
        out["texels"] = plan.objects[-1].hi
        print(f"{out['texels']:,} texels ({args.texels}^2 lightmap)", flush=True)

    def new_gather(dyn):
        return LoopGather(dyn, **gkw) if plan is None else plan.final_gather(dyn, **gkw)

    def output(dyn):
        return g.loop_radiance(dyn) if plan is None else plan.radiance(dyn, gather=g)

    def window(cx, em=20.0):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.broadcast_to(np.asarray(em, float), (3,)).copy(), "window")

    prof = None
    only = set(args.profile_steps.split(",")) if args.profile_steps else None
    if args.profile:
        import cProfile

        prof = cProfile.Profile() if only is None else None
    dumps = {}
    for method in args.methods.split(","):
        c0 = cpu()
        dyn = DynamicRadiosity(s.copy(), method=method, **dkw)
        out[f"{method}_base_solve_cpu_s"] = cpu() - c0
        out[f"{method}_base_iterations"] = int(dyn.base_iterations)
        if g is None:
            c0 = cpu()
            g = new_gather(dyn)
            out["gather_precompute_cpu_s"] = cpu() - c0
            out["gather_samples"], out["gather_weights_mb"] = g.n, g.weights_bytes / 1e6
            c0 = cpu()
            output(dyn)
            out["gather_first_frame_cpu_s"] = cpu() - c0
            print(f"gather precompute {out['gather_precompute_cpu_s']:.1f} s CPU", flush=True)
        else:
            lv = g
            while lv is not None:  # the shape's direct light is the method's event cost too
                lv._shape_cache.clear()
                lv = lv.second
            output(dyn)  # base parts of this DynamicRadiosity
        steps = [
            ("add", lambda: dyn.add("w", window(0.7))),
            ("move", lambda: dyn.apply({"w": window(1.2)})),
            ("colour", lambda: dyn.apply({"w": window(1.2, (10.0, 20.0, 30.0))})),
            ("strength", lambda: dyn.apply({"w": window(1.2, (20.0, 40.0, 60.0))})),
        ]
        for name, ev in steps:
            if only is not None and f"{method}_{name}" in only:
                prof = cProfile.Profile(time.process_time)
            if prof is not None:
                prof.enable()
            e0 = g.stats.get("edge_texels_cpu", 0.0)
            c0, w0 = cpu(), wall()
            rep = ev()
            c1 = cpu()
            v = output(dyn)
            c2, w2 = cpu(), wall()
            edge = g.stats.get("edge_texels_cpu", 0.0) - e0  # texel_edges.edge_direct (texels)
            if prof is not None:
                prof.disable()
                if only is not None:
                    _write_profile(prof, f"{args.profile}.{method}_{name}.txt")
                    prof = None
            out[f"{method}_{name}_cpu_s"] = c2 - c0
            out[f"{method}_{name}_wall_s"] = w2 - w0
            out[f"{method}_{name}_solve_cpu_s"] = c1 - c0
            out[f"{method}_{name}_iterations"] = int(rep.iterations)
            out[f"{method}_{name}_edge_texels_cpu_s"] = edge
            dumps[f"{method}_{name}"] = v
            print(
                f"{method} {name}: {c2 - c0:.3f} s CPU (event {c1 - c0:.3f} s, {rep.iterations} it; "
                f"gather {c2 - c1:.3f} s, of it edge texels {edge:.3f} s; wall {w2 - w0:.3f} s)",
                flush=True,
            )
        dyn = None  # noqa: F841 (frees it before the next method)
    out["peak_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    print(json.dumps({k: v for k, v in out.items() if k != "params"}), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    if args.dump and plan is None:
        obj = np.asarray(s.mesh.object_id)[np.repeat(np.arange(len(s.mesh.loop_start)), s.mesh.loop_total)]
        np.savez_compressed(args.dump, loop_object=obj, **dumps)
    if prof is not None:
        _write_profile(prof, args.profile)


def _write_profile(prof, path):
    import io
    import pstats

    buf = io.StringIO()
    st = pstats.Stats(prof, stream=buf).sort_stats("cumulative")
    st.print_stats(60)
    st.sort_stats("tottime").print_stats(40)
    Path(path).write_text(buf.getvalue())


def texture_plan(s, res):
    """TexturePlan of the system's mesh: its polygons packed into one res x res lightmap, each
    object's texels of it an object of the plan."""
    from hr_addon.lightmap import charts
    from hr_addon.lightmap.plan import TexturePlan, triangle_uvs

    m = s.mesh
    uv = charts.pack_lightmap(m.verts, m.loop_start, m.loop_total, m.loop_verts, res)
    plan = TexturePlan()
    for oid in np.unique(s.patches.object_id):
        tri_uv, corners, tri_patch, _ = triangle_uvs(
            s.patches, oid, uv, m.loop_start, m.loop_total, m.loop_verts, 0, 0, len(m.verts)
        )
        if len(tri_uv):
            plan.add_object(f"o{oid}", f"o{oid}", res, tri_uv, corners, tri_patch, "")
    return plan


if __name__ == "__main__":
    main()
