"""Accuracy against Cycles, and the speed-accuracy chart (see docs/accuracy.md).

For each sample scene and a few frames: a converged Cycles reference bake (Diffuse, Direct +
Indirect + Color = reflected radiance, one-sided emitters, 64 bounces, no clamping, float
Non-Color images, margin 0; helpers in benchmarks/cycles_ref.py) and our solution (the add-on's
own scene reader, RadiositySystem + DynamicRadiosity, every method and quality preset, frames
applied in order as the bake does) compared texel by texel on the same surfaces. Cycles is also
baked at several sample counts with two seeds (its noise = error of an unbiased estimate).

    .venv/bin/python benchmarks/cycles_compare.py [--quick] [--scenes cornell,searchbeam]
    .venv/bin/python benchmarks/cycles_compare.py --plot-only      # chart from the JSON

Writes benchmarks/out/cycles.json, benchmarks/cycles_speed_accuracy.png and
benchmarks/out/cycles_maps_cornell.png (error maps). Cycles bakes are cached in
benchmarks/out/cycles_cache/ (not committed). Everything runs on one thread (Cycles threads=1,
BLAS single-threaded) so that times compare like for like.
"""
import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, HERE)
OUT = os.path.join(HERE, "out")
CACHE = os.path.join(OUT, "cycles_cache")
JSON_PATH = os.path.join(OUT, "cycles.json")
CHART = os.path.join(HERE, "cycles_speed_accuracy.png")

SCENES = {
    # frames in bake order; sweep_frame: Cycles at several sample counts (two seeds each)
    "cornell": dict(frames=[1, 6, 13, 21], sweep_frame=13, ref_spp=512, sweep=[4, 16, 64, 256],
                    qualities=["draft", "medium", "high"], methods=["NAIVE", "AR", "FE", "AUTO"],
                    texel_rel=1 / 64),
    "searchbeam": dict(frames=[1, 6, 12], sweep_frame=None, ref_spp=256, sweep=[],
                       qualities=["medium"], methods=["FE", "AUTO"], texel_rel=1 / 48),
    "office": dict(frames=[1, 4, 8], sweep_frame=None, ref_spp=256, sweep=[],
                   qualities=["medium"], methods=["FE", "AUTO"], texel_rel=1 / 48),
}
QUICK = {"frames": [1, 13], "sweep": [4, 16], "ref_spp": 64, "qualities": ["draft"], "methods": ["FE", "AUTO"]}
REF_SEEDS = (1, 2)
SWEEP_SEEDS = (11, 12)
VARIANTS = ("refl_leaf", "refl_smooth", "total_leaf", "total_vertex")


def log(msg, t0=[time.perf_counter()]):
    print(f"{time.perf_counter() - t0[0]:7.1f}s {msg}", flush=True)


def load_bpy():
    import bpy
    import hr_addon
    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    return bpy


def open_scene(name):
    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "sample_blends", f"{name}.blend"), load_ui=False)
    return bpy.context.scene


def clone(system):
    """Independent copy of a built RadiositySystem (hierarchy deep-copied, links shared)."""
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import Refiner
    c = object.__new__(RadiositySystem)
    c.__dict__.update(system.__dict__)
    c.h = copy.deepcopy(system.h)
    c.refiner = Refiner(c.h, system.backend, system.params)
    c._op = None
    return c


# --------------------------------------------------------------------------------------------
# Cycles side (cached)
# --------------------------------------------------------------------------------------------

def _atlas_key(rs):
    m = hashlib.sha1()
    for n in rs.objects:
        at = rs.atlases[n]
        m.update(f"{n}:{at.width}x{at.height}:{at.n}:{at.texel:.6g};".encode())
    return m.hexdigest()[:10]


USE_CACHE = True


def cycles_bake(rs, scene, frame, spp, seed, need_time=False):
    """Reflected radiance per texel {name: (N, 3)}, bake times {wall, cpu}, cached flag. Cached
    bakes are reused (values only matter for references); need_time re-bakes cached bakes that
    have no CPU time."""
    import cycles_ref as C
    key = f"{scene}_f{frame}_s{spp}_seed{seed}_{_atlas_key(rs)}"
    path = os.path.join(CACHE, key + ".npz")
    if USE_CACHE and os.path.exists(path):
        z = np.load(path)
        if not need_time or "__cpu" in z:
            t = {"wall": float(z["__seconds"]), "cpu": float(z["__cpu"]) if "__cpu" in z else float("nan")}
            return {n: z[n].astype(np.float64) for n in rs.objects}, t, True
    vals, dt, mask = C.bake(rs, spp, seed)
    bad = {n: int((~m).sum()) for n, m in mask.items() if (~m).any()}
    if bad:
        log(f"  warning: texels not written by the bake: {bad}")
    for n in rs.objects:
        vals[n][~mask[n]] = np.nan
    os.makedirs(CACHE, exist_ok=True)
    np.savez(path, __seconds=dt["wall"], __cpu=dt["cpu"], **{n: v.astype(np.float32) for n, v in vals.items()})
    return vals, dt, False


# --------------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------------

def pooled(d):
    """Concatenate {name: (N, 3)} in a fixed order."""
    return np.concatenate([d[n] for n in sorted(d)])


def compare(res, ref, sigma_ref, objects):
    """Metrics of every variant against the reference, per surface and pooled."""
    import cycles_ref as C
    out = {}
    for var in VARIANTS:
        kind, src = var.split("_")
        key = {"leaf": "leaf_refl" if kind == "refl" else "leaf_total", "smooth": "smooth_refl",
               "vertex": "vertex_total"}[src]
        if key not in res[objects[0]]:
            continue
        per, ours_all, ref_all = {}, {}, {}
        for n in objects:
            r = ref[n] if kind == "refl" else ref[n] + res[n]["emission"]
            o = res[n][key]
            per[n] = C.metrics(o, r)
            ours_all[n], ref_all[n] = o, r
        pa = C.metrics(pooled(ours_all), pooled(ref_all))
        s2 = sigma_ref ** 2
        pa["rmse_corrected"] = float(np.sqrt(max(pa["rmse"] ** 2 - s2, 0.0)))
        pa["worst_mre"] = max(per[n]["mre"] for n in objects)
        pa["worst_surface"] = max(objects, key=lambda n: per[n]["mre"])
        pa["mean_mre"] = float(np.mean([per[n]["mre"] for n in objects]))
        out[var] = {"all": pa, "surfaces": per}
    return out


def footprint_masks(rs, band):
    """(inside, near) floor texel masks: texel centres under a block footprint / within `band`
    of one (outside). Footprints from the blocks' vertices at floor height (convex)."""
    import bpy
    at = rs.atlases["floor"]
    cen = at.s_centre
    pts = np.zeros((at.n, 3))
    pts[at.s_texel[cen]] = at.s_point[cen]
    p = pts[:, :2]
    inside = np.zeros(at.n, bool)
    dist = np.full(at.n, np.inf)
    for ob in bpy.data.objects:
        if ob.type != "MESH" or "block" not in ob.name or ob.name.startswith("REF"):
            continue
        M = np.array(ob.matrix_world)
        v = np.array([M[:3, :3] @ np.array(x.co) + M[:3, 3] for x in ob.data.vertices])
        base = v[np.abs(v[:, 2] - pts[:, 2].mean()) < 1e-5][:, :2]
        hull = _convex_hull(base)
        e = np.roll(hull, -1, 0) - hull
        # signed distance to a convex CCW polygon: max over edges of outward distance
        nrm = np.column_stack([e[:, 1], -e[:, 0]]) / np.linalg.norm(e, axis=1)[:, None]
        sd = ((p[:, None, :] - hull[None]) * nrm[None]).sum(-1).max(1)
        inside |= sd < 0
        dist = np.minimum(dist, np.where(sd < 0, np.inf, sd))
    return inside, (~inside) & (dist < band)


def _convex_hull(pts):
    pts = np.unique(np.round(pts, 9), axis=0)
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def half(seq):
        h = []
        for q in seq:
            while len(h) >= 2 and np.cross(h[-1] - h[-2], q - h[-2]) <= 0:
                h.pop()
            h.append(q)
        return h
    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


# --------------------------------------------------------------------------------------------
# one scene
# --------------------------------------------------------------------------------------------

def run_scene(name, cfg, results, maps=None):
    import cycles_ref as C
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams
    scene = open_scene(name)
    rs = C.prepare(scene, texel_rel=cfg["texel_rel"])
    n_tex = sum(rs.atlases[n].n for n in rs.objects)
    log(f"[{name}] {len(rs.objects)} objects, {n_tex} texels "
        f"(texel {1000 * rs.atlases[rs.objects[0]].texel:.1f} mm), {len(rs.scene_in.mesh.loop_start)} polygons")
    out = {"scene": name, "config": cfg, "texels": n_tex, "texel_m": rs.atlases[rs.objects[0]].texel,
           "objects": {n: {"texels": rs.atlases[n].n, "size": [rs.atlases[n].width, rs.atlases[n].height]}
                       for n in rs.objects},
           "frames": {}, "cycles_sweep": [], "ours": []}
    shapes_at, refs = {}, {}
    # Cycles: reference per frame, sweep on one frame
    for f in cfg["frames"]:
        shapes_at[f] = C.shape_proxies(rs, f)
        a, ta, ca = cycles_bake(rs, name, f, cfg["ref_spp"], REF_SEEDS[0])
        b, tb, cb = cycles_bake(rs, name, f, cfg["ref_spp"], REF_SEEDS[1])
        ref = {n: (a[n] + b[n]) / 2 for n in rs.objects}
        pa, pb = pooled(a), pooled(b)
        sig, sig_mean = C.noise(pa, pb)
        refs[f] = ref
        fr = {"shapes": sorted(shapes_at[f]), "ref_spp": 2 * cfg["ref_spp"], "ref_bake_seconds": [ta, tb],
              "shape_faces_its_surface": C.shape_orientation(rs, shapes_at[f]),
              "ref_sigma": sig / np.sqrt(2), "ref_sigma_surface_mean": {},
              "ref_mean": {n: ref[n].mean(0).tolist() for n in rs.objects}}
        for n in rs.objects:
            fr["ref_sigma_surface_mean"][n] = C.noise(a[n], b[n])[1] / np.sqrt(2)
        out["frames"][str(f)] = fr
        rev = [k for k, ok in fr["shape_faces_its_surface"].items() if not ok]
        if rev:
            log(f"  note: light shape(s) {rev} are wound against the surface they lie on (they emit on the surface's side)")
        log(f"[{name}] frame {f}: reference {2 * cfg['ref_spp']} spp ({ta['wall'] + tb['wall']:.1f} s{', cached' if ca and cb else ''}), "
            f"texel noise of the reference {fr['ref_sigma']:.4f}, shapes {len(shapes_at[f])}")
        if f == cfg.get("sweep_frame"):
            for spp in cfg["sweep"]:
                x, tx, _ = cycles_bake(rs, name, f, spp, SWEEP_SEEDS[0], need_time=True)
                y, ty, _ = cycles_bake(rs, name, f, spp, SWEEP_SEEDS[1], need_time=True)
                sig_n, sig_n_mean = C.noise(pooled(x), pooled(y))
                cmp_ = compare({n: {"leaf_refl": x[n], "emission": 0 * x[n]} for n in rs.objects}, ref,
                               fr["ref_sigma"], rs.objects)["refl_leaf"]
                out["cycles_sweep"].append({"frame": f, "spp": spp, "seconds": [tx["cpu"], ty["cpu"]],
                                            "wall_seconds": [tx["wall"], ty["wall"]], "noise_rmse": sig_n,
                                            "noise_surface_mean": sig_n_mean, "vs_ref": cmp_["all"],
                                            "vs_ref_surfaces": {n: cmp_["surfaces"][n]["mre"] for n in rs.objects}})
                log(f"[{name}] cycles {spp:4d} spp: {np.mean([tx['cpu'], ty['cpu']]):6.2f} s CPU/bake "
                    f"({np.mean([tx['wall'], ty['wall']]):.2f} s wall), texel noise {sig_n:.4f}, "
                    f"worst surface-mean error vs ref {100 * cmp_['all']['worst_mre']:.2f}%")
    # ours
    for q in cfg["qualities"]:
        t0 = time.perf_counter()
        base = RadiositySystem(rs.scene_in.mesh, RefineParams.preset(q))
        t_build = time.perf_counter() - t0
        log(f"[{name}/{q}] hierarchy: {base.h.n} nodes, {len(base.links)} links, {t_build:.1f} s")
        for meth in cfg["methods"]:
            if meth == "NAIVE" and q == "high":
                continue   # a full high-quality rebuild per event (~30 s each): off the chart anyway
            t0 = time.perf_counter()
            dyn = DynamicRadiosity(clone(base), method=meth)
            t_init = time.perf_counter() - t0
            ours = C.Ours(rs, dyn.system, dyn)
            run = {"quality": q, "method": meth, "build_seconds": t_build, "init_seconds": t_init,
                   "nodes": base.h.n, "links": len(base.links), "frames": {}}
            for f in cfg["frames"]:
                c0 = time.process_time()
                fr = dyn.apply(shapes_at[f])
                cpu = time.process_time() - c0
                res = ours.evaluate(shapes_at[f], smooth=(meth == "AUTO" and q != "draft"))
                cmp_ = compare(res, refs[f], out["frames"][str(f)]["ref_sigma"], rs.objects)
                ev = {"seconds": cpu, "wall_seconds": fr.seconds, "events": [e.kind for e in fr.events],
                      "method_used": fr.method,
                      "nodes": fr.nodes, "links": fr.links, "messages": fr.messages, "metrics": cmp_}
                if q == "medium" and meth == "AUTO" and "floor" in rs.objects and name == "cornell":
                    ev["contacts"] = contact_metrics(rs, res, refs[f])
                run["frames"][str(f)] = ev
                if maps is not None and q == "medium" and meth == "AUTO" and f == cfg.get("sweep_frame"):
                    maps.update(rs=rs, res=res, ref=refs[f], frame=f, scene=name)
                a = cmp_["refl_leaf"]["all"]
                log(f"[{name}/{q}/{meth}] frame {f}: {cpu:7.3f} s CPU {'+'.join(ev['events']) or '-':12s} "
                    f"reflected: worst surface {100 * a['worst_mre']:5.2f}% ({a['worst_surface']}), "
                    f"bias {100 * a['bias']:+.2f}%, RMSE {a['rmse']:.4f} (ref-noise corrected {a['rmse_corrected']:.4f}), "
                    f"p95 {a['p95']:.4f}")
            out["ours"].append(run)
        del base
    results[name] = out
    return rs


def contact_metrics(rs, res, ref, band=None):
    """Reflected-radiance error of the floor under the blocks and in a band around them."""
    import cycles_ref as C
    band = band or 2 * rs.atlases["floor"].texel
    inside, near = footprint_masks(rs, band)
    o, r = res["floor"]["leaf_refl"], ref["floor"]
    out = {"band_m": band}
    for label, m in (("under_blocks", inside), ("around_blocks", near), ("rest", ~inside & ~near)):
        mm = C.metrics(o, r, m)
        if mm is not None:
            mm["vertex_bias"] = C.metrics(res["floor"]["vertex_total"], r + res["floor"]["emission"], m)["bias"]
            out[label] = mm
    return out


# --------------------------------------------------------------------------------------------
# chart, maps, summary
# --------------------------------------------------------------------------------------------

MARK = {"NAIVE": "s", "AR": "^", "FE": "v", "AUTO": "o"}
COL = {"draft": "#9ecae1", "medium": "#3182bd", "high": "#08306b"}


def plot(results, path=CHART):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    r = results["cornell"]
    f = str(r["config"]["sweep_frame"])
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, metric, label in ((axes[0], "rmse", "texel RMSE of reflected radiance [W sr$^{-1}$ m$^{-2}$]"),
                              (axes[1], "worst_mre", "worst per-surface mean error (relative)")):
        sw = r["cycles_sweep"]
        t = [np.mean(s["seconds"]) for s in sw]
        e = [s["noise_rmse"] if metric == "rmse" else s["vs_ref"]["worst_mre"] for s in sw]
        ax.plot(t, e, "k-", marker="D", label="Cycles bake (1 thread), per bake")
        for ti, ei, s in zip(t, e, sw):
            ax.annotate(f"{s['spp']} spp", (ti, ei), textcoords="offset points", xytext=(5, 4), fontsize=8)
        for run in r["ours"]:
            fr = run["frames"][f]
            a = fr["metrics"]["refl_leaf"]["all"]
            y = a["rmse_corrected"] if metric == "rmse" else a["worst_mre"]
            ax.plot([fr["seconds"]], [y], MARK[run["method"]], color=COL[run["quality"]], ms=8, mec="k",
                    label=f"{run['method']} {run['quality']}")
        if metric == "worst_mre":
            ax.axhline(0.03, color="r", ls=":", lw=1)
            ax.text(ax.get_xlim()[0] if False else t[0], 0.031, "3% target", color="r", fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU seconds (one thread): per light event (ours), per bake (Cycles)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    h, lab = axes[0].get_legend_handles_labels()
    uniq = dict(zip(lab, h))
    fig.legend(uniq.values(), uniq.keys(), loc="lower center", ncol=7, fontsize=8, frameon=False)
    fig.suptitle(f"Cornell box frame {f} (window + back patch appear): error against a converged Cycles bake "
                 f"({r['frames'][f]['ref_spp']} spp), {r['texels']} texels", fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    log(f"wrote {path}")


def plot_maps(maps, path):
    if not maps:
        return
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rs, res, ref = maps["rs"], maps["res"], maps["ref"]
    names = [n for n in ("floor", "back", "right_green", "ceiling") if n in rs.objects]
    cols = ["Cycles (reflected)", "ours: leaves", "ours: vertex output - emission", "leaves - Cycles"]
    fig, axes = plt.subplots(len(names), 4, figsize=(13, 3.2 * len(names)))
    for i, n in enumerate(names):
        at = rs.atlases[n]

        def img(v):
            a = np.full((at.height, at.width), np.nan)
            a[at.ty, at.tx] = v.mean(1)
            return a
        r = ref[n]
        vmax = np.nanpercentile(img(r), 99)
        data = [img(r), img(res[n]["leaf_refl"]), img(res[n]["vertex_total"] - res[n]["emission"]),
                img(res[n]["leaf_refl"] - r)]
        for j, d in enumerate(data):
            ax = axes[i, j]
            if j < 3:
                im = ax.imshow(d, origin="lower", vmin=0, vmax=vmax, cmap="inferno")
            else:
                lim = np.nanpercentile(np.abs(d), 99)
                im = ax.imshow(d, origin="lower", vmin=-lim, vmax=lim, cmap="RdBu_r")
            fig.colorbar(im, ax=ax, fraction=0.046)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(cols[j], fontsize=9)
        axes[i, 0].set_ylabel(n)
    fig.suptitle(f"{maps['scene']} frame {maps['frame']}, medium AUTO: mean of RGB, radiance units (charts in UV layout)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    log(f"wrote {path}")


def equal_error(results):
    """Cycles time at our error, from a fit t = t0 + c spp and sigma = a / sqrt(spp)."""
    r = results.get("cornell")
    if not r or len(r["cycles_sweep"]) < 2:
        return {}
    sw = r["cycles_sweep"]
    spp = np.array([s["spp"] for s in sw], float)
    t = np.array([np.mean(s["seconds"]) for s in sw])
    sig = np.array([s["noise_rmse"] for s in sw])
    mre = np.array([s["vs_ref"]["worst_mre"] for s in sw])
    c, t0 = np.polyfit(spp, t, 1)
    a = float(np.exp(np.mean(np.log(sig * np.sqrt(spp)))))
    am = float(np.exp(np.mean(np.log(mre * np.sqrt(spp)))))
    f = str(r["config"]["sweep_frame"])
    out = {"fit": {"t0": t0, "seconds_per_spp": c, "sigma_sqrt_spp": a, "worst_mre_sqrt_spp": am}, "runs": []}
    for run in r["ours"]:
        fr = run["frames"][f]
        al = fr["metrics"]["refl_leaf"]["all"]
        rows = {"quality": run["quality"], "method": run["method"], "event_seconds": fr["seconds"]}
        for key, err, coef in (("rmse", al["rmse_corrected"], a), ("worst_mre", al["worst_mre"], am)):
            n_eq = (coef / max(err, 1e-12)) ** 2
            t_eq = max(t0, 0.0) + c * n_eq
            rows[key] = {"error": err, "cycles_spp": n_eq, "cycles_seconds": t_eq,
                         "speedup": t_eq / max(fr["seconds"], 1e-9)}
        out["runs"].append(rows)
    return out


def summary_table(results, eq):
    lines = []
    for name, r in results.items():
        lines.append(f"\n{name}: reflected radiance, leaf values (texel RMSE corrected for reference noise)")
        lines.append(f"{'quality':7s} {'method':6s} {'frame':>5s} {'event s':>8s} {'worst %':>8s} {'surface':12s} "
                     f"{'bias %':>7s} {'RMSE':>7s} {'p95':>7s} {'vtx RMSE':>8s}")
        for run in r["ours"]:
            for f, fr in run["frames"].items():
                a = fr["metrics"]["refl_leaf"]["all"]
                v = fr["metrics"]["total_vertex"]["all"]
                lines.append(f"{run['quality']:7s} {run['method']:6s} {f:>5s} {fr['seconds']:8.3f} "
                             f"{100 * a['worst_mre']:8.2f} {a['worst_surface']:12s} {100 * a['bias']:+7.2f} "
                             f"{a['rmse_corrected']:7.4f} {a['p95']:7.4f} {v['rmse']:8.4f}")
    if eq:
        lines.append("\nequal-error Cycles time (Cornell, sweep frame)")
        for row in eq["runs"]:
            lines.append(f"{row['quality']:7s} {row['method']:6s} event {row['event_seconds']:.3f} s | RMSE "
                         f"{row['rmse']['error']:.4f} ~ Cycles {row['rmse']['cycles_spp']:.0f} spp "
                         f"{row['rmse']['cycles_seconds']:.2f} s (x{row['rmse']['speedup']:.1f}) | worst surface "
                         f"{100 * row['worst_mre']['error']:.2f}% ~ {row['worst_mre']['cycles_spp']:.1f} spp "
                         f"{row['worst_mre']['cycles_seconds']:.2f} s (x{row['worst_mre']['speedup']:.2f})")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="Cornell only, 2 frames, few samples, draft")
    ap.add_argument("--scenes", default="cornell,searchbeam,office")
    ap.add_argument("--plot-only", action="store_true")
    ap.add_argument("--no-cache", action="store_true", help="re-bake Cycles even when cached")
    ap.add_argument("--out", default=JSON_PATH)
    args = ap.parse_args()
    global USE_CACHE
    USE_CACHE = not args.no_cache
    if args.plot_only:
        with open(args.out) as fh:
            data = json.load(fh)
        plot(data["scenes"])
        print(summary_table(data["scenes"], data.get("equal_error", {})))
        return
    t_start = time.perf_counter()
    results, maps = {}, {}
    names = ["cornell"] if args.quick else [s for s in args.scenes.split(",") if s]
    for name in names:
        cfg = dict(SCENES[name])
        if args.quick:
            cfg.update(QUICK)
            cfg["sweep_frame"] = 13
        run_scene(name, cfg, results, maps if name == "cornell" else None)
    eq = equal_error(results)
    data = {"scenes": results, "equal_error": eq, "total_seconds": time.perf_counter() - t_start,
            "total_cpu_seconds": time.process_time(),
            "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version(),
                        "numpy": np.__version__, "load_avg_end": os.getloadavg()},
            "settings": {"cycles_threads": 1, "ref_seeds": REF_SEEDS, "sweep_seeds": SWEEP_SEEDS,
                         "bounces": 64, "filter": "box 1 px", "sub_texels": 3}}
    try:
        import bpy
        data["machine"]["blender"] = bpy.app.version_string
    except ImportError:
        pass
    os.makedirs(OUT, exist_ok=True)
    out = args.out if not args.quick else args.out.replace(".json", "_quick.json")
    with open(out, "w") as fh:
        json.dump(data, fh, indent=1, default=float)
    log(f"wrote {out}")
    if "cornell" in results and results["cornell"]["cycles_sweep"] and not args.quick:
        plot(results)
        plot_maps(maps, os.path.join(OUT, "cycles_maps_cornell.png"))
    print(summary_table(results, eq))


if __name__ == "__main__":
    main()
