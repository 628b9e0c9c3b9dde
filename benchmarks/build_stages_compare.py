"""Side by side: build_stages.py JSONs of two checkouts (A: the first group, B: the second), the mean
CPU per stage and the ratio B / A.

    python benchmarks/build_stages_compare.py A1.json [A2.json ...] -- B1.json [B2.json ...]
"""

import json
import sys

import numpy as np


def main(argv):
    i = argv.index("--")
    A = [json.load(open(f)) for f in argv[:i]]
    B = [json.load(open(f)) for f in argv[i + 1 :]]
    order = []
    for r in B + A:
        for k in r["order"]:
            if k not in order:
                order.append(k)
    # keep B's (the newer) order, A's stages where B has none appended after their parents' place

    def mean(runs, k, f="cpu_s"):
        v = [r["stages"].get(k, {}).get(f, 0) for r in runs]
        return float(np.mean(v))

    a, b = np.mean([r["build_cpu_s"] for r in A]), np.mean([r["build_cpu_s"] for r in B])
    print(f"{'stage':40s} {A[0]['commit']:>9s} {B[0]['commit']:>9s}  ratio   diff   calls A/B   rays A/B")
    runs = [[r["build_cpu_s"] for r in x] for x in (A, B)]
    print(f"{'build':40s} {a:9.2f} {b:9.2f}  x{b / a:.2f} {b - a:+6.2f}  (runs {runs[0]} / {runs[1]})")
    for k in order:
        x, y = mean(A, k), mean(B, k)
        ca, cb = mean(A, k, "calls"), mean(B, k, "calls")
        rays = ""
        if any("rays" in r["stages"].get(k, {}) for r in A + B):
            rays = f"{mean(A, k, 'rays') / 1e6:.2f}M/{mean(B, k, 'rays') / 1e6:.2f}M"
        ratio = f"x{y / x:.2f}" if x > 0 else "  new"
        print(f"{k:40s} {x:9.2f} {y:9.2f}  {ratio:5s} {y - x:+6.2f}  {ca:.0f}/{cb:.0f}  {rays}")
    print("links", A[0]["links"], "->", B[0]["links"], " far", A[0]["far_links"], "->", B[0]["far_links"])
    print("nodes", A[0]["nodes"], "->", B[0]["nodes"])


if __name__ == "__main__":
    main(sys.argv[1:])
