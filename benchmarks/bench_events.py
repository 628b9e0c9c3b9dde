"""Dynamic light events: NAIVE vs AR vs FE vs AUTO, time per event and error against a converged NAIVE.

Scenarios (the seed slides' plus a moving shape):
- cornell: a window-shaped light (sheared, rotated, with a cross-shaped hole for the mullions) appears on
  the green side wall; a second light (rotated ellipse) appears on the back wall; the first disappears.
- office: a 5 x 4 m office with two flat monitors; screen 0 lights up, then screen 1, then screen 0
  changes colour (screen saver -> desktop).
- beam: an elliptical search beam sweeps the Cornell back wall over 30 frames (each frame a reshape).

Every method runs on a clone of the same base system per quality setting. Error: reflected radiance
(B - E) at stratified sample points on all input patches against NAIVE rebuilt at reference quality,
RMSE and max over points (radiance units), for the whole solution ("total": includes the base
hierarchy's own discretisation error) and for the light's contribution ("delta" = with minus without
the shapes, what the event methods control). Beam errors are evaluated on 4 of the 30 frames.
Timings: CPU seconds of this process per event (time.process_time; the machine may be shared, wall
seconds are kept too); incremental methods are run `--repeat` times and the fastest run is kept.

    .venv/bin/python benchmarks/bench_events.py [--quick] [--out benchmarks/out/events.json]
    .venv/bin/python benchmarks/bench_events.py --gather [--quick] [--out benchmarks/out/events_gathered.json]
    .venv/bin/python benchmarks/plot_events.py

--gather: the output the product shows by default (Final Gather on), not the hierarchy's leaves. Each
quality's base is built as a bake with the gather builds it (RefineParams.for_gather, the solver's
DynamicRadiosity.gather_options), and a FinalGather at the same sample points with the bake's gather
settings (blender/settings.py GATHER: rays, shadow rays, levels, iterations; seed 0) is traced once per
base (its precompute is reported, not charged to the events). Every event is followed by the gathered
output's update (FinalGather.evaluate "reflected"), as a bake's frame: time per event = the event
(DynamicRadiosity.apply, "transport_cpu_seconds") + the update ("gather_cpu_seconds"), CPU s; each
variant starts with the gather's per-shape caches empty, so it pays its shapes' direct light. Errors are
of the light's contribution (reflected, with minus without the shapes) at the same sample points,
against two references:
- "ref": independent of the method's discretisation: NAIVE rebuilt at REFERENCE quality, gathered over
  the REFERENCE base's fine leaves with REF_GATHER (one level, 8x the rays, 4-8x the shadow rays), the
  mean of two seeds (REF_SEEDS; their difference is stored: the reference's own noise). Contains the method's
  transport error and its gather's ray noise and leaf discretisation (and the reference's noise).
- "transport": the method's own gather (the same rays, hits and leaves) reading NAIVE rebuilt at
  REFERENCE quality: the direct light and the ray pattern cancel, what is left is the transport's error
  as the gather sees it. The same gather reading it against "ref" is the floor a perfect transport
  would reach ("floor": the gather's noise and discretisation).
Host visibility (gather/hostvis.py, on in the product since session 29, for shapes that move since
session 30: LightShape.moves): the beam moves (a bake reads it from its keys), the Cornell and office
shapes are still (one-off events: their direct light by shadow rays). The timed methods, the
transport reference and the floor read it as the product does (the transport reference must read the
shapes' direct light exactly as the method's gather does, for it to cancel); the independent "ref" is
computed with hostvis.ENABLED = False (hostvis_off), so its direct light is by shadow rays and does not
share the methods' estimator. The floor is also recorded with this gather's shapes read by shadow rays
("floor_hostvis_off"). Each variant starts with the gather's host visibility stores empty too.
NAIVE at REFERENCE is rebuilt once per light configuration and shared by both references and every
quality (a cache around events.naive._NaiveState, used only for REFERENCE parameters).
"""

import argparse
import contextlib
import hashlib
import json
import os
import platform
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from hr_testing import scenes  # noqa: E402
from hr_testing import shapes as S  # noqa: E402
from hr_addon.core.events import DynamicRadiosity, LightShape, surface_samples  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.refine import RefineParams  # noqa: E402

QUALITY = {
    "coarse": RefineParams(feps=0.1, aeps=4e-3, shadow_feps=0.02, veps=0.02),
    "draft": RefineParams.preset("draft"),
    "medium": RefineParams.preset("medium"),
}
REFERENCE = RefineParams(feps=0.01, aeps=5e-5, shadow_feps=0.001)
# --gather: qualities a bake offers with the gather (the transport's RefineParams.for_gather presets)
GATHER_QUALITY = {"cornell": ["draft", "medium"], "office": ["draft"], "beam": ["draft"]}
# the gathered reference: the REFERENCE solution (NAIVE rebuilt at REFERENCE) read by a one-level
# gather with many rays over the REFERENCE base's own leaves (its fine leaves, aeps 5e-5 of the scene,
# are read one bounce away: their values need no second level), exact direct light with many shadow
# rays, other seeds than the methods' gathers (0)
REF_GATHER = dict(rays=1024, shadow_rays=128, levels=1)
REF_SEEDS = (1, 2)
# (label, method, DynamicRadiosity keyword arguments)
VARIANTS = [
    ("NAIVE", "NAIVE", {}),
    ("FE", "FE", {}),
    ("FE warm", "FE", {"incremental": "warm"}),
    ("AR", "AR", {}),
    ("AUTO", "AUTO", {}),
    ("AUTO bf=1e-2", "AUTO", {"bf_rel": 1e-2}),
]


def ls(outline, frame, em, name, moves=False):
    return LightShape(S.on_plane(outline, frame), np.asarray(em, float), name, moves)


def cornell_scenario():
    win = ls(
        S.window(0.2, 0.16, 0.02, centre=(0.3, 0.3), angle=0.3, shear=0.3),
        S.CORNELL_GREEN_WALL,
        (8.0, 7.0, 5.0),
        "window",
    )
    east = ls(
        S.ellipse(0.1, 0.06, centre=(0.3, 0.3), angle=0.5), S.CORNELL_BACK_WALL, (3.0, 4.0, 8.0), "east"
    )
    return [
        ("window appears", {"window": win}),
        ("second light appears", {"window": win, "east": east}),
        ("window disappears", {"east": east}),
    ]


def office_scenario(frames):
    def screen(i, em):
        return ls(S.rect(0.56, 0.34, (0.28, 0.17)), frames[i], em, f"screen{i}")

    s0, s1 = screen(0, (2.0, 2.5, 4.0)), screen(1, (2.0, 2.5, 4.0))
    s0b = screen(0, (4.0, 4.0, 3.5))
    return [
        ("screen 0 on", {"s0": s0}),
        ("screen 1 on", {"s0": s0, "s1": s1}),
        ("screen 0 colour", {"s0": s0b, "s1": s1}),
    ]


def beam_scenario(n=30):
    out = []
    for k in range(n):
        t = k / (n - 1)
        sh = ls(
            S.ellipse(
                0.09, 0.05, centre=(0.1 + 0.35 * t, 0.3 + 0.08 * np.sin(2 * np.pi * t)), angle=0.4 + 0.5 * t
            ),
            S.CORNELL_BACK_WALL,
            (10.0, 10.0, 8.0),
            "beam",
            moves=True,
        )
        out.append((f"frame {k}", {"beam": sh}))
    return out


def config_key(scene, config, params):
    m = hashlib.sha1(scene.encode())
    for k in sorted(config):
        s = config[k]
        m.update(str(k).encode())
        for r in s.rings:
            m.update(np.ascontiguousarray(r, float).tobytes())
        m.update(np.asarray(s.emission, float).tobytes())
    m.update(repr(params).encode())
    return m.hexdigest()[:16]


def reference(scene, mesh, config, pts, ids, cache_dir, cheap_base):
    """Reflected radiance at the sample points of NAIVE at reference quality (cached on disk). The
    empty configuration is the reference-quality base system; others are NAIVE rebuilds at reference
    quality (naive_params), started from a cheap base so the reference base is not built again."""
    key = config_key("cornell" if scene == "beam" else scene, config, REFERENCE)
    path = os.path.join(cache_dir, f"{key}.npy")
    if os.path.exists(path):
        ref = np.load(path)
        if ref.shape == (len(pts), 3):
            return ref, 0.0
    t0 = time.perf_counter()
    if config:
        dyn = DynamicRadiosity(cheap_base.copy(), method="NAIVE", naive_params=REFERENCE)
        dyn.apply(config)
    else:
        dyn = DynamicRadiosity(RadiositySystem(mesh, REFERENCE), method="NAIVE")
    B, E = dyn.evaluate(pts, ids)
    ref = B - E
    os.makedirs(cache_dir, exist_ok=True)
    np.save(path, ref)
    return ref, time.perf_counter() - t0


def err(x, ref, w):
    d2 = ((x - ref) ** 2).sum(1)
    return float(np.sqrt(np.average(d2, weights=w))), float(np.sqrt(d2.max()))


def event_record(label, fr, **cpu):
    """The JSON record of one applied frame (fr: DynamicRadiosity.apply's report) with its CPU figures."""
    return {
        "event": label,
        "seconds": fr.seconds,
        **cpu,
        "iterations": fr.iterations,
        "nodes_added": fr.nodes_added,
        "nodes_removed": fr.nodes_removed,
        "nodes": fr.nodes,
        "links": fr.links,
        "memory_bytes": fr.memory_bytes,
        "method_used": fr.method,
        "emission_l1": max([e.emission_l1 for e in fr.events] + [0.0]),
        "messages": fr.messages,
    }


def naive_ratios(runs, q):
    """Each run of quality q gets naive_ratio: NAIVE's CPU per event over its own, in the same run."""
    naive = next(r for r in runs if r["quality"] == q and r["method"] == "NAIVE")
    for r in runs:
        if r["quality"] == q:
            r["naive_ratio"] = [
                n["cpu_seconds"] / max(e["cpu_seconds"], 1e-9) for n, e in zip(naive["events"], r["events"])
            ]


def run_variant(base, method, kw, events, pts, ids, eval_at):
    dyn = DynamicRadiosity(base.copy(), method=method, **kw)
    B0, E0 = dyn.evaluate(pts, ids)
    refl0 = B0 - E0
    out, refl = [], {}
    for i, (label, config) in enumerate(events):
        c0 = time.process_time()
        fr = dyn.apply(config)
        cpu = time.process_time() - c0
        rec = event_record(label, fr, cpu_seconds=cpu)
        if i in eval_at:
            B, E = dyn.evaluate(pts, ids)
            refl[i] = B - E
        out.append(rec)
    return out, refl, refl0


def run_scenario(name, mesh, events, qualities, variants, repeat, per_area, eval_at, cache_dir, log):
    from hr_addon.core.geometry import prepare_patches

    pts, ids, w = surface_samples(prepare_patches(mesh), per_area)
    t0 = time.perf_counter()
    cheap = RadiositySystem(mesh, QUALITY["coarse"])
    ref0, _ = reference(name, mesh, {}, pts, ids, cache_dir, cheap)
    refs = {}
    for i in eval_at:
        refs[i], _ = reference(name, mesh, events[i][1], pts, ids, cache_dir, cheap)
    log(f"[{name}] references: {time.perf_counter() - t0:.1f} s ({len(pts)} sample points)")
    result = {
        "scene": name,
        "sample_points": int(len(pts)),
        "events": [e[0] for e in events],
        "eval_at": sorted(eval_at),
        "runs": [],
    }
    for q in qualities:
        t0 = time.perf_counter()
        base = RadiositySystem(mesh, QUALITY[q])
        log(
            f"[{name}/{q}] base system: {base.h.n} nodes, {len(base.links)} links, "
            f"{time.perf_counter() - t0:.1f} s"
        )
        for label, method, kw in variants:
            reps = 1 if method == "NAIVE" else repeat
            best = None
            for _ in range(reps):
                evs, refl, refl0 = run_variant(base, method, kw, events, pts, ids, eval_at)
                if best is None:
                    best = evs
                else:
                    for b, e in zip(best, evs):
                        b["seconds"] = min(b["seconds"], e["seconds"])
                        b["cpu_seconds"] = min(b["cpu_seconds"], e["cpu_seconds"])
            for i in eval_at:
                best[i]["err_total_rmse"], best[i]["err_total_max"] = err(refl[i], refs[i], w)
                best[i]["err_delta_rmse"], best[i]["err_delta_max"] = err(refl[i] - refl0, refs[i] - ref0, w)
            run = {"quality": q, "variant": label, "method": method, "kwargs": kw, "events": best}
            result["runs"].append(run)
            tt = [e["cpu_seconds"] for e in best]
            ee = [best[i]["err_delta_rmse"] for i in eval_at]
            log(
                f"  {label:13s} mean {np.mean(tt):7.3f} s/event  "
                f"delta RMSE {np.sqrt(np.mean(np.square(ee))):.4f}  "
                f"nodes+ {max(e['nodes_added'] for e in best)}"
            )
        naive_ratios(result["runs"], q)
    return result


# -- --gather: the gathered output ------------------------------------------------------------------
def bake_gather(q):
    """The bake's final-gather settings at quality q (blender/settings.py GATHER, no bpy)."""
    from hr_addon.blender.settings import GATHER

    return dict(GATHER[q.upper()])


class NaiveCache:
    """events.dynamic._NaiveState kept per light configuration (shapes' geometry and emission, the
    input patches) for REFERENCE parameters only: both references and every quality read one REFERENCE
    rebuild per configuration. Other parameters (the NAIVE variant's own rebuilds, timed) pass through."""

    def __init__(self):
        from hr_addon.core.events import dynamic

        self.mod, self.orig, self.store, self.seconds = dynamic, dynamic._NaiveState, {}, 0.0

    def __enter__(self):
        def make(system, shapes, lights, params, *a):
            if params != REFERENCE or lights:
                return self.orig(system, shapes, lights, params, *a)
            m = hashlib.sha1(np.ascontiguousarray(system.patches.corners).tobytes())
            for r in shapes:
                m.update(repr(r.geom_key).encode())
                m.update(np.asarray(r.emission, float).tobytes())
            key = m.hexdigest()
            if key not in self.store:
                c0 = time.process_time()
                self.store[key] = self.orig(system, shapes, lights, params, *a)
                self.seconds += time.process_time() - c0
            return self.store[key]

        self.mod._NaiveState = make
        return self

    def __exit__(self, *exc):
        self.mod._NaiveState = self.orig
        self.store.clear()


class Plain:
    """A solved RadiositySystem on the input patches read as a NAIVE rebuild without shapes (what
    FinalGather._naive_values reads: .system, .remap): the REFERENCE base solution seen through a
    quality's gather."""

    def __init__(self, system):
        self.system = system

    def remap(self, points, patch_ids):
        return np.asarray(patch_ids, np.int64).copy(), np.asarray(points, float).copy()


def clear_shape_caches(g):
    """Empty the gather's per-shape caches and host visibility stores on every level and slot facing
    copy (each variant pays its shapes' direct light and the host visibility's rays)."""
    lv = g
    while lv is not None:
        slot = getattr(lv, "_slot", None)
        for x in (lv, slot["f"] if slot else None):
            if x is not None:
                x._shape_cache.clear()
                for k in ("_preview_cache", "_host_stores"):
                    x.__dict__.pop(k, None)
        lv._naive_key = None
        lv = getattr(lv, "second", None)
    g._responses.clear()
    g._responses_of = None


@contextlib.contextmanager
def hostvis_off():
    """hostvis.ENABLED off inside (restored after): the independent reference's gathers read their
    shapes' direct light by shadow rays, not by the host visibility the timed methods read."""
    from hr_addon.core.gather import hostvis

    was, hostvis.ENABLED = hostvis.ENABLED, False
    try:
        yield
    finally:
        hostvis.ENABLED = was


def gathered_references(name, mesh, events, eval_at, pts, ids, naive_cache, log):
    """Per evaluated event i and None (no shapes): the independent gathered reference (mean of the
    REF_SEEDS gathers over the REFERENCE base), and the two seeds' values; plus the REFERENCE base."""
    from hr_addon.core.gather import FinalGather

    c0 = time.process_time()
    ref_base = RadiositySystem(mesh, REFERENCE)
    ref_base.solve()
    log(
        f"[{name}] REFERENCE base: {ref_base.h.n} nodes, {len(ref_base.links)} links, "
        f"{time.process_time() - c0:.1f} s CPU"
    )
    nrm = ref_base.patches.normal[ids]
    per_seed = {}
    cost = {"reference_base_cpu_s": time.process_time() - c0}
    for seed in REF_SEEDS:
        c0 = time.process_time()
        g = FinalGather(ref_base, pts, nrm, ids, seed=seed, **REF_GATHER)
        cost[f"reference_gather_precompute_cpu_s_seed{seed}"] = time.process_time() - c0
        c0 = time.process_time()
        vals = {None: g.evaluate(ref_base, "reflected")}
        for i in sorted(eval_at):
            dyn = DynamicRadiosity(ref_base.copy(), method="NAIVE", naive_params=REFERENCE)
            dyn.apply(events[i][1])
            vals[i] = g.evaluate(dyn, "reflected")
        cost[f"reference_gather_evaluate_cpu_s_seed{seed}"] = ev = time.process_time() - c0
        pre = cost[f"reference_gather_precompute_cpu_s_seed{seed}"]
        log(f"[{name}] gathered reference seed {seed}: {g.n} samples, {pre:.1f} + {ev:.1f} s CPU")
        per_seed[seed] = vals
        del g
    a, b = (per_seed[s] for s in REF_SEEDS)
    ref = {k: 0.5 * (a[k] + b[k]) for k in a}
    return ref, a, b, ref_base, cost


def run_gathered(name, mesh, events, qualities, variants, repeat, per_area, eval_at, log, noise_seed=True):
    from hr_addon.core.gather import FinalGather
    from hr_addon.core.geometry import prepare_patches

    pts, ids, w = surface_samples(prepare_patches(mesh), per_area)
    result = {
        "scene": name,
        "sample_points": int(len(pts)),
        "events": [e[0] for e in events],
        "eval_at": sorted(eval_at),
        "runs": [],
    }
    with NaiveCache() as nc:
        with hostvis_off():
            ref, ra, rb, ref_base, cost = gathered_references(name, mesh, events, eval_at, pts, ids, nc, log)
        # the reference's own noise: the two seeds' light contribution apart (RMSE / max of a - b; the
        # mean's noise is about half the RMSE of a - b)
        result["reference"] = dict(REF_GATHER, seeds=list(REF_SEEDS), params=repr(REFERENCE), **cost)
        result["reference"]["seed_diff"] = {
            str(i): err(ra[i] - ra[None], rb[i] - rb[None], w) for i in sorted(eval_at)
        }
        result["reference"]["contribution_rms"] = {
            str(i): float(np.sqrt(np.average(((ref[i] - ref[None]) ** 2).sum(1), weights=w)))
            for i in sorted(eval_at)
        }
        for q in qualities:
            params = RefineParams.for_gather(q)
            dkw0 = DynamicRadiosity.gather_options(q)
            gset = bake_gather(q)
            c0 = time.process_time()
            base = RadiositySystem(mesh, params)
            build = time.process_time() - c0
            assert np.array_equal(base.patches.corners, ref_base.patches.corners)
            c0 = time.process_time()
            g = FinalGather(
                DynamicRadiosity(base.copy(), method="FE", **dkw0),
                pts,
                base.patches.normal[ids],
                ids,
                seed=0,
                **gset,
            )
            pre = time.process_time() - c0
            log(
                f"[{name}/{q} gathered] base {base.h.n} nodes, {len(base.links)} links, {build:.1f} s CPU; "
                f"gather {g.n} samples, precompute {pre:.1f} s CPU"
            )
            # the transport reference through this gather: NAIVE at REFERENCE (cached rebuilds)
            fake = DynamicRadiosity(base.copy(), method="NAIVE")
            fake._naive = Plain(ref_base)

            def reading_reference(gg):
                """gg's reflected radiance reading NAIVE at REFERENCE: no shapes, then each event."""
                out = {None: gg.evaluate(fake, "reflected")}
                for i in sorted(eval_at):
                    dyn = DynamicRadiosity(base.copy(), method="NAIVE", naive_params=REFERENCE)
                    dyn.apply(events[i][1])
                    out[i] = gg.evaluate(dyn, "reflected")
                return out

            tr = reading_reference(g)
            clear_shape_caches(g)
            floor = {i: err(tr[i] - tr[None], ref[i] - ref[None], w) for i in sorted(eval_at)}
            # the same floor with this gather's shapes read by shadow rays (hostvis off): the floor of
            # the gather before the host visibility
            with hostvis_off():
                t0 = reading_reference(g)
                clear_shape_caches(g)
            floor_off = {str(i): err(t0[i] - t0[None], ref[i] - ref[None], w) for i in sorted(eval_at)}
            # the floor's ray noise: the same gather settings with another seed (seed 1) on the same
            # REFERENCE transport; the RMSE of the two light contributions apart / sqrt 2 is one
            # gather's noise (what the floor holds beyond it: the gather's leaf discretisation)
            noise = {}
            if noise_seed:
                g1 = FinalGather(fake, pts, base.patches.normal[ids], ids, seed=1, **gset)
                t1 = reading_reference(g1)
                noise = {str(i): err(t1[i] - t1[None], tr[i] - tr[None], w) for i in sorted(eval_at)}
                del g1
            qrec = {
                "quality": q,
                "params": repr(params),
                "solve_options": dkw0,
                "gather": gset,
                "build_cpu_s": build,
                "gather_precompute_cpu_s": pre,
                "gather_samples": int(g.n),
                "floor": {str(i): v for i, v in floor.items()},
                "floor_hostvis_off": floor_off,
                "gather_seed_diff": noise,
            }
            result.setdefault("qualities", []).append(qrec)
            for label, method, kw in variants:
                reps = 1 if method == "NAIVE" else repeat
                best = None
                for _ in range(reps):
                    clear_shape_caches(g)
                    dyn = DynamicRadiosity(base.copy(), method=method, **dict(dkw0, **kw))
                    v0 = g.evaluate(dyn, "reflected")
                    evs, vals = [], {}
                    for i, (elabel, config) in enumerate(events):
                        c0 = time.process_time()
                        fr = dyn.apply(config)
                        c1 = time.process_time()
                        v = g.evaluate(dyn, "reflected")
                        c2 = time.process_time()
                        evs.append(
                            event_record(
                                elabel,
                                fr,
                                cpu_seconds=c2 - c0,
                                transport_cpu_seconds=c1 - c0,
                                gather_cpu_seconds=c2 - c1,
                            )
                        )
                        if i in eval_at:
                            vals[i] = v
                    dyn = None
                    if best is None:
                        best = evs
                    else:
                        for b, e in zip(best, evs):
                            for k in (
                                "seconds",
                                "cpu_seconds",
                                "transport_cpu_seconds",
                                "gather_cpu_seconds",
                            ):
                                b[k] = min(b[k], e[k])
                for i in eval_at:
                    d = vals[i] - v0
                    best[i]["err_delta_rmse"], best[i]["err_delta_max"] = err(d, ref[i] - ref[None], w)
                    best[i]["err_transport_rmse"], best[i]["err_transport_max"] = err(d, tr[i] - tr[None], w)
                    best[i]["err_total_rmse"], best[i]["err_total_max"] = err(vals[i], ref[i], w)
                run = {"quality": q, "variant": label, "method": method, "kwargs": kw, "events": best}
                result["runs"].append(run)
                tt = [e["cpu_seconds"] for e in best]
                tg = [e["gather_cpu_seconds"] for e in best]
                ee = [best[i]["err_delta_rmse"] for i in eval_at]
                et = [best[i]["err_transport_rmse"] for i in eval_at]
                log(
                    f"  {label:13s} mean {np.mean(tt):7.3f} s/event (gather {np.mean(tg):.3f})  delta RMSE "
                    f"{np.sqrt(np.mean(np.square(ee))):.4f}  transport {np.sqrt(np.mean(np.square(et))):.4f}"
                )
            naive_ratios(result["runs"], q)
            fl = [floor[i][0] for i in eval_at]
            fo = [v[0] for v in floor_off.values()]
            log(
                f"  floor (the gather on REFERENCE transport vs ref) {np.sqrt(np.mean(np.square(fl))):.4f}"
                f" (hostvis off {np.sqrt(np.mean(np.square(fo))):.4f})"
            )
            if noise:
                nz = [v[0] for v in noise.values()]
                log(
                    f"  seed 0 vs 1 of that gather: {np.sqrt(np.mean(np.square(nz))):.4f} "
                    "(/ sqrt 2: one's noise)"
                )
            del g
        result["naive_reference_rebuild_cpu_s"] = nc.seconds
    return result


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="coarse quality only, 6 beam frames, 1 repeat")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--gather", action="store_true", help="the gathered output (module doc)")
    ap.add_argument("--no-noise", action="store_true", help="--gather: skip the floor's seed-1 gather")
    ap.add_argument("--only", default="", help="scenarios to run (comma separated; default all)")
    ap.add_argument("--out", default=None, help="default benchmarks/out/events.json (events_gathered.json)")
    ap.add_argument("--cache", default=os.path.join(ROOT, "benchmarks", "out", "events_refcache"))
    args = ap.parse_args()
    if args.out is None:
        args.out = os.path.join(
            ROOT, "benchmarks", "out", "events_gathered.json" if args.gather else "events.json"
        )
    t_start = time.perf_counter()

    def log(msg):
        print(f"{time.perf_counter() - t_start:7.1f}s {msg}", flush=True)

    repeat = 1 if args.quick else args.repeat
    office, frames = S.office_scene()
    beam = beam_scenario(6 if args.quick else 30)
    plan = [
        (
            "cornell",
            scenes.cornell_box(),
            cornell_scenario(),
            ["coarse"] if args.quick else ["coarse", "draft", "medium"],
            2000,
            None,
        ),
        (
            "office",
            office,
            office_scenario(frames),
            ["coarse"] if args.quick else ["coarse", "draft"],
            60,
            None,
        ),
        (
            "beam",
            scenes.cornell_box(),
            beam,
            ["coarse"] if args.quick else ["coarse", "draft"],
            2000,
            {0, len(beam) // 3, 2 * len(beam) // 3, len(beam) - 1},
        ),
    ]
    results = []
    only = set(args.only.split(",")) if args.only else None
    for name, mesh, events, quals, per_area, eval_at in plan:
        if only is not None and name not in only:
            continue
        eval_at = set(range(len(events))) if eval_at is None else eval_at
        if args.gather:
            quals = ["draft"] if args.quick else GATHER_QUALITY[name]
            results.append(
                run_gathered(
                    name, mesh, events, quals, VARIANTS, repeat, per_area, eval_at, log, not args.no_noise
                )
            )
        else:
            results.append(
                run_scenario(name, mesh, events, quals, VARIANTS, repeat, per_area, eval_at, args.cache, log)
            )
    out = {
        "mode": "gathered" if args.gather else "classic",
        "reference_params": repr(REFERENCE),
        "quality": {k: repr(v) for k, v in QUALITY.items()}
        if not args.gather
        else {q: repr(RefineParams.for_gather(q)) for q in ("draft", "medium")},
        "variants": [(lb, m, kw) for lb, m, kw in VARIANTS],
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
        },
        "total_seconds": time.perf_counter() - t_start,
        "scenarios": results,
    }
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    log(f"wrote {args.out}")


if __name__ == "__main__":
    main()
