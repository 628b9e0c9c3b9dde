"""Approximate cuts of a light event at 100k, in one process, against main's settings: each
variant's CPU (event, output, and the output's parts) and its gathered output per object against
the reference variant's of the same round (compare_gather_dumps.difference: lit objects, median /
p95 / worst relative difference, pooled bias). Variants alternate within a round, each on a fresh
DynamicRadiosity (the base parts computed once and shared: only the shape's part is timed).

    .venv/bin/python benchmarks/event_cuts.py --store /work/cache/ev25store \\
        --variants 'dict(main={}, r4=dict(second_shadow_rays=4))' [--methods FE,AUTO] \\
        [--rounds 2] [--json out.json]

A variant is a dict of: shadow_rays / second_shadow_rays (a level's shadow rays), iterations (the
passes), seed / second_seed (the levels' shadow-ray seeds: a noise floor), far_rays / far_near
(the second level's FAR_RAYS / FAR_NEAR: FinalGather._second_shape), dyn
(DynamicRadiosity options over gather_options("draft")).
"""

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", default="/work/cache/ev25store")
    ap.add_argument("--variants", required=True)
    ap.add_argument("--ref", default="main")
    ap.add_argument("--methods", default="FE,AUTO")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", default=None)
    ap.add_argument("--dump", default=None, help="npz of each variant's outputs (last round)")
    ap.add_argument("--objects", default="", help="object ids whose difference is printed: 198,516")
    args = ap.parse_args(argv)

    from bench_gather_events import load_store
    from compare_gather_dumps import difference, per_object
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.gather import final as fg
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    cpu = time.process_time
    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    s.links.extended(s.h)
    g.iterations = 4
    _, info = furnished_room("100k")
    _, frame = info["light_wall"]
    obj = np.asarray(s.mesh.object_id)[np.repeat(np.arange(len(s.mesh.loop_start)), s.mesh.loop_total)]
    g2 = g.second
    defaults = dict(shadow=g2.shadow_rays, iterations=g.iterations, seed=g.seed, seed2=g2.seed)
    defaults.update(shadow_top=g.shadow_rays)
    defaults.update(far=g2.FAR_RAYS, far_near=g2.FAR_NEAR)
    variants = eval(args.variants)
    base_opts = DynamicRadiosity.gather_options("draft")

    # per-part CPU: the levels' direct light and reads, wrapped on the instances
    acc = {}

    def wrap(name):  # on the class: a level's copies (FinalGather._unoccluded) count too
        f = getattr(fg.FinalGather, name)

        def w(self, *a, **k):
            key = name.strip("_").split("_")[0] + ("_second" if hasattr(self, "_leaf_nodes") else "_top")
            c0 = cpu()
            try:
                return f(self, *a, **k)
            finally:
                acc[key] = acc.get(key, 0.0) + cpu() - c0

        setattr(fg.FinalGather, name, w)

    wrap("direct_light")
    wrap("_read")

    def window(cx):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.full(3, 20.0), "window")

    def setup(v):
        g2.shadow_rays = v.get("second_shadow_rays", defaults["shadow"])
        g.shadow_rays = v.get("shadow_rays", defaults["shadow_top"])
        g.iterations = v.get("iterations", defaults["iterations"])
        g.seed = v.get("seed", defaults["seed"])
        g2.seed = v.get("second_seed", defaults["seed2"])
        g2.FAR_RAYS = v.get("far_rays", defaults["far"])
        g2.FAR_NEAR = v.get("far_near", defaults["far_near"])
        for lv in (g, g2):
            lv._shape_cache.clear()

    base_part = {}
    res = {m: {n: [] for n in variants} for m in args.methods.split(",")}
    outs = {}
    for rnd in range(args.rounds):
        for method in res:
            for name, v in variants.items():
                setup(v)
                dyn = DynamicRadiosity(s.copy(), method=method, **{**base_opts, **v.get("dyn", {})})
                if method not in base_part:
                    g.loop_radiance(dyn)  # the base parts, once per method
                    base_part[method] = (
                        g._responses[("base",)],
                        g._loop_parts[("base",)],
                    )
                else:  # the same base parts for this DynamicRadiosity (untimed)
                    g._responses.clear()
                    g._responses[("base",)] = base_part[method][0]
                    g._responses_of = dyn
                    g._loop_parts.clear()
                    g._loop_parts[("base",)] = base_part[method][1]
                row = {}
                for step, ev in (
                    ("add", lambda: dyn.add("w", window(0.7))),
                    ("move", lambda: dyn.apply({"w": window(1.2)})),
                ):
                    acc.clear()
                    c0 = cpu()
                    ev()
                    c1 = cpu()
                    out = g.loop_radiance(dyn)
                    c2 = cpu()
                    row[step] = dict(event=c1 - c0, output=c2 - c1, total=c2 - c0, **acc)
                    outs[(method, name, step)] = np.array(out, np.float32)
                    # (loops whose output has a negative channel: an estimator's values below 0)
                    row[step]["negative_loops"] = int((outs[(method, name, step)] < 0).any(1).sum())
                res[method][name].append(row)
                print(
                    f"round {rnd} {method} {name}: "
                    + ", ".join(
                        f"{st} {r['total']:.3f} s (event {r['event']:.3f}, output {r['output']:.3f}, "
                        f"negative loops {r['negative_loops']})"
                        for st, r in row.items()
                    ),
                    flush=True,
                )
                dyn = None
            for name in variants:
                if name == args.ref:
                    continue
                for step in ("add", "move"):
                    a = per_object(outs[(method, args.ref, step)], obj)
                    b = per_object(outs[(method, name, step)], obj)
                    d = difference(a, b)
                    # the objects moved by more than 2%: how many, the share darker (a reseed:
                    # about half; a one-sided estimator: most)
                    lit = a > 0.05 * a[a > 0].mean()
                    rel = (b[lit] - a[lit]) / a[lit]
                    d["moved2"] = int((np.abs(rel) > 0.02).sum())
                    d["darker2"] = float((rel < -0.02).sum() / max(d["moved2"], 1))
                    for o in (int(t) for t in args.objects.split(",") if t):
                        d[f"object_{o}"] = float((b[o] - a[o]) / a[o]) if a[o] > 0 else None
                    res[method][name][-1][step]["vs_ref"] = d
                    print(
                        f"   {method} {name} {step} vs {args.ref}: median {100 * d['median']:.3f}%, p95 "
                        f"{100 * d['p95']:.3f}%, worst {100 * d['worst']:.3f}%, bias {100 * d['bias']:+.3f}% "
                        f"({d['objects']} lit objects; moved > 2% {d['moved2']}, "
                        f"darker {100 * d['darker2']:.0f}%)",
                        flush=True,
                    )
                    if args.objects:
                        got = [(k[7:], v) for k, v in d.items() if k.startswith("object_") and v is not None]
                        print("      objects: " + ", ".join(f"{k} {100 * v:+.1f}%" for k, v in got))
    # medians over the rounds, ratios against the reference
    summary = {}
    for method, vs in res.items():
        for name, rows in vs.items():
            for step in ("add", "move"):
                med = {
                    k: float(np.median([r[step].get(k, 0.0) for r in rows]))
                    for k in rows[0][step]
                    if k != "vs_ref"
                }
                summary[f"{method}_{name}_{step}"] = med
    for key, med in summary.items():
        method, name, step = key.split("_", 2)[0], key.split("_")[1], key.rsplit("_", 1)[1]
        ref = summary[f"{method}_{args.ref}_{step}"]
        med["ratio"] = med["total"] / ref["total"]
        parts = ", ".join(f"{k} {v:.3f}" for k, v in med.items() if k not in ("total", "ratio"))
        print(f"{key}: total {med['total']:.3f} s, x{med['ratio']:.3f} ({parts})", flush=True)
    if args.json:
        Path(args.json).write_text(
            json.dumps(dict(rounds=res, medians=summary, variants=args.variants), indent=1)
        )
    if args.dump:
        np.savez_compressed(args.dump, loop_object=obj, **{"_".join(k): v for k, v in outs.items()})


if __name__ == "__main__":
    main()
