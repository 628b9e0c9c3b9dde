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
    .venv/bin/python benchmarks/plot_events.py
"""

import argparse
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
# (label, method, DynamicRadiosity keyword arguments)
VARIANTS = [
    ("NAIVE", "NAIVE", {}),
    ("FE", "FE", {}),
    ("FE warm", "FE", {"incremental": "warm"}),
    ("AR", "AR", {}),
    ("AUTO", "AUTO", {}),
    ("AUTO bf=1e-2", "AUTO", {"bf_rel": 1e-2}),
]


def ls(outline, frame, em, name):
    return LightShape(S.on_plane(outline, frame), np.asarray(em, float), name)


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


def run_variant(base, method, kw, events, pts, ids, eval_at):
    dyn = DynamicRadiosity(base.copy(), method=method, **kw)
    B0, E0 = dyn.evaluate(pts, ids)
    refl0 = B0 - E0
    out, refl = [], {}
    for i, (label, config) in enumerate(events):
        c0 = time.process_time()
        fr = dyn.apply(config)
        cpu = time.process_time() - c0
        rec = {
            "event": label,
            "seconds": fr.seconds,
            "cpu_seconds": cpu,
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
            f"[{name}/{q}] base system: {base.h.n} nodes, {len(base.links)} links, {time.perf_counter() - t0:.1f} s"
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
                f"  {label:13s} mean {np.mean(tt):7.3f} s/event  delta RMSE {np.sqrt(np.mean(np.square(ee))):.4f}"
                f"  nodes+ {max(e['nodes_added'] for e in best)}"
            )
        # ratios in the same run
        naive = next(r for r in result["runs"] if r["quality"] == q and r["method"] == "NAIVE")
        for r in result["runs"]:
            if r["quality"] == q:
                r["naive_ratio"] = [
                    n["cpu_seconds"] / max(e["cpu_seconds"], 1e-9)
                    for n, e in zip(naive["events"], r["events"])
                ]
    return result


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="coarse quality only, 6 beam frames, 1 repeat")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "out", "events.json"))
    ap.add_argument("--cache", default=os.path.join(ROOT, "benchmarks", "out", "events_refcache"))
    args = ap.parse_args()
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
    for name, mesh, events, quals, per_area, eval_at in plan:
        eval_at = set(range(len(events))) if eval_at is None else eval_at
        results.append(
            run_scenario(name, mesh, events, quals, VARIANTS, repeat, per_area, eval_at, args.cache, log)
        )
    out = {
        "reference_params": repr(REFERENCE),
        "quality": {k: repr(v) for k, v in QUALITY.items()},
        "variants": [(l, m, kw) for l, m, kw in VARIANTS],
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
