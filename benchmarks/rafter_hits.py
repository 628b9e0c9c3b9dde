"""What the loft's Rafter 0 gathers (issue 19, docs/accuracy.md, session 38, branch loftdx38): the
draft vertex bake of frame 1 run with a hook on the top gather's evaluation that, for the samples on
one object, keeps its terms (direct D, the rays' read of the leaf values, the hot leaves' explicit
bounce) and re-traces `rays` cosine rays per sample itself, each hit read three ways:
  Y: the leaf value the top level's rays read (the second level's leaf means, hot bounce included),
  V: the transport's own leaf value (solution_values: one level's read),
  X: a fresh one-level gather at the hit point itself (its exact direct light + its rays over V),
     on a random subset of the hits (`sub`);
with the hit's object, leaf, distance. Then the bake stops (nothing saved).

    nice -n 19 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/rafter_hits.py \
        /work/cache/.../loft.blend OUT.npz [object=Rafter 0] [rays=512] [sub=40000]
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))


def analyse(g, dyn, name, rays, sub, out):
    from hr_addon.core.gather import FinalGather, cosine_directions
    from hr_addon.core.gather.points import locate_below

    s = g.system
    h, pt = s.h, s.patches
    names = np.array(pt.object_names)
    obj = pt.object_id
    R = np.flatnonzero(names[obj[g.patch]] == name)
    print(f"rafter_hits: {len(R)} samples on {name!r}, {g.dark[R].sum()} covered", flush=True)
    L = g._leaf_levels(dyn)
    Yall = np.array(L[0])
    Y = Yall.copy()
    own = sum(g._light_bounce(rec, Y, rec.scale[None]) for rec in dyn.lights.values())
    own = np.zeros((g.n, 3)) + own
    I_read = g._read((Y,) + tuple(L[1:]))
    D, E = g.direct_and_emission(dyn)
    V = g.solution_values(dyn)
    hot = np.zeros(0, np.int64)
    for rec in dyn.lights.values():
        got = g._bounce_leaves(rec)
        if got is not None:
            hot = np.r_[hot, got[0]]
    # re-trace
    d = cosine_directions(g.normals[R], g.keys[R], rays, 4242, stream=0).reshape(-1, 3)
    org = g._origins(R)
    row = np.repeat(np.arange(len(R)), rays)
    prim, t = g.first_hit(org, d, np.full(len(R), rays))
    ok = prim >= 0
    patch = np.where(ok, g.tri_patch[np.maximum(prim, 0)], 0)
    ok &= np.einsum("ij,ij->i", d, pt.normal[patch]) < 0
    i = np.flatnonzero(ok)
    hit = org[row[i]] + d[i] * t[i, None]
    leaf = locate_below(h, patch[i], hit, g.n_hr, g._lines())
    dark = h.dark(leaf, hit, boxes=g._leaf_boxes())
    # X at a subset of the uncovered hits
    rng = np.random.default_rng(1)
    lit = np.flatnonzero(~dark)
    xs = np.sort(rng.choice(lit, min(sub, len(lit)), replace=False))
    gx = FinalGather(
        dyn, hit[xs], pt.normal[patch[i][xs]], patch[i][xs], rays=128, shadow_rays=16, levels=1, seed=7
    )
    Dx = gx.direct_and_emission(dyn)[0]
    Xr = gx.evaluate(dyn, "reflected")
    # the second level's samples on the leaves hit (their points, covered flags, final values: the rows
    # n_hr + sample of the leaf values a near hit reads)
    used, start = g._second_map[0], g._second_start
    k = np.searchsorted(used, np.unique(leaf))
    k = k[(k < len(used)) & (used[np.minimum(k, len(used) - 1)] == np.unique(leaf))]
    j = np.concatenate([np.arange(start[q], start[q + 1]) for q in k] + [[]]).astype(np.int64)
    y2 = Yall[g.n_hr + j] if len(Yall) > g.n_hr else np.zeros((len(j), 3))
    np.savez_compressed(
        out,
        s2=j, s2_leaf=np.repeat(used[k], start[k + 1] - start[k]), s2_points=g.second.points[j],
        s2_dark=g.second.dark[j], s2_y=y2, s2_w=g._second_map[1][j],
        R=R, points=g.points[R], normals=g.normals[R], dark=g.dark[R], rho=g.rho[R],
        D=D[R], own=own[R], I_read=I_read[R], E=E[R],
        row=row[i].astype(np.int32), hit=hit.astype(np.float32), t=t[i].astype(np.float32),
        hit_patch=patch[i].astype(np.int32), hit_obj=obj[patch[i]].astype(np.int32),
        leaf=leaf.astype(np.int32),
        hit_dark=dark, Yv=Yall[leaf].astype(np.float32), Vv=V[leaf].astype(np.float32),
        xs=xs.astype(np.int32), Xr=Xr.astype(np.float32), Dx=(gx.rho * Dx).astype(np.float32),
        hot=hot, names=names, rays=rays, leaf_area=h.area[leaf].astype(np.float32),
        leaf_ex=h.exposure[leaf].astype(np.float32),
    )  # fmt: skip
    print(f"rafter_hits: written {out}", flush=True)


def main():
    src, out = sys.argv[1], sys.argv[2]
    opt = dict(object="Rafter 0", rays="512", sub="40000")
    opt.update(a.split("=", 1) for a in sys.argv[3:])
    from hr_addon.core.gather.layouts import LoopGather

    def loop_radiance(self, dyn, *a, **k):  # the bake's output: analysed, then the process ends
        analyse(self, dyn, opt["object"], int(opt["rays"]), int(opt["sub"]), out)
        os._exit(0)

    LoopGather.loop_radiance = loop_radiance
    from hr_addon.__main__ import main as hr_main

    argv = ["bake", src, "--frames", "1-1", "--quality", "draft", "--output", "vertex", "--threads", "1"]
    sys.exit(hr_main(argv))


if __name__ == "__main__":
    main()
