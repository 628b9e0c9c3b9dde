"""Issue 19, measure only: how many of a light shape's shadow rays a conservative group test could
skip. The FE window-add event's shape light at each gather level (`DirectLight._shape`, as
direct_cuts.py) with `DirectLight._rays` and `ClearShafts.clear` wrapped: per sample its rays and
how many got through; the shares of samples / rays all unoccluded, all occluded, mixed; the same by
group (the top level's transport leaf `leaf0` and patch, the second level's leaf); and for a
sample of the all-unoccluded groups how many scene triangles' boxes meet the box of the group's
points and the shape's polygon, how many of them meet boxes swept from the group to the shape, and
whether an exact hull test (`separated`) clears the group; and the existing ClearShafts grid applied
per group (the cheap conservative form).

    .venv/bin/python benchmarks/cull_groups.py STORE [--window 0.7] [--boxes 400] [--json out.json]
"""

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def shares(tot, got):
    """{all_clear, all_occluded, mixed} shares of the items (tot rays, got unoccluded) and of rays."""
    t = tot > 0
    tot, got = tot[t], got[t]
    kinds = dict(all_clear=got == tot, all_occluded=got == 0, mixed=(got > 0) & (got < tot))
    n, r = len(tot), tot.sum()
    return dict(
        items=int(n),
        rays=int(r),
        **{f"{k}_items": round(float(m.sum() / max(n, 1)), 4) for k, m in kinds.items()},
        **{f"{k}_rays": round(float(tot[m].sum() / max(r, 1)), 4) for k, m in kinds.items()},
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument("--window", type=float, default=0.7)
    ap.add_argument("--boxes", type=int, default=400, help="all-clear groups sampled for the box counts")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from bench_gather_events import load_store
    from hr_addon.core import planes
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.core.gather.direct import DirectLight
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    s, g, _ = load_store(Path(args.store) / pc.FILENAME)
    s.links.extended(s.h)
    _, info = furnished_room("100k")
    _, frame = info["light_wall"]
    rect = S.on_plane(S.rect(0.9, 0.7, centre=(args.window, 0.6), angle=0.2), frame)
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    dyn.add("w", LightShape(rect, np.full(3, 20.0), "window"))
    rec = dyn.shapes["w"]

    log = {"rays": [], "clear": [0, 0]}
    rays0, clear0 = DirectLight._rays, planes.ClearShafts.clear

    def rays(self, em, xo, no, u, area):
        kern, vis = rays0(self, em, xo, no, u, area)
        log["rays"].append((xo.copy(), vis.shape[1], vis.sum(1)))
        return kern, vis

    def clear(self, o, elo, ehi):
        ok = clear0(self, o, elo, ehi)
        log["clear"][0] += len(o)
        log["clear"][1] += int(ok.sum())
        log.setdefault("clear_pts", []).append(o[ok].copy())
        return ok

    DirectLight._rays, planes.ClearShafts.clear = rays, clear
    out = dict(store=args.store, window=args.window)
    em = None
    levels = [("top", g), ("second", g.second)]
    for name, lv in levels:
        log["rays"], log["clear"], log["clear_pts"] = [], [0, 0], []
        lv._shape_cache.clear()
        D = lv._shape(dyn, rec)[0]
        if em is None:
            em = rec.emitter[1]
        # each traced sample's index on the level (by its point's bytes; duplicates: the first)
        key = np.ascontiguousarray(lv.points).view(np.dtype((np.void, 24))).ravel()
        order = np.argsort(key, kind="stable")
        skey = key[order]

        def index(x):
            k = np.ascontiguousarray(x).view(np.dtype((np.void, 24))).ravel()
            j = np.searchsorted(skey, k)
            assert (skey[np.minimum(j, len(skey) - 1)] == k).all()
            return order[j]

        tot, got = np.zeros(lv.n, np.int64), np.zeros(lv.n, np.int64)
        for xo, S_, ok in log["rays"]:
            i = index(xo)
            np.add.at(tot, i, S_)
            np.add.at(got, i, ok)
        dup = lv.n - len(np.unique(key))
        traced = tot > 0
        lit_nr = (D > 0) & ~traced  # lit without rays: the clear shafts
        per = shares(tot, got)
        row = dict(
            n=int(lv.n),
            lit=int((D > 0).sum()),
            traced_samples=int(traced.sum()),
            shadow_rays=int(lv.shadow_rays),
            rays_per_traced=round(float(tot[traced].mean()), 2),
            shaft_tested=log["clear"][0],
            shaft_clear=log["clear"][1],
            lit_without_rays=int(lit_nr.sum()),
            duplicate_points=int(dup),
            per_sample=per,
        )
        # groups: the samples a group test would take together (the shaft-clear ones count as clear
        # samples of no rays: a group of them and traced clear samples is all clear)
        if name == "top":
            groups = dict(leaf=lv.leaf0, patch=lv.patch)
        else:
            used, k2 = lv._leaf_nodes
            groups = dict(leaf=np.repeat(np.arange(len(used)), k2))
        cand = traced | lit_nr
        for gname, gid in groups.items():
            ids, inv = np.unique(gid[cand], return_inverse=True)
            gt = np.bincount(inv, tot[cand], len(ids)).astype(np.int64)
            gg = np.bincount(inv, got[cand], len(ids)).astype(np.int64)
            gs = np.bincount(inv, minlength=len(ids))
            # a group of only shaft-clear samples: no rays to skip (already skipped)
            gr = shares(gt, gg)
            gr["samples_per_group"] = round(float(gs[gt > 0].mean()), 2)
            gr["groups_all_clear_by_shafts_only"] = int((gt == 0).sum())
            clear_g = np.flatnonzero((gt > 0) & (gg == gt))
            gr["skippable_rays_share_of_level"] = round(float(gt[clear_g].sum() / max(tot.sum(), 1)), 4)
            gr["clear_shafts"] = shaft_groups(s, lv, em, gid, traced, tot, got, clear0)
            gr["boxes"] = boxes(s, lv, em, ids[clear_g], gid, cand, args.boxes, gt[clear_g])
            row[f"by_{gname}"] = gr
        out[name] = row
        print(name, json.dumps(row, indent=1), flush=True)
    DirectLight._rays, planes.ClearShafts.clear = rays0, clear0
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


def shaft_groups(s, lv, em, gid, traced, tot, got, clear0):
    """The conservative test the code has (planes.ClearShafts: swept boxes against a grid of the
    triangles' boxes), per traced sample and per group (the box of its traced samples' ray origins
    swept to the emitter's box): the shares of the level's traced rays they would skip."""
    import time

    from hr_addon.core.events.direct import clear_shafts

    sh = clear_shafts(s, em.point, em.normal)
    eps = lv.eps
    e = eps * em.normal
    elo, ehi = em.lo + e, em.hi + e
    i = np.flatnonzero(traced)
    o = lv.points[i] + eps * lv.normals[i]
    c0 = time.process_time()
    ok = clear0(sh, o, elo, ehi)
    per_cpu = time.process_time() - c0
    assert (got[i][ok] == tot[i][ok]).all()  # conservative: a clear shaft's rays all got through
    ids, inv = np.unique(gid[i], return_inverse=True)
    glo = np.full((len(ids), 3), np.inf)
    ghi = np.full((len(ids), 3), -np.inf)
    np.minimum.at(glo, inv, o)
    np.maximum.at(ghi, inv, o)
    c0 = time.process_time()
    gok = np.zeros(len(ids), bool)
    if sh._empty((elo - sh.m)[None], (ehi + sh.m)[None])[0]:
        gok[:] = True
        for k in range(sh.STEPS):
            t0, t1 = k / sh.STEPS, (k + 1) / sh.STEPS
            j = np.flatnonzero(gok)
            lo = np.minimum((1 - t0) * glo[j] + t0 * elo, (1 - t1) * glo[j] + t1 * elo) - sh.m
            hi = np.maximum((1 - t0) * ghi[j] + t0 * ehi, (1 - t1) * ghi[j] + t1 * ehi) + sh.m
            gok[j] = sh._empty(lo, hi)
    grp_cpu = time.process_time() - c0
    gt = np.bincount(inv, tot[i], len(ids))
    gg = np.bincount(inv, got[i], len(ids))
    assert (gg[gok] == gt[gok]).all()
    T = max(tot.sum(), 1)
    return dict(
        per_sample_rays=round(float(tot[i][ok].sum() / T), 4),
        per_sample_samples=int(ok.sum()),
        per_sample_cpu_s=round(per_cpu, 3),
        group_rays=round(float(gt[gok].sum() / T), 4),
        groups=int(gok.sum()),
        group_cpu_s=round(grp_cpu, 3),
    )


def separated(P, T, steps=3000):
    """(C,) True where a plane separates the convex hull of points P (k, 3) from triangle T[c]
    (C, 3, 3): Frank-Wolfe on the distance of the two hulls, a certificate at each step."""
    C = len(T)
    a = np.broadcast_to(P.mean(0), (C, 3)).copy()
    b = T.mean(1)
    sep = np.zeros(C, bool)
    for _ in range(steps):
        z = a - b  # from the triangle to the hull
        lo_p = (P @ z.T).min(0)  # (C,) the hull's nearest extent along z
        hi_t = np.einsum("cvk,ck->cv", T, z).max(1)
        sep |= lo_p > hi_t + 1e-12 * np.maximum(np.abs(lo_p), 1)
        if sep.all() or (np.einsum("ck,ck->c", z, z) < 1e-18).any():  # all apart, or one meets
            break
        sa = P[(P @ z.T).argmin(0)]
        sb = T[np.arange(C), np.einsum("cvk,ck->cv", T, z).argmax(1)]
        dd = (sa - sb) - z  # the step direction of z
        den = np.einsum("ck,ck->c", dd, dd)
        g = np.clip(-np.einsum("ck,ck->c", z, dd) / np.where(den > 0, den, 1), 0, 1)
        a += g[:, None] * (sa - a)
        b += g[:, None] * (sb - b)
    return sep


def boxes(s, lv, em, gids, gid, cand, k, gray):
    """For k of the all-clear groups (sampled with their rays' weight): how many scene triangles'
    boxes meet the box of (the group's points + the emitter's corners); also those not wholly
    behind the emitter's plane, and of those the ones not in the group's own plane."""
    if len(gids) == 0:
        return {}
    tri = s.patches.triangles.reshape(-1, 3, 3)
    tlo, thi = tri.min(1), tri.max(1)
    eps = lv.eps
    nrm, pnt = em.normal, em.point
    behind = ((tri - pnt) @ nrm <= eps).all(1)
    rng = np.random.default_rng(0)
    pick = rng.choice(len(gids), min(k, len(gids)), replace=False, p=gray / gray.sum())
    ec = np.concatenate([c[:k] for c, k in zip(em.corners, em.nv)])
    res = {
        "all": [],
        "front": [],
        "front_not_own_plane": [],
        "shaft8": [],
        "hull_clear": [],
        "samples": [],
        "box_diag": [],
    }
    elo, ehi = em.lo, em.hi
    for j in pick:
        m = np.flatnonzero(cand & (gid == gids[j]))
        pts = np.r_[lv.points[m], ec]
        lo, hi = pts.min(0) - eps, pts.max(0) + eps
        meet = (tlo <= hi).all(1) & (thi >= lo).all(1)
        front = meet & ~behind
        n0 = lv.normals[m[0]]
        own = (np.abs((tri - lv.points[m[0]]) @ n0) <= 10 * eps).all(1)
        res["all"].append(int(meet.sum()))
        res["front"].append(int(front.sum()))
        res["front_not_own_plane"].append(int((front & ~own).sum()))
        # ClearShafts' swept boxes (8 along the segments) from the group's box to the emitter's
        glo, ghi = lv.points[m].min(0), lv.points[m].max(0)
        sw = np.zeros(len(tri), bool)
        for t in range(8):
            t0, t1 = t / 8, (t + 1) / 8
            blo = np.minimum((1 - t0) * glo + t0 * elo, (1 - t1) * glo + t1 * elo) - eps
            bhi = np.maximum((1 - t0) * ghi + t0 * ehi, (1 - t1) * ghi + t1 * ehi) + eps
            sw |= (tlo <= bhi).all(1) & (thi >= blo).all(1)
        res["shaft8"].append(int((sw & ~behind & ~own).sum()))
        # exact: the hull of the rays' ends (origins eps along the normals, the emitter's corners
        # eps in front) against each candidate triangle (Frank-Wolfe on their distance, a
        # separating plane certifies it; undecided counts as meeting)
        c = np.flatnonzero(sw & ~behind & ~own)
        ends = np.r_[lv.points[m] + eps * lv.normals[m], ec + eps * nrm]
        sep = separated(ends, tri[c]) if len(c) else np.zeros(0, bool)
        res["hull_clear"].append(bool(sep.all()))
        res["samples"].append(len(m))
        res["box_diag"].append(float(np.linalg.norm(hi - lo)))
    q = lambda v: [float(np.percentile(v, p)) for p in (10, 50, 90)]  # noqa: E731
    return dict(
        groups=len(pick),
        triangles=int(len(tri)),
        meet_p10_50_90=q(res["all"]),
        front_p10_50_90=q(res["front"]),
        front_not_own_plane_p10_50_90=q(res["front_not_own_plane"]),
        shaft8_front_not_own_plane_p10_50_90=q(res["shaft8"]),
        hull_clear=round(float(np.mean(res["hull_clear"])), 4),
        zero_shaft8=round(float(np.mean(np.array(res["shaft8"]) == 0)), 4),
        zero_front_not_own_plane=round(float(np.mean(np.array(res["front_not_own_plane"]) == 0)), 4),
        samples_p50=float(np.median(res["samples"])),
        box_diag_p50=float(np.median(res["box_diag"])),
    )


if __name__ == "__main__":
    main()
