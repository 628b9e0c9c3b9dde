"""Our camera renders against the per-object Cycles means a camera_compare.py JSON keeps (session 36,
branch two36, docs/accuracy.md): for a machine whose Cycles references are gone (a 64-spp pair of
the two rooms is ~9 CPU minutes a view and frame; on two cores shared by six engineers, hours).

    .venv/bin/python benchmarks/camera_refmeans.py --json benchmarks/out/camera_lead34_u_f1.json \
        --view unseen_a_flip --scene two_rooms [--index REF.exr] [--tag T] OURS.exr [OURS.exr ...]

Each object's mean over its pixels in our render (camera_compare.ours' EXR) against the JSON's
`mean_ref` of that object (the mean of its two reference seeds, kept to 4 digits), over the JSON's
lit objects: the same metrics and summary as camera_compare.compare (cycles_ref.metrics /
object_summary). The pixels: the index pass of --index (any render of the references of that view:
any seed or spp gives the same pixels), else our own render's (it may differ from the references'
by a pixel at edges). Not the interior-pixel figures nor the reference noise (the JSON keeps
neither per pixel). --tag writes benchmarks/out/camera_<tag>.json in camera_compare's layout (one
view entry per EXR: VIEW, or with several EXRs VIEW_<the EXR's folder>); two such files of one EXR each
are what camera_diff.py compares.
"""

import argparse
import json
import os
import re
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))


def against_means(rgb, ob, names, kept):
    """{"objects": {name: {"vertex": metrics}}, "lit", "summary"} of a render (rgb (H, W, 3), object
    index ob (H, W): names[i - 1] at index i) against kept, a camera_compare JSON's view entry
    (its `lit` list and each object's `mean_ref`); objects below MIN_PIXELS pixels left out."""
    from hr_testing import cycles_ref as C

    from camera_compare import MIN_PIXELS

    per = {}
    for i, n in enumerate(names):
        if n not in kept["lit"]:
            continue
        m = ob == i + 1
        if m.sum() < MIN_PIXELS:
            continue
        mo, mr = rgb[m].mean(0), np.asarray(kept["objects"][n]["mean_ref"], np.float64)
        per[n] = {
            "texels": int(m.sum()),
            "mean_ours": mo.tolist(),
            "mean_ref": mr.tolist(),
            "mre": float(np.mean(np.abs(mo - mr) / np.maximum(mr, 1e-12))),
            "bias": float(np.mean((mo - mr) / np.maximum(mr, 1e-12))),
        }
    lit = [n for n in kept["lit"] if n in per]
    return {
        "objects": {n: {"vertex": p, "pixels": p["texels"]} for n, p in per.items()},
        "lit": lit,
        "summary": {"vertex|all": C.object_summary(per, lit)},
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", required=True, help="a camera_compare.py JSON whose view keeps mean_ref")
    p.add_argument("--view", required=True, help="its view entry (e.g. unseen_a_flip, unseen_a_f3_flip)")
    p.add_argument("--scene", default="two_rooms", help="the scene (camera_compare's VIEWS) for the names")
    p.add_argument("--work", help="camera_compare's work folder holding the scene's .blend (--work)")
    p.add_argument("--index", help="a reference render of the view: its object index pass")
    p.add_argument("--tag", help="write benchmarks/out/camera_<tag>.json")
    p.add_argument("exrs", nargs="+")
    a = p.parse_args()
    import camera_compare as cc

    if a.work:
        cc.WORK = a.work
    kept = json.load(open(a.json))["views"][a.view]
    names = cc.geometry_names(dict(kept["view"], scene=a.scene))
    index = cc.read_render(a.index)[1] if a.index else None
    out = {"references": f"{a.json}: {a.view} (mean_ref, {kept.get('ref_spp')} spp)", "views": {}}
    for exr in a.exrs:
        rgb, ob = cc.read_render(exr)
        r = against_means(rgb, ob if index is None else index, names, kept)
        st = r["summary"]["vertex|all"]
        folder = os.path.basename(os.path.dirname(os.path.abspath(exr)))
        key = a.view if len(a.exrs) == 1 else f"{a.view}_{folder}"
        baked = os.path.join(os.path.dirname(exr), "baked.blend.json")  # (camera_compare's bake, beside)
        cpu = json.load(open(baked)) if os.path.exists(baked) else {}
        out["views"][key] = dict(r, exr=exr, cpu_seconds={"bake_vertex": cpu.get("cpu")}, bake=cpu)
        print(
            f"{key}: {st['objects']} lit objects, within 5% {100 * st['within_5']:.1f}%, median "
            f"{100 * st['median']:.2f}%, pooled bias {100 * st['pooled_bias']:+.2f}%"
        )
        for n in sorted(r["objects"], key=lambda n: r["objects"][n]["vertex"]["bias"]):
            v = r["objects"][n]["vertex"]
            if v["mre"] >= 0.05:
                print(f"    {n:20s} {100 * v['bias']:+6.1f}% ({v['texels']} px)")
    if a.tag:  # (4 significant digits, as camera_compare's mean_ref: small files)
        text = json.dumps(out, separators=(",", ":"))
        text = re.sub(r"(-?\d+\.\d+(?:e-?\d+)?)", lambda m: f"{float(m.group(1)):.4g}", text)
        open(os.path.join(HERE, "out", f"camera_{a.tag}.json"), "w").write(text)


if __name__ == "__main__":
    main()
