"""Accuracy against Cycles, and the speed-accuracy chart (see docs/accuracy.md).

For each sample scene and a few frames: a converged Cycles reference bake (Diffuse, Direct +
Indirect + Color = reflected radiance, one-sided emitters, 64 bounces, no clamping, float
Non-Color images, margin 0; helpers in hr_testing/cycles_ref.py) and our solution (the add-on's
own scene reader, RadiositySystem + DynamicRadiosity, every method and quality preset, frames
applied in order as the bake does) compared texel by texel on the same surfaces. Cycles is also
baked at several sample counts with two seeds (its noise = error of an unbiased estimate).

    .venv/bin/python benchmarks/cycles_compare.py [--quick] [--scenes cornell,searchbeam]
    .venv/bin/python benchmarks/cycles_compare.py --plot-only      # chart from the JSON

Writes benchmarks/out/cycles.json, benchmarks/cycles_speed_accuracy.png and
benchmarks/out/cycles_maps_cornell.png (error maps). With --gather, the Cornell floor's texels in
the short block's shadow from the ceiling light (core, penumbra: shadow_regions) get their own
figures ("shadows" in the JSON). Cycles bakes are cached in
benchmarks/out/cycles_cache/ (not committed; --no-cache re-bakes). Times are CPU seconds of the
process (all threads: Cycles is asked for one thread but may use more, BLAS is single-threaded), so
that other users of the machine do not distort them. About 16 min of CPU from scratch, 8.5 min
with cached references.
"""

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
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
    "cornell": dict(
        frames=[1, 6, 13, 21],
        sweep_frame=13,
        ref_spp=512,
        sweep=[1, 4, 16, 64, 256],
        qualities=["draft", "medium", "high"],
        methods=["NAIVE", "AR", "FE", "AUTO"],
        texel_rel=1 / 64,
    ),
    "searchbeam": dict(
        frames=[1, 6, 12],
        sweep_frame=None,
        ref_spp=256,
        sweep=[],
        qualities=["medium"],
        methods=["FE", "AUTO"],
        texel_rel=1 / 48,
    ),
    "office": dict(
        frames=[1, 4, 8],
        sweep_frame=None,
        ref_spp=256,
        sweep=[],
        qualities=["medium"],
        methods=["FE", "AUTO"],
        texel_rel=1 / 48,
    ),
    # the ~20k-triangle furnished room (850 objects): per-object means, clusters at work
    "furnished": dict(
        frames=[1],
        sweep_frame=1,
        ref_spp=128,
        # Blender bakes object by object, a Cycles session each (scene sync, BVH): ~0.43 s CPU per
        # object at any sample count, 6-8 min per bake of the room. So the sweep is one bake of all
        # objects in one call (as a user bakes) at 1 and 64 spp, its time line fitted through them
        # (equal_object_error), and one with a seed per object at 64 spp.
        # In one call the texels at one image position of all objects share their random numbers,
        # alike objects' errors (the 678 books) do not pool down: the per-object error's scale
        # comes from the reference's two seeds, checked against sweep_po's
        sweep=[1, 64],
        sweep_seeds=(11,),
        sweep_per_object=False,
        sweep_po=[64],
        per_object=True,  # errors as per-object medians over the lit objects (furnished_vs_cycles.py)
        unburied=True,  # the vertex output also over the texels a camera sees (unburied.py)
        light_event=True,  # frame 1 has no light shape: a window's events time a frame (light_event)
        qualities=["draft", "medium"],
        methods=["FE", "AUTO"],
        texel_rel=1 / 150,
    ),
}
QUICK = {
    "frames": [1, 13],
    "sweep": [4, 16],
    "ref_spp": 64,
    "qualities": ["draft"],
    "methods": ["FE", "AUTO"],
}
PARAMS = {}  # --params
GATHER = 0  # --gather: hemisphere rays of the final gather compared alongside (0: off)
GATHER_LEVELS = 1  # --gather-levels
GATHER_ITERATIONS = 0  # --gather-iterations
GATHER_SHADOW_RAYS = 32  # --gather-shadow-rays (the bake's medium setting; 0: the bake's per quality)
SOLVE = "default"  # --solve: "gather" the bake's solver options with the gather (gather_options),
# "gather-tol" those with responses solved to response_tol (before response_steps)
GATHER_AREA = True  # --gather-centres: texels gather at their centres only (before texel_samples)
BAKE_TRANSPORT = False  # --bake-transport: links and tolerances as the bake takes them with the gather
DYN = {}  # --dyn: DynamicRadiosity options over those (e.g. gather_responses="zero")
REF_SEEDS = (1, 2)
SWEEP_SEEDS = (11, 12)
MIN_SURFACE_SHARE = 0.01
VARIANTS = (
    "refl_leaf",
    "refl_smooth",
    "total_leaf",
    "total_smooth",
    "total_vertex",
    "refl_gather",  # the final gather at texel centres (--gather; cycles_ref.gather_results)
    "total_gather",
    "total_gvertex",  # the final gather at the mesh's corners, interpolated as total_vertex
)


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
# each object baked with its own seed (cycles_ref.bake's seed_per_object): baked together, the
# texels at one image position (x, y) of every object share their random numbers, and the errors of
# alike objects (the furnished room's 678 books) do not pool down (docs/gather.md, branch booksx).
# False: the references of before 2026-12-04 (their cache names have no "_po").
PER_OBJECT_SEEDS = True


def ref_path(rs, scene, frame, spp, seed, per_object=None):
    """The cached reference's file."""
    po = "_po" if (PER_OBJECT_SEEDS if per_object is None else per_object) else ""
    return os.path.join(CACHE, f"{scene}_f{frame}_s{spp}_seed{seed}{po}_{_atlas_key(rs)}.npz")


def cycles_bake(rs, scene, frame, spp, seed, need_time=False, per_object=None):
    """Reflected radiance per texel {name: (N, 3)}, bake times {wall, cpu}, cached flag. Cached
    bakes are reused (values only matter for references); need_time re-bakes cached bakes that
    have no CPU time. per_object: a seed per object (one bake call each), None: PER_OBJECT_SEEDS."""
    from hr_testing import cycles_ref as C

    per_object = PER_OBJECT_SEEDS if per_object is None else per_object
    path = ref_path(rs, scene, frame, spp, seed, per_object)
    if USE_CACHE and os.path.exists(path):
        z = np.load(path)
        if not need_time or "__cpu" in z:
            t = {"wall": float(z["__seconds"]), "cpu": float(z["__cpu"]) if "__cpu" in z else float("nan")}
            return {n: z[n].astype(np.float64) for n in rs.objects}, t, True
    vals, dt, mask = C.bake(rs, spp, seed, seed_per_object=per_object)
    bad = {n: int((~m).sum()) for n, m in mask.items() if (~m).any()}
    if bad:
        log(f"  warning: texels not written by the bake: {bad}")
    for n in rs.objects:
        vals[n][~mask[n]] = np.nan
    os.makedirs(CACHE, exist_ok=True)
    np.savez(
        path, __seconds=dt["wall"], __cpu=dt["cpu"], **{n: v.astype(np.float32) for n, v in vals.items()}
    )
    return vals, dt, False


# --------------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------------


def pooled(d):
    """Concatenate {name: (N, 3)} in a fixed order."""
    return np.concatenate([d[n] for n in sorted(d)])


def _ratio_box(ax, x, ha, title, lines, fontsize):
    """A chart's boxed list of speed-ups at equal error, at the top of its axes."""
    ax.text(
        x,
        0.98,
        f"{title} (target x100):\n" + "\n".join(lines),
        transform=ax.transAxes,
        ha=ha,
        va="top",
        fontsize=fontsize,
        bbox=dict(boxstyle="round", fc="w", ec="0.7"),
    )


def unburied_vertex(res, unburied, objects):
    """The vertex outputs of res over the texels a camera sees (unburied[name], a texel mask), NaN
    elsewhere, with each object's emission: compare()'s input for what a camera sees."""
    return {
        n: {
            k: np.where(unburied[n][:, None], res[n][k], np.nan)
            for k in ("vertex_total", "gvertex_total")
            if k in res[n]
        }
        | {"emission": res[n]["emission"]}
        for n in objects
    }


def compare(res, ref, sigma_ref, objects):
    """Metrics of every variant against the reference, per surface and pooled."""
    from hr_testing import cycles_ref as C

    out = {}
    for var in VARIANTS:
        kind, src = var.split("_")
        key = {
            "leaf": "leaf_refl" if kind == "refl" else "leaf_total",
            "smooth": "smooth_refl" if kind == "refl" else "smooth_total",
            "vertex": "vertex_total",
            "gather": "gather_refl" if kind == "refl" else "gather_total",
            "gvertex": "gvertex_total",
        }[src]
        if key not in res[objects[0]]:
            continue
        per, ours_all, ref_all = {}, {}, {}
        for n in objects:
            r = ref[n] if kind == "refl" else ref[n] + res[n]["emission"]
            o = res[n][key]
            m = C.metrics(o, r)
            if m is None:  # no texel the Cycles bake wrote
                continue
            per[n] = m
            ours_all[n], ref_all[n] = o, r
        pa = C.metrics(pooled(ours_all), pooled(ref_all))
        s2 = sigma_ref**2
        pa["rmse_corrected"] = float(np.sqrt(max(pa["rmse"] ** 2 - s2, 0.0)))
        # worst surface among those holding >= 1% of the texels (the Cornell light, 0.5%, is left out:
        # its reflected radiance is invisible next to its emission and very noisy in Cycles)
        big = [n for n in per if per[n]["texels"] >= MIN_SURFACE_SHARE * pa["texels"]]
        pa["worst_mre"] = max(per[n]["mre"] for n in big)
        pa["worst_surface"] = max(big, key=lambda n: per[n]["mre"])
        pa["worst_mre_all_surfaces"] = max(per[n]["mre"] for n in per)
        pa["mean_mre"] = float(np.mean([per[n]["mre"] for n in per]))
        out[var] = {"all": pa, "surfaces": per}
    return out


def shadow_rays_of(quality):
    """The final gather's shadow rays at `quality`: --gather-shadow-rays, or with 0 the bake's."""
    from hr_addon.blender.settings import GATHER as BAKE_GATHER

    return GATHER_SHADOW_RAYS or BAKE_GATHER[quality.upper()]["shadow_rays"]


def footprint_masks(rs, surface, occluders, band):
    """(inside, near) texel masks of `surface`: texel centres under the vertical (z) projection of
    the occluders (the blocks on the floor, the light under the ceiling) and within `band` of it."""
    import bpy

    at = rs.atlases[surface]
    cen = at.s_centre
    pts = np.zeros((at.n, 3))
    pts[at.s_texel[cen]] = at.s_point[cen]
    p = pts[:, :2]
    inside = np.zeros(at.n, bool)
    dist = np.full(at.n, np.inf)
    for name in occluders:
        ob = bpy.data.objects.get(name)
        if ob is None:
            continue
        M = np.array(ob.matrix_world)
        v = np.array([M[:3, :3] @ np.array(x.co) + M[:3, 3] for x in ob.data.vertices])
        hull = _convex_hull(v[:, :2])
        e = np.roll(hull, -1, 0) - hull
        nrm = np.column_stack([e[:, 1], -e[:, 0]]) / np.linalg.norm(e, axis=1)[:, None]
        sd = ((p[:, None, :] - hull[None]) * nrm[None]).sum(-1).max(1)  # > 0 outside (CCW hull)
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
    from hr_testing import cycles_ref as C
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    scene = open_scene(name)
    rs = C.prepare(scene, texel_rel=cfg["texel_rel"])
    n_tex = sum(rs.atlases[n].n for n in rs.objects)
    small = rs.not_compared
    if small:
        log(f"[{name}] {len(small)} objects smaller than a texel light the others but are not compared")
    log(
        f"[{name}] {len(rs.objects)} objects, {n_tex} texels "
        f"(texel {1000 * rs.atlases[rs.objects[0]].texel:.1f} mm), "
        f"{len(rs.scene_in.mesh.loop_start)} polygons"
    )
    out = {
        "scene": name,
        "config": cfg,
        "gather_settings": dict(
            rays=GATHER,
            levels=GATHER_LEVELS,
            iterations=GATHER_ITERATIONS,
            texel_area=GATHER_AREA,
            shadow_rays=GATHER_SHADOW_RAYS,
            bake_transport=BAKE_TRANSPORT,
        )
        if GATHER
        else {},
        "texels": n_tex,
        "not_compared": len(small),
        "texel_m": rs.atlases[rs.objects[0]].texel,
        "objects": {
            n: {"texels": rs.atlases[n].n, "size": [rs.atlases[n].width, rs.atlases[n].height]}
            for n in rs.objects
        },
        "frames": {},
        "cycles_sweep": [],
        "ours": [],
    }
    shapes_at, refs, seeds_of, regions = {}, {}, {}, {}
    per_obj = cfg.get("per_object", False)
    # Cycles: reference per frame, sweep on one frame
    for f in cfg["frames"]:
        shapes_at[f] = C.shape_proxies(rs, f)
        a, ta, ca = cycles_bake(rs, name, f, cfg["ref_spp"], REF_SEEDS[0])
        b, tb, cb = cycles_bake(rs, name, f, cfg["ref_spp"], REF_SEEDS[1])
        ref = {n: (a[n] + b[n]) / 2 for n in rs.objects}
        pa, pb = pooled(a), pooled(b)
        sig, sig_mean = C.noise(pa, pb)
        refs[f] = ref
        seeds_of[f] = (a, b)
        fr = {
            "shapes": sorted(shapes_at[f]),
            "ref_spp": 2 * cfg["ref_spp"],
            "ref_bake_seconds": [ta, tb],
            "shape_faces_its_surface": C.shape_orientation(rs, shapes_at[f]),
            "ref_sigma": sig / np.sqrt(2),
            "ref_sigma_surface_mean": {},
            "ref_mean": {n: ref[n].mean(0).tolist() for n in rs.objects},
        }
        for n in rs.objects:
            fr["ref_sigma_surface_mean"][n] = C.noise(a[n], b[n])[1] / np.sqrt(2)
        if per_obj:
            out["lit"] = lit = C.lit_objects(ref)
            # the error of the reference's per-object mean: the two seeds' difference (independent)
            fr["ref_noise_objects_median"] = float(np.median([fr["ref_sigma_surface_mean"][n] for n in lit]))
            log(
                f"[{name}] frame {f}: {len(lit)} lit objects, median noise of the reference's object "
                f"means {100 * fr['ref_noise_objects_median']:.2f}%"
            )
        out["frames"][str(f)] = fr
        rev = [k for k, ok in fr["shape_faces_its_surface"].items() if not ok]
        if rev:
            log(
                f"  note: light shape(s) {rev} are wound against the surface they lie on "
                "(they emit on the surface's side)"
            )
        cached = ", cached" if ca and cb else ""
        log(
            f"[{name}] frame {f}: reference {2 * cfg['ref_spp']} spp "
            f"({ta['wall'] + tb['wall']:.1f} s{cached}), "
            f"texel noise of the reference {fr['ref_sigma']:.4f}, shapes {len(shapes_at[f])}"
        )
        if f == cfg.get("sweep_frame"):
            po = cfg.get("sweep_per_object", True)

            def vs_ref(x):
                """A sweep bake's metrics against the reference."""
                return compare(
                    {n: {"leaf_refl": x[n], "emission": 0 * x[n]} for n in rs.objects},
                    ref,
                    fr["ref_sigma"],
                    rs.objects,
                )["refl_leaf"]

            for spp in cfg["sweep"]:
                bakes = [
                    cycles_bake(rs, name, f, spp, seed, need_time=True, per_object=po)
                    for seed in cfg.get("sweep_seeds", SWEEP_SEEDS)
                ]
                x, y = bakes[0][0], bakes[1][0] if len(bakes) > 1 else None
                ts = [b[1] for b in bakes]
                # Cycles' own noise from two seeds (none with one)
                sig_n, sig_n_mean = C.noise(pooled(x), pooled(y)) if y is not None else (np.nan, np.nan)
                cmp_ = vs_ref(x)
                sw = {
                    "frame": f,
                    "spp": spp,
                    "per_object_seeds": po,
                    "seconds": [t["cpu"] for t in ts],
                    "wall_seconds": [t["wall"] for t in ts],
                    "noise_rmse": sig_n,
                    "noise_surface_mean": sig_n_mean,
                    "vs_ref": cmp_["all"],
                    "vs_ref_surfaces": {n: m["mre"] for n, m in cmp_["surfaces"].items()},
                }
                if per_obj:
                    sw["objects"] = sweep_objects(cmp_, lit, x, y)
                out["cycles_sweep"].append(sw)
                log(
                    f"[{name}] cycles {spp:4d} spp: {np.mean(sw['seconds']):6.2f} s CPU/bake "
                    f"({np.mean(sw['wall_seconds']):.2f} s wall), texel noise {sig_n:.4f}, "
                    f"worst surface-mean error vs ref {100 * cmp_['all']['worst_mre']:.2f}%"
                    + (
                        f", per-object median vs ref {100 * sw['objects']['vs_ref']['median']:.2f}%"
                        if per_obj
                        else ""
                    )
                )
            # per-object seeded bakes at these counts, one seed: per-object errors independent
            out["cycles_sweep_po"] = []
            for spp in cfg.get("sweep_po", []):
                x, tx, _ = cycles_bake(rs, name, f, spp, SWEEP_SEEDS[0], need_time=True, per_object=True)
                cmp_ = vs_ref(x)
                sw = {"frame": f, "spp": spp, "seconds": tx["cpu"], "wall_seconds": tx["wall"]}
                sw["objects"] = sweep_objects(cmp_, lit)
                out["cycles_sweep_po"].append(sw)
                log(
                    f"[{name}] cycles {spp:4d} spp, a seed per object: {tx['cpu']:.1f} s CPU, "
                    f"per-object median vs ref {100 * sw['objects']['vs_ref']['median']:.2f}%"
                )
    # ours
    unburied = None
    if cfg.get("unburied") and GATHER:
        from unburied import unburied_texels

        c0 = time.process_time()
        unburied = unburied_texels(rs, 5e-5 * rs.diag)
        log(f"[{name}] unburied texels: {time.process_time() - c0:.1f} s CPU")
    for q in cfg["qualities"]:
        t0 = time.process_time()
        # the bake with the final gather on builds RefineParams.for_gather's links and solves to
        # DynamicRadiosity.gather_options' tolerances (blender/settings.py); without
        # --bake-transport the quality's preset and the system's tolerance, as before
        pre = RefineParams.for_gather(q) if BAKE_TRANSPORT else RefineParams.preset(q)
        base = RadiositySystem(rs.scene_in.mesh, dataclasses.replace(pre, **PARAMS))
        t_build = time.process_time() - t0
        log(f"[{name}/{q}] hierarchy: {base.h.n} nodes, {len(base.links)} links, {t_build:.1f} s")
        for meth in cfg["methods"]:
            if meth == "NAIVE" and q == "high":
                continue  # a full high-quality rebuild per event (~30 s each): off the chart anyway
            t0 = time.process_time()
            gather_solve = BAKE_TRANSPORT or SOLVE != "default"
            opts = DynamicRadiosity.gather_options(q) if gather_solve else {}
            if SOLVE == "gather-tol":
                opts.pop("response_steps")
            opts.update(DYN)
            dyn = DynamicRadiosity(base.copy(), method=meth, **opts)
            t_init = time.process_time() - t0
            ours = C.Ours(rs, dyn.system, dyn)
            gcache = {}  # the final gather's precompute, once per run (geometry only)
            run = {
                "gather_shadow_rays": shadow_rays_of(q) if GATHER else None,
                "quality": q,
                "method": meth,
                "build_seconds": t_build,
                "init_seconds": t_init,
                "nodes": base.h.n,
                "links": len(base.links),
                "frames": {},
            }
            for f in cfg["frames"]:
                c0 = time.process_time()
                fr = dyn.apply(shapes_at[f])
                cpu = time.process_time() - c0
                res = ours.evaluate(shapes_at[f], smooth=(meth == "AUTO" and q != "draft"))
                gcost = None
                if GATHER:
                    gres, gcost = C.gather_results(
                        rs,
                        ours,
                        dyn,
                        rays=GATHER,
                        cache=gcache,
                        levels=GATHER_LEVELS,
                        iterations=GATHER_ITERATIONS,
                        texel_area=GATHER_AREA,
                        shadow_rays=shadow_rays_of(q),
                    )
                    for n in rs.objects:
                        res[n].update(gres[n])
                cmp_ = compare(res, refs[f], out["frames"][str(f)]["ref_sigma"], rs.objects)
                if unburied is not None:  # the vertex outputs over the texels a camera sees
                    ub = unburied_vertex(res, unburied, rs.objects)
                    for var, m in compare(ub, refs[f], 0.0, rs.objects).items():
                        cmp_[var + "_unburied"] = m
                ev = {
                    "seconds": cpu,
                    "wall_seconds": fr.seconds,
                    "events": [e.kind for e in fr.events],
                    "method_used": fr.method,
                    "nodes": fr.nodes,
                    "links": fr.links,
                    "messages": fr.messages,
                    "metrics": cmp_,
                }
                if gcost is not None:
                    ev["gather_cost"] = gcost
                if per_obj:
                    ev["objects"] = {
                        var: C.object_summary(m["surfaces"], out["lit"]) for var, m in cmp_.items()
                    }
                if (meth == "AUTO" or GATHER) and name in CONTACTS:
                    ev["contacts"] = contact_metrics(rs, res, refs[f], name)
                if GATHER and name in SHADOWS:
                    ev["shadows"] = shadow_metrics(rs, res, *seeds_of[f], name, regions)
                    for k, d in ev["shadows"].items():
                        for lab, x in d.items():
                            log(
                                f"      shadow {k} {lab}: {x['texels']} texels, Cycles {x['mean_ref']:.4f}, "
                                f"gather {100 * x['gather_bias']:+.1f}% "
                                f"(leaves {100 * x['leaf_bias']:+.1f}%"
                                + (
                                    f", smooth {100 * x['smooth_bias']:+.1f}%"
                                    if x["smooth_bias"] is not None
                                    else ""
                                )
                                + "), "
                                f"per texel {x['gather_rel_rmse']:.3f}; "
                                f"Cycles' noise: mean {100 * x['ref_noise_of_mean']:.1f}%, "
                                f"per texel {x['ref_noise_per_texel']:.3f}"
                            )
                run["frames"][str(f)] = ev
                if maps is not None and q == "medium" and meth == "AUTO" and f == cfg.get("sweep_frame"):
                    maps.update(rs=rs, res=res, ref=refs[f], frame=f, scene=name)
                a = cmp_["refl_leaf"]["all"]
                log(
                    f"[{name}/{q}/{meth}] frame {f}: {cpu:7.3f} s CPU {'+'.join(ev['events']) or '-':12s} "
                    f"reflected: worst surface {100 * a['worst_mre']:5.2f}% ({a['worst_surface']}), "
                    f"bias {100 * a['bias']:+.2f}%, RMSE {a['rmse']:.4f} "
                    f"(ref-noise corrected {a['rmse_corrected']:.4f}), "
                    f"p95 {a['p95']:.4f}"
                )
                if per_obj:
                    for var in OBJECT_OUTPUTS:
                        if var in ev["objects"]:
                            x = ev["objects"][var]
                            log(
                                f"      {var}: {x['objects']} lit objects, median "
                                f"{100 * x['median']:.2f}%, within 5% {100 * x['within_5']:.0f}%, "
                                f"pooled bias {100 * x['pooled_bias']:+.2f}%"
                            )
                for var in ("refl_gather", "total_gvertex", "total_vertex"):
                    if GATHER and var in cmp_:
                        g = cmp_[var]["all"]
                        log(
                            f"      {var}: worst surface {100 * g['worst_mre']:5.2f}% "
                            f"({g['worst_surface']}), "
                            f"bias {100 * g['bias']:+.2f}%, RMSE {g['rmse']:.4f} "
                            f"(corrected {g['rmse_corrected']:.4f}), p95 {g['p95']:.4f}"
                        )
                if GATHER and "contacts" in ev:
                    for k, d in ev["contacts"].items():
                        for lab in ("under", "around"):
                            if lab in d:
                                x = d[lab]
                                gb = x.get("gather", {}).get("bias", float("nan"))
                                gr = x.get("gather", {}).get("rmse", float("nan"))
                                log(
                                    f"      {k} {lab}: {x['texels']} texels, "
                                    f"leaf bias {100 * x['bias']:+.1f}%, "
                                    f"gather bias {100 * gb:+.1f}%, gather RMSE {gr:.4f}"
                                )
            if GATHER and cfg.get("light_event"):
                try:
                    ev["light_event"] = x = light_event(dyn, gcache)
                    log(
                        f"[{name}/{q}/{meth}] a window after frame {f}: add {x['add_s']:.3f} s + texels "
                        f"{x['add_texel_first_s']:.3f} s; move {x['move_s']:.3f} s + corners "
                        f"{x['move_loop_first_s']:.3f} s CPU"
                    )
                except Exception:  # the accuracy figures above are still written
                    import traceback

                    traceback.print_exc()
            out["ours"].append(run)
        del base
    results[name] = out
    return rs


# the per-object measure's outputs: texture output (the gather at texels), vertex output (the
# gather at the corners, over the texels a camera sees), and the leaves
OBJECT_OUTPUTS = {
    "refl_gather": ("gather", "texture output"),
    "total_gvertex_unburied": ("vertex", "vertex output"),
    "refl_leaf": ("leaf", "leaf values"),
}


OUTPUT_NAME = {o: name for o, name in OBJECT_OUTPUTS.values()}


def sweep_objects(cmp_, lit, x=None, y=None):
    """A sweep bake's per-object errors over the lit objects: against the reference (its noise
    included), and with a second seed y the two seeds' own per-object noise (no reference)."""
    from hr_testing import cycles_ref as C

    out = {"vs_ref": C.object_summary(cmp_["surfaces"], lit)}
    if y is not None:
        out["pair_noise_median"] = float(np.median([C.noise(x[n], y[n])[1] for n in lit]))
    return out


CONTACTS = {"cornell": [("floor", ("short_block", "tall_block")), ("ceiling", ("light",))]}


def contact_metrics(rs, res, ref, scene):
    """Reflected-radiance error under occluders touching a surface (blocks on the floor; the light
    0.5 mm under the ceiling), in a band of 2 texels around them, and on the rest of the surface."""
    from hr_testing import cycles_ref as C

    out = {}
    for surface, occ in CONTACTS.get(scene, []):
        if surface not in rs.objects:
            continue
        band = 2 * rs.atlases[surface].texel
        inside, near = footprint_masks(rs, surface, occ, band)
        o, r = res[surface]["leaf_refl"], ref[surface]
        d = {"band_m": band}
        for label, m in (("under", inside), ("around", near), ("rest", ~inside & ~near)):
            mm = C.metrics(o, r, m)
            if mm is not None:
                mm["vertex"] = C.metrics(res[surface]["vertex_total"], r + res[surface]["emission"], m)
                if "smooth_refl" in res[surface]:
                    mm["smooth"] = C.metrics(res[surface]["smooth_refl"], r, m)
                if "gather_refl" in res[surface]:
                    mm["gather"] = C.metrics(res[surface]["gather_refl"], r, m)
                d[label] = mm
        out[f"{surface}/{'+'.join(occ)}"] = d
    return out


# the short block's shadow on the floor from the ceiling light (issue 19): (surface, occluder, light,
# occluders whose shadows are left out)
SHADOWS = {"cornell": [("floor", "short_block", "light", ("tall_block",))]}
SHADOW_SUB = 4  # points per side of a texel's sampled part
SHADOW_LIGHT = 8  # light points: SHADOW_LIGHT^2 per triangle of the light


def _world_tris(name):
    """(T, 3, 3) loop triangles of object `name` in world coordinates."""
    import bpy

    from hr_testing.cycles_ref import _world_mesh

    verts, _, _, lv, tri_loops, _ = _world_mesh(bpy.data.objects[name])
    return verts[lv[tri_loops]]


def _tri_points(tris, k):
    """Centroids of the k^2 equal sub-triangles of each triangle: points uniform in area, and their
    weights (the sub-triangle's area)."""
    b = [((i + 1 / 3) / k, (j + 1 / 3) / k) for i in range(k) for j in range(k - i)]
    b += [((i + 2 / 3) / k, (j + 2 / 3) / k) for i in range(k) for j in range(k - i - 1)]
    b = np.array(b)
    bary = np.column_stack([b, 1 - b.sum(1)])
    pts = np.einsum("pk,tkj->tpj", bary, tris).reshape(-1, 3)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    return pts, np.repeat(area / k**2, len(b))


def shadow_regions(rs, surface, occluder, light, others=(), reach=0.4):
    """Texels of `surface` classified by how much of `light` (an emitting object) `occluder` hides
    from the part of the texel Cycles' bake samples (bakepoints.texel_points: SHADOW_SUB^2 points
    over the middle half, folded into the centre's triangle), against SHADOW_LIGHT^2 area-uniform
    points per triangle of the light (segments tested against the occluder's triangles alone).
    Texels within `reach` of the occluder's footprint are tested. Left out: texels with a point
    under an object standing on the surface (contacts, measured apart) and texels with a point
    that `others` shadow. -> {core: hidden from every point (umbra), edge: partly (penumbra),
    edge_inner / edge_outer: its texels less / more than half seen, lit: the rest of the tested
    texels, seen whole}, (N,) seen fraction (area-weighted, mean over the texel's points; nan
    untested)."""
    import bpy

    from hr_addon.core.gather.bakepoints import texel_points
    from hr_addon.core.visibility import make_backend

    at = rs.atlases[surface]
    cen = np.flatnonzero(at.s_centre)
    tex = at.s_texel[cen]
    occ = _world_tris(occluder)
    lo, hi = occ.reshape(-1, 3).min(0), occ.reshape(-1, 3).max(0)
    c = at.s_point[cen]
    near = np.all((c >= lo - reach) & (c <= hi + reach), axis=1)
    g = (
        np.stack(np.meshgrid(np.arange(SHADOW_SUB), np.arange(SHADOW_SUB), indexing="ij"), -1) + 0.5
    ) / SHADOW_SUB
    g = g.reshape(-1, 2)
    pts = texel_points(
        c[near], at.s_axes[cen[near]], at.s_tri[cen[near]], np.broadcast_to(g, (int(near.sum()),) + g.shape)
    )
    k = pts.shape[1]
    flat = pts.reshape(-1, 3)
    lp, lw = _tri_points(_world_tris(light), SHADOW_LIGHT)
    hide = make_backend(occ)
    seen = (~hide.occluded(flat[:, None], lp[None])) @ lw / lw.sum()
    other = np.zeros(len(flat), bool)
    if others:
        other = (
            make_backend(np.concatenate([_world_tris(o) for o in others]))
            .occluded(flat[:, None], lp[None])
            .any(1)
        )
    seen, other = seen.reshape(-1, k), other.reshape(-1, k).any(1)
    # under an object standing on the surface (a footprint, vertical projection)
    covered = np.zeros(len(flat), bool)
    for name in CONTACTS_OF.get(surface, ()):
        ob = bpy.data.objects.get(name)
        if ob is None:
            continue
        v = _world_tris(name).reshape(-1, 3)
        hull = _convex_hull(v[:, :2])
        e = np.roll(hull, -1, 0) - hull
        nh = np.column_stack([e[:, 1], -e[:, 0]]) / np.linalg.norm(e, axis=1)[:, None]
        covered |= ((flat[:, None, :2] - hull[None]) * nh[None]).sum(-1).max(1) < 1e-9
    covered = covered.reshape(-1, k).any(1)
    keep = ~covered & ~other
    frac = np.full(at.n, np.nan)
    frac[tex[near][keep]] = seen[keep].mean(1)
    core = np.zeros(at.n, bool)
    edge = np.zeros(at.n, bool)
    lit = np.zeros(at.n, bool)
    t = tex[near][keep]
    core[t] = seen[keep].max(1) == 0
    lit[t] = seen[keep].min(1) == 1
    edge[t] = ~core[t] & ~lit[t]
    masks = {
        "core": core,
        "edge": edge,
        "edge_inner": edge & (frac < 0.5),
        "edge_outer": edge & (frac >= 0.5),
        "lit": lit,
    }
    return masks, frac


CONTACTS_OF = {"floor": ("short_block", "tall_block")}


def shadow_metrics(rs, res, a, b, scene, regions):
    """Per region of shadow_regions (kept in `regions` between frames): Cycles' mean (the two
    seeds a, b averaged), the mean signed error of the final gather, of the leaves and of the
    texture output's smooth interpolation before the gather (AUTO runs) (cycles_ref metrics'
    bias), the root mean square of (gather - Cycles) per texel over the region's mean, and Cycles'
    own noise of the region's mean and per texel (from the two seeds, of their average)."""
    from hr_testing import cycles_ref as C

    out = {}
    for surface, occ, light, others in SHADOWS.get(scene, []):
        key = f"{surface}/{occ}/{light}"
        if key not in regions:
            regions[key] = shadow_regions(rs, surface, occ, light, others)
        masks, _ = regions[key]
        ref = (a[surface] + b[surface]) / 2
        d = {}
        for label, m in masks.items():
            ok = m & np.isfinite(ref).all(1) & np.isfinite(res[surface]["gather_refl"]).all(1)
            if not ok.any():
                continue
            g = C.metrics(res[surface]["gather_refl"], ref, ok)
            lf = C.metrics(res[surface]["leaf_refl"], ref, ok)
            # the texture output before the final gather (its smooth interpolation; AUTO runs)
            sm = C.metrics(res[surface]["smooth_refl"], ref, ok) if "smooth_refl" in res[surface] else None
            mr = float(np.mean(g["mean_ref"]))
            ma, mb = a[surface][ok].mean(0), b[surface][ok].mean(0)
            d[label] = {
                "texels": g["texels"],
                "mean_ref": mr,
                "gather_bias": g["bias"],
                "leaf_bias": lf["bias"],
                "smooth_bias": sm["bias"] if sm else None,
                "gather_rel_rmse": float(
                    np.sqrt(np.mean((res[surface]["gather_refl"][ok] - ref[ok]).mean(1) ** 2)) / mr
                ),
                "ref_noise_of_mean": float(np.mean(np.abs(ma - mb) / 2 / np.maximum((ma + mb) / 2, 1e-12))),
                "ref_noise_per_texel": float(
                    np.sqrt(np.mean(((a[surface][ok] - b[surface][ok]) / 2).mean(1) ** 2)) / mr
                ),
            }
        out[key] = d
    return out


# --------------------------------------------------------------------------------------------
# chart, maps, summary
# --------------------------------------------------------------------------------------------

MARK = {"NAIVE": "s", "AR": "^", "FE": "v", "AUTO": "o"}
COL = {"draft": "#9ecae1", "medium": "#3182bd", "high": "#08306b"}
MCOL = {"NAIVE": "tab:red", "AR": "tab:green", "FE": "tab:blue", "AUTO": "tab:purple"}


def light_event(dyn, gcache):
    """CPU seconds of two light events on the furnished room after its frames (no shape there: the
    room's own light): a window appears on the west wall (bench_gather_events.py's), the texel
    gather's first evaluate, then the corners' (second: the new shape's responses are computed
    already); the window moves, the corners' evaluate first, then the texels'. Each output's
    per-frame cost: an event and its first evaluate."""
    from hr_addon.core.events import LightShape
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    _, frame = furnished_room("20k")[1]["light_wall"]

    def window(cx):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.full(3, 20.0), "window")

    tex, loops = gcache["texel"], gcache["loops"]
    out, cpu = {}, time.process_time
    for step, cx, first in (("add", 0.7, "texel"), ("move", 1.2, "loop")):
        c0 = cpu()
        dyn.apply({"w": window(cx)})
        c1 = cpu()
        evals = {"texel": lambda: tex.evaluate(dyn, "reflected"), "loop": lambda: loops.loop_radiance(dyn)}
        evals.pop(first)()
        c2 = cpu()
        (second,) = evals
        evals[second]()
        out[f"{step}_s"] = c1 - c0
        out[f"{step}_{first}_first_s"] = c2 - c1
        out[f"{step}_{second}_second_s"] = cpu() - c2
    return out


def frame_cost(fr, output):
    """CPU seconds of one frame: the light event (DynamicRadiosity.apply), plus for the final gather
    its first evaluate of the frame (new shapes' direct light and responses, the weighted sum);
    "vertex": the gather at the mesh's corners instead (its evaluate came after the texels' in the
    same frame: what that one computed for the new shapes and kept on the system is not in it).
    With a light_event (a frame with no shape of its own): its window's events instead."""
    le = fr.get("light_event")
    if le and output == "gather":
        return le["add_s"] + le["add_texel_first_s"]
    if le and output == "vertex":
        return le["move_s"] + le["move_loop_first_s"]
    t = fr["seconds"]
    g = fr.get("gather_cost", {})
    if output == "gather":
        t += g.get("texel_evaluate_first_s", g.get("texel_evaluate_s", 0.0))
    elif output == "vertex":
        t += g["loop_evaluate_s"]
    return t


def build_cost(run, fr_all):
    """CPU seconds once per bake: the hierarchy, and the final gather's precompute (texel gather)."""
    pre = sum(fr.get("gather_cost", {}).get("texel_precompute_s", 0.0) for fr in fr_all.values())
    return run["build_seconds"] + run.get("init_seconds", 0.0), pre


def plot_objects(ax, name, r, eqo, date=""):
    """A scene measured per object (the furnished room): its per-object median error against CPU
    seconds per frame, Cycles' sweep beside ours, and the ratios at equal error."""
    f = str(r["config"]["sweep_frame"])
    n_ref = r["frames"][f]["ref_spp"]
    sw = r["cycles_sweep"]
    t = np.array([np.mean(s["seconds"]) for s in sw])
    ax.plot(
        t,
        [s["objects"]["vs_ref"]["median"] for s in sw],
        "k-",
        marker="D",
        label="Cycles bake (one frame, all objects) against the reference",
    )
    po = r.get("cycles_sweep_po", [])
    if po:
        ax.plot(
            [s["seconds"] for s in po],
            [s["objects"]["vs_ref"]["median"] for s in po],
            "kx",
            ms=9,
            label="Cycles bake, a seed per object, against the reference",
        )
        sw = sw + po
        t = np.concatenate([t, [s["seconds"] for s in po]])
    for ti, s in zip(t, sw):
        ax.annotate(
            f"{s['spp']} spp",
            (ti, s["objects"]["vs_ref"]["median"]),
            textcoords="offset points",
            xytext=(5, 4),
            fontsize=8,
        )
    if eqo:
        # Cycles against the truth: the reference's two seeds' scale at 1/sqrt(spp), its time fitted
        n = np.geomspace(1, 1024, 40)
        fit = eqo["fit"]
        ax.plot(
            max(fit["t0"], 0.0) + fit["seconds_per_spp"] * n,
            eqo["scale"] / np.sqrt(n),
            "k:",
            label=f"Cycles against the truth: {100 * eqo['scale']:.1f}% / sqrt(spp) "
            f"(the {n_ref}-spp reference's two seeds)",
        )
    for run in r["ours"]:
        fr = run["frames"][f]
        for var, (output, lab) in OBJECT_OUTPUTS.items():
            if output == "leaf" or var not in fr.get("objects", {}):
                continue
            ax.plot(
                [frame_cost(fr, output)],
                [fr["objects"][var]["median"]],
                MARK[run["method"]],
                color=MCOL[run["method"]],
                mfc=MCOL[run["method"]] if output == "gather" else "none",
                ms=9,
                mew=1.5,
                label=f"{run['method']} {run['quality']}: {lab}" if run["quality"] == "draft" else None,
            )
    if eqo:
        lines = [
            f"{x['method']} {x['quality']} {OUTPUT_NAME[x['output']]}: x{x['as_measured']['speedup']:.0f}"
            f"-{x['ref_noise_removed']['speedup']:.0f} (sampling alone "
            f"x{x['as_measured']['speedup_sampling']:.2g}"
            f"-{x['ref_noise_removed']['speedup_sampling']:.2g}; {x['as_measured']['cycles_spp']:.0f}"
            f"-{x['ref_noise_removed']['cycles_spp']:.0f} spp)"
            for x in eqo["runs"]
        ]
        # top centre: ours sit at the left, Cycles' bakes (their per-object sessions) at the right
        title = "per frame, faster than Cycles at equal\nper-object median error"
        _ratio_box(ax, 0.5, "center", title, lines, 7.5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.margins(x=0.1, y=0.1)
    from plot_events import label_log_axis
    from matplotlib.ticker import FuncFormatter

    label_log_axis(ax.xaxis)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{100 * v:g}%"))
    ax.set_xlabel("CPU seconds per frame: ours = light event + final gather; Cycles = one bake")
    ax.set_ylabel(f"median over {len(r['lit'])} lit objects of the object mean's error vs Cycles")
    ax.set_title(
        f"{name} room, {r['texels']} texels, frame {f}, against {n_ref} spp" + (f" ({date})" if date else ""),
        fontsize=9,
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")


def plot(results, path=CHART, eq=None, date="", eqo=None, dates=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    from plot_events import label_log_axis

    r = results["cornell"]
    f = str(r["config"]["sweep_frame"])
    eqr = {(x["quality"], x["method"], x.get("output", "leaf")): x for x in (eq or {}).get("runs", [])}
    objs = [n for n in (eqo or {}) if n in results and n != "cornell"]
    fig, axes = plt.subplots(1, 2 + len(objs), figsize=(13 + 6.5 * len(objs), 6.2 + 0.6 * len(objs)))
    for ax, n in zip(axes[2:], objs):
        plot_objects(ax, n, results[n], eqo[n], (dates or {}).get(n, date))
    for ax, metric, label in (
        (axes[0], "worst_mre", "per-surface error: worst surface's mean radiance vs Cycles"),
        (axes[1], "rmse", "texel RMSE of reflected radiance (reference noise removed)"),
    ):
        sw = r["cycles_sweep"]
        t = [np.mean(s["seconds"]) for s in sw]
        e = [s["noise_rmse"] if metric == "rmse" else s["vs_ref"]["worst_mre"] for s in sw]
        ax.plot(t, e, "k-", marker="D", label="Cycles bake (one frame, all surfaces)")
        lines = []
        for run in r["ours"]:
            row = eqr.get((run["quality"], run["method"], "gather"))
            if row and metric in row:
                x = row[metric]
                ext = ", extrapolated" if x.get("extrapolated") else ""
                lines.append(
                    f"{run['method']}: x{x['speedup']:.0f} (Cycles {x['cycles_spp']:.0f} spp, "
                    f"{x['cycles_seconds']:.0f} s{ext})"
                )
        if lines:
            # top right: ours sit at the bottom left, Cycles' sweep runs from top left to bottom right
            title = "final gather, per frame, faster than\nCycles at equal error"
            _ratio_box(ax, 0.98, "right", title, lines, 8)
        for ti, ei, s in zip(t, e, sw):
            ax.annotate(f"{s['spp']} spp", (ti, ei), textcoords="offset points", xytext=(5, 4), fontsize=8)
        for run in r["ours"]:
            if run["quality"] != "medium":
                continue
            fr = run["frames"][f]
            for output, key, fill in (
                ("leaf", "refl_leaf", "none"),
                ("gather", "refl_gather", MCOL[run["method"]]),
            ):
                if key not in fr["metrics"]:
                    continue
                al = fr["metrics"][key]["all"]
                y = al["rmse_corrected"] if metric == "rmse" else al["worst_mre"]
                x = frame_cost(fr, output)
                lab = f"{run['method']}: " + (
                    "final gather" if output == "gather" else "leaf values (before)"
                )
                ax.plot(
                    [x],
                    [y],
                    MARK[run["method"]],
                    color=MCOL[run["method"]],
                    mfc=fill,
                    ms=9,
                    mew=1.5,
                    label=lab,
                )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.margins(x=0.1, y=0.1)
        ax.set_xlim(left=0.001)  # room for the box at the lower left (left panel)
        label_log_axis(ax.xaxis)
        label_log_axis(ax.yaxis)
        if metric == "worst_mre":
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{100 * v:g}%"))
        ax.set_xlabel("CPU seconds per frame: ours = light event (+ final gather); Cycles = one bake")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    h, lab = axes[0].get_legend_handles_labels()
    uniq = dict(zip(lab, h))
    fig.legend(uniq.values(), uniq.keys(), loc="lower center", ncol=5, fontsize=8, frameon=False)
    meds = [x for x in r["ours"] if x["quality"] == "medium"]
    bt = [build_cost(x, x["frames"]) for x in meds]
    build_txt = ""
    if bt:
        h_s = np.mean([b[0] for b in bt])
        pre = [b[1] for b in bt if b[1] > 0]
        build_txt = f"once per bake, not in x: hierarchy {h_s:.1f} s" + (
            f" + final gather precompute {np.mean(pre):.1f} s CPU" if pre else ""
        )
    gs = r.get("gather_settings", {})
    gtxt = (
        f"final gather: {gs.get('rays')} rays, {gs.get('levels')} levels, {gs.get('iterations')} iterations; "
        if gs
        else ""
    )
    fig.suptitle(
        ("Left two panels: " if objs else "")
        + f"Cornell sample, medium quality, frame {f} (the back-wall shape appears; the window is on): "
        f"error against a {r['frames'][f]['ref_spp']}-spp Cycles bake, {r['texels']} texels of "
        f"{1000 * r['texel_m']:.0f} mm"
        + (f"; measured {date}" if date else "")
        + "\n"
        + gtxt
        + build_txt
        + ".\nxN = Cycles CPU time at equal error / ours per frame (Cycles' error interpolated between its "
        "sample counts, 1/sqrt(spp) beyond 256 spp); CPU seconds of one process each, same run"
        + (
            ".\nRight: "
            + ", ".join(objs)
            + " room, draft, its own run: a frame = a window's event + the output's first evaluate; "
            "Blender bakes a Cycles session per object, so Cycles' time hardly moves with its samples"
            if objs
            else ""
        ),
        fontsize=9,
    )
    fig.tight_layout(rect=(0, 0.1, 1, 0.89))
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
        data = [
            img(r),
            img(res[n]["leaf_refl"]),
            img(res[n]["vertex_total"] - res[n]["emission"]),
            img(res[n]["leaf_refl"] - r),
        ]
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
    fig.suptitle(
        f"{maps['scene']} frame {maps['frame']}, medium AUTO: mean of RGB, radiance units "
        "(charts in UV layout)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    log(f"wrote {path}")


def equal_error(results):
    """Cycles time at our error on the sweep frame: sample count by log-log interpolation of the
    measured error-vs-spp curve (its monotone envelope; 1/sqrt(spp) beyond the measured range),
    time from a linear fit t = t0 + c spp of the measured bake times."""
    r = results.get("cornell")
    if not r or len(r["cycles_sweep"]) < 2:
        return {}
    sw = r["cycles_sweep"]
    spp = np.array([s["spp"] for s in sw], float)
    t = np.array([np.mean(s["seconds"]) for s in sw])
    curves = {
        "rmse": np.minimum.accumulate(np.array([s["noise_rmse"] for s in sw])),
        "worst_mre": np.minimum.accumulate(np.array([s["vs_ref"]["worst_mre"] for s in sw])),
    }
    c, t0 = np.polyfit(spp, t, 1)

    def spp_at(curve, err):
        if err >= curve[0]:
            return float(spp[0] * (curve[0] / err) ** 2)
        if err <= curve[-1]:
            return float(spp[-1] * (curve[-1] / err) ** 2)
        i = int(np.searchsorted(-curve, -err))  # curve[i-1] > err >= curve[i]
        x0, x1, y0, y1 = np.log(spp[i - 1]), np.log(spp[i]), np.log(curve[i - 1]), np.log(curve[i])
        return float(np.exp(x0 + (np.log(err) - y0) * (x1 - x0) / (y1 - y0))) if y1 != y0 else float(spp[i])

    f = str(r["config"]["sweep_frame"])
    out = {
        "fit": {
            "t0": t0,
            "seconds_per_spp": c,
            "note": "spp at equal error: log-log interpolation of the measured curves (monotone "
            "envelope, 1/sqrt(spp) beyond them), at least 1; time = t0 + c spp",
        },
        "runs": [],
    }
    for run in r["ours"]:
        fr = run["frames"][f]
        for output, var in (("leaf", "refl_leaf"), ("gather", "refl_gather")):
            if var not in fr["metrics"]:
                continue
            al = fr["metrics"][var]["all"]
            sec = frame_cost(fr, output)
            rows = {
                "quality": run["quality"],
                "method": run["method"],
                "output": output,
                "event_seconds": sec,
            }
            for key, err in (("rmse", al["rmse_corrected"]), ("worst_mre", al["worst_mre"])):
                n_eq = max(spp_at(curves[key], max(err, 1e-12)), 1.0)
                t_eq = max(t0, 0.0) + c * n_eq
                rows[key] = {
                    "error": err,
                    "cycles_spp": n_eq,
                    "cycles_seconds": t_eq,
                    "speedup": t_eq / max(sec, 1e-9),
                    "extrapolated": bool(n_eq > spp[-1]),
                }
            out["runs"].append(rows)
    return out


def slim(results):
    """Scenes measured per object (849 objects) keep each object's error and bias of the outputs
    OBJECT_OUTPUTS names only, not every variant's full metrics: the JSON stays small."""
    for r in results.values():
        if not r["config"].get("per_object"):
            continue
        for run in r["ours"]:
            for fr in run["frames"].values():
                for var, m in fr["metrics"].items():
                    sur = m.pop("surfaces", None)
                    if var in OBJECT_OUTPUTS and sur:
                        m["objects"] = {
                            n: {k: x[k] for k in ("mre", "bias", "texels")} for n, x in sur.items()
                        }
    return results


def equal_object_errors(results):
    """equal_object_error of every scene measured per object with a sweep."""
    return {
        n: equal_object_error(r)
        for n, r in results.items()
        if r["config"].get("per_object")
        and r["cycles_sweep"]
        and r["frames"][str(r["config"]["sweep_frame"])].get("ref_noise_objects_median")
    }


def equal_object_error(r):
    """Cycles' CPU time at our per-object error on the sweep frame (scenes with per_object: the
    median over the lit objects of |mean ours - mean Cycles| / mean Cycles). Cycles' median at one
    sample against the truth (cycles_ref.noise_scale) from the reference's two seeds' difference
    (a seed per object: independent), checked against the sweep's bakes; the sample count at our
    error two ways (cycles_ref.spp_at_error): "as_measured" counts the reference's noise in our
    error as ours (fewer samples for Cycles: the ratio's lower side), "ref_noise_removed" reads
    Cycles against the same reference. Time t0 + c spp fitted to the timed sweep (one bake call)."""
    from hr_testing import cycles_ref as C

    f = str(r["config"]["sweep_frame"])
    fr0 = r["frames"][f]
    n_ref = fr0["ref_spp"]
    scale = C.noise_scale(fr0["ref_noise_objects_median"], n_ref)
    sw = r["cycles_sweep"]
    # the time line through the sweep's bakes, one call each as a user bakes; a seed per object
    # (sweep_po, the reference) adds ~0.1 s per object's call: kept beside it, not fitted
    timed = [(s["spp"], t) for s in sw for t in s["seconds"]]
    others = [(s["spp"], s["seconds"]) for s in r.get("cycles_sweep_po", [])]
    others += [(r["config"]["ref_spp"], t["cpu"]) for t in fr0["ref_bake_seconds"]]
    spp = np.array([x[0] for x in timed], float)
    c, t0 = np.polyfit(spp, [x[1] for x in timed], 1)
    checks = [
        {
            "spp": s["spp"],
            "bakes": f"one call, {len(s['seconds'])} seed(s)",
            "scale_vs_ref": C.noise_scale(s["objects"]["vs_ref"]["median"], s["spp"], n_ref),
        }
        | (
            {"scale_pair": C.noise_scale(s["objects"]["pair_noise_median"], s["spp"])}
            if "pair_noise_median" in s["objects"]
            else {}
        )
        for s in sw
    ] + [
        {
            "spp": s["spp"],
            "bakes": "a seed per object",
            "scale_vs_ref": C.noise_scale(s["objects"]["vs_ref"]["median"], s["spp"], n_ref),
        }
        for s in r.get("cycles_sweep_po", [])
    ]
    out = {
        "scale": scale,
        "ref_spp": n_ref,
        "scale_checks": checks,
        "fit": {"t0": t0, "seconds_per_spp": c, "bakes": timed, "per_object_seed_bakes": others},
        "runs": [],
    }
    for run in r["ours"]:
        fr = run["frames"][f]
        for var, (output, _) in OBJECT_OUTPUTS.items():
            if var not in fr.get("objects", {}) or output == "leaf":
                continue
            err, sec = fr["objects"][var]["median"], frame_cost(fr, output)
            row = {"quality": run["quality"], "method": run["method"], "output": output, "frame_seconds": sec}
            for mode, ref_spp in (("as_measured", None), ("ref_noise_removed", n_ref)):
                n_eq = max(C.spp_at_error(err, scale, ref_spp), 1.0)
                t_eq = max(t0, 0.0) + c * n_eq
                row[mode] = {
                    "error": err,
                    "cycles_spp": n_eq,
                    "cycles_seconds": t_eq,
                    "speedup": t_eq / max(sec, 1e-9),
                    # Cycles' sampling alone, without the bake's per-object sessions (t0)
                    "speedup_sampling": c * n_eq / max(sec, 1e-9),
                    "extrapolated": bool(n_eq > max(spp.max(), *(x[0] for x in others))),
                }
            out["runs"].append(row)
    return out


def summary_table(results, eq):
    lines = []
    for name, r in results.items():
        lines.append(f"\n{name}: reflected radiance, leaf values (texel RMSE corrected for reference noise)")
        lines.append(
            f"{'quality':7s} {'method':6s} {'frame':>5s} {'event s':>8s} {'worst %':>8s} {'surface':12s} "
            f"{'bias %':>7s} {'RMSE':>7s} {'p95':>7s} {'vtx RMSE':>8s}"
        )
        for run in r["ours"]:
            for f, fr in run["frames"].items():
                a = fr["metrics"]["refl_leaf"]["all"]
                v = fr["metrics"]["total_vertex"]["all"]
                lines.append(
                    f"{run['quality']:7s} {run['method']:6s} {f:>5s} {fr['seconds']:8.3f} "
                    f"{100 * a['worst_mre']:8.2f} {a['worst_surface']:12s} {100 * a['bias']:+7.2f} "
                    f"{a['rmse_corrected']:7.4f} {a['p95']:7.4f} {v['rmse']:8.4f}"
                )
    if eq:
        lines.append("\nequal-error Cycles time (Cornell, sweep frame; per frame: event + final gather)")
        for row in eq["runs"]:
            lines.append(
                f"{row['quality']:7s} {row['method']:6s} {row.get('output', 'leaf'):6s} "
                f"frame {row['event_seconds']:.3f} s | RMSE "
                f"{row['rmse']['error']:.4f} ~ Cycles {row['rmse']['cycles_spp']:.0f} spp "
                f"{row['rmse']['cycles_seconds']:.2f} s (x{row['rmse']['speedup']:.1f}) | worst surface "
                f"{100 * row['worst_mre']['error']:.2f}% ~ {row['worst_mre']['cycles_spp']:.1f} spp "
                f"{row['worst_mre']['cycles_seconds']:.2f} s (x{row['worst_mre']['speedup']:.2f})"
            )
    return "\n".join(lines)


def markdown_objects(name, r, eqo):
    """The per-object tables of a scene with a sweep (equal_object_error)."""
    f = str(r["config"]["sweep_frame"])
    n_ref = eqo["ref_spp"]
    L = [
        f"{name}, frame {f}: median over the {len(r['lit'])} lit objects of the object mean's error against "
        f"the {n_ref}-spp reference (its own noise: {100 * r['frames'][f]['ref_noise_objects_median']:.2f}%, "
        f"the two seeds' difference; Cycles at one sample against the truth {100 * eqo['scale']:.1f}%).\n",
        "| Cycles spp | bakes | CPU s / bake | median vs reference | within 5% "
        "| at one spp: vs reference / seeds' difference |",
        "|---|---|---|---|---|---|",
    ]
    scale = {(c["spp"], c["bakes"]): c for c in eqo["scale_checks"]}
    for sw, bakes in [(s, f"one call, {len(s['seconds'])} seed(s)") for s in r["cycles_sweep"]] + [
        (s, "a seed per object") for s in r.get("cycles_sweep_po", [])
    ]:
        o, c = sw["objects"]["vs_ref"], scale[(sw["spp"], bakes)]
        pair = f" / {100 * c['scale_pair']:.1f}%" if "scale_pair" in c else ""
        L.append(
            f"| {sw['spp']} | {bakes} | {np.mean(sw['seconds']):.1f} | {100 * o['median']:.2f}% | "
            f"{100 * o['within_5']:.0f}% | {100 * c['scale_vs_ref']:.1f}%{pair} |"
        )
    fit = eqo["fit"]
    L += [
        "",
        f"Ours per frame (light event + the gathered output's evaluate, CPU s) and Cycles' CPU time at the "
        f"same median (time {fit['t0']:.1f} s + {fit['seconds_per_spp']:.2f} s/spp fitted to the room's "
        f"{len(fit['bakes'])} one-call bakes; our error as measured / with the reference's noise removed; "
        "x Cycles "
        "with the whole bake, and with its sampling alone, c spp):\n",
        "| quality | method | output | median | within 5% | per frame "
        "| Cycles spp | Cycles CPU s | x Cycles | x Cycles' sampling |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for x in eqo["runs"]:
        run = next(u for u in r["ours"] if (u["quality"], u["method"]) == (x["quality"], x["method"]))
        var = next(v for v, (o, _) in OBJECT_OUTPUTS.items() if o == x["output"])
        st = run["frames"][f]["objects"][var]
        a, b = x["as_measured"], x["ref_noise_removed"]
        L.append(
            f"| {x['quality']} | {x['method']} | {OBJECT_OUTPUTS[var][1]} | {100 * st['median']:.2f}% | "
            f"{100 * st['within_5']:.0f}% | {x['frame_seconds']:.3f} | "
            f"{a['cycles_spp']:.0f} / {b['cycles_spp']:.0f} | {a['cycles_seconds']:.0f} / "
            f"{b['cycles_seconds']:.0f} | x{a['speedup']:.0f} / x{b['speedup']:.0f} | "
            f"x{a['speedup_sampling']:.2g} / x{b['speedup_sampling']:.2g} |"
        )
    L.append("")
    return L


def markdown(data):
    """The tables of docs/accuracy.md from the JSON."""
    res, eq = data["scenes"], data.get("equal_error", {})
    L = []
    r = res.get("cornell")
    if r:
        frames = list(r["frames"])
        sf = str(r["config"]["sweep_frame"] or r["config"]["frames"][0])
        L.append(
            f"Cornell box, reflected radiance at {r['texels']} texels ({1000 * r['texel_m']:.0f} mm), "
            f"reference {r['frames'][sf]['ref_spp']} spp per frame. Worst surface = largest per-surface "
            "mean error; bias, RMSE (corrected for the reference's noise) and p95 over all texels at frame "
            f"{sf}; vertex = HR_Radiance interpolated, total radiance, RMSE at frame {sf}.\n"
        )
        L.append(
            "| quality | method | worst surface, frames "
            + " / ".join(frames)
            + f" | bias f{sf} | RMSE f{sf} "
            f"| p95 f{sf} | total radiance RMSE f{sf}: leaves / texture / vertex output |"
        )
        L.append("|---|---|---|---|---|---|---|")
        for run in r["ours"]:
            fr = run["frames"]
            w = " / ".join(f"{100 * fr[f]['metrics']['refl_leaf']['all']['worst_mre']:.1f}%" for f in frames)
            a = fr[sf]["metrics"]["refl_leaf"]["all"]
            mt = fr[sf]["metrics"]
            tex = f"{mt['total_smooth']['all']['rmse']:.3f}" if "total_smooth" in mt else "-"
            L.append(
                f"| {run['quality']} | {run['method']} | {w} | {100 * a['bias']:+.2f}% | "
                f"{a['rmse_corrected']:.4f} "
                f"| {a['p95']:.4f} | {mt['total_leaf']['all']['rmse']:.3f} / {tex} / "
                f"{mt['total_vertex']['all']['rmse']:.3f} |"
            )
        L.append("")
        L.append(
            "| quality | method | hierarchy CPU s | event CPU s, frames "
            + " / ".join(frames[1:])
            + f" | Cycles at equal RMSE (f{sf}) | speed-up | Cycles at equal worst surface | speed-up |"
        )
        L.append("|---|---|---|---|---|---|---|---|")
        eqr = {
            (x["quality"], x["method"]): x for x in eq.get("runs", []) if x.get("output", "leaf") == "leaf"
        }
        for run in r["ours"]:
            fr = run["frames"]
            ev = " / ".join(f"{fr[f]['seconds']:.3f}" for f in frames[1:])
            x = eqr.get((run["quality"], run["method"]))
            if x:
                a, b = x["rmse"], x["worst_mre"]
                tail = (
                    f"{a['cycles_spp']:.0f} spp, {a['cycles_seconds']:.1f} s | x{a['speedup']:.1f} | "
                    f"{'<= 1' if b['cycles_spp'] <= 1 else format(b['cycles_spp'], '.0f')} spp, "
                    f"{b['cycles_seconds']:.1f} s | x{b['speedup']:.2f} |"
                )
            else:
                tail = " | | | |"
            L.append(f"| {run['quality']} | {run['method']} | {run['build_seconds']:.1f} | {ev} | {tail}")
        L.append("")
        L.append(
            f"| Cycles spp (frame {sf}) | CPU s / bake | texel noise (RMS) | worst surface vs reference |"
        )
        L.append("|---|---|---|---|")
        for sw in r["cycles_sweep"]:
            L.append(
                f"| {sw['spp']} | {np.mean(sw['seconds']):.2f} | {sw['noise_rmse']:.4f} | "
                f"{100 * sw['vs_ref']['worst_mre']:.2f}% ({sw['vs_ref']['worst_surface']}) |"
            )
        L.append("")
        rows = []
        for run in r["ours"]:
            for f in frames:
                c = run["frames"][f].get("contacts")
                if not c or run["quality"] != "medium" or not isinstance(next(iter(c.values())), dict):
                    continue
                for key, d in c.items():
                    row = [f"| {run['method']} {run['quality']} f{f} | {key} "]
                    u = d.get("under")
                    uv = u["vertex"] if u else None
                    row.append(
                        f"| {np.mean(u['mean_ref']):.4f} / {np.mean(u['mean_ours']):.4f} / "
                        f"{np.mean(uv['mean_ours']) - np.mean(uv['mean_ref']) + np.mean(u['mean_ref']):.4f} "
                        f"({u['texels']}) "
                        if u
                        else "| - "
                    )
                    for lab in ("around", "rest"):
                        m = d.get(lab)
                        row.append(
                            f"| {np.mean(m['mean_ref']):.4f}: {100 * m['bias']:+.0f}% / "
                            f"{100 * m['vertex']['bias']:+.0f}% ({m['texels']}) "
                            if m
                            else "| - "
                        )
                    rows.append("".join(row) + "|")
        if rows:
            L.append(
                "Contacts: reflected radiance of the surface under the occluder (Cycles / leaves / vertex "
                "output; texels), and Cycles' mean with the bias of leaves / vertex output in a band "
                "of 2 texels around the occluder and on the rest of the surface:\n"
            )
            L.append("| run | surface / occluders | under | band around | rest of the surface |")
            L.append("|---|---|---|---|---|")
            L += rows
            L.append("")
    if r and any("refl_gather" in fr["metrics"] for run in r["ours"] for fr in run["frames"].values()):
        frames = list(r["frames"])
        sf = str(r["config"]["sweep_frame"] or r["config"]["frames"][0])
        eqg = {(x["quality"], x["method"], x.get("output", "leaf")): x for x in eq.get("runs", [])}
        L.append(
            f"Final gather ({r.get('gather_settings', {})}) against the leaf values, reflected radiance at "
            f"texel centres; per frame = light event + the gather's first evaluate of frame {sf}, CPU s; "
            "Cycles at equal error from its sample-count sweep (xN = its CPU time / ours):\n"
        )
        L.append(
            "| quality | method | output | worst surface, frames " + " / ".join(frames) + f" | bias f{sf} "
            f"| RMSE f{sf} (noise removed) | per frame f{sf} "
            "| x Cycles, equal worst surface | x Cycles, equal RMSE |"
        )
        L.append("|---|---|---|---|---|---|---|---|---|")
        for run in r["ours"]:
            fr = run["frames"]
            for out_, var in (("leaf", "refl_leaf"), ("gather", "refl_gather")):
                if var not in fr[sf]["metrics"]:
                    continue
                w = " / ".join(f"{100 * fr[f]['metrics'][var]['all']['worst_mre']:.2f}%" for f in frames)
                a = fr[sf]["metrics"][var]["all"]
                x = eqg.get((run["quality"], run["method"], out_))
                sp = (
                    f"x{x['worst_mre']['speedup']:.1f}"
                    f"{' (extrapolated)' if x['worst_mre'].get('extrapolated') else ''}"
                    f" | x{x['rmse']['speedup']:.1f}"
                    if x
                    else " | "
                )
                L.append(
                    f"| {run['quality']} | {run['method']} | {out_} | {w} | {100 * a['bias']:+.2f}% | "
                    f"{a['rmse_corrected']:.4f} | {frame_cost(fr[sf], out_):.3f} s | {sp} |"
                )
        L.append("")
    for name, x in data.get("equal_object_error", {}).items():
        L += markdown_objects(name, res[name], x)
    for name, r in res.items():
        if name == "cornell":
            continue
        frames = list(r["frames"])
        L.append(
            f"{name}: {r['texels']} texels ({1000 * r['texel_m']:.0f} mm), reference "
            f"{r['frames'][frames[0]]['ref_spp']} spp.\n"
        )
        L.append("| quality | method | frame | event | CPU s | worst surface | bias | RMSE | vertex RMSE |")
        L.append("|---|---|---|---|---|---|---|---|---|")
        for run in r["ours"]:
            for f in frames:
                fr = run["frames"][f]
                a = fr["metrics"]["refl_leaf"]["all"]
                L.append(
                    f"| {run['quality']} | {run['method']} | {f} | {'+'.join(fr['events']) or '-'} | "
                    f"{fr['seconds']:.3f} | {100 * a['worst_mre']:.1f}% ({a['worst_surface']}) | "
                    f"{100 * a['bias']:+.2f}% | {a['rmse_corrected']:.4f} | "
                    f"{fr['metrics']['total_vertex']['all']['rmse']:.4f} |"
                )
        L.append("")
    return "\n".join(L)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="Cornell only, 2 frames, few samples, draft")
    ap.add_argument("--scenes", default="cornell,searchbeam,office")
    ap.add_argument("--qualities", help="comma-separated, overrides each scene's list")
    ap.add_argument("--methods", help="comma-separated, overrides each scene's list")
    ap.add_argument(
        "--params",
        default="",
        help="RefineParams overrides for every preset, e.g. shadow_feps=5e-4,contacts=0",
    )
    ap.add_argument("--frames", help="comma-separated, overrides each scene's frames")
    ap.add_argument("--no-sweep", action="store_true", help="no Cycles sample-count sweep")
    ap.add_argument("--gather", type=int, default=0, help="also the final gather, with this many rays")
    ap.add_argument("--gather-levels", type=int, default=1, help="1: one-level gather, 2: two-level")
    ap.add_argument(
        "--gather-iterations", type=int, default=0, help="two levels: passes among gather samples"
    )
    ap.add_argument(
        "--gather-shadow-rays",
        type=int,
        default=32,
        help="shadow rays per sample and emitter; 0: the bake's per quality (settings.py GATHER)",
    )
    ap.add_argument(
        "--gather-centres", action="store_true", help="texels gather at their centres only (no texel area)"
    )
    ap.add_argument("--solve", default="default", choices=("default", "gather", "gather-tol"))
    ap.add_argument(
        "--bake-transport",
        action="store_true",
        help="links and solver tolerances as the bake takes them with the final gather on "
        "(RefineParams.for_gather, DynamicRadiosity.gather_options)",
    )
    ap.add_argument(
        "--no-fit",
        action="store_true",
        help="the gathered vertex output's corners unshifted (gather/layouts.FIT, corner_fit)",
    )
    ap.add_argument(
        "--fit-every", action="store_true", help="every face shifted, not only those cut by another solid"
    )
    ap.add_argument("--dyn", default="dict()", help="DynamicRadiosity option overrides (a Python dict)")
    ap.add_argument("--plot-only", action="store_true")
    ap.add_argument(
        "--also",
        action="append",
        default=[],
        help="with --plot-only: another run's JSON whose scenes join the chart",
    )
    ap.add_argument("--no-cache", action="store_true", help="re-bake Cycles even when cached")
    ap.add_argument("--out", default=JSON_PATH)
    args = ap.parse_args()
    global USE_CACHE, GATHER, GATHER_LEVELS, GATHER_ITERATIONS, GATHER_AREA, GATHER_SHADOW_RAYS, SOLVE
    global BAKE_TRANSPORT
    USE_CACHE = not args.no_cache
    GATHER_AREA = not args.gather_centres
    GATHER_SHADOW_RAYS = args.gather_shadow_rays
    SOLVE = args.solve
    BAKE_TRANSPORT = args.bake_transport
    from hr_addon.core.gather import layouts

    layouts.FIT = not args.no_fit
    layouts.corner_fit.EVERY = args.fit_every
    DYN.update(eval(args.dyn))
    GATHER, GATHER_LEVELS, GATHER_ITERATIONS = args.gather, args.gather_levels, args.gather_iterations
    from hr_addon.core.refine import RefineParams

    for kv in filter(None, args.params.split(",")):
        k, v = kv.split("=")
        PARAMS[k] = type(getattr(RefineParams(), k))(float(v))
    if args.plot_only:
        with open(args.out) as fh:
            data = json.load(fh)
        data["equal_error"] = equal_error(data["scenes"])
        data["equal_object_error"] = equal_object_errors(data["scenes"])
        c = data["scenes"].get("cornell")
        if (
            c is not None and not c.get("gather_settings") and args.gather
        ):  # JSON written before they were kept
            c["gather_settings"] = dict(
                rays=args.gather, levels=args.gather_levels, iterations=args.gather_iterations
            )
        with open(args.out, "w") as fh:
            json.dump(data | {"scenes": slim(data["scenes"])}, fh, indent=1, default=float)
        if "date" not in data:  # JSON written before the date was kept: the file's own
            data["date"] = time.strftime("%Y-%m-%d", time.gmtime(os.path.getmtime(args.out)))
        dates = {}
        # scenes of other runs (the furnished room's) beside this one's, not written back
        for path in args.also:
            with open(path) as fh:
                other = json.load(fh)
            data["scenes"].update(other["scenes"])
            dates.update({n: other.get("date", "") for n in other["scenes"]})
        eqo = equal_object_errors(data["scenes"])
        if "cornell" in data["scenes"]:
            plot(data["scenes"], eq=data["equal_error"], date=data["date"], eqo=eqo, dates=dates)
        print(summary_table(data["scenes"], data["equal_error"]))
        md = markdown(data)
        with open(os.path.join(OUT, "cycles_tables.md"), "w") as fh:
            fh.write(md + "\n")
        print(md)
        return
    t_start = time.perf_counter()
    results, maps = {}, {}
    names = ["cornell"] if args.quick else [s for s in args.scenes.split(",") if s]
    for name in names:
        cfg = dict(SCENES[name])
        if args.quick:
            cfg.update(QUICK)
            cfg["sweep_frame"] = 13
        for key in ("qualities", "methods"):
            if getattr(args, key):
                cfg[key] = getattr(args, key).split(",")
        if args.frames:
            cfg["frames"] = [int(x) for x in args.frames.split(",")]
        if args.no_sweep:
            cfg["sweep_frame"] = None
        run_scene(name, cfg, results, maps if name == "cornell" else None)
    eq = equal_error(results)
    data = {
        "scenes": results,
        "equal_error": eq,
        "equal_object_error": equal_object_errors(results),
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "total_seconds": time.perf_counter() - t_start,
        "total_cpu_seconds": time.process_time(),
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "load_avg_end": os.getloadavg(),
        },
        "settings": {
            "cycles_threads": 1,
            "ref_seeds": REF_SEEDS,
            "sweep_seeds": SWEEP_SEEDS,
            "bounces": 64,
            "filter": "box 1 px",
            "sub_texels": 3,
        },
    }
    try:
        import bpy

        data["machine"]["blender"] = bpy.app.version_string
    except ImportError:
        pass
    os.makedirs(OUT, exist_ok=True)
    out = args.out if not args.quick else args.out.replace(".json", "_quick.json")
    with open(out, "w") as fh:
        json.dump(data | {"scenes": slim(results)}, fh, indent=1, default=float)
    log(f"wrote {out}")
    if "cornell" in results and results["cornell"]["cycles_sweep"] and not args.quick:
        plot(results, eq=eq, date=data["date"], eqo=data["equal_object_error"])
        plot_maps(maps, os.path.join(OUT, "cycles_maps_cornell.png"))
    print(summary_table(results, eq))
    md = markdown(data)
    with open(os.path.join(OUT, "cycles_tables.md"), "w") as fh:
        fh.write(md + "\n")
    print(md)


if __name__ == "__main__":
    main()
