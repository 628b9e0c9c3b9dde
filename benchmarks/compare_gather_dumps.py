"""Per-object difference of two bench_gather_events.py dumps (the gathered output after each
event): which transport settings change the gathered output by how much.

    .venv/bin/python benchmarks/compare_gather_dumps.py fine.npz coarse.npz
"""

import sys

import numpy as np


def per_object(v, obj):
    """Mean radiance (summed over channels) of each object's loops."""
    n = obj.max() + 1
    s = np.bincount(obj, v.sum(1), n)
    c = np.bincount(obj, None, n)
    return s / np.maximum(c, 1)


def difference(ma, mb, lit_frac=0.05):
    """Per-object means mb against the reference ma over the objects lit above lit_frac of ma's
    mean: the relative differences' median, p95, worst, share within 1%, and the pooled bias."""
    lit = ma > lit_frac * ma[ma > 0].mean()
    rel = (mb[lit] - ma[lit]) / ma[lit]
    tot = (mb[lit].sum() - ma[lit].sum()) / ma[lit].sum()
    return dict(
        objects=int(lit.sum()),
        median=float(np.median(np.abs(rel))),
        p95=float(np.percentile(np.abs(rel), 95)),
        worst=float(np.abs(rel).max()),
        within1=float(np.mean(np.abs(rel) <= 0.01)),
        bias=float(tot),
    )


def compare(ref_path, other_path, lit_frac=0.05):
    a, b = np.load(ref_path), np.load(other_path)
    obj = a["loop_object"]
    return {
        k: difference(per_object(a[k], obj), per_object(b[k], obj), lit_frac)
        for k in a.files
        if k != "loop_object" and k in b.files
    }


def line(k, r):
    return (
        f"{k:>14}: {r['objects']} lit objects, |diff| median {100 * r['median']:.2f}%, "
        f"p95 {100 * r['p95']:.2f}%, worst {100 * r['worst']:.2f}%, within 1% {100 * r['within1']:.0f}%, "
        f"bias {100 * r['bias']:+.2f}%"
    )


if __name__ == "__main__":
    for k, r in compare(sys.argv[1], sys.argv[2]).items():
        print(line(k, r))
