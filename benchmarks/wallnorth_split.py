"""The close view's wall_north at frame 3 (the Window shape on), split (docs/accuracy.md, session 30,
branch wallnorth): camera_compare.py's renders (renders.npz) of the same view at frame 1 and 3,
per output, over the object's pixels.

    .venv/bin/python benchmarks/wallnorth_split.py --f1 furnished_close_vs0.25 \
        --f3 furnished_close_f3_vs0.25,furnished_close_f3_texel0.02,... [--object wall_north] [--json OUT]

- Per run: ours / Cycles - 1 (sum over the pixels, RGB pooled), all and interior pixels.
- The window's light: Cycles frame 3 - frame 1 per pixel (what the Window shape adds, its direct
  light and its bounces); pixels binned by that share of frame 3's light (window-lit patches against
  the shade), each run's error per bin.
- The most window-lit patches: 4 x 4-pixel blocks wholly on the object with >= 80% window light,
  the percentiles of their errors (blocks).
- The added light itself: (ours f3 - ours f1) / (Cycles f3 - Cycles f1) - 1, for each --f3 run whose
  output --f1 also holds (same output, same spacing: --pairs f3run:f1run).
"""

import argparse
import json
import os

import numpy as np
from camera_compare import OUT, interior


def load(view):
    z = np.load(os.path.join(OUT, f"camera_{view}", "renders.npz"))
    out = next(k for k in ("vertex", "texture") if k in z.files)
    return dict(ref=(z["ref1"] + z["ref2"]) / 2, ours=z[out], index=z["index"], names=list(z["names"]))


def blocks(ours, ref, m, share, b=4, lo=0.8):
    """ours / Cycles - 1 of the b x b pixel blocks wholly on the object whose mean window share is at
    least lo (the most window-lit patches, the pixels' noise averaged): count and 10/50/90th percentiles."""
    h, w = (m.shape[0] // b) * b, (m.shape[1] // b) * b

    def tile(x):
        return x[:h, :w].reshape(h // b, b, w // b, b)

    sel = tile(m).all((1, 3)) & (tile(share).mean((1, 3)) >= lo)
    r = tile(ours.sum(-1)).sum((1, 3))[sel] / tile(ref.sum(-1)).sum((1, 3))[sel] - 1
    return dict(blocks=int(sel.sum()), p10_50_90=np.percentile(r, [10, 50, 90]).tolist())


def err(ours, ref, m):
    return float(ours[m].sum() / ref[m].sum() - 1) if m.any() else None


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--f1", required=True)
    p.add_argument("--f3", required=True)
    p.add_argument("--pairs", default="", help="f3run:f1run,... for the added light's error")
    p.add_argument("--object", default="wall_north")
    p.add_argument("--json", default=os.path.join(OUT, "wallnorth_split.json"))
    a = p.parse_args()
    f1 = {v: load(v) for v in a.f1.split(",")}
    f3 = {v: load(v) for v in a.f3.split(",")}
    base = next(iter(f3.values()))
    ob = base["index"]
    m = ob == base["names"].index(a.object) + 1
    inner = m & interior(ob)
    ref1 = next(iter(f1.values()))["ref"]
    ref3 = base["ref"]
    for r in list(f1.values()) + list(f3.values()):
        assert (r["index"] == ob).mean() > 0.999
    win = (ref3 - ref1).sum(-1)
    share = win / np.maximum(ref3.sum(-1), 1e-12)
    bins = [(0.0, 0.5), (0.5, 0.7), (0.7, 0.8), (0.8, 1.01)]
    res = dict(
        object=a.object,
        pixels=int(m.sum()),
        interior=int(inner.sum()),
        cycles_mean_f1=ref1[m].mean(0).tolist(),
        cycles_mean_f3=ref3[m].mean(0).tolist(),
        window_share_f3=float(win[m].sum() / ref3[m].sum(-1).sum()),
        window_share_bins={
            f"{lo:.1f}-{hi:.1f}": int((m & (share >= lo) & (share < hi)).sum()) for lo, hi in bins
        },
        runs={},
    )
    print(
        f"{a.object}: {res['pixels']} px ({res['interior']} interior), window's share of f3's light "
        f"{100 * res['window_share_f3']:.1f}%"
    )
    for name, runs in (("f1", f1), ("f3", f3)):
        for v, r in runs.items():
            e = dict(all=err(r["ours"], r["ref"], m), interior=err(r["ours"], r["ref"], inner))
            if name == "f3":
                e["by_window_share"] = {
                    f"{lo:.1f}-{hi:.1f}": err(r["ours"], r["ref"], m & (share >= lo) & (share < hi))
                    for lo, hi in bins
                }
                e["blocks_window_08"] = blocks(r["ours"], r["ref"], m, share)
            res["runs"][v] = e
            print(
                f"  {v:36s} all {100 * e['all']:+6.1f}%  interior {100 * e['interior']:+6.1f}%  "
                + "  ".join(
                    f"{k}: {100 * x:+.1f}%" for k, x in e.get("by_window_share", {}).items() if x is not None
                )
            )
    res["added"] = {}
    for pair in filter(None, a.pairs.split(",")):
        v3, v1 = pair.split(":")
        d_ours = f3[v3]["ours"] - f1[v1]["ours"]
        d_ref = ref3 - ref1
        res["added"][pair] = dict(all=err(d_ours, d_ref, m), interior=err(d_ours, d_ref, inner))
        res["added"][pair]["base_f1"] = err(f1[v1]["ours"], ref1, m)
        e = res["added"][pair]
        print(
            f"  window's added light {pair}: {100 * e['all']:+.1f}% (interior {100 * e['interior']:+.1f}%), "
            f"frame 1's {100 * e['base_f1']:+.1f}%"
        )
    with open(a.json, "w") as f:
        json.dump(res, f, indent=1)
    print("wrote", a.json)


if __name__ == "__main__":
    main()
