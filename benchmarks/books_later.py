"""Where the books' second and later bounces are lost (issue 19, docs/gather.md "The books' later
bounces"): case3's books against Cycles' books-only bakes at bounces 0 / 1 / 2 / 64
(books_bounces.py's cache, seed 1, 64 spp), one build, several gather variants in turn.

    .venv/bin/python benchmarks/books_later.py [--exact 32] [name='dict(...)' ...]

A variant is texel_gather keywords over the bake's draft gather with near hits (BASE), plus:
  _second: keywords for the second level's own FinalGather (e.g. dict(covered_samples="gather"));
  _iters: a list of iteration counts evaluated on the same precompute (the passes only).
--exact R: the second bounce with the second-level samples' first bounce read exactly: R cosine rays
per sample (of the leaves the texels' rays read), each reading rho x the exact direct light at its
hit (16 shadow rays), in place of the sample's gather of the leaves' first bounce. Per class: ours /
Cycles for the first bounce (b1 - b0), the second (b2 - b1), the rest (b64 - b2), all (b64), and
each class's part of the books' deficit in the second and later bounces (points of the books'
light). --pointwise R1,R2: the second bounce path-traced from the texels' samples outside the slots
(exact hit points, exact direct light at the second hit) and, by what the first ray hits, against
the gather's read there. The base variant also prints the case3 lit books' deficit by class and
bounce (the books the room run, benchmarks/out/furnished_vs_cycles_fgboth.json, finds below -5%)
and the slot texels by depth and by the mouth they gather at. Writes
benchmarks/out/books_later[NAME].json."""

import argparse
import json
import os
import time

import numpy as np

import books_common as BC
import cycles_compare as CC
from hr_testing import cycles_ref as C
from hr_addon.core.events import DynamicRadiosity
from hr_addon.core.gather import FinalGather, cosine_directions, texel_gather
from hr_addon.core.gather.points import locate_below, split_lines
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams

ap = argparse.ArgumentParser()
ap.add_argument("--exact", type=int, default=0)
ap.add_argument(
    "--pointwise", default="", help="R1,R2: the second bounce path-traced with exact direct light"
)
ap.add_argument("--name", default="")
ap.add_argument("variants", nargs="*")
opt = ap.parse_args()
BASE = {**BC.BASE, "near_points": 4}
VARIANTS = {"base": {}}
VARIANTS.update({k: eval(v) for k, v in (x.split("=", 1) for x in opt.variants)})
BOUNCES, SEED, SPP = (0, 1, 2, 64), 1, 64
CACHE = os.path.join(BC.HERE, "out", "books_bounces_cache")

cfg = CC.SCENES["furnished"]
rs = C.prepare(CC.open_scene("furnished"), texel_rel=cfg["texel_rel"])
books = [n for n in rs.objects if n.startswith("case3_book")]
key = CC._atlas_key(rs)
cyc = {}
for b in BOUNCES:
    z = np.load(os.path.join(CACHE, f"furnished_f1_{key}_case3_{len(books)}books_b{b}_s{SPP}_seed{SEED}.npz"))
    cyc[b] = {n: z[n].astype(np.float64) for n in books}
t0 = time.process_time()
s = RadiositySystem(rs.scene_in.mesh, RefineParams.preset("draft"))
dyn = DynamicRadiosity(s, method="FE")
dyn.apply(C.shape_proxies(rs, 1))
ours = C.Ours(rs, s, dyn)
print(f"build + frame 1: {time.process_time() - t0:.0f} s CPU", flush=True)
ref = {n: np.hstack([cyc[b][n] for b in BOUNCES]) for n in books}
X, P, AX, TR, REF, OBJ, CLS, ZREL = BC.book_texels(
    rs, s, ours, ref, books, BC.book_boxes(rs), 0.002, grey=False
)
REF = REF.reshape(len(REF), len(BOUNCES), 3).mean(2)
groups = BC.front_groups(X, OBJ, CLS) + [(BC.FACE[c], CLS == c) for c in (1, 2, 3, 4, 5, 6, 7, 9)]
groups = [(lab, m) for lab, m in groups if m.any() and REF[m, -1].sum() > 0]
TOT = REF[:, -1].sum()
print(f"{len(books)} books, {len(X)} texels", flush=True)

_init = FinalGather.__init__
SECOND = {}


def _patched(self, *a, **kw):
    if kw.get("open_edge") == 0.0:  # the second level's construction (final.py passes it so)
        kw.update(SECOND)
    _init(self, *a, **kw)


FinalGather.__init__ = _patched


def exact_first(g, R):
    """(g.second.n, 3) the second-level samples' first bounce (incident) read exactly: R cosine rays
    each reading rho x the exact direct light at its hit; only samples of leaves the top level's rays
    read (the others: nan)."""
    g2, pt = g.second, s.patches
    used, start = g._second_map[0], g._second_start
    gc = g.leaf_columns()
    read = np.unique(gc[gc < g.n_hr])
    near = np.unique(gc[gc >= g.n_hr] - g.n_hr)  # samples read directly
    li = np.flatnonzero(np.isin(used, read))
    idx = np.union1d(np.concatenate([np.arange(start[i], start[i + 1]) for i in li]), near)
    idx = idx[~g2.dark[idx]]
    dirs = cosine_directions(g2.normals[idx], g2.keys[idx], R, 4321, stream=0).reshape(-1, 3)
    row = np.repeat(np.arange(len(idx)), R)
    org = g2.origins[idx][row]
    prim, t = g2.first_hit(org, dirs)
    hp = np.where(prim >= 0, pt.triangle_patch[np.maximum(prim, 0)], 0)
    i = np.flatnonzero((prim >= 0) & (np.einsum("ij,ij->i", dirs, pt.normal[hp]) < 0))
    gh = FinalGather(
        dyn, org[i] + t[i, None] * dirs[i], pt.normal[hp[i]], hp[i], rays=1, shadow_rays=16, seed=7
    )
    hit = gh.rho * gh.direct_and_emission(dyn)[0]
    out = np.full((g2.n, 3), np.nan)
    out[idx] = np.stack([np.bincount(row[i], hit[:, c], len(idx)) for c in range(3)], 1) / R
    return out, len(idx)


def trace(g, org, nrm, keys, R, seed):
    """(row (m,), hit points (m, 3), patches (m,)) of R cosine rays from each origin (front-face
    hits only)."""
    pt = s.patches
    dirs = cosine_directions(nrm, keys, R, seed, stream=0).reshape(-1, 3)
    row = np.repeat(np.arange(len(org)), R)
    prim, t = g.first_hit(org[row], dirs)
    hp = np.where(prim >= 0, pt.triangle_patch[np.maximum(prim, 0)], 0)
    i = np.flatnonzero((prim >= 0) & (np.einsum("ij,ij->i", dirs, pt.normal[hp]) < 0))
    return row[i], org[row[i]] + t[i, None] * dirs[i], hp[i]


def categories(q, p):
    """(m,) category of hits on patches q at points p (CATS)."""
    pt = s.patches
    name = np.array(pt.object_names)[pt.object_id[q]]
    book = np.char.find(name.astype(str), "_book") >= 0
    case = np.char.startswith(name.astype(str), "case") & ~book
    nz, nx = pt.normal[q, 2], np.abs(pt.normal[q, 0])
    cov = s.h.dark(locate_below(s.h, q, p, dyn.n_hr, split_lines(s.h, dyn.n_hr)), p)
    cat = np.where(
        book, np.where(nz > 0.9, 0, np.where(nx > 0.9, 1, 2)), np.where(case, np.where(nz < -0.9, 3, 4), 5)
    )
    categories.last = (cat, cov)  # (what covered hits lie on)
    return np.where(cov, 6, cat)


CATS = ("book top", "book side", "book front/back", "case: board underside", "case: other", "room", "covered")


def pointwise(g, R1, R2, sel):
    """(g.n, 3) incident second bounce at samples sel (nan elsewhere), path-traced: R1 rays from
    the sample, R2 from each hit (at the exact hit point, covered or not), each reading rho x the
    exact direct light (16 shadow rays) at its hit."""
    pt = s.patches
    r1, p1, q1 = trace(g, g.origins[sel], g.normals[sel], g.keys[sel], R1, 4321)
    h1 = FinalGather(dyn, p1, pt.normal[q1], q1, rays=1, shadow_rays=1, seed=11, open_edge=0.0)
    r2, p2, q2 = trace(h1, h1.origins, h1.normals, h1.keys, R2, 1234)
    h2 = FinalGather(dyn, p2, pt.normal[q2], q2, rays=1, shadow_rays=16, seed=7, open_edge=0.0)
    v2 = h2.rho * h2.direct_and_emission(dyn)[0]
    b1 = np.stack([np.bincount(r2, v2[:, c], h1.n) for c in range(3)], 1) / R2 * h1.rho
    out = np.full((g.n, 3), np.nan)
    out[sel] = np.stack([np.bincount(r1, b1[:, c], len(sel)) for c in range(3)], 1) / R1
    return out, (sel[r1], p1, q1, b1 / R1)


def bounces(g, iters):
    """{b: (texels,) grey}: ours truncated at 0, 1, 2 bounces and the full value."""

    def out(inc):
        inc = inc.copy()
        inc[g.dark] = 0.0
        return g.outputs(g.rho * g.scaled(np.maximum(inc, 0.0))).mean(1)

    g2 = g.second
    D, D2 = g.direct_and_emission(dyn)[0], g2.direct_and_emission(dyn)[0]
    if g2.second is not None:  # levels > 2: no ladder, the full value only
        res = {0: out(D), 1: np.full(g.n_out, np.nan), 2: np.full(g.n_out, np.nan)}
        res[64, iters[0]] = g.evaluate(dyn, "reflected").mean(1)
        return res, (D, D2, None, out)
    z = np.zeros((g.n_hr, 3))
    L1 = (g._leaf_means(g2.rho * D2, z), None, None, None)
    L2 = (g._leaf_means(g2.rho * (D2 + g2._read(L1)), z), None, None, None)
    res = {0: out(D), 1: out(D + g._read(L1)), 2: out(D + g._read(L2))}
    for k in iters:
        g.iterations = k
        g._responses.clear()  # (the base solution's D + I is cached per gather)
        res[64, k] = g.evaluate(dyn, "reflected").mean(1)
    return res, (D, D2, L1, out)


def table(res, full):
    rows = {}
    for lab, m in groups:
        c = {b: REF[m, i].sum() for i, b in enumerate(BOUNCES)}
        o = {b: res[b][m].sum() for b in (0, 1, 2)}
        o[64] = res[full][m].sum()
        r = {
            "share": c[64] / TOT,
            "first": (o[1] - o[0]) / (c[1] - c[0]),
            "second": (o[2] - o[1]) / (c[2] - c[1]),
            "rest": (o[64] - o[2]) / (c[64] - c[2]),
            "all": o[64] / c[64],
            # the class's part of the books' deficit, points of the books' light
            "def_second": 100 * ((o[2] - o[1]) - (c[2] - c[1])) / TOT,
            "def_rest": 100 * ((o[64] - o[2]) - (c[64] - c[2])) / TOT,
        }
        if "pw2" in res:
            r["second_pointwise"] = res["pw2"][m].sum() / (c[2] - c[1])
        if "x2" in res:
            r["second_exact"] = (res["x2"][m].sum() - o[1]) / (c[2] - c[1])
        rows[lab] = r
    return rows


results = {}
for name, kw in VARIANTS.items():
    kw = dict(kw)
    SECOND.clear()
    SECOND.update(kw.pop("_second", {}))
    iters = kw.pop("_iters", None)
    GKW = {**BASE, **kw}
    iters = iters or [GKW["iterations"] if GKW.get("levels", 2) == 2 else 0]
    t0 = time.process_time()
    g = texel_gather(dyn, P, X, axes=AX, tris=TR, **GKW)
    pre = time.process_time() - t0
    g2 = g.second
    info = {
        "gather": {**GKW, "_second": dict(SECOND)},
        "precompute_cpu": pre,
        "samples": g.n,
        "second_samples": g2.n,
        "second_dark": float(g2.dark.mean()),
        "weights_mb": g.weights_bytes / 1e6,
        "near_leaves": g.stats.get("near_leaves"),
    }
    res, (D, D2, L1, out) = bounces(g, iters)
    # what the rays read on leaves whose second-level samples are partly or all covered
    used, start = g._second_map[0], g._second_start
    nd = np.add.reduceat(g2.dark.astype(int), start[:-1])
    k2 = np.diff(start)
    alld, part = np.zeros(g.n_hr, bool), np.zeros(g.n_hr, bool)
    alld[used[nd == k2]], part[used[(nd > 0) & (nd < k2)]] = True, True
    exp_ = s.h.exposure[: g.n_hr] > 0
    for lev, gg in (("first", g), ("second", g2)):
        c, w = gg.leaf_columns().astype(np.int64), gg.entry_weights().astype(float)
        leaf = np.where(
            c < g.n_hr, c, used[np.searchsorted(start, c - g.n_hr, "right") - 1] if len(used) else 0
        )
        tot = w.sum()
        info[f"{lev}_weight_all_dark"] = float(w[(c < g.n_hr) & alld[leaf]].sum() / tot)
        info[f"{lev}_weight_part_dark"] = float(w[(c < g.n_hr) & part[leaf]].sum() / tot)
        info[f"{lev}_weight_near"] = float(w[c >= g.n_hr].sum() / tot)
        print(
            f"{lev} level's rays: weight on leaves with all samples covered "
            f"{info[f'{lev}_weight_all_dark']:.4f} "
            f"(exposed {float(w[(c < g.n_hr) & alld[leaf] & exp_[leaf]].sum() / tot):.4f}), partly "
            f"{info[f'{lev}_weight_part_dark']:.4f}, near reads {info[f'{lev}_weight_near']:.4f}",
            flush=True,
        )
    if opt.exact and name == "base":
        t1 = time.process_time()
        ex, ne = exact_first(g, opt.exact)
        # pass 2 with the exact first bounce where it was computed (the gather's elsewhere)
        gat = g2._read(L1)
        use = np.where(np.isnan(ex), gat, ex)
        L2x = (g._leaf_means(g2.rho * (D2 + use), np.zeros((g.n_hr, 3))), None, None, None)
        res["x2"] = out(D + g._read(L2x))
        ok = ~np.isnan(ex[:, 0])
        info["exact"] = {"rays": opt.exact, "samples": ne, "cpu": time.process_time() - t1}
        print(
            f"exact first bounce at {ne} second-level samples: {time.process_time() - t1:.0f} s CPU",
            flush=True,
        )
        print(
            "  gathered / exact first bounce at them (unweighted sum):", f"{gat[ok].sum() / ex[ok].sum():.3f}"
        )
    if opt.pointwise and name == "base" and L1 is not None:
        t1 = time.process_time()
        R1, R2 = (int(v) for v in opt.pointwise.split(","))
        # the classes outside the slots (their samples gather through a mouth, scaled by a gain)
        keep = ~np.isin(CLS, (5, 6, 7))
        sel = (
            np.flatnonzero(keep[g.group] & ~g.dark) if g.group is not None else np.flatnonzero(keep & ~g.dark)
        )
        pw, (sr, p1, q1, b1) = pointwise(g, R1, R2, sel)
        # per class of the texel and category of the first hit: the pointwise one-bounce light at
        # the hit against what the gather reads there (the second level's leaf mean of its second
        # pass's increment; covered hits: 0)
        h = s.h
        lines = split_lines(h, g.n_hr)
        leaf = locate_below(h, q1, p1, g.n_hr, lines)
        cat = categories(q1, p1)
        z = np.zeros((g.n_hr, 3))
        Lb = g._leaf_means(g2.rho * g2._read(L1), z)[: g.n_hr]  # second pass minus first: rho W2 L1
        rd = np.where((cat == 6)[:, None], 0.0, Lb[leaf]) / R1
        grp = g.group[sr] if g.group is not None else sr
        tcls = CLS[grp]
        tex_rho = g.rho[sr].mean(1)
        info["attribution"] = {}
        for lab, cm in (("sides above", (8,)), ("fronts", (1,)), ("tops", (0,))):
            m = np.isin(tcls, cm)
            ntex = np.isin(CLS, cm)
            cyc2 = (REF[ntex, 2] - REF[ntex, 1]).sum()
            print(
                f"  {lab}: second bounce by first hit, of Cycles' (pointwise / gather's read / weight share)"
            )
            att = {}
            for k, cn in enumerate(CATS):
                mk = m & (cat == k)
                nsamp = np.bincount(g.group, minlength=g.n_out)[grp[mk]] if g.group is not None else 1
                a = float((tex_rho[mk] * b1[mk].mean(1) / nsamp).sum() / cyc2)
                b = float((tex_rho[mk] * rd[mk].mean(1) / nsamp).sum() / cyc2)
                wsh = float(mk.sum() / max(m.sum(), 1))
                att[cn] = (a, b, wsh)
                print(f"    {cn:24s} {a:6.3f} {b:6.3f}  {wsh:5.3f}")
            info["attribution"][lab] = att
            c0, cv = categories.last
            mc = m & cv
            dist = np.linalg.norm(p1[mc] - g.origins[sr[mc]], axis=1)
            on = {CATS[k]: round(float((c0[mc] == k).mean()), 3) for k in range(6)}
            print(
                f"    covered hits lie on: {on}; "
                f"distance quartiles (m) {np.round(np.percentile(dist, [25, 50, 75]), 4)}"
            )
            att["covered_on"] = on
        pw[np.isnan(pw)] = 0.0
        res["pw2"] = out(pw)  # the second bounce alone (reflected at the texel)
        print(
            f"pointwise second bounce ({R1} x {R2} rays at {len(sel)} samples): "
            f"{time.process_time() - t1:.0f} s CPU",
            flush=True,
        )
    if name == "base" and L1 is not None:
        # per book: its error at b64 (case3 only: 64 spp, one seed), and for the books more than 5%
        # dark, the mean part of each class and bounce in it (points of the book's light)
        full = res[64, iters[0]]
        cl = {
            "slot sides": (5, 6, 7),
            "sides above": (8,),
            "tops": (0,),
            "fronts": (1,),
            "other": (2, 3, 4, 9),
        }
        ob = np.unique(OBJ)
        inv = np.searchsorted(ob, OBJ)
        cb = np.bincount(inv, REF[:, 3], len(ob))
        err = np.bincount(inv, full - REF[:, 3], len(ob)) / np.maximum(cb, 1e-30)
        # the lit books and their error in the room run against the 128-spp reference (near hits on)
        room = json.load(open(os.path.join(BC.HERE, "out", "furnished_vs_cycles_fgboth.json")))
        names = [books[i] for i in ob]
        lit = np.isin(names, room["lit"])
        rerr = np.array([room["objects"][n]["refl_gather"]["bias"] for n in names])
        print(
            f"case3's lit books: {lit.sum()}, error here against the room run's: corr "
            f"{np.corrcoef(err[lit], rerr[lit])[0, 1]:.3f}, median {np.median(err[lit] - rerr[lit]):+.4f}"
        )
        dark = lit & (rerr < -0.05)
        parts = {}
        for lab, cc in cl.items():
            m = np.isin(CLS, cc)
            for bn, (o, c) in {
                "direct": (res[0], REF[:, 0]),
                "first": (res[1] - res[0], REF[:, 1] - REF[:, 0]),
                "second": (res[2] - res[1], REF[:, 2] - REF[:, 1]),
                "rest": (full - res[2], REF[:, 3] - REF[:, 2]),
            }.items():
                d = np.bincount(inv[m], (o - c)[m], len(ob)) / np.maximum(cb, 1e-30)
                parts[f"{lab} {bn}"] = float(100 * d[dark].mean())
        info["books"] = {
            "n": int(lit.sum()),
            "within5": int((np.abs(err[lit]) <= 0.05).sum()),
            "dark5": int(dark.sum()),
            "median_abs": float(np.median(np.abs(err))),
            "dark_parts_pts": parts,
        }
        print(
            f"per book (case3's lit, {lit.sum()}): within 5% here {(np.abs(err[lit]) <= 0.05).sum()}, "
            f"below -5% in the room run {dark.sum()}; "
            f"in those, points of the book's light by class and bounce (direct / first / second / rest):"
        )
        # the slot sides by depth below the overlap's top (gap widths of 2 mm) and by texel row from
        # the book's front (0: the front row): ours / Cycles, all light and direct
        srow = BC.front_rows(X, OBJ)
        info["slot_profile"] = {}
        for c, lab in ((5, "receiver shorter"), (6, "receiver taller")):
            for a, b in ((0, 5), (5, 10), (10, 20), (20, 50), (50, 1e9)):
                for rl, rm in (("front row", srow == 0), ("rows behind", srow > 0)):
                    m = (CLS == c) & (-ZREL >= a) & (-ZREL < b) & rm
                    if m.sum() < 5:
                        continue
                    v = (
                        float(full[m].sum() / REF[m, 3].sum()),
                        float(res[0][m].sum() / max(REF[m, 0].sum(), 1e-30)),
                    )
                    # the band's share of the books' light and its deficit (points of it)
                    sh, dp = 100 * REF[m, 3].sum() / TOT, 100 * (full[m].sum() - REF[m, 3].sum()) / TOT
                    info["slot_profile"][f"{lab} {a}-{b} {rl}"] = (int(m.sum()), *v, float(sh), float(dp))
                    print(
                        f"  slot, {lab}, {a}-{b:g} gap widths deep, {rl}: {m.sum()} texels, "
                        f"all {v[0]:.3f}, direct {v[1]:.3f}, share {sh:.2f}%, deficit {dp:+.3f} pts"
                    )
        # the slot samples by the mouth they gather at (where the sample was moved: within 3 mm of
        # the book's top, its front or its back, as its texel's first sample has it)
        box = BC.book_boxes(rs)
        lo = np.array([box[books[o]][0] for o in OBJ])
        hi = np.array([box[books[o]][1] for o in OBJ])
        first = np.searchsorted(g.group, np.arange(g.n_out)) if g.group is not None else np.arange(g.n_out)
        q = g.points[first]
        moved = np.linalg.norm(q - X, axis=1) > 1e-4
        d_front, d_back = q[:, 1] - lo[:, 1], hi[:, 1] - q[:, 1]
        kind = np.where(d_front < 0.003, "front", np.where(d_back < 0.003, "back", "top"))
        info["slot_mouth"] = {}
        for c, lab in ((5, "receiver shorter"), (6, "receiver taller")):
            for kd in ("top", "front", "back"):
                m = (CLS == c) & moved & (kind == kd)
                if m.sum() < 5:
                    continue
                v = (
                    float(full[m].sum() / REF[m, 3].sum()),
                    float(res[0][m].sum() / max(REF[m, 0].sum(), 1e-30)),
                )
                info["slot_mouth"][f"{lab} {kd}"] = (int(m.sum()), *v)
                print(
                    f"  slot, {lab}, gathers at the {kd}: {m.sum()} texels, all {v[0]:.3f}, direct {v[1]:.3f}"
                )
        for lab in cl:
            print(
                f"  {lab:12s} "
                + " / ".join(f"{parts[f'{lab} {bn}']:+5.2f}" for bn in ("direct", "first", "second", "rest"))
            )
    for k in iters:
        rows = table(res, (64, k))
        results[f"{name}_it{k}" if len(iters) > 1 else name] = {**info, "iterations": k, "classes": rows}
        print(
            f"\n== {name} iterations {k}: precompute {pre:.1f} s CPU, {g.n} + {g2.n} samples "
            f"({100 * info['second_dark']:.1f}% of the second level dark), "
            f"weights {info['weights_mb']:.1f} MB",
            flush=True,
        )
        print(
            f"{'class':32s} share  first second  rest   all   deficit 2nd / rest (pts)"
            + ("  2nd exact" if "x2" in res else "")
        )
        for lab, r in rows.items():
            print(
                f"{lab:32s} {100 * r['share']:5.1f} {r['first']:6.3f} {r['second']:6.3f} {r['rest']:6.3f} "
                f"{r['all']:6.3f}   {r['def_second']:+6.2f} / {r['def_rest']:+6.2f}"
                + (f"   {r['second_exact']:6.3f}" if "second_exact" in r else "")
                + (f"   {r['second_pointwise']:6.3f}" if "second_pointwise" in r else ""),
                flush=True,
            )
    del g

with open(os.path.join(BC.HERE, "out", f"books_later{opt.name}.json"), "w") as f:
    json.dump(results, f, indent=1, default=float)
