"""The two rooms' floor-lamp pole from a close camera (it is in neither of camera_compare's views):
Cycles at 2 x 64 spp against the Preview Bake of one or more vertex bakes, per object's bias.

    python benchmarks/two_rooms_pole.py --work DIR --frame 1 NAME=BAKED.blend [NAME=BAKED.blend ...]

DIR is camera_compare.py's --work (its two_rooms/two_rooms.blend is the scene the references render,
doorway flipped as the bake turns it); each BAKED.blend is a bake of that scene (its hr_cache beside
it). Writes DIR/pole_fN/ (references, renders) and pole.json there (session 38, branch two38)."""

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import camera_compare as cc  # noqa: E402

# 85 mm from the room, 1.75 m off: the pole's top 0.7 m (the part under the lamp) ~13 px wide
CAMERA = ((3.5, 1.75, 1.35), (4.6, 0.4, 1.25), 85)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", required=True)
    p.add_argument("--frame", type=int, default=1)
    p.add_argument("--spp", type=int, default=64)
    p.add_argument("bakes", nargs="+", help="NAME=path of a baked .blend")
    a = p.parse_args()
    cc.WORK, cc.FLIP_REF[:] = a.work, ["doorway"]
    view = dict(scene="two_rooms", frame=a.frame, camera=CAMERA, res=(240, 320))
    names = cc.geometry_names(view)
    d = os.path.join(a.work, f"pole_f{a.frame}")
    os.makedirs(d, exist_ok=True)
    refs = []
    for seed in cc.SEEDS:
        path = os.path.join(d, f"ref_s{a.spp}_seed{seed}.exr")
        if not os.path.exists(path):
            cc.reference(view, names, a.spp, seed, path)
        refs.append(cc.read_render(path))
    ours = {}
    for item in a.bakes:
        tag, saved = item.split("=", 1)
        path = os.path.join(d, f"ours_{tag}.exr")
        if not os.path.exists(path):
            cc.ours(view, names, saved, cc.OURS_SPP, path)
        ours[tag] = cc.read_render(path)[0]
    (ra, ob), (rb, _) = refs
    inner = cc.interior(ob)
    res = {}
    for i, n in enumerate(names):
        for part, m in (("all", ob == i + 1), ("interior", (ob == i + 1) & inner)):
            if m.sum() < cc.MIN_PIXELS:
                continue
            ma, mb = ra[m].mean(0), rb[m].mean(0)
            ref = (ma + mb) / 2
            e = dict(pixels=int(m.sum()), ref_noise=float(np.mean(np.abs(ma - mb) / (ma + mb))))
            e.update({f"bias_{t}": float(np.mean(img[m].mean(0) / ref - 1)) for t, img in ours.items()})
            res[f"{n}|{part}"] = e
            print(f"{n:16s} {part:8s} {e['pixels']:6d} noise {e['ref_noise']:.2%}", end="")
            print("".join(f"  {t} {e[f'bias_{t}']:+.2%}" for t in ours))
    out = dict(view=view, ref_spp=a.spp, seeds=cc.SEEDS, bakes=a.bakes, objects=res)
    json.dump(out, open(os.path.join(d, "pole.json"), "w"), indent=1)


if __name__ == "__main__":
    main()
