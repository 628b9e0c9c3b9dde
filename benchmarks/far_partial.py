"""Issue 19 (branch pl32, docs/gather.md): where the kept far links over-transfer (kern31: 4.8% of
their exact exchange, partly facing ends +19%), bpy-free, on the furnished room (draft gather
transport, orient on). Measure only.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/far_partial.py [--room 20k] \
        [--points 16] [--json benchmarks/out/far_partial_20k.json]

Uniform unit radiance on every exposed leaf; per bin of far links: the exact exchange (2 x dense
kernel visibility x unoccluded exchange, far_vis_check.dense_visibility) as a share of all far
links', and the model (one gather + push over that bin's links, kernel_split.received) over it,
once with the links' traced visibility and once with every link at its dense kernel visibility
(what is left then is the kernel's: the ends' SH, one visibility for all members). Bins: partly
facing or facing ends, traced wholly visible or partly, strong or weak, cluster-cluster or
node-cluster, the area share of a partial end's members that face the other end's centre, ends
with a bookcase member.
"""

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from far_vis_check import BASE, dense_visibility, link_vis, with_visibility  # noqa: E402
from kernel_split import far_subset, received  # noqa: E402

from hr_addon.core.cluster import Ends, decode, estimate  # noqa: E402
from hr_addon.core.links import Links  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def members(tree, ids):
    """(owner, member patch) of every cluster end in ids (< 0); node ends are their own member."""
    cl = ids < 0
    ci = decode(np.minimum(ids, -1))
    cnt = np.where(cl, tree.end[ci] - tree.start[ci], 1)
    owner = np.repeat(np.arange(len(ids)), cnt)
    off = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    m = np.where(cl[owner], tree.perm[np.minimum(tree.start[ci][owner] + off, len(tree.perm) - 1)], 0)
    return owner, m, cl


def facing_share(s, tree, ids, other):
    """Per end: the exposed-area share of its members (a node: itself) facing the point `other`."""
    h = s.h
    owner, m, cl = members(tree, ids)
    node = np.maximum(ids, 0)[owner]
    m = np.where(cl[owner], m, node)
    w = h.area[m] * h.exposure[m]
    f = np.einsum("ij,ij->i", other[owner] - h.centre[m], h.normal[m]) > 0
    return np.bincount(owner, w * f, len(ids)) / np.maximum(np.bincount(owner, w, len(ids)), 1e-300)


def has_object(s, tree, ids, prefix):
    h = s.h
    owner, m, cl = members(tree, ids)
    m = np.where(cl[owner], m, np.maximum(ids, 0)[owner])
    names = np.array(list(s.patches.object_names)).astype(str)
    hit = np.char.startswith(names[np.asarray(s.patches.object_id)[h.patch[m]]], prefix)
    return np.bincount(owner, hit, len(ids)) > 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--room", default="20k")
    ap.add_argument("--points", type=int, default=16)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    mesh, _ = furnished_room(args.room)
    t0 = time.process_time()
    s = RadiositySystem(mesh, dataclasses.replace(BASE))
    out = {"room": args.room, "points": args.points, "build_cpu_s": time.process_time() - t0}
    h, far = s.h, s.links.far
    op = s.operator()
    lf = op.leaves
    ex = np.ones(op.n) if op.expo is None else op.expo.astype(float)
    U = np.zeros((1, op.n))
    U[0, lf] = ex[lf]
    t0 = time.process_time()
    _, vk, exch = dense_visibility(s, far, args.points, seed=2)
    out["dense_cpu_s"] = time.process_time() - t0
    exact = 2 * vk * exch
    dense_far = with_visibility(far, vk)
    ea, eb = Ends(far.tree, h, far.a), Ends(far.tree, h, far.b)
    f_ab, f_ba, _ = estimate(ea, eb, both=True)
    strong = np.maximum(f_ab, f_ba) >= BASE.shadow_feps
    lv = link_vis(far)
    part = far.part_a | far.part_b
    fa = facing_share(s, far.tree, far.a, eb.centre)
    fb = facing_share(s, far.tree, far.b, ea.centre)
    fmin = np.where(far.part_a & far.part_b, np.minimum(fa, fb), np.where(far.part_a, fa, fb))
    case = has_object(s, far.tree, far.a, "case") | has_object(s, far.tree, far.b, "case")
    clcl = (far.a < 0) & (far.b < 0)
    v1, vp = lv >= 1, (lv > 0) & (lv < 1)
    bins = {
        "all": np.ones(len(far), bool),
        "facing": ~part,
        "facing traced 1": ~part & v1,
        "facing traced partly": ~part & vp,
        "partial": part,
        "partial traced 1": part & v1,
        "partial traced partly": part & vp,
        "partial strong": part & strong,
        "partial weak": part & ~strong,
        "partial clcl": part & clcl,
        "partial node-cluster": part & ~clcl,
        "partial both ends": far.part_a & far.part_b,
        "partial facing share < 0.25": part & (fmin < 0.25),
        "partial facing share 0.25-0.5": part & (fmin >= 0.25) & (fmin < 0.5),
        "partial facing share 0.5-0.75": part & (fmin >= 0.5) & (fmin < 0.75),
        "partial facing share >= 0.75": part & (fmin >= 0.75),
        "partial bookcase end": part & case,
        "partial no bookcase end": part & ~case,
        "facing bookcase end": ~part & case,
    }
    total = exact.sum()
    out["bins"] = {}
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0))
    for k, m in bins.items():
        if not m.any():
            continue
        mod = float(received(s, Links(*empty, far=far_subset(far, m)), U)[0])
        mod_d = float(received(s, Links(*empty, far=far_subset(dense_far, m)), U)[0])
        e = float(exact[m].sum())
        r = dict(
            n=int(m.sum()),
            exact_share=e / total,
            traced_over_exact=mod / e,
            dense_vis_over_exact=mod_d / e,
            excess_share=(mod - e) / total,
            traced_vis_over_dense=float((lv * exch)[m].sum() / (vk * exch)[m].sum()),
        )
        out["bins"][k] = r
        print(
            f"{k:32s} n {r['n']:6d}  share {r['exact_share']:.3f}  traced/exact {r['traced_over_exact']:.3f}"
            f"  dense-vis/exact {r['dense_vis_over_exact']:.3f}  excess {r['excess_share']:+.4f}"
            f"  vis traced/dense {r['traced_vis_over_dense']:.3f}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
