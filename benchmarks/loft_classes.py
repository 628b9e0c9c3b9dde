"""The loft's camera figures (hr_testing/loft.py, session 34, branch unseen3) as docs/accuracy.md's
table, and the objects out of 5% by class: what in the scene each stands for.

    .venv/bin/python benchmarks/loft_classes.py benchmarks/out/camera_s34_loft_f1.json \
        benchmarks/out/camera_s34_loft_f3.json [--direct benchmarks/out/camera_s34_loft_direct_f1.json] \
        [--json benchmarks/out/s34_loft_classes.json]

Per view and output: lit objects, median error, share within 5%, pooled bias (camera_compare's
summaries), then each object out of 5% (all its pixels) with its class, its signed error in both
outputs, over interior pixels, the reference's own noise (|seed 1 - seed 2| / 2), whether the error
is beyond 5% + 2 x that noise ("real"), with --direct the same object in bias_split's
direct-light-only run (our direct light against Cycles with no bounces), and with --cycles-direct
WORK Cycles' direct share of its light (WORK/<view>/ref_direct_s16_seed1.exr, Cycles with no
bounces, over the references ref_s<spp>_seed1/2.exr: --spp).
"""

import argparse
import json
import re

CLASSES = [  # (class, pattern on the object's name), first match
    ("shell", r"^(Floor|Ceiling|Wall |Window reveal)"),
    ("light-shape host", r"^Monitor$"),
    ("modifier", r"^(Desk top|Desk leg|Shelf boards|Radiator|Mullions|Window sill|Pendant shade)$"),
    ("mirrored", r"^Armchair mirrored$"),
    ("two materials", r"^Cabinet$"),
    ("thin", r"^(Rug|Frame|Keyboard|Monitor stand)"),
    ("plant", r"(leaves|pot|soil)$"),
    ("book", r"^(Book|Desk book)"),
    ("small item", r"^(Cup|Plate|Bowl|Vase|Shelf item|Desk mug|Monitor neck|Pendant cord|Table stem)"),
]


def klass(name):
    return next((c for c, p in CLASSES if re.search(p, name)), "furniture")


def cycles_direct(work, vn, v, spp):
    """{object: Cycles' direct light / its whole light} over the object's pixels (mean over RGB)."""
    import os

    import numpy as np
    from camera_compare import HERE, read_render

    d = os.path.join(work, vn)
    if not os.path.exists(os.path.join(d, "ref_direct_s16_seed1.exr")):
        return {}
    direct, ob = read_render(os.path.join(d, "ref_direct_s16_seed1.exr"))
    full = sum(read_render(os.path.join(d, f"ref_s{spp}_seed{s}.exr"))[0] for s in (1, 2)) / 2
    names = list(np.load(os.path.join(HERE, "out", f"camera_{vn}", "renders.npz"))["names"])  # pass indices
    out = {}
    for n in v["lit"]:
        m = ob == names.index(n) + 1
        out[n] = float(direct[m].sum() / max(full[m].sum(), 1e-12))
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+")
    p.add_argument("--direct", nargs="*", default=[])
    p.add_argument("--json")
    p.add_argument("--cycles-direct", metavar="WORK")
    p.add_argument("--spp", type=int, default=16)
    a = p.parse_args()
    direct = {}
    for path in a.direct:
        for vn, v in json.load(open(path))["views"].items():
            direct[vn.replace("_direct", "")] = v["objects"]
    out = {"rows": [], "misses": {}}
    for path in a.runs:
        for vn, v in json.load(open(path))["views"].items():
            for k in ("vertex", "texture"):
                s = v["summary"].get(f"{k}|all")
                si = v["summary"].get(f"{k}_interior|all")
                if s is None:
                    continue
                row = dict(view=vn, output=k, lit=s["objects"], median=s["median"], within_5=s["within_5"])
                row.update(
                    pooled_bias=s["pooled_bias"], interior_within_5=si["within_5"], interior_n=si["objects"]
                )
                out["rows"].append(row)
                print(
                    f"| {vn} | {k} | {s['objects']} | {100 * s['median']:.2f}% | "
                    f"{100 * s['within_5']:.0f}% | {100 * s['pooled_bias']:+.2f}% | "
                    f"{100 * si['within_5']:.0f}% ({si['objects']}) |"
                )
            share = cycles_direct(a.cycles_direct, vn, v, a.spp) if a.cycles_direct else {}
            miss = []
            for n in v["lit"]:
                o = v["objects"][n]
                if any(o.get(k, {}).get("mre", 0) > 0.05 for k in ("vertex", "texture")):
                    e = {
                        k: o[k]["bias"]
                        for k in ("vertex", "texture", "vertex_interior", "texture_interior")
                        if k in o
                    }
                    e.update(klass=klass(n), pixels=o["pixels"], ref_noise=o["ref_noise"])
                    worst = max(abs(o[k]["bias"]) for k in ("vertex", "texture") if k in o)
                    e["real"] = bool(worst > 0.05 + 2 * o["ref_noise"])
                    if n in share:
                        e["cycles_direct_share"] = share[n]
                    d = direct.get(vn, {}).get(n)
                    if d:
                        e.update({f"direct_{k}": d[k]["bias"] for k in ("vertex", "texture") if k in d})
                    miss.append((n, e))
            out["misses"][vn] = dict(miss)
            print(f"\n{vn}: {len(miss)} objects out of 5% in either output")
            for n, e in sorted(miss, key=lambda t: (t[1]["klass"], t[0])):
                print(
                    f"  {e['klass']:16s} {n:22s} {e['pixels']:6d} px {'real ' if e['real'] else 'noise'} "
                    + "  ".join(f"{k} {100 * x:+.1f}%" for k, x in e.items() if isinstance(x, float))
                )
    if a.json:
        from hr_testing.cycles_ref import write_json

        write_json(a.json, out)


if __name__ == "__main__":
    import os
    import sys

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    main()
