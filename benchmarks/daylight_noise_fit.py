"""How the daylight room's median per-object error depends on the Cycles reference's noise (issue
20's daylight target, docs/lights.md *A daylight reference through a portal*): our values of a
furnished_lights.py run against every reference one can form from the cached seeds (each seed
alone, each set of seeds averaged; the portal reference and the plain World's), and the fit
median^2 = a + k noise^2 over them: a^0.5, the median at no noise, is a model's figure.

    .venv/bin/python benchmarks/daylight_noise_fit.py [--ours portal] [--portal-seeds 1,2,3]
        [--world-seeds 1,2] [--spp 128]

noise: the median over the lit objects of the noise of an object's mean (one seed's, from the seed
pairs' texel differences, / sqrt(seeds averaged)). Reads benchmarks/out/furnished_lights_OURS.json
and _ours.npz and the cached references; bakes nothing."""

import argparse
import glob
import itertools
import json
import os

import numpy as np

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "out")


def seeds_of(key, seeds, spp, names):
    out = []
    for s in seeds:
        (f,) = glob.glob(os.path.join(OUT, "cycles_cache", f"{key}_f1_s{spp}_seed{s}_po_*.npz"))
        z = np.load(f)
        out.append({n: z[n].astype(np.float64) for n in names})
    return out


def one_seed_noise(refs, names):
    """Per object: the noise of one seed's mean relative to the mean, from all seed pairs' texels."""
    out = []
    for n in names:
        v = []
        for a, b in itertools.combinations(refs, 2):
            d = (a[n] - b[n]).mean(1)
            d = d[np.isfinite(d)]
            if len(d) > 1:
                v.append(np.var(d, ddof=1) / 2 / len(d))
        out.append(np.sqrt(np.mean(v)) / np.nanmean(sum(r[n] for r in refs) / len(refs)) if v else np.nan)
    return np.array(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ours", default="portal")
    ap.add_argument("--portal-seeds", default="1,2,3")
    ap.add_argument("--world-seeds", default="1,2")
    ap.add_argument("--spp", type=int, default=128)
    args = ap.parse_args()
    run = json.load(open(os.path.join(OUT, f"furnished_lights_{args.ours}.json")))
    lit = run["lit"]
    z = np.load(os.path.join(OUT, f"furnished_lights_{args.ours}_ours.npz"))
    ours = {n: z[f"{n}|gather_refl"].astype(np.float64) for n in lit}
    books = np.array(["_book" in n for n in lit])
    key = run["scene"].replace("_portal", "")
    groups = {"all": np.ones(len(lit), bool), "books": books, "others": ~books}
    points = {g: [] for g in groups}
    for label, k, seeds in (
        ("portal", run["scene"], args.portal_seeds),
        ("World", key, args.world_seeds),
    ):
        seeds = [int(s) for s in seeds.split(",")]
        refs = seeds_of(k, seeds, args.spp, lit)
        s1 = one_seed_noise(refs, lit)
        for m in range(1, len(refs) + 1):
            for c in itertools.combinations(range(len(refs)), m):
                err = []
                for n in lit:
                    r = sum(refs[i][n] for i in c) / m
                    ok = np.isfinite(ours[n]).all(1) & np.isfinite(r).all(1)
                    mo, mr = ours[n][ok].mean(0), r[ok].mean(0)
                    err.append(np.mean(np.abs(mo - mr) / np.maximum(mr, 1e-12)))
                err = np.array(err)
                line = []
                for g, sel in groups.items():
                    nz, med = np.nanmedian(s1[sel]) / np.sqrt(m), np.median(err[sel])
                    points[g].append((nz, med))
                    line.append(f"{g} noise {100 * nz:.2f}% median {100 * med:.2f}%")
                print(f"{label} seeds {[seeds[i] for i in c]}: " + ", ".join(line), flush=True)
    for g, p in points.items():
        p = np.array(p)
        A = np.c_[np.ones(len(p)), p[:, 0] ** 2]
        (a, k), *_ = np.linalg.lstsq(A, p[:, 1] ** 2, rcond=None)
        worst = np.abs(np.sqrt(np.maximum(A @ (a, k), 0)) - p[:, 1]).max()
        print(
            f"{g}: median at no noise {100 * np.sqrt(max(a, 0)):.2f}% (k {k:.2f}), "
            f"worst residual {100 * worst:.2f}%"
        )


if __name__ == "__main__":
    main()
