"""Issue 19 (branch cl29, docs/gather.md): which part of a far link's visibility carries the draft
transport's remaining loss, bpy-free, on the furnished room (hr_testing.furnished).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/far_vis_check.py \
        [--room 2k] [--points 16] [--json benchmarks/out/far_vis_check_2k.json]

The room is built on RefineParams.for_gather("draft") with orient on (shadow_feps 0.03, the preset)
and solved; its balance is tests/test_core_engine.py's absorbed over emitted. Then every far link's
visibility is replaced by a dense estimate and the room solved again with the same links:
- dense_area: the fraction of unoccluded segments among front-facing pairs of --points x --points
  random points on the two ends (members by area, stratified; points on covered parts left out),
  what the link's 4 (weak) or 16 segments estimate (--centroid: at the members' centroids);
- dense_kernel: the same segments weighted by their kernel cos cos / (pi r^2): the visibility that
  gives the link's exact exchange between uniformly bright ends (sum V k / sum k).
By class of link (the traced value: wholly visible, partly, traced 0 (with --all-links); strong
(above shadow_feps, 16 segments) or weak; two clusters or a node and a cluster) the traced and
dense means, also weighted by each link's unoccluded exchange (A_a A_b x the kernel's mean): only
classes not chosen by the traced value (all links, strong, weak) measure the estimator's bias
(branch far30). --all-links keeps the links traced wholly occluded (farlinks.KEEP_OCCLUDED),
--one-trace turns farlinks.SECOND_TRACE off, --shadow-feps builds the room at another split,
--no-fine skips the room split finer.
The gap between dense_kernel and the preset split finer (shadow_feps 0.003) is what one visibility
for all members cannot give (which members see each other and which carry the light) plus the
partial ends' SH kernel; the gap between the preset and dense_area is its 4-sample estimate.
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

from hr_addon.core.cluster import Ends, decode, estimate  # noqa: E402
from hr_addon.core.farlinks import FarLinks  # noqa: E402
from hr_addon.core.params import RefineParams  # noqa: E402
from hr_addon.core.radiosity import RadiositySystem  # noqa: E402
from hr_testing.furnished import furnished_room  # noqa: E402

BASE = dataclasses.replace(RefineParams.for_gather("draft"), orient=True)


def balance(s):
    """tests/test_core_engine.py's _absorbed_over_emitted."""
    B = s.solve(warm=False)
    lf = s.h.leaves()
    E = s.base_emission()[:, lf] * s.h.exposure[lf]
    a, rho = s.h.area[lf], s.patches.reflectance[:, s.h.patch[lf]]
    return (a * (1 - rho) * (B[:, lf] - E) / rho).sum(1) / (a * E).sum(1)


def _in_polygon(c, nv, u, v):
    """Points in nodes' polygons (corners c (N, 4, 3), nv (N,)) at unit-square (u, v): bilinear on
    quads, folded barycentric on triangles."""
    q = (
        (1 - u)[..., None] * (1 - v)[..., None] * c[:, None, 0]
        + u[..., None] * (1 - v)[..., None] * c[:, None, 1]
        + u[..., None] * v[..., None] * c[:, None, 2]
        + (1 - u)[..., None] * v[..., None] * c[:, None, 3]
    )
    f = u + v > 1
    tu, tv = np.where(f, 1 - u, u), np.where(f, 1 - v, v)
    t = (
        c[:, None, 0]
        + tu[..., None] * (c[:, None, 1] - c[:, None, 0])
        + tv[..., None] * (c[:, None, 2] - c[:, None, 0])
    )
    return np.where((nv == 4)[:, None, None], q, t)


def end_points(s, tree, ids, M, rng):
    """(N, M, 3) random points on link ends (stratified by area over a cluster's members; uniform
    in a patch node) pushed eps off, their normals, and (N, M) whether each is covered."""
    h = s.h
    N = len(ids)
    node = np.where(ids >= 0, ids, 0)
    cl = ids < 0
    if cl.any():
        ws = h.area[tree.perm]
        cum = np.cumsum(ws)
        c = decode(ids[cl])
        lo = cum[tree.start[c]] - ws[tree.start[c]]
        tot = cum[tree.end[c] - 1] - lo
        tgt = lo[:, None] + (np.arange(M) + rng.random((len(c), M))) / M * tot[:, None]
        pos = np.clip(np.searchsorted(cum, tgt), tree.start[c][:, None], tree.end[c][:, None] - 1)
        mem = np.repeat(node[:, None], M, 1)
        mem[cl] = tree.perm[pos]
    else:
        mem = np.repeat(node[:, None], M, 1)
    u, v = rng.random((N, M)), rng.random((N, M))
    if os.environ.get("FAR_VIS_CENTROID"):
        u, v = np.full((N, M), 0.5), np.full((N, M), 0.5)
    flat = mem.ravel()
    p = _in_polygon(h.corners[flat], h.nv[flat], u.ravel()[:, None], v.ravel()[:, None])[:, 0].reshape(
        N, M, 3
    )
    n = h.normal[mem]
    cov = np.zeros((N, M), bool)
    if h.contacts is not None:  # points on covered parts (contacts) are no part of the end
        cov = h.contacts.covered(p.reshape(-1, 3), h.patch[flat]).reshape(N, M)
    return p + s.refiner.eps * n, n, cov


def dense_visibility(s, far, M, seed=1, chunk=1000):
    """(area, kernel) dense visibilities of every far link (see the module's doc) and (exch) each
    link's unoccluded exchange A_a A_b x the mean of its front-facing, uncovered segments' kernel
    (the weight of its visibility in the room's energy)."""
    rng = np.random.default_rng(seed)
    va, vk, ex = np.ones(len(far)), np.ones(len(far)), np.zeros(len(far))
    area = lambda ids: np.where(
        ids < 0, far.tree.area[decode(np.minimum(ids, -1))], s.h.area[np.maximum(ids, 0)]
    )
    for i in range(0, len(far), chunk):
        sl = slice(i, i + chunk)
        pa, na, ca_ = end_points(s, far.tree, far.a[sl], M, rng)
        pb, nb, cb_ = end_points(s, far.tree, far.b[sl], M, rng)
        d = pb[:, None] - pa[:, :, None]
        ca = np.einsum("nijk,nik->nij", d, na)
        cb = -np.einsum("nijk,njk->nij", d, nb)
        r2 = np.einsum("nijk,nijk->nij", d, d)
        front = (ca > 0) & (cb > 0) & ~ca_[:, :, None] & ~cb_[:, None, :]
        k = np.where(front, ca * cb / (np.pi * r2 * r2), 0.0)
        occ = np.zeros(front.shape, bool)
        ii = np.nonzero(front)
        occ[ii] = s.backend.occluded(pa[ii[0], ii[1]], pb[ii[0], ii[2]])
        vis = front & ~occ
        nf = front.sum((1, 2))
        K = k.sum((1, 2))
        va[sl] = np.where(nf > 0, vis.sum((1, 2)) / np.maximum(nf, 1), 1.0)
        vk[sl] = np.where(K > 0, (k * vis).sum((1, 2)) / np.where(K > 0, K, 1), 1.0)
        ex[sl] = area(far.a[sl]) * area(far.b[sl]) * K / M**2
    return va, vk, ex


def with_visibility(far, v):
    """far's links with one visibility v each (full mask, scale v)."""
    return FarLinks(
        far.tree,
        far.a,
        far.b,
        v,
        np.full(len(far), 0xFFFF, np.uint16),
        far.part_a,
        far.part_b,
        far.eps,
        far.grad_eps,
        v,
    )


def link_vis(far):
    """Each far link's own visibility as the solver uses it (kernel-free: mask fraction x scale)."""
    bits = ((far.mask[:, None] >> np.arange(16)) & 1).mean(1)
    return bits * far.scale


def _keep_occluded():
    """--all-links: link_clusters keeps the far links it traced wholly occluded (farlinks.KEEP_OCCLUDED:
    no transfer, their mask or scale 0), so the traced visibilities of every far link can be set
    against dense ones (the selection by the traced value left out) and the dense solves include
    them; the preset's own solve is the same as without them."""
    import hr_addon.core.farlinks as FL

    FL.KEEP_OCCLUDED = True


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--room", default="2k")
    ap.add_argument("--points", type=int, default=16)
    ap.add_argument("--shadow-feps", type=float, default=BASE.shadow_feps, help="the room's (the preset's)")
    ap.add_argument("--fine", type=float, default=0.003, help="the shadow_feps split finer")
    ap.add_argument("--json", default=None)
    ap.add_argument("--all-links", action="store_true", help="keep the links traced wholly occluded too")
    ap.add_argument("--one-trace", action="store_true", help="farlinks.SECOND_TRACE off")
    ap.add_argument("--no-fine", action="store_true", help="skip the room split finer")
    ap.add_argument("--centroid", action="store_true", help="dense points at the members' centroids")
    args = ap.parse_args()
    if args.centroid:
        os.environ["FAR_VIS_CENTROID"] = "1"
    if args.all_links:
        _keep_occluded()
    if args.one_trace:
        import hr_addon.core.farlinks as FL

        FL.SECOND_TRACE = False
    mesh, _ = furnished_room(args.room)
    out = {
        "room": args.room,
        "points": args.points,
        "all_links": args.all_links,
        "shadow_feps": args.shadow_feps,
    }
    t0 = time.process_time()
    s = RadiositySystem(mesh, dataclasses.replace(BASE, shadow_feps=args.shadow_feps))
    out["build_cpu_s"] = time.process_time() - t0
    far = s.links.far
    out["links"], out["far_links"] = len(s.links), len(far)
    out["preset"] = balance(s).tolist()
    print("preset", np.round(out["preset"], 4), "far links", len(far), flush=True)
    t0 = time.process_time()
    va, vk, ex = dense_visibility(s, far, args.points)
    out["dense_cpu_s"] = time.process_time() - t0
    lv = link_vis(far)
    part = (lv < 1) | (va < 1)
    out["partial_links"] = int(part.sum())
    # the links' visibility against the dense ones, weighted by an unoccluded size (area product / r^2)
    for name, v in (("link", lv), ("dense_area", va), ("dense_kernel", vk)):
        out[f"mean_vis_{name}"] = float(v.mean())
    for name, v in (("dense_area", va), ("dense_kernel", vk)):
        links = s.links
        s.links = type(links)(
            links.a, links.b, links.f_ab, links.f_ba, links.vis, links.corr, with_visibility(far, v)
        )
        s._op, s.B = None, None
        out[name] = balance(s).tolist()
        s.links = links
        s._op, s.B = None, None
        print(name, np.round(out[name], 4), flush=True)
    # the kept links by their traced visibility: wholly visible (1) or partly, and by their ends'
    # kinds (two clusters, or a patch node and a cluster): traced against dense means
    both_cl = (far.a < 0) & (far.b < 0)
    f_ab, f_ba, _ = estimate(Ends(far.tree, s.h, far.a), Ends(far.tree, s.h, far.b), both=True)
    strong = np.maximum(f_ab, f_ba) >= args.shadow_feps  # traced with 16 segments (weak: 4)
    classes = [("whole", lv >= 1), ("part", (lv > 0) & (lv < 1)), ("zero", lv <= 0), ("all", lv >= 0)]
    for name, sel in classes:
        for kind, k in (
            ("", True),
            ("_clcl", both_cl),
            ("_nodecl", ~both_cl),
            ("_strong", strong),
            ("_weak", ~strong),
        ):
            m = sel & k
            out[f"{name}{kind}_n"] = int(m.sum())
            if not m.any():
                continue
            for vn, v in (("link", lv), ("dense_area", va), ("dense_kernel", vk)):
                out[f"{name}{kind}_mean_{vn}"] = float(v[m].mean())
                # weighted by the unoccluded exchange: the visibility as the room's energy reads it
                out[f"{name}{kind}_wmean_{vn}"] = float((v * ex)[m].sum() / max(ex[m].sum(), 1e-300))
            out[f"{name}{kind}_exchange_share"] = float(ex[m].sum() / ex.sum())
        if not sel.any():
            continue
        g = lambda k: out[f"{name}_{k}"]  # noqa: E731
        print(
            f"{name}: n {g('n')}, traced {g('mean_link'):.4f}, dense area {g('mean_dense_area'):.4f}, "
            f"kernel {g('mean_dense_kernel'):.4f}; by exchange ({g('exchange_share'):.3f} of it) "
            f"traced {g('wmean_link'):.4f}, dense kernel {g('wmean_dense_kernel'):.4f}",
            flush=True,
        )
    # where they differ: links whose area and kernel visibilities differ, and by partial ends
    pe = far.part_a | far.part_b
    for name, sel in (("partial_ends", pe), ("facing_ends", ~pe)):
        out[f"{name}_n"] = int(sel.sum())
        out[f"{name}_mean_link_minus_area"] = float((lv - va)[sel].mean())
        out[f"{name}_mean_area_minus_kernel"] = float((va - vk)[sel].mean())
    del s
    if args.no_fine:
        print(json.dumps(out, indent=1))
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
        return
    t0 = time.process_time()
    s2 = RadiositySystem(mesh, dataclasses.replace(BASE, shadow_feps=args.fine))
    out["fine_build_cpu_s"] = time.process_time() - t0
    out["fine_links"] = len(s2.links)
    out["fine"] = balance(s2).tolist()
    print(f"shadow_feps {args.fine}", np.round(out["fine"], 4), flush=True)
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
