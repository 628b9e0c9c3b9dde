"""Memory and CPU of the texture output's final gather at a Texel Density, core only: the furnished
room (hr_testing.furnished), every object's lightmap sized by area (lightmap.charts.lightmap_size
at `--density` texels per unit, 8 to `--largest`, as the bake's texture.resolution_for) and packed
from its world-space polygons (charts.pack_lightmap), the texel gather built as the bake builds it
(TexturePlan.final_gather with settings.GATHER[quality], then io.precompute.prepare), its first
frame evaluated. Peak RSS per stage from a sampler thread (every 20 ms; where the peak was: the
main thread's stack at the sample that set it), CPU seconds (time.process_time), one run.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_texel_memory.py \
        [--size 20k] [--density 50] [--store DIR] [--profile out.txt] [--dump out.npz] [--json out.json]

--store DIR: also write the scene precompute (io.precompute.write) there: the file's size and the
write's peak. --dump: the first frame's texel values (outgoing radiance and irradiance) and the
gather's sample and weight counts, to compare variants bitwise.
"""

import argparse
import dataclasses
import json
import os
import resource
import sys
import threading
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

PAGE = os.sysconf("SC_PAGE_SIZE")


class RssSampler(threading.Thread):
    """Peak RSS per stage (`stage` set by the main thread) and the main thread's stack at the
    sample that set the overall peak."""

    def __init__(self, every=0.02):
        super().__init__(daemon=True)
        self.every, self.stage, self.peaks, self.peak, self.where = every, "start", {}, 0, ""
        self.main = threading.main_thread().ident
        self.done = False
        self.by_line = {}  # innermost hr_addon frame -> peak RSS while there
        self.timeline = []  # [function (outermost two hr_addon frames), peak RSS, samples] in order

    @staticmethod
    def rss():
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * PAGE

    def run(self):
        while not self.done:
            r = self.rss()
            st = self.stage
            self.peaks[st] = max(self.peaks.get(st, 0), r)
            fr = sys._current_frames().get(self.main)
            if fr is not None:
                f = fr
                while f is not None and "hr_addon" not in f.f_code.co_filename:
                    f = f.f_back
                if f is not None:
                    k = f"{Path(f.f_code.co_filename).name}:{f.f_lineno} {f.f_code.co_name}"
                    self.by_line[k] = max(self.by_line.get(k, 0), r)
                    names = []
                    while f is not None:
                        if "hr_addon" in f.f_code.co_filename:
                            names.append(f"{f.f_code.co_name}:{f.f_lineno}")
                        f = f.f_back
                    k = " < ".join(names[-4:-1][::-1] if len(names) > 1 else names)
                    if self.timeline and self.timeline[-1][0] == k:
                        self.timeline[-1][1] = max(self.timeline[-1][1], r)
                        self.timeline[-1][2] += 1
                    else:
                        self.timeline.append([k, r, 1])
            if r > self.peak:
                self.peak = r
                if fr is not None:
                    self.where = "".join(traceback.format_stack(fr, limit=12)[-8:])
            time.sleep(self.every)


def furnished_plan(s, density, largest):
    """TexturePlan of the system's objects, each lightmap sized and packed as the bake does it."""
    from hr_addon.lightmap import charts
    from hr_addon.lightmap.plan import TexturePlan, triangle_uvs

    m = s.mesh
    ls, lt, lv = (np.asarray(a, np.int64) for a in (m.loop_start, m.loop_total, m.loop_verts))
    oid_poly = np.asarray(m.object_id)
    uv = np.zeros((len(lv), 2))
    sizes = {}
    for oid in np.unique(oid_poly):
        polys = np.flatnonzero(oid_poly == oid)
        loops = np.concatenate([np.arange(ls[p], ls[p] + lt[p]) for p in polys])
        verts, lv_o = np.unique(lv[loops], return_inverse=True)
        ls_o = np.concatenate([[0], np.cumsum(lt[polys])[:-1]])
        co = np.asarray(m.verts, np.float64)[verts]
        res = charts.lightmap_size(co, ls_o, lt[polys], lv_o, density, 8, largest) if density > 0 else largest
        uv[loops] = charts.pack_lightmap(co, ls_o, lt[polys], lv_o, res)
        sizes[int(oid)] = res
    plan = TexturePlan()
    for oid in np.unique(s.patches.object_id):
        tri_uv, corners, tri_patch, _ = triangle_uvs(s.patches, oid, uv, ls, lt, lv, 0, 0, len(m.verts))
        if len(tri_uv):
            plan.add_object(f"o{oid}", f"o{oid}", sizes[int(oid)], tri_uv, corners, tri_patch, "")
    return plan, sizes


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="20k")
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--density", type=float, default=50.0)
    ap.add_argument("--largest", type=int, default=128)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--store", default=None)
    ap.add_argument("--profile", default=None, help="cProfile of the gather's precompute, written here")
    ap.add_argument("--dump", default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--trace", action="store_true", help="tracemalloc: what the gather holds after prepare")
    args = ap.parse_args(argv)

    from hr_testing.furnished import furnished_room
    from hr_addon.blender.settings import GATHER
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    from hr_addon.io import precompute as pc

    cpu = time.process_time
    smp = RssSampler()
    smp.start()
    out = dict(size=args.size, quality=args.quality, density=args.density, threads=args.threads)
    out["load_average"] = os.getloadavg()[0]
    mesh, _ = furnished_room(args.size)
    q = args.quality
    # the bake's (settings.refine_params with the final gather: RefineParams.for_gather, orient)
    params = dataclasses.replace(RefineParams.for_gather(q), contacts=True, orient=True)
    smp.stage = "build"
    c0 = cpu()
    s = RadiositySystem(mesh, params, threads=args.threads)
    dyn = DynamicRadiosity(s, method="FE")
    out["build_cpu_s"] = cpu() - c0
    smp.stage = "plan"
    c0 = cpu()
    plan, sizes = furnished_plan(s, args.density, args.largest)
    out["plan_cpu_s"] = cpu() - c0
    out["texels"] = plan.texels
    out["sizes"] = {str(r): int(c) for r, c in zip(*np.unique(list(sizes.values()), return_counts=True))}
    print(f"build {out['build_cpu_s']:.1f} s CPU; {plan.texels:,} texels", flush=True)
    gkw = dict(GATHER[q.upper()], threads=args.threads)
    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile(time.process_time)
        prof.enable()
    if args.trace:
        import tracemalloc

        tracemalloc.start(6)
    smp.stage = "gather"
    base_rss = smp.rss()
    c0 = cpu()
    g = plan.final_gather(dyn, **gkw)
    out["gather_cpu_s"] = cpu() - c0
    smp.stage = "prepare"
    c0 = cpu()
    pc.prepare(g)
    out["prepare_cpu_s"] = cpu() - c0
    if prof is not None:
        prof.disable()
    if args.trace:
        snap = tracemalloc.take_snapshot()
        out["traced_peak_gb"] = tracemalloc.get_traced_memory()[1] / 1e9
        tracemalloc.stop()
        top = snap.statistics("traceback")[:25]
        where = [[f"{Path(f.filename).name}:{f.lineno}" for f in st.traceback] for st in top]
        out["held"] = [[st.size / 1e6, w] for st, w in zip(top, where)]
        for st, w in zip(top, where):
            print(f"{st.size / 1e6:8.1f} MB", " < ".join(w))
    out["after_gather_rss_gb"] = smp.rss() / 1e9
    out["gather_samples"], out["weights_mb"] = g.n, g.weights_bytes / 1e6
    lv, levels = g, []
    while lv is not None:
        levels.append(dict(samples=int(lv.n), entries=int(len(lv.cols)), weights_mb=lv.weights_bytes / 1e6))
        lv = lv.second
    out["levels"] = levels
    smp.stage = "frame"
    c0 = cpu()
    rad = plan.radiance(dyn, gather=g)
    irr = plan.radiance(dyn, "IRRADIANCE", gather=g)
    out["frame_cpu_s"] = cpu() - c0
    if args.store:
        smp.stage = "store"
        c0 = cpu()
        want = pc.expected(mesh, params, gather=dict(GATHER[q.upper()]), final_gather="texture")
        pc.write(args.store, *pc.capture(s, g), want, info={})
        out["store_cpu_s"] = cpu() - c0
        out["store_gb"] = (Path(args.store) / pc.FILENAME).stat().st_size / 1e9
    smp.done = True
    smp.join()
    out["peak_rss_gb"] = {k: v / 1e9 for k, v in smp.peaks.items()}
    out["gather_base_rss_gb"] = base_rss / 1e9
    out["maxrss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    out["peak_where"] = smp.where
    out["timeline"] = [[k, v / 1e9, c] for k, v, c in smp.timeline if c >= 5 or v > 0.8 * smp.peak]
    by_line = sorted(((k, v / 1e9) for k, v in smp.by_line.items()), key=lambda x: -x[1])
    out["peak_by_line_gb"] = dict(by_line[:40])
    out["stats"] = {k: v for k, v in g.stats.items() if np.isscalar(v)}
    print(json.dumps({k: v for k, v in out.items() if k != "peak_where"}, indent=1), flush=True)
    print("peak at:\n" + smp.where, flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    if args.dump:
        np.savez_compressed(args.dump, radiance=rad, irradiance=irr, samples=g.n)
    if prof is not None:
        import io
        import pstats

        buf = io.StringIO()
        st = pstats.Stats(prof, stream=buf).sort_stats("cumulative")
        st.print_stats(70)
        st.sort_stats("tottime").print_stats(40)
        Path(args.profile).write_text(buf.getvalue())


if __name__ == "__main__":
    main()
