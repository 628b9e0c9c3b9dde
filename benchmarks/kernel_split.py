"""Issue 19 (branch kern31, docs/gather.md): where the closed furnished room's transport loses light,
by link class and source, bpy-free (hr_testing.furnished).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/kernel_split.py \
        [--room 20k] [--points 16] [--json benchmarks/out/kernel_split_20k.json]

The room is built on RefineParams.for_gather("draft") with orient on and solved. Then:
- by source: the solved B restricted to one group of leaves (light, ceiling, walls, floor,
  furniture), one gather + push with all links / patch links only / far links only: the power
  received (sum over leaves of A x exposure x G) over the power the group sends (sum A B). In a
  closed room every unit sent arrives somewhere: 1 - that ratio is the transport's loss, by where the
  light leaves and by the class of link carrying it;
- by link class, uniform unit radiance on every exposed surface: each class's modelled exchange (the
  operator with that class's links only, both directions) over its exact exchange (2 sum A_a F_ab by
  dense point sampling, far_vis_check.dense_visibility: --points x --points random points an end,
  covered points and back-facing pairs out, with visibility), for patch links (per link, binned by
  geometry) and far links (binned, one operator per bin);
- the push-pull: a node's children's areas against its own, and what uniform radiance gathers.
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

from far_vis_check import BASE, balance, dense_visibility  # noqa: E402

from hr_addon.core.cluster import Ends, decode, estimate  # noqa: E402
from hr_addon.core.farlinks import FarLinks  # noqa: E402
from hr_addon.core.links import Links  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_addon.core.solver import Operator  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402


def far_subset(far, m):
    return FarLinks(
        far.tree,
        far.a[m],
        far.b[m],
        far.vis[m],
        far.mask[m],
        far.part_a[m],
        far.part_b[m],
        far.eps,
        far.grad_eps,
        far.scale[m],
    )


def received(s, links, B):
    """(C,) power received at the leaves (A x exposure x G) from one gather + push of B (leaves set,
    pulled here) over `links`."""
    op = Operator(s.h, links)
    Bp = op.pull(B.copy())
    G = op.push(op.gather(Bp))
    lf = op.leaves
    ex = np.ones(op.n) if op.expo is None else op.expo
    return (op.area[lf] * ex[lf] * G[:, lf]).sum(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--room", default="20k")
    ap.add_argument("--points", type=int, default=16)
    ap.add_argument("--shadow-feps", type=float, default=BASE.shadow_feps)
    ap.add_argument("--json", default=None)
    ap.add_argument("--all-links", action="store_true", help="keep the links traced wholly occluded too")
    args = ap.parse_args()
    if args.all_links:  # links traced wholly occluded kept (no transfer): their exact exchange
        import hr_addon.core.farlinks as FL
        import hr_addon.core.refine as RF

        FL.KEEP_OCCLUDED = RF.KEEP_OCCLUDED = True
    mesh, _ = furnished_room(args.room)
    out = {
        "room": args.room,
        "points": args.points,
        "shadow_feps": args.shadow_feps,
        "all_links": args.all_links,
    }
    t0 = time.process_time()
    s = RadiositySystem(mesh, dataclasses.replace(BASE, shadow_feps=args.shadow_feps))
    out["build_cpu_s"] = time.process_time() - t0
    h, L = s.h, s.links
    far = L.far
    out["balance"] = balance(s).tolist()
    B = s.B.copy()
    print("balance", np.round(out["balance"], 4), "links", len(L.a), "far", len(far), flush=True)
    op = s.operator()
    lf, A = op.leaves, op.area
    ex = np.ones(op.n) if op.expo is None else op.expo.astype(float)
    patch_only = Links(L.a, L.b, L.f_ab, L.f_ba, L.vis, L.corr, None)
    far_only = Links(*(np.zeros(0, dt) for dt in (np.int64, np.int64, float, float, float)), far=far)
    # -- push-pull: children's areas against the parent's
    inner = np.flatnonzero(op.child0 >= 0)
    kids = op.child0[inner][:, None] + np.arange(4)
    rel = A[kids].sum(1) / A[inner] - 1
    out["pull_area_rel_max"] = float(np.abs(rel).max())
    ex_rel = (A[kids] * ex[kids]).sum(1) / (A[inner] * ex[inner]).clip(1e-300) - 1
    out["pull_exposed_area_rel_max"] = float(np.abs(ex_rel[ex[inner] > 0]).max())
    print(
        "push-pull: children's area / parent's - 1, max",
        out["pull_area_rel_max"],
        "exposed",
        out["pull_exposed_area_rel_max"],
    )
    # -- by source group, the solved B
    names = list(s.patches.object_names)
    oid = np.asarray(s.patches.object_id)[h.patch[lf]]
    nm = np.array(names)[oid]
    group = np.full(len(lf), "furniture", object)
    for g in ("ceiling_light", "ceiling", "wall", "floor"):
        group[np.char.startswith(nm.astype(str), g) & (group == "furniture")] = g
    out["source"] = {}
    Bl = np.zeros_like(B)
    for g in ("all", "ceiling_light", "ceiling", "wall", "floor", "furniture"):
        sel = np.ones(len(lf), bool) if g == "all" else group == g
        Bg = np.zeros_like(B)
        Bg[:, lf[sel]] = B[:, lf[sel]]
        sent = (A[lf] * Bg[:, lf]).sum(1)
        r = {
            k: (received(s, lk, Bg) / sent).tolist()
            for k, lk in (("all", L), ("patch", patch_only), ("far", far_only))
        }
        r["sent_share"] = float(sent[0] / (A[lf] * B[0, lf]).sum())
        out["source"][g] = r
        print(
            f"source {g}: share {r['sent_share']:.3f}, received/sent all {r['all'][0]:.4f}, "
            f"patch links {r['patch'][0]:.4f}, far {r['far'][0]:.4f}",
            flush=True,
        )
    del Bl
    # -- uniform unit radiance: per class, modelled against dense exact exchange
    U = np.zeros((1, op.n))
    U[0, lf] = ex[lf]
    Up = op.pull(U.copy())[0]
    t0 = time.process_time()

    class _P:
        def __init__(self, tree, a, b):
            self.tree, self.a, self.b = tree, a, b

        def __len__(self):
            return len(self.a)

    pl = _P(far.tree, L.a.astype(np.int64), L.b.astype(np.int64))
    _, vk_p, ex_p = dense_visibility(s, pl, args.points)
    exact_p = 2 * vk_p * ex_p
    model_p = L.vis * Up[L.a] * Up[L.b] * (L.f_ab * A[L.a] + L.f_ba * A[L.b])
    _, vk_f, ex_f = dense_visibility(s, far, args.points, seed=2)
    exact_f = 2 * vk_f * ex_f
    out["dense_cpu_s"] = time.process_time() - t0
    tot_exact = exact_p.sum() + exact_f.sum()
    total_U = (A[lf] * U[0, lf]).sum()
    out["uniform_sent"] = float(total_U)
    out["uniform_received_all"] = float(received(s, L, U)[0])
    out["uniform_received_patch_op"] = float(received(s, patch_only, U)[0])
    out["uniform_received_far_op"] = float(received(s, far_only, U)[0])
    out["patch_model_direct"] = float(model_p.sum())
    out["patch_exact"] = float(exact_p.sum())
    out["far_exact"] = float(exact_f.sum())
    print(
        f"uniform: sent {total_U:.4f}, received all {out['uniform_received_all']:.4f} "
        f"(patch {out['uniform_received_patch_op']:.4f} (direct {model_p.sum():.4f}), "
        f"far {out['uniform_received_far_op']:.4f}); "
        f"exact patch {exact_p.sum():.4f}, far {exact_f.sum():.4f}, sum {tot_exact:.4f}",
        flush=True,
    )
    # patch links binned by geometry (per link)
    dist = np.linalg.norm(h.centre[L.a] - h.centre[L.b], axis=1)
    size = (np.sqrt(A[L.a]) + np.sqrt(A[L.b])) / np.maximum(dist, 1e-9)
    cos_ab = np.abs(np.einsum("ij,ij->i", h.normal[L.a], h.normal[L.b]))
    cov = (Up[L.a] < 0.999) | (Up[L.b] < 0.999)
    pbins = {
        "all": np.ones(len(L.a), bool),
        "vis1": L.vis >= 1,
        "vis_part": (L.vis > 0) & (L.vis < 1),
        "traced0": L.vis <= 0,
        "near(size>1)": size > 1,
        "mid(0.3-1)": (size > 0.3) & (size <= 1),
        "far(<0.3)": size <= 0.3,
        "perpendicular": cos_ab < 0.1,
        "contact_ends": cov,
        "no_contact": ~cov,
    }
    out["patch_bins"] = {}
    for k, m in pbins.items():
        r = dict(
            n=int(m.sum()),
            exact_share=float(exact_p[m].sum() / tot_exact),
            model_over_exact=float(model_p[m].sum() / max(exact_p[m].sum(), 1e-300)),
            deficit_share=float((exact_p[m].sum() - model_p[m].sum()) / tot_exact),
        )
        out["patch_bins"][k] = r
        print(f"patch {k}: {r}", flush=True)
    # far links binned: one operator per bin
    ea, eb = Ends(far.tree, h, far.a), Ends(far.tree, h, far.b)
    f_ab, f_ba, fd = estimate(ea, eb, both=True)
    strong = np.maximum(f_ab, f_ba) >= args.shadow_feps
    fsize = (ea.radius + eb.radius) / np.maximum(fd, 1e-9)
    lv = ((far.mask[:, None] >> np.arange(16)) & 1).mean(1) * far.scale
    both_cl = (far.a < 0) & (far.b < 0)
    part = far.part_a | far.part_b
    # ends with covered parts: a node end below full exposure, or a cluster with a covered member
    K = far.tree.K
    pe = Up[:K]  # patch roots' exposed fraction
    pcov = np.zeros(len(far.tree.area), bool)
    cum = np.r_[0, np.cumsum(pe[far.tree.perm] < 0.999)]
    pcov = cum[far.tree.end] - cum[far.tree.start] > 0

    def covered_end(ids):
        return np.where(ids < 0, pcov[decode(np.minimum(ids, -1))], Up[np.maximum(ids, 0)] < 0.999)

    fcov = covered_end(far.a) | covered_end(far.b)
    big = np.maximum(ea.area, eb.area)
    fbins = {
        "all": np.ones(len(far), bool),
        "strong": strong,
        "weak": ~strong,
        "clcl": both_cl,
        "nodecl": ~both_cl,
        "partial": part,
        "facing": ~part,
        "size<0.1": fsize < 0.1,
        "size0.1-0.2": (fsize >= 0.1) & (fsize < 0.2),
        "size>=0.2": fsize >= 0.2,
        "vis1": lv >= 1,
        "vis_part": (lv > 0) & (lv < 1),
        "traced0": lv <= 0,
        "contact_ends": fcov,
        "no_contact": ~fcov,
        "big_end>1m2": big > 1,
        "big_end<=1m2": big <= 1,
    }
    out["far_bins"] = {}
    for k, m in fbins.items():
        if not m.any():
            continue
        lk = Links(
            *(np.zeros(0, dt) for dt in (np.int64, np.int64, float, float, float)), far=far_subset(far, m)
        )
        mod = float(received(s, lk, U)[0])
        r = dict(
            n=int(m.sum()),
            exact_share=float(exact_f[m].sum() / tot_exact),
            model_over_exact=mod / max(float(exact_f[m].sum()), 1e-300),
            deficit_share=float((exact_f[m].sum() - mod) / tot_exact),
        )
        out["far_bins"][k] = r
        print(f"far {k}: {r}", flush=True)
    print(json.dumps({k: v for k, v in out.items() if not isinstance(v, dict)}, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
