"""Issue 19 (branch kern31, docs/gather.md): the patch links the draft transport drops as occluded
(refine._finish: vis_k 1, one ray between the nodes' visibility points, `keep = vis > 0`), their
exact exchange and why their ray is blocked, bpy-free, on the furnished room.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/patch_dropped.py [--room 20k] \
        [--points 8] [--json benchmarks/out/patch_dropped_20k.json]

The room is built with refine.KEEP_OCCLUDED (the links traced wholly occluded kept, no transfer).
For the kept and the dropped patch links: the exact exchange (2 A_a F_ab, far_vis_check's dense
kernel visibility) as a share of the room's uniform exchange (sum of exposed areas), the dense
visibility weighted by it, and for the dropped ones: where their ray's first hit is (from the a
end), whether a visibility point is on a covered part (contacts), whether the hit face is one of
the link's own patches, whether an end is partly covered.
"""

import argparse
import dataclasses
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE, dense_visibility  # noqa: E402

import hr_addon.core.refine as RF  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


class _Pairs:
    def __init__(self, tree, a, b):
        self.tree, self.a, self.b = tree, a, b

    def __len__(self):
        return len(self.a)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--room", default="20k")
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--vis-k", type=int, default=None, help="the build's vis_k (draft: 1)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--no-unsplit", action="store_true", help="refine.UNSPLIT_2X2 off (main before pl32)")
    args = ap.parse_args()
    RF.KEEP_OCCLUDED = True
    RF.UNSPLIT_2X2 = not args.no_unsplit
    mesh, _ = furnished_room(args.room)
    prm = BASE if args.vis_k is None else dataclasses.replace(BASE, vis_k=args.vis_k)
    s = RadiositySystem(mesh, prm)
    h, L, r = s.h, s.links, s.refiner
    op = s.operator()
    lf = op.leaves
    sent = float((op.area[lf] * op.expo[lf]).sum())
    a, b = L.a.astype(np.int64), L.b.astype(np.int64)
    _, vk, ex = dense_visibility(s, _Pairs(L.far.tree, a, b), args.points)
    exact = 2 * vk * ex
    out = {"room": args.room, "points": args.points, "vis_k": prm.vis_k, "sent": sent}

    def split(m):
        return dict(
            n=int(m.sum()),
            exact_share=float(exact[m].sum() / sent),
            dense_vis=float((vk * ex)[m].sum() / ex[m].sum()),
            traced_vis=float((L.vis * ex)[m].sum() / ex[m].sum()),
        )

    drop = L.vis <= 0
    for name, m in (("kept", ~drop), ("dropped", drop)):
        out[name] = split(m)
        print(name, out[name], flush=True)
    # the links neither end of which can split, strong (pl32's class), kept and dropped together:
    # the estimator against dense, not selected by its own value
    aeps_all = prm.aeps * r.total_area
    cls = (h.area[a] <= aeps_all) & (h.area[b] <= aeps_all) & (np.maximum(L.f_ab, L.f_ba) >= prm.shadow_feps)
    for name, m in (("unsplit_strong_all", cls), ("other_all", ~cls)):
        out[name] = split(m)
        print(name, out[name], flush=True)
    # the dropped links' rays (vis_k 1: one point a node): why blocked
    i = np.flatnonzero(drop)
    k = prm.vis_k
    pa = r.sample_points(a[i]) + r.eps * h.normal[a[i]][:, None]
    pb = r.sample_points(b[i]) + r.eps * h.normal[b[i]][:, None]
    pa, pb = pa[:, 0], pb[:, (k * k - 1)]  # (the weak links' first segment)
    cov_a = cov_b = np.zeros(len(i), bool)
    if h.contacts is not None:
        cov_a = h.contacts.covered(pa, h.patch[a[i]])
        cov_b = h.contacts.covered(pb, h.patch[b[i]])
    prim, t = s.backend.first_hit(pa, pb - pa, 1.0)
    seg = np.linalg.norm(pb - pa, axis=1)
    dist = t * seg
    tri_patch = s.patches.triangle_patch
    w = exact[i]
    W = w.sum()
    part = (h.exposure[a[i]] < 1) | (h.exposure[b[i]] < 1)
    aeps = prm.aeps * r.total_area
    unsplit = (h.area[a[i]] <= aeps) & (h.area[b[i]] <= aeps)
    weak = np.maximum(L.f_ab[i], L.f_ba[i]) < prm.shadow_feps
    classes = {
        "neither_end_splits_strong": unsplit & ~weak,
        "neither_end_splits_weak": unsplit & weak,
        "an_end_splits_weak": ~unsplit & weak,
        "an_end_splits_strong": ~unsplit & ~weak,
        "point_covered": cov_a | cov_b,
        "end_partly_covered": part,
        "hit_within_1cm": dist < 0.01,
        "hit_within_2mm": dist < 0.002,
        "no_hit(?)": ~np.isfinite(dist),
    }
    if tri_patch is not None:
        hp = np.where(prim >= 0, tri_patch[np.maximum(prim, 0)], -1)
        classes["hit_own_patch"] = (hp == h.patch[a[i]]) | (hp == h.patch[b[i]])
    out["dropped_by_cause"] = {}
    for kk, m in classes.items():
        out["dropped_by_cause"][kk] = dict(
            n=int(m.sum()),
            exact_share_of_dropped=float(w[m].sum() / W),
            dense_vis=float((vk * ex)[i][m].sum() / max(ex[i][m].sum(), 1e-300)),
        )
        print(kk, out["dropped_by_cause"][kk], flush=True)
    q = np.quantile(dist[np.isfinite(dist)], [0.1, 0.25, 0.5])
    out["hit_distance_quantiles_10_25_50"] = q.tolist()
    print("first hit distance quantiles 10/25/50%", np.round(q, 4))
    # by object class of the two ends
    names = np.array(list(s.patches.object_names))
    oid = np.asarray(s.patches.object_id)
    cls = lambda n: np.where(
        np.char.startswith(n, "case"), "case", np.where(np.char.startswith(n, "box"), "box", "other")
    )  # noqa: E731
    ca, cb = cls(names[oid[h.patch[a[i]]]].astype(str)), cls(names[oid[h.patch[b[i]]]].astype(str))
    out["dropped_by_objects"] = {}
    for x in ("case", "box", "other"):
        m = (ca == x) | (cb == x)
        out["dropped_by_objects"][x] = float(w[m].sum() / W)
    same = oid[h.patch[a[i]]] == oid[h.patch[b[i]]]
    out["dropped_by_objects"]["same_object"] = float(w[same].sum() / W)
    print("dropped by objects (share of the dropped exchange)", out["dropped_by_objects"])
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
