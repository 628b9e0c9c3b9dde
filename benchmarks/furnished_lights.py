"""Furnished room lit by daylight against Cycles (issue 20's target: median per-object error at most
5% at draft). The scene: hr_testing.furnished.daylight_room (the furnished 20k room without its
ceiling panel, a window opening through the south wall) with its sun and uniform World sky, built
in Blender by hr_testing/cycles_lights.daylight_scene. Ours: the draft bake's own path (BakeConfig
at DRAFT: the final gather's hierarchy and solver options, solver_setup, the lights and the World
read by lights_in.collect_lights, the final gather's settings) evaluated at the comparison atlas's
texels; Cycles: DIFFUSE bakes (direct + indirect x colour) of the same texels. Per object as
benchmarks/furnished_vs_cycles.py: median error of the object's mean, share within 5%, median
signed error, pooled bias; apart for the objects the sun lights directly, those only the sky
lights directly and those lit by bounce light only (by our direct light's share).

    .venv/bin/python benchmarks/furnished_lights.py [--size 20k] [--spp 128] [--seeds 1,2]
        [--ref-only] [--wait] [--name NAME] [--quality DRAFT] [--texel-rel 0.00667]
        [--gather 'dict(near=1e9)'] [--no-portal] [--split-sky] [--ours-from NAME]

The reference is baked with a Cycles portal filling the window (the same light, the sky's part
with less noise: docs/lights.md, *A daylight reference through a portal*); --no-portal: without
(the references before 2026-12-05); --split-sky: the sky as an emitter in the window instead.

--ref-only: bake (and cache) the Cycles references only; --wait: wait for references another
process is baking. References are cached in benchmarks/out/cycles_cache/ under a key naming the
scene, its window and lights, the portal, and the atlas. Writes benchmarks/out/furnished_lights_NAME.json.
"""

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.dirname(HERE))
import numpy as np  # noqa: E402

import cycles_compare as CC  # noqa: E402
from hr_testing import cycles_lights as CL  # noqa: E402
from hr_testing import cycles_ref as C  # noqa: E402
from hr_testing import furnished as F  # noqa: E402

TEXEL_REL = CC.SCENES["furnished"]["texel_rel"]


def ref_key(size, portal=False):
    """The Cycles reference's cache name: the scene, its window and its lights."""
    facts = json.dumps([F.SOUTH_WINDOW, F.SUN, F.SKY], sort_keys=True, default=float)
    tag = "_portal" if portal else ""
    return f"furnished_daylight_{size}{tag}_{hashlib.sha1(facts.encode()).hexdigest()[:8]}"


def reference(rs, key, spp, seed, wait, split=None):
    """{name: (N, 3)} Cycles reference of one seed (cycles_compare.cycles_bake's cache). split:
    daylight_scene's info: the sun's and the sky's light baked apart (the sky as an emitter in the
    window, CL.daylight_part) and summed."""
    if split is not None:
        parts = []
        for part in ("sun", "sky"):
            CL.daylight_part(part, split)
            parts.append(reference(rs, f"{key}_{part}", spp, seed, wait))
        CL.daylight_part("all", split)
        return (
            {n: parts[0][0][n] + parts[1][0][n] for n in rs.objects},
            {k: parts[0][1][k] + parts[1][1][k] for k in parts[0][1]},
            parts[0][2] and parts[1][2],
        )
    path = CC.ref_path(rs, key, 1, spp, seed)
    while wait and not os.path.exists(path):
        time.sleep(20)
    for _ in range(30):
        try:
            return CC.cycles_bake(rs, key, 1, spp, seed)
        except Exception as e:  # another process is still writing the file
            if not wait:
                raise
            print(f"   waiting for {os.path.basename(path)}: {e}", flush=True)
            time.sleep(10)
    raise RuntimeError(f"{path}: cannot be read")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="20k")
    ap.add_argument("--spp", type=int, default=CC.SCENES["furnished"]["ref_spp"])
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--ref-only", action="store_true")
    ap.add_argument("--wait", action="store_true")
    ap.add_argument("--name", default="draft")
    ap.add_argument("--quality", default="DRAFT")
    ap.add_argument("--texel-rel", type=float, default=TEXEL_REL)
    ap.add_argument(
        "--no-portal", action="store_true", help="Cycles samples the World without a portal in the window"
    )
    ap.add_argument(
        "--split-sky", action="store_true", help="the sun and the sky (an emitter in the window) baked apart"
    )
    ap.add_argument("--noise", default="", help="SPP:SEED,SEED: the reference's noise from two bakes at SPP")
    ap.add_argument("--ours-from", default="", help="NAME: our values of an earlier run (its npz and JSON)")
    ap.add_argument(
        "--gather", default="", help="dict(...): texel gather keywords over the bake's (a variant)"
    )
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    portal = not (args.no_portal or args.split_sky)  # the split sky's parts need no portal
    scene, info = CL.daylight_scene(args.size, portal)
    rs = C.prepare(scene, texel_rel=args.texel_rel)
    key = ref_key(args.size, portal)
    split = info if args.split_sky else None
    lo, hi = info["window"]
    print(
        f"{key}: {len(rs.objects)} objects compared, {sum(rs.atlases[n].n for n in rs.objects)} texels, "
        f"window x {lo[0]:.3f}..{hi[0]:.3f} z {lo[2]:.3f}..{hi[2]:.3f} m",
        flush=True,
    )
    if args.ref_only:
        for s in seeds:
            _, t, cached = reference(rs, key, args.spp, s, False, split)
            print(f"   Cycles seed {s}: {'cached' if cached else 'baked'}, {t}", flush=True)
        return
    if args.ours_from:  # the values and costs of an earlier run (same scene)
        z = np.load(os.path.join(HERE, "out", f"furnished_lights_{args.ours_from}_ours.npz"))
        res = {n: {} for n in rs.objects}
        for k in z.files:
            if k == "__meta":
                continue
            n, var = k.split("|")
            res[n][var] = z[k].astype(np.float64)
        cost, our_info = json.loads(str(z["__meta"])) if "__meta" in z.files else ({}, {})
        our_info["values_from"] = args.ours_from
    else:
        res, cost, our_info = CL.bake_ours(
            rs, args.quality, gather=eval(args.gather) if args.gather else None
        )
        # our per-texel values for a closer look (not committed: benchmarks/out keeps JSON only)
        np.savez_compressed(
            os.path.join(HERE, "out", f"furnished_lights_{args.name}_ours.npz"),
            **{
                f"{n}|{k}": v.astype(np.float32)
                for n in rs.objects
                for k, v in res[n].items()
                if np.ndim(v) == 2
            },
            __meta=json.dumps([cost, our_info], default=float),
        )
    print(f"   ours: {', '.join(f'{k} {v:.3g}' for k, v in cost.items())}", flush=True)
    refs, ref_times = [], []
    for s in seeds:
        r, t, _ = reference(rs, key, args.spp, s, args.wait, split)
        refs.append(r)
        ref_times.append(t)
    noise_pair, noise_note = None, f"{len(seeds)} seeds"
    if args.noise:  # two bakes at fewer samples: their noise scaled to the reference's samples
        nspp, nseeds = args.noise.split(":")
        a, b = (reference(rs, key, int(nspp), int(s), args.wait, split)[0] for s in nseeds.split(","))
        noise_pair = (a, b, np.sqrt(int(nspp) / (args.spp * len(seeds))))
        noise_note = f"seeds {nseeds} at {nspp} spp, scaled"
    objects, lit, summary = CL.per_object(rs, res, refs, noise_pair)
    for g, st in summary.items():
        print(
            f"   {g:10s} {st['objects']} lit objects: median {100 * st['median']:.1f}%, within 5%: "
            f"{100 * st['within_5']:.0f}%, median signed {100 * st['median_signed']:+.1f}%, pooled bias "
            f"{100 * st['pooled_bias']:+.2f}%, texel-weighted error {100 * st['weighted']:.1f}%",
            flush=True,
        )
    if lit and "ref_noise" in objects[lit[0]]:
        nz = [objects[n]["ref_noise"] for n in lit]
        print(
            f"   reference noise of an object's mean ({noise_note}): median {100 * np.median(nz):.2f}%",
            flush=True,
        )
        summary["all"]["ref_noise_median"] = float(np.median(nz))
        summary["all"]["ref_noise_from"] = noise_note
    if lit and "ref_noise_texels" in objects[lit[0]]:
        nt = np.array([objects[n]["ref_noise_texels"] for n in lit])
        books = np.array(["_book" in n for n in lit])
        print(
            f"   reference noise of an object's mean from its texels' seed differences: median "
            f"{100 * np.nanmedian(nt):.2f}% (books {100 * np.nanmedian(nt[books]):.2f}%, others "
            f"{100 * np.nanmedian(nt[~books]):.2f}%)",
            flush=True,
        )
        summary["all"]["ref_noise_texels_median"] = float(np.nanmedian(nt))
        for lim in (0.025, 0.05):  # the objects whose reference mean is known well enough to judge
            k = nt < lim
            if k.any():
                summary[f"ref_noise_texels_below_{lim}"] = st = C.object_summary(
                    objects, [n for n, y in zip(lit, k) if y]
                )
                print(
                    f"   reference known within {100 * lim:g}% (texel noise): {st['objects']} objects, "
                    f"median {100 * st['median']:.1f}%, within 5%: {100 * st['within_5']:.0f}%, "
                    f"books {int(np.sum(k & books))}",
                    flush=True,
                )
    sc = np.array([objects[n]["scatter_noise"] for n in lit])
    err = np.array([objects[n]["mre"] for n in lit])
    print(
        f"   texel-scatter bound of the reference's noise: median {100 * np.nanmedian(sc):.1f}%", flush=True
    )
    for lim in (0.025, 0.05):  # the objects whose reference mean is known well enough to judge
        k = sc < lim
        if k.any():
            summary[f"scatter_below_{lim}"] = st = C.object_summary(objects, [n for n, y in zip(lit, k) if y])
            print(
                f"   reference known within {100 * lim:g}% (scatter): {st['objects']} objects, median "
                f"{100 * st['median']:.1f}%, within 5%: {100 * st['within_5']:.0f}%",
                flush=True,
            )
    summary["all"]["scatter_noise_median"] = float(np.nanmedian(sc))
    summary["all"]["beyond_2_scatter"] = int(np.sum(err > 2 * sc))
    room = ["floor", "ceiling", "wall_south", "wall_north", "wall_west", "wall_east"]
    print(
        "   room: "
        + ", ".join(
            f"{n} {100 * objects[n]['bias']:+.1f}% (sun {100 * objects[n]['share_sun']:.0f}%, "
            f"sky {100 * objects[n]['share_sky']:.0f}%)"
            for n in room
            if n in objects
        ),
        flush=True,
    )
    worst = sorted(lit, key=lambda n: -objects[n]["mre"])[:12]
    print(
        "   worst: "
        + ", ".join(
            f"{n} {100 * objects[n]['bias']:+.1f}% ({objects[n]['kind']}, {objects[n]['texels']} texels"
            + (
                f", noise {100 * objects[n]['ref_noise_texels']:.1f}%"
                if "ref_noise_texels" in objects[n]
                else ""
            )
            + ")"
            for n in worst
        ),
        flush=True,
    )
    dump = {
        "scene": key,
        "size": args.size,
        "window": [np.asarray(v).tolist() for v in info["window"]],
        "sun": F.SUN,
        "sky": F.SKY,
        "cycles_portal": portal,
        "cycles_spp": args.spp,
        "seeds": seeds,
        "cycles_ref_bakes": ref_times,
        "ours": our_info,
        "cpu_seconds": cost,
        "summary": summary,
        "lit": lit,
        "objects": objects,
    }

    C.write_json(os.path.join(HERE, "out", f"furnished_lights_{args.name}.json"), dump)


if __name__ == "__main__":
    main()
