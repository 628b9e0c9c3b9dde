"""The output's per-event parts at 100k alone, for exact cuts: a light shape's direct light at each
gather level (`DirectLight._shape`, its cache cleared) and the reads (`FinalGather._read` of the
top level and the second level on a fixed 3-channel input), CPU seconds (process time) per part,
repeated; with --save the values are written, with --check compared bit for bit to a saved run.

    .venv/bin/python benchmarks/direct_cuts.py STORE [--rounds 3] [--profile out.txt] \\
        [--save ref.npz | --check ref.npz] [--parts direct,read] [--window 0.7]
"""

import argparse
import hashlib
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def digest(a):
    return hashlib.sha1(np.ascontiguousarray(a).tobytes()).hexdigest()[:12]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--profile", default=None)
    ap.add_argument("--save", default=None)
    ap.add_argument("--check", default=None)
    ap.add_argument("--parts", default="direct,read")
    ap.add_argument("--window", type=float, default=0.7)
    ap.add_argument("--method", default="FE")
    ap.add_argument("--set", default="dict()", help="attributes per level: dict(top=dict(shadow_rays=12))")
    ap.add_argument(
        "--ab",
        default=None,
        help="alternate within each round: dict(name=dict(top=dict(shadow_rays=12)), ...) (levels' "
        "attributes; the first is the reference of the errors)",
    )
    args = ap.parse_args(argv)

    from bench_gather_events import stored_room
    from hr_addon.core.events import DynamicRadiosity

    cpu = time.process_time
    s, g, window = stored_room(args.store)
    dyn = DynamicRadiosity(s.copy(), method=args.method, **DynamicRadiosity.gather_options("draft"))
    dyn.add("w", window(args.window))
    rec = dyn.shapes["w"]
    levels = [("top", g), ("second", g.second)]
    for name, lv in levels:
        for k, v in eval(args.set).get(name, {}).items():
            setattr(lv, k, v)
    rng = np.random.default_rng(1)
    # a fixed 3-channel input per level's read (the leaf values' rows it reads)
    reads = []
    for name, lv in levels:
        cols, used = lv._read_cols()
        rows = lv.n_hr + (lv.n if lv.near_points and lv.second is None else 0)
        if lv.second is not None and lv.second.near_points:
            rows = lv.n_hr + lv.second.n
        Y = rng.random((max(rows, int(used.max()) + 1), 3))
        reads.append((name, lv, Y))
    if args.ab:
        return ab_rounds(args, levels, dyn, rec, eval(args.ab))
    parts = args.parts.split(",")
    got, times = {}, {}
    prof = None
    if args.profile:
        import cProfile

        prof = cProfile.Profile(time.process_time)
    for rnd in range(args.rounds):
        row = {}
        if prof is not None and rnd == args.rounds - 1:
            prof.enable()
        if "direct" in parts:
            for name, lv in levels:
                lv._shape_cache.clear()
                c0 = cpu()
                D = lv._shape(dyn, rec)[0]
                row[f"direct_{name}"] = cpu() - c0
                got[f"direct_{name}"] = D
        if "read" in parts:
            for name, lv, Y in reads:
                c0 = cpu()
                r = lv._read((Y, None, None, None))
                row[f"read_{name}"] = cpu() - c0
                got[f"read_{name}"] = r
        if prof is not None and rnd == args.rounds - 1:
            prof.disable()
        for k, v in row.items():
            times.setdefault(k, []).append(v)
        print(f"round {rnd}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
    print("medians: " + ", ".join(f"{k} {np.median(v):.3f}" for k, v in times.items()))
    print("digests: " + ", ".join(f"{k} {digest(v)}" for k, v in got.items()))
    for name, lv in levels:
        D = got.get(f"direct_{name}")
        if D is not None:
            print(f"{name}: n {lv.n:,}, lit {int((D > 0).sum()):,}, shadow rays {lv.shadow_rays}")
    if prof is not None:
        import io
        import pstats

        out = io.StringIO()
        st = pstats.Stats(prof, stream=out)
        st.sort_stats("cumulative").print_stats(50)
        st.sort_stats("tottime").print_stats(40)
        Path(args.profile).write_text(out.getvalue())
    if args.save:
        np.savez(args.save, **got)
    if args.check:
        ref = np.load(args.check)
        for k, v in got.items():
            same = k in ref.files and ref[k].dtype == v.dtype and np.array_equal(ref[k], v)
            print(f"check {k}: {'EQUAL' if same else 'DIFFERENT'}", flush=True)
            if not same and k in ref.files and k.startswith("direct"):
                a, b = ref[k].astype(np.float64), v.astype(np.float64)
                d = np.abs(b - a)
                print(
                    f"   samples changed {int((d > 0).sum()):,} of {int((a > 0).sum()):,} lit; sum "
                    f"{b.sum() / a.sum() - 1:+.4%}; |diff| / mean lit {d.mean() / a[a > 0].mean():.4%}",
                    flush=True,
                )


def ab_rounds(args, levels, dyn, rec, variants):
    """Each round every variant's direct light at every level, alternating; medians per variant
    and level, and each variant's values against the first's (samples changed, the level's sum)."""
    cpu = time.process_time
    keep = {
        name: {k: getattr(lv, k) for v in variants.values() for k in v.get(name, {})} for name, lv in levels
    }
    times, got = {}, {}
    for rnd in range(args.rounds):
        for vname, v in variants.items():
            for name, lv in levels:
                for k, val in {**keep[name], **v.get(name, {})}.items():
                    setattr(lv, k, val)
                lv._shape_cache.clear()
                c0 = cpu()
                got[(vname, name)] = lv._shape(dyn, rec)[0]
                times.setdefault((vname, name), []).append(cpu() - c0)
        print(f"round {rnd}: " + ", ".join(f"{a} {b} {t[-1]:.3f}" for (a, b), t in times.items()), flush=True)
    ref = next(iter(variants))
    # the penumbrae: samples the reference sees the shape partly from (0 < D < F, F its exact
    # unoccluded form factor), where fewer or other rays change the values
    pen = {}
    for name, lv in levels:
        F = lv._unoccluded(lv._shape_emitter(dyn, rec)[0]).astype(np.float64)
        D = got[(ref, name)].astype(np.float64)
        pen[name] = (D > 0) & (D < F * (1 - 1e-6))
    for (vname, name), t in times.items():
        a, b = got[(ref, name)].astype(np.float64), got[(vname, name)].astype(np.float64)
        r = np.median(t) / np.median(times[(ref, name)])
        print(
            f"{vname} {name}: median {np.median(t):.3f} s (x{r:.3f}); vs {ref}: changed "
            f"{int((a != b).sum()):,} of {int((a > 0).sum()):,} lit, sum {b.sum() / a.sum() - 1:+.4%}",
            flush=True,
        )
        p = pen[name]
        if vname != ref and p.any():
            ch = p & (a != b)
            print(
                f"   penumbra samples {int(p.sum()):,} ({a[p].sum() / a.sum():.1%} of the light): changed "
                f"{int(ch.sum()):,}, their light {b[p].sum() / a[p].sum() - 1:+.3%}; changed outside "
                f"{int(((a != b) & ~p).sum()):,}",
                flush=True,
            )


if __name__ == "__main__":
    main()
