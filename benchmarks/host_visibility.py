"""Issue 19, measure only (bpy-free prototype): a light shape's direct light at the top gather level
from visibility precomputed toward its HOST surface, no shadow rays per event.

A light shape lying on a wall is emission on static geometry: the visibility from each gather
sample toward points of that wall does not depend on the shape. So a grid of cells (size h) over
the part of the wall the bake's shapes cover (here: the FE window at its two positions, add 0.7 and
move 1.2 m) is traced once: per sample facing the region and per cell one segment from the sample
to a point of the cell (uniform in the cell: the cells' lattice shifted by the sample's own hash,
so every sample has its own points and the per-entry terms are separable), one bit stored
(samples whose shaft to the region's box is certainly clear, planes.ClearShafts: no rays, every
bit 1). An event then costs no rays:

- ``pin`` (ratio, points inside): D = F x sum k v / sum k over the cells' points that fall inside
  the shape (F: the exact unoccluded form factor, events.direct.shape_form_factors, as main; k: the
  area density's cos_x cos_y / r^2 at the point). This is main's ratio estimator with its shadow
  rays replaced by the stored, cell-stratified ones (about area(shape) / h^2 of them per sample).
- ``ovl`` (ratio, overlap weights): every cell the shape overlaps, its point weighted by the
  overlap area x k, whether or not the point is inside (no point-in-polygon test; biased where a
  partly covered cell's visibility differs between its covered and its other part).
- ``mc`` (no F): D = sum over the points inside of h^2 k v / pi (unbiased, no form factor).

Against main's 16 shadow rays, main with another seed (its noise), and references with 64 and 256
rays at the top level (the second level and the slot copy are main's in every variant: only the
top level's shape light differs). Per object: the gathered output (loop_radiance) with the top
level's shape light replaced, compare_gather_dumps.difference against the reference.

    .venv/bin/python benchmarks/host_visibility.py STORE [--level top|second] [--cells 0.2,0.1,0.05] \\
        [--modes pin,ovl,mc] [--refs r64,r256,r256s7] [--shape 0.9,0.7] [--size 100k] [--json out.json]
    .venv/bin/python benchmarks/host_visibility.py --end-to-end STORE [--top 0.1] [--second 0.2]
    .venv/bin/python benchmarks/host_visibility.py --sweep STORE [--frames 6] [--cells 0.1]

STORE: a `bench_gather_events.py --transport gather --cache DIR` build of the furnished room (docs/events.md,
session 28, has the figures).
"""

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402

from hr_addon.core.gather.hostvis import cell_overlaps, inside_rings  # noqa: E402

STREAM = 0x5A17  # the host visibility's own random stream
CHUNK = 1 << 21  # (samples x cells) entries per block


def to2d(P, frame):
    o, U, V = frame
    d = np.asarray(P, float) - o
    return np.column_stack([d @ U, d @ V])


class HostVisibility:
    """Bits of visibility from a gather level's samples to points of h-cells over a rectangle
    [lo, lo + (nx, ny) h] of a host plane (frame: origin, U, V; normal n = U x V's side the samples
    face). Each sample's points form the cells' lattice shifted by the sample's own uniform r_s
    (hash of its key): y = lo + (i + r_s) h, uniform in each cell, so every per-entry term is a sum
    of a term of the sample and column and one of the sample and row (separable: cheap numpy)."""

    def __init__(self, lv, frame, normal, lo, hi, h, shafts=None):
        from hr_addon.core.gather.sampling import hash_uniform

        self.lv, self.frame, self.n, self.h = lv, frame, np.asarray(normal, float), h
        self.nx, self.ny = (int(np.ceil((hi[k] - lo[k]) / h - 1e-9)) for k in (0, 1))
        self.lo = np.asarray(lo, float)
        self.C = self.nx * self.ny
        o, U, V = frame
        eps = lv.eps
        x, nx_ = lv.points, lv.normals
        corners = np.array(
            [
                o + (self.lo[0] + a * self.nx * h) * U + (self.lo[1] + b * self.ny * h) * V
                for a in (0, 1)
                for b in (0, 1)
            ]
        )
        ok = ~lv.dark & ((x - o) @ self.n > eps)
        ok &= (np.einsum("ik,jk->ij", nx_, corners) - np.einsum("ik,ik->i", x, nx_)[:, None]).max(1) > eps
        self.idx = np.flatnonzero(ok)  # the samples facing the region (one row each)
        self.row = np.full(lv.n, -1, np.int64)
        self.row[self.idx] = np.arange(len(self.idx))
        L = len(self.idx)
        # per sample: its shift, its 2D position and height over the plane, its normal in the frame
        self.r = hash_uniform(lv.seed, lv.keys[self.idx], STREAM)
        d = x[self.idx] - o
        self.ab = np.column_stack([d @ U, d @ V])
        self.z = d @ self.n
        N = nx_[self.idx]
        self.nuvw = np.column_stack([N @ U, N @ V, N @ self.n])
        self.clear = np.zeros(L, bool)
        if shafts is not None:
            e = eps * self.n
            lo3, hi3 = corners.min(0) + e, corners.max(0) + e
            self.clear = shafts.clear(x[self.idx] + eps * nx_[self.idx], lo3, hi3)
        self.bits = np.full((L, (self.C + 7) // 8), 255, np.uint8)  # packed, row-major cells per sample
        self.rays = 0
        trace = np.flatnonzero(~self.clear)
        step = max(1, CHUNK // self.C)
        ci, cj = np.arange(self.C) % self.nx, np.arange(self.C) // self.nx
        for s0 in range(0, len(trace), step):
            r = trace[s0 : s0 + step]
            gi = self.idx[r]
            a = self.lo[0] + (ci[None] + self.r[r, :1]) * h  # (l, C)
            b = self.lo[1] + (cj[None] + self.r[r, 1:]) * h
            org = (x[gi] + eps * nx_[gi]).T  # (3, l)
            y = [o[k] + a * U[k] + b * V[k] + eps * self.n[k] - org[k][:, None] for k in range(3)]
            vis = ~lv.system.backend.occluded_cm(org, np.stack(y).reshape(3, -1), self.C)
            self.bits[r] = np.packbits(vis.reshape(len(r), self.C), axis=1)
            self.rays += vis.size

    @property
    def nbytes(self):
        return sum(a.nbytes for a in (self.bits, self.idx, self.r, self.ab, self.z, self.nuvw))

    def direct(self, em, rings2d, mode="pin", convex=True, skip_uniform=True):
        """((n,) float32 the shape's unit direct light at the level's samples with no rays, the
        samples none of whose points fell inside the shape with weight). mode: pin (ratio over the
        points inside the shape), ovl (ratio over every overlapped cell's point, weight overlap
        area), mc (sum h^2 k v / pi over the points inside, no form factor). convex: the inside
        test by the outline's edges' half planes (separable); else even-odd per entry.
        skip_uniform: a sample whose bits over the overlapped cells are all 1 reads V = 1, all 0
        reads 0, without weights (the ratio's own values; self.mixed counts the others)."""
        from hr_addon.core.events.direct import shape_form_factors

        lv, h = self.lv, self.h
        eps = lv.eps
        out = np.zeros(lv.n)
        # main's culls (direct_batch): in front of the shape, a vertex above the horizon
        x, nx_ = lv.points, lv.normals
        ok = ~lv.dark & ((x - em.point) @ em.normal > eps)
        i = np.flatnonzero(ok)
        xn = np.einsum("mk,mk->m", x[i], nx_[i])[:, None]
        i = i[(nx_[i] @ em.verts.T - xn).max(1) > eps]
        rows = self.row[i]
        assert (rows >= 0).all(), "a sample facing the shape is not stored: the region misses the shape"
        # the block of cells the shape's box overlaps, and their overlap areas
        allr = np.concatenate(rings2d)
        c0 = np.floor((allr.min(0) - self.lo) / h + 1e-9).astype(int).clip(0)
        c1 = np.ceil((allr.max(0) - self.lo) / h - 1e-9).astype(int).clip(max=[self.nx, self.ny])
        ov = cell_overlaps(rings2d, *(self.lo + c0 * h), h, *(c1 - c0))
        full = ov >= h * h * (1 - 1e-9)
        ovf = np.flatnonzero(ov.ravel() > 0)
        nov = len(ovf)
        self.mixed = 0
        part = (ov > 0) & ~full
        ci, cj = np.arange(c0[0], c1[0]), np.arange(c0[1], c1[1])
        # the outline's edges as half planes e_a a + e_b b >= c (convex, CCW in the frame)
        P = rings2d[0]
        if convex:
            ccw = np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1]) > 0
            Q = P if ccw else P[::-1]
            E = np.roll(Q, -1, 0) - Q
            nrm = np.column_stack([-E[:, 1], E[:, 0]])  # inward for CCW
            cst = np.einsum("ek,ek->e", nrm, Q)
        V = np.zeros(len(i))
        mcv = np.zeros(len(i))
        nofall = 0
        nb = len(cj) * len(ci)
        step = max(1, (1 << 18) // max(nb, 1))
        f32 = np.float32
        ovw = ov.astype(f32)
        for s0 in range(0, len(i), step):
            sl = slice(s0, s0 + step)
            rr = rows[sl]
            nl = len(rr)
            vis = np.unpackbits(self.bits[rr], axis=1, count=self.C).reshape(nl, self.ny, self.nx)
            vis = vis[:, c0[1] : c1[1], c0[0] : c1[0]]
            Vc, Mc = np.zeros(nl), np.zeros(nl)
            if skip_uniform:  # every overlapped cell's bit alike: V exactly 1 or 0, no weights
                cnt = vis.reshape(nl, -1)[:, ovf].sum(1, dtype=np.int32)
                Vc[cnt == nov] = 1.0
                mix = np.flatnonzero((cnt > 0) & ((cnt < nov) | (mode == "mc")))
                self.mixed += len(mix)
                rr, vis = rr[mix], vis[mix]
            else:
                mix = slice(None)
            r = self.r[rr]
            a = self.lo[0] + (ci[None] + r[:, :1]) * h  # (l, ci)
            b = self.lo[1] + (cj[None] + r[:, 1:]) * h  # (l, cj)
            da, db = (a - self.ab[rr, :1]).astype(f32), (b - self.ab[rr, 1:]).astype(f32)
            z = self.z[rr].astype(f32)
            nu, nv, nw = (self.nuvw[rr, k].astype(f32) for k in range(3))
            # cos_x r = d . N, d = da U + db V - z n; r^2 = da^2 + db^2 + z^2 (cos_y r = z: a
            # constant of the sample, out of the ratio)
            cx = (da * nu[:, None])[:, None, :] + (db * nv[:, None] - (z * nw)[:, None])[:, :, None]
            r2 = (da * da)[:, None, :] + (db * db + (z * z)[:, None])[:, :, None]
            k = np.maximum(cx, 0) / (r2 * r2)
            if mode == "ovl":
                w = k * ovw[None]
            else:
                m = np.broadcast_to(full[None], k.shape)
                if part.any():
                    if convex:
                        inn = np.broadcast_to(part[None], k.shape).copy()
                        for e in range(len(cst)):
                            sa = nrm[e, 0] * a - cst[e]  # (l, ci)
                            sb = nrm[e, 1] * b  # (l, cj)
                            inn &= (sa[:, None, :] + sb[:, :, None]) >= 0
                    else:
                        q = np.stack(np.broadcast_arrays(a[:, None, :], b[:, :, None]), -1)
                        inn = part[None] & inside_rings(q, rings2d)
                    m = m | inn
                w = k * m
            ws = w.sum((1, 2))
            wv = (w * vis).sum((1, 2))
            nofall += int((ws <= 0).sum())
            Vc[mix] = np.where(ws > 0, wv / np.where(ws > 0, ws, 1), 1.0)
            V[sl] = Vc
            if mode == "mc":
                Mc[mix] = wv * z * (h * h / np.pi)
                mcv[sl] = Mc
        if mode == "mc":
            out[i] = mcv
            return out.astype(np.float32), nofall
        seen = np.flatnonzero(V != 0)
        F = shape_form_factors(x[i[seen]], nx_[i[seen]], em.rings, em.corners, em.nv, eps)
        out[i[seen]] = F * V[seen]
        return out.astype(np.float32), nofall


def open_store(store, size="100k", sw=0.9, sh=0.7):
    """(system, gather, the light wall's frame, each loop's object, window(cx)) of a stored room:
    the FE window of bench_gather_events (sw x sh m, 20 W sr^-1 m^-2) centred cx along its wall."""
    from bench_gather_events import load_store

    from hr_addon.core.events import LightShape
    from hr_addon.io import precompute as pc
    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room

    s, g, _ = load_store(Path(store) / pc.FILENAME)
    s.links.extended(s.h)
    g.iterations = 4
    frame = tuple(np.asarray(f, float) for f in furnished_room(size)[1]["light_wall"][1])
    obj = np.asarray(s.mesh.object_id)[np.repeat(np.arange(len(s.mesh.loop_start)), s.mesh.loop_total)]

    def window(cx):
        rect = S.on_plane(S.rect(sw, sh, centre=(cx, 0.6), angle=0.2), frame)
        return LightShape(rect, np.full(3, 20.0), "window")

    return s, g, frame, obj, window


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store")
    ap.add_argument(
        "--level", default="top", choices=("top", "second"), help="the level whose shape light varies"
    )
    ap.add_argument("--cells", default="0.2,0.1,0.05")
    ap.add_argument("--modes", default="pin,ovl,mc", help="modes at 0.1 m cells (pin at every size)")
    ap.add_argument(
        "--refs", default=None, help="reference variants (top: r64,r256,r256s7; second: r64,r64s7)"
    )
    ap.add_argument("--ref", default=None, help="the reference (top: r256, second: r64)")
    ap.add_argument("--repeat", type=int, default=3, help="per-event CPU: median of this many")
    ap.add_argument("--no-skip", action="store_true", help="weights at every sample (no uniform shortcut)")
    ap.add_argument("--shape", default="0.9,0.7", help="the window's width, height (m)")
    ap.add_argument("--size", default="100k", help="the furnished room the store was built from")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    sw, sh = (float(v) for v in args.shape.split(","))

    from compare_gather_dumps import difference, per_object
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.events.direct import clear_shafts

    cpu = time.process_time
    s, g, frame, obj, window = open_store(args.store, args.size, sw, sh)
    lv = g if args.level == "top" else g.second
    top = args.level == "top"
    refs = (args.refs or ("r64,r256,r256s7" if top else "r64,r64s7")).split(",")
    ref = args.ref or ("r256" if top else "r64")

    # the host region: the bake's shapes over all its frames (here the two positions)
    pos = {"add": 0.7, "move": 1.2}
    r2d = [to2d(np.concatenate(window(cx).rings), frame) for cx in pos.values()]
    lo, hi = np.min([r.min(0) for r in r2d], 0), np.max([r.max(0) for r in r2d], 0)
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    res = dict(
        store=args.store,
        size=args.size,
        level=args.level,
        shape=[sw, sh],
        region_lo=lo.tolist(),
        region_hi=hi.tolist(),
        samples=int(lv.n),
        shadow_rays=int(lv.shadow_rays),
        ref=ref,
        skip_uniform=not args.no_skip,
    )
    print(f"region {lo.round(3)} .. {hi.round(3)} ({np.prod(hi - lo):.3f} m2), {args.level} samples {lv.n:,}")
    base = dict(rays=lv.shadow_rays, seed=lv.seed, far=getattr(lv, "FAR_RAYS", 0))

    def level_light(rec, rays=None, seed=None, far=None):
        """The level's shape light by its own shadow rays (main's code), other rays / seed."""
        lv.shadow_rays = rays or base["rays"]
        lv.seed = base["seed"] if seed is None else seed
        if not top:
            lv.FAR_RAYS = base["far"] if far is None else far
        lv._shape_cache.pop(rec.geom_key, None)
        c0 = cpu()
        D, inside = lv._shape(dyn, rec)
        t = cpu() - c0
        lv._shape_cache.pop(rec.geom_key, None)
        lv.shadow_rays, lv.seed = base["rays"], base["seed"]
        if not top:
            lv.FAR_RAYS = base["far"]
        return D, inside, t

    def output(rec, D, inside):
        """The gathered output with the level's shape light D (the other levels main's)."""
        lv._shape_cache[rec.geom_key] = (D, inside)
        for k in [k for k in g._responses if k[0] == "shape"]:
            del g._responses[k]
        return np.array(g.loop_radiance(dyn), np.float32)

    kinds = dict(
        main={},
        seed7=dict(seed=7),
        r64=dict(rays=64, far=0),
        r64s7=dict(rays=64, far=0, seed=7),
        r256=dict(rays=256, far=0),
        r256s7=dict(rays=256, far=0, seed=7),
    )
    events = {}
    hv = {}
    shafts = None
    for step, cx in pos.items():
        c0 = cpu()
        if step == "add":
            dyn.add("w", window(cx))
        else:
            dyn.apply({"w": window(cx)})
        rec = dyn.shapes["w"]
        print(f"{step}: event {cpu() - c0:.3f} s", flush=True)
        em = g._shape_emitter(dyn, rec)[0]
        if shafts is None:
            shafts = clear_shafts(s, em.point, em.normal)
        rings2d = [to2d(r, frame) for r in rec.rings]
        ev = dict(D={}, cpu={}, nofall={}, mixed={})
        for name in ["main", "seed7"] + refs:
            D, inside, t = level_light(rec, **kinds[name])
            ev["D"][name], ev["cpu"][name] = D, t
            print(f"   {name}: shape light {t:.3f} s, lit {int((D > 0).sum()):,}", flush=True)
        # the precompute, once per cell size (the first event pays it)
        for h in (float(c) for c in args.cells.split(",")):
            if h not in hv:
                c0 = cpu()
                hv[h] = HostVisibility(lv, frame, em.normal, lo, hi, h, shafts)
                t = cpu() - c0
                H = hv[h]
                res.setdefault("precompute", {})[f"h{h:g}"] = dict(
                    cells=H.C,
                    samples=len(H.idx),
                    shaft_clear=int(H.clear.sum()),
                    rays=int(H.rays),
                    cpu_s=round(t, 3),
                    bytes=int(H.nbytes),
                    bits_bytes=int(H.bits.nbytes),
                )
                print(f"   precompute h {h:g}: {res['precompute'][f'h{h:g}']}", flush=True)
            modes = args.modes.split(",") if abs(h - 0.1) < 1e-9 else ["pin"]
            for mode in modes:
                ts = []
                for _ in range(args.repeat):
                    c0 = cpu()
                    D, nof = hv[h].direct(em, rings2d, mode, skip_uniform=not args.no_skip)
                    ts.append(cpu() - c0)
                name = f"{mode}{int(round(h * 100))}"
                ev["D"][name], ev["cpu"][name], ev["nofall"][name] = D, float(np.median(ts)), nof
                ev["mixed"][name] = hv[h].mixed
                print(
                    f"   {name}: {np.median(ts):.3f} s, lit {int((D > 0).sum()):,}, samples weighted "
                    f"{hv[h].mixed:,}, with no weighted point inside {nof}",
                    flush=True,
                )
        # per sample against the reference, then per object
        R = ev["D"][ref].astype(np.float64)
        lit = R > 0
        inside = lv._shape_emitter(dyn, rec)[1]
        po = {name: per_object(output(rec, D, inside), obj) for name, D in ev["D"].items()}
        rows = {}
        for name, D in ev["D"].items():
            d = D.astype(np.float64) - R
            row = dict(
                cpu_s=round(ev["cpu"][name], 4),
                sum_vs_ref=float(D.sum() / R.sum() - 1),
                rms_per_sample_rel=float(np.sqrt(np.mean(d[lit] ** 2)) / R[lit].mean()),
                nofall=ev["nofall"].get(name, 0),
                weighted_samples=ev["mixed"].get(name),
            )
            if name != ref:
                row.update({f"obj_{k}": v for k, v in difference(po[ref], po[name]).items()})
                a, b = po[ref], po[name]
                m = a > 0.05 * a[a > 0].mean()
                rel = (b[m] - a[m]) / a[m]
                row["obj_moved2"] = int((np.abs(rel) > 0.02).sum())
                row["obj_darker2"] = float((rel < -0.02).sum() / max(row["obj_moved2"], 1))
                row["obj_worst_id"] = int(np.flatnonzero(m)[np.argmax(np.abs(rel))])
                row["obj_worst_signed"] = float(rel[np.argmax(np.abs(rel))])
            rows[name] = row
            print(
                f"   {step} {name}: cpu {row['cpu_s']:.3f} s, sum {100 * row['sum_vs_ref']:+.3f}%, "
                f"per-sample rms {100 * row['rms_per_sample_rel']:.2f}%"
                + (
                    f"; objects median {100 * row['obj_median']:.3f}%, p95 {100 * row['obj_p95']:.2f}%, "
                    f"worst {100 * row['obj_worst_signed']:+.1f}% (object {row['obj_worst_id']}), bias "
                    f"{100 * row['obj_bias']:+.3f}%, moved>2% {row['obj_moved2']} "
                    f"(darker {100 * row['obj_darker2']:.0f}%)"
                    if name != ref
                    else " (reference)"
                ),
                flush=True,
            )
        events[step] = rows
    res["events"] = events
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def end_to_end(argv=None):
    """Both levels at once, the whole FE event with its gathered output: main (each level's shadow
    rays) against the host visibility at both levels (top h_top, second h_second cells, precomputed
    before the events, untimed), alternating per round on one DynamicRadiosity; per object each
    against a reference with 256 rays at the top and 64 at the second level.

        .venv/bin/python benchmarks/host_visibility.py --end-to-end STORE [--top 0.1] [--second 0.2]
    """
    ap = argparse.ArgumentParser()
    ap.add_argument("store")
    ap.add_argument("--top", type=float, default=0.1)
    ap.add_argument("--second", type=float, default=0.2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from compare_gather_dumps import difference, per_object
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.events.direct import clear_shafts

    cpu = time.process_time
    s, g, frame, obj, window = open_store(args.store)
    g2 = g.second

    pos = {"add": 0.7, "move": 1.2}
    r2d = [to2d(np.concatenate(window(cx).rings), frame) for cx in pos.values()]
    lo, hi = np.min([r.min(0) for r in r2d], 0), np.max([r.max(0) for r in r2d], 0)
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    g.loop_radiance(dyn)  # the base parts
    em0 = None
    hv = None
    res = dict(store=args.store, top_cells=args.top, second_cells=args.second, events={})

    def clear():  # the levels' and the slot samples' facing copy's shape light, the shape's parts
        for lv in (g, g2) + ((g._slot["f"],) if getattr(g, "_slot", None) is not None else ()):
            lv._shape_cache.clear()
        for k in [k for k in g._responses if k[0] == "shape"]:
            del g._responses[k]

    out, times, refs = {}, {}, {}
    for rnd in range(args.rounds):
        for name in ("main", "host"):
            if "w" in dyn.shapes:
                clear()
                dyn.remove("w")
            for step, cx in pos.items():
                clear()
                c0 = cpu()
                if step == "add":
                    dyn.add("w", window(cx))
                else:
                    dyn.apply({"w": window(cx)})
                c1 = cpu()
                rec = dyn.shapes["w"]
                if name == "host":
                    if hv is None:  # (untimed: the precompute)
                        t0 = cpu()
                        em0 = g._shape_emitter(dyn, rec)[0]
                        sh = clear_shafts(s, em0.point, em0.normal)
                        hv = (
                            HostVisibility(g, frame, em0.normal, lo, hi, args.top, sh),
                            HostVisibility(g2, frame, em0.normal, lo, hi, args.second, sh),
                        )
                        res["precompute_cpu_s"] = round(cpu() - t0, 3)
                        res["precompute_rays"] = int(hv[0].rays + hv[1].rays)
                        res["precompute_bits_bytes"] = int(hv[0].bits.nbytes + hv[1].bits.nbytes)
                        c0, c1 = c0 + cpu() - t0, c1 + cpu() - t0  # (out of both parts)
                    rings2d = [to2d(r, frame) for r in rec.rings]
                    for lv, H in zip((g, g2), hv):
                        em, inside, _ = lv._shape_emitter(dyn, rec)
                        lv._shape_cache[rec.geom_key] = (H.direct(em, rings2d, "pin")[0], inside)
                v = np.array(g.loop_radiance(dyn), np.float32)
                c2 = cpu()
                times.setdefault((step, name), []).append((c1 - c0, c2 - c1))
                out[(step, name)] = v
                print(f"{step} round {rnd} {name}: event {c1 - c0:.3f} s, output {c2 - c1:.3f} s", flush=True)
                if rnd == 0 and name == "host":  # the reference: 256 rays at the top, 64 at the second
                    clear()
                    g.shadow_rays, g2.shadow_rays, far = 256, 64, g2.FAR_RAYS
                    g2.FAR_RAYS = 0
                    refs[step] = per_object(np.array(g.loop_radiance(dyn), np.float32), obj)
                    g.shadow_rays, g2.shadow_rays, g2.FAR_RAYS = 16, 8, far
                    clear()
    for step in pos:
        row = {}
        for name in ("main", "host"):
            d = difference(refs[step], per_object(out[(step, name)], obj))
            ev = [t[0] for t in times[(step, name)]]
            op = [t[1] for t in times[(step, name)]]
            row[name] = dict(event_cpu_s=float(np.median(ev)), output_cpu_s=float(np.median(op)), **d)
            print(
                f"{step} {name}: event {np.median(ev):.3f} + output {np.median(op):.3f} s; vs reference "
                f"median {100 * d['median']:.3f}%, p95 {100 * d['p95']:.2f}%, worst {100 * d['worst']:.1f}%, "
                f"bias {100 * d['bias']:+.3f}%",
                flush=True,
            )
        res["events"][step] = row
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


def sweep(argv=None):
    """A window swept along its wall in small steps (a Live drag, a sweeping beam): per frame the
    top level's shape light by main's 16 rays, by the host visibility (pin, --cells) and by 256 rays
    (the reference); per object its error each frame, then over the frames its frame-to-frame change
    (flicker) and its mean (the part that stays).

        .venv/bin/python benchmarks/host_visibility.py --sweep STORE [--frames 6] [--cells 0.1]
    """
    ap = argparse.ArgumentParser()
    ap.add_argument("store")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--cells", type=float, default=0.1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)

    from compare_gather_dumps import per_object
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.events.direct import clear_shafts

    s, g, frame, obj, window = open_store(args.store)

    xs = np.linspace(0.7, 1.2, args.frames)
    r2d = [to2d(np.concatenate(window(cx).rings), frame) for cx in xs]
    lo, hi = np.min([r.min(0) for r in r2d], 0), np.max([r.max(0) for r in r2d], 0)
    dyn = DynamicRadiosity(s.copy(), method="FE", **DynamicRadiosity.gather_options("draft"))
    H = None
    err = {"main": [], "host": []}
    for f, cx in enumerate(xs):
        if f == 0:
            dyn.add("w", window(cx))
        else:
            dyn.apply({"w": window(cx)})
        rec = dyn.shapes["w"]
        em, inside, _ = g._shape_emitter(dyn, rec)
        if H is None:
            H = HostVisibility(g, frame, em.normal, lo, hi, args.cells, clear_shafts(s, em.point, em.normal))
        Ds = {}
        for name, rays in (("main", 16), ("ref", 256)):
            g.shadow_rays = rays
            g._shape_cache.pop(rec.geom_key, None)
            Ds[name] = g._shape(dyn, rec)[0]
            g._shape_cache.pop(rec.geom_key, None)
        g.shadow_rays = 16
        Ds["host"] = H.direct(em, [to2d(r, frame) for r in rec.rings], "pin")[0]
        po = {}
        for name, D in Ds.items():
            g._shape_cache[rec.geom_key] = (D, inside)
            for k in [k for k in g._responses if k[0] == "shape"]:
                del g._responses[k]
            po[name] = per_object(np.array(g.loop_radiance(dyn), np.float32), obj)
        g._shape_cache.pop(rec.geom_key, None)
        a = po["ref"]
        lit = a > 0.05 * a[a > 0].mean()
        for name in ("main", "host"):
            e = np.full(len(a), np.nan)
            e[lit] = (po[name][lit] - a[lit]) / a[lit]
            err[name].append(e)
        print(f"frame {f} at {cx:.2f}: lit objects {int(lit.sum())}", flush=True)
    res = dict(store=args.store, frames=args.frames, cells=args.cells, positions=xs.tolist())
    for name, es in err.items():
        E = np.array(es)  # (frames, objects)
        keep = np.isfinite(E).all(0)
        E = E[:, keep]
        per = np.abs(E)
        flick = np.sqrt(np.mean(np.diff(E, axis=0) ** 2, 0))
        stay = np.abs(E.mean(0))
        q = lambda v: [float(np.median(v)), float(np.percentile(v, 95)), float(v.max())]  # noqa: E731
        res[name] = dict(objects=int(keep.sum()), per_frame=q(per.ravel()), flicker=q(flick), stays=q(stay))
        print(
            f"{name}: {int(keep.sum())} objects lit in every frame; per frame |error| median / p95 / worst "
            f"{', '.join(f'{100 * v:.2f}%' for v in q(per.ravel()))}; frame-to-frame change rms "
            f"{', '.join(f'{100 * v:.2f}%' for v in q(flick))}; |mean over frames| "
            f"{', '.join(f'{100 * v:.2f}%' for v in q(stay))}",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    if "--end-to-end" in sys.argv:
        sys.argv.remove("--end-to-end")
        end_to_end()
    elif "--sweep" in sys.argv:
        sys.argv.remove("--sweep")
        sweep()
    else:
        main()
