"""The vertex output at contacts, bpy-free (ctc32, issue 19): what the output layout's corners
(Vertex Spacing: each coarse quad split 2^L x 2^L, as own_values.levels does) paint over a face
next to a contact, against a dense gather over the same face, by strip: the part hidden inside or
behind another object (a camera never sees it; Cycles' bake reads it black), the visible strip
within 3.5 cm of the contact, and the rest.

Scenes (a 4 m floor plane, a 1 m square emitter 1.5 m up off to the side, grey everything else):
- `stand`: a 0.5 m box standing on the floor (touching);
- `sunk`: the same box sunk 5 cm through the floor plane (the artist room's Crate);
- `wall`: the box standing against a wall (a second plane, 2 mm away);
- `leg`: a 3.5 cm x 44 cm chair leg under a 45 x 42 x 4 cm seat it is sunk 1 cm into, its outer
  faces 1 cm inside the seat's edge (the artist room's Chair legs: the seat's shadow on the leg's
  top few centimetres).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 /work/main/.venv/bin/python benchmarks/contact_strips.py \
        [--scenes stand,sunk,wall,leg] [--spacing 0.25] [--grid 48] [--set layouts.X=V ...] [--json NAME]

Per scene and object face group: the rendered mean (the corner values interpolated over the
face at a grid x grid of points, as a render does) and the dense gather's mean at the same points
(each on the transport patch under it), per strip, and their difference as points of the object's
visible mean (so the strips add up to the object's error over what it shows, hidden strip apart).
"""

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

STRIP = 0.035  # the contact strip's width (art30's split: texels within 3.5 cm of another object)
# the sides' height bands printed per scene (the contact at the floor, and for the leg at the seat)
BANDS = {
    "stand": [0, 0.01, 0.035, 0.1, 0.25, 0.5],
    "sunk": [0, 0.01, 0.035, 0.1, 0.25, 0.45],
    "wall": [0, 0.01, 0.035, 0.1, 0.25, 0.5],
    "leg": [0, 0.035, 0.1, 0.22, 0.34, 0.395, 0.43],
}


def _box(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)]
    v += [(x, y, z1) for x, y, _ in v]
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    return [[v[i] for i in f] for f in faces]


def scene(name):
    """[(object name, [quad corners (4, 3)], rho, emission)], the solids' boxes (lo, hi) a point may
    lie inside (hidden), and the planes (point, normal, outline lo, hi) a point may lie behind."""
    floor = [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]
    lamp = [(0.3, -1.0, 1.5), (0.3, 0.0, 1.5), (1.3, 0.0, 1.5), (1.3, -1.0, 1.5)]  # facing down
    objs = [("floor", [floor], 0.5, 0.0), ("lamp", [lamp], 0.0, 1.0)]
    solids, planes = [], [((0, 0, 0), (0, 0, 1.0), (-2, -2), (2, 2))]
    if name in ("stand", "sunk", "wall"):
        lo = {"stand": (0, 0, 0), "sunk": (0, 0, -0.05), "wall": (0, 0, 0)}[name]
        box = (lo, (lo[0] + 0.5, lo[1] + 0.5, lo[2] + 0.5))
        if name == "wall":  # a wall 2 mm behind the box's +y side, facing -y
            w = [(-2, 0.502, 0), (2, 0.502, 0), (2, 0.502, 2), (-2, 0.502, 2)]
            objs.append(("wall", [w], 0.5, 0.0))
        objs.append(("box", _box(*box), 0.5, 0.0))
    elif name == "leg":
        seat = ((-0.225, -0.21, 0.43), (0.225, 0.21, 0.47))
        leg = ((0.2175 - 0.035 - 0.0075, 0.21 - 0.0125 - 0.035, 0.0), (0.2175 - 0.0075, 0.21 - 0.0125, 0.44))
        objs.append(("seat", _box(*seat), 0.5, 0.0))
        objs.append(("leg", _box(*leg), 0.5, 0.0))
        solids.append(seat)
    else:
        raise ValueError(name)
    return objs, solids, planes


def _grid(c, n):
    c = np.asarray(c, float)
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    u, v = u.ravel()[:, None], v.ravel()[:, None]
    verts = (1 - u) * (1 - v) * c[0] + u * (1 - v) * c[1] + u * v * c[2] + (1 - u) * v * c[3]
    k = lambda i, j: i * (n + 1) + j  # noqa: E731
    return verts, [[k(i, j), k(i + 1, j), k(i + 1, j + 1), k(i, j + 1)] for i in range(n) for j in range(n)]


def meshes(objs, spacing):
    """(coarse MeshInput, fine MeshInput, fine polygon -> coarse polygon): each quad split at
    `spacing` as own_values.levels does (level L: 2^L x 2^L), the emitter as it is."""
    from hr_addon.blender.own_values import levels
    from hr_addon.core.geometry import MeshInput

    verts, polys, rho, em, oid = [], [], [], [], []
    fv, fq, frho, fem, foid, fpoly = [], [], [], [], [], []
    for o, (name, quads, r, e) in enumerate(objs):
        for q in quads:
            q = np.asarray(q, float)
            polys.append(list(range(len(verts), len(verts) + 4)))
            verts += [tuple(x) for x in q]
            rho.append((r,) * 3)
            em.append((e,) * 3)
            oid.append(o)
            longest = np.float32(max(np.linalg.norm(q[(i + 1) % 4] - q[i]) for i in range(4)))
            lv = 0 if e > 0 else int(levels(np.array([longest]), spacing)[0])
            v, f = _grid(q, 2**lv)
            fq += [[len(fv) + j for j in p] for p in f]
            fv += [tuple(x) for x in v]
            frho += [(r,) * 3] * len(f)
            fem += [(e,) * 3] * len(f)
            foid += [o] * len(f)
            fpoly += [len(polys) - 1] * len(f)
    names = [o[0] for o in objs]
    coarse = MeshInput.from_polygons(verts, polys, np.array(rho), np.array(em), np.array(oid), names)
    fine = MeshInput.from_polygons(fv, fq, np.array(frho), np.array(fem), np.array(foid), names)
    return coarse, fine, np.array(fpoly)


def hidden(p, solids, planes, own_box):
    """(M,) points inside a solid box or behind a plane's outline (for an object that crosses it)."""
    h = np.zeros(len(p), bool)
    for lo, hi in solids:
        h |= np.all((p > np.asarray(lo) + 1e-9) & (p < np.asarray(hi) - 1e-9), 1)
    for o, n, lo, hi in planes:
        s = (p - np.asarray(o)) @ np.asarray(n)
        if own_box is not None and not (own_box[0] @ np.asarray(n) < o @ np.asarray(n) - 1e-9):
            continue  # the object does not cross the plane
        h |= (s < -1e-9) & np.all((p[:, :2] > lo) & (p[:, :2] < hi), 1)
    return h


def contact_dist(p, solids, planes, others):
    """(M,) distance of each point to the nearest other object (the boxes of the solids, the floor
    plane, other planes given as boxes)."""
    d = np.full(len(p), np.inf)
    for o, n, _, _ in planes:
        d = np.minimum(d, np.abs((p - np.asarray(o)) @ np.asarray(n)))
    for lo, hi in list(solids) + list(others):
        q = np.clip(p, lo, hi)
        d = np.minimum(d, np.linalg.norm(p - q, axis=1))
    return d


def run(name, spacing, grid, seed_rays=64):
    from hr_addon.blender.settings import gather_params
    from hr_addon.core.gather import FinalGather, LoopGather, OutputLayout
    from hr_addon.core.output import corner_weights
    from hr_addon.core.radiosity import RadiositySystem
    from hr_addon.core.refine import RefineParams

    objs, solids, planes = scene(name)
    coarse, fine, poly = meshes(objs, spacing)
    s = RadiositySystem(coarse, RefineParams.for_gather("draft"))
    out = OutputLayout(s, fine, poly)
    t0 = time.process_time()
    g = LoopGather(s, output=out, **dict(gather_params("draft"), rays=seed_rays))
    loops = g.loop_radiance(s).astype(np.float64).mean(1)
    cpu = time.process_time() - t0
    lp = out.patches
    names = [o[0] for o in objs]
    # the other objects' boxes (for the contact distance): every object but the floor, lamp and self
    boxes = {}
    for o, (nm, quads, _, _) in enumerate(objs):
        q = np.concatenate([np.asarray(x, float) for x in quads])
        boxes[nm] = (q.min(0), q.max(0))
    res = {"cpu_loop_gather": cpu, "objects": {}}
    u = (np.arange(grid) + 0.5) / grid
    U, V = (x.ravel()[:, None] for x in np.meshgrid(u, u, indexing="ij"))
    for o, nm in enumerate(names):
        if nm in ("floor", "lamp", "wall", "seat"):
            continue
        others = [boxes[k] for k in names if k not in (nm, "floor", "lamp")]
        faces = np.flatnonzero(fine.object_id == o)
        P, R, H, Dc, F = [], [], [], [], []
        for f in faces:
            k = np.flatnonzero(lp.poly == f)
            if len(k) != 1:
                continue
            k = int(k[0])
            q = lp.corners[k]
            p = (1 - U) * (1 - V) * q[0] + U * (1 - V) * q[1] + U * V * q[2] + (1 - U) * V * q[3]
            w = corner_weights(np.repeat(q[None], len(p), 0), np.full(len(p), 4), lp.normal[[k] * len(p)], p)
            R.append(w @ loops[g.average[4][k]])
            P.append(p)
            H.append(hidden(p, solids, planes, boxes[nm]))
            Dc.append(contact_dist(p, [b for b in solids], planes, others))
            F.append(np.full(len(p), k))
        p, r, h, dc, fc = (np.concatenate(x) for x in (P, R, H, Dc, F))
        tp = out.transport(fc, p)
        dense = FinalGather(s, p, s.patches.normal[tp], tp, **dict(gather_params("draft"), rays=64))
        dv = dense.evaluate(s, "radiance").mean(1)
        dv[dense.dark] = 0.0
        vis = ~h
        tot = dv[vis].sum()
        row = {"visible_mean_dense": float(dv[vis].mean()), "visible_mean_ours": float(r[vis].mean())}
        row["visible_error_pct"] = 100 * (r[vis].sum() / tot - 1)
        for lab, m in (
            ("hidden", h),
            ("contact", vis & (dc < STRIP)),
            ("beyond", vis & (dc >= STRIP)),
        ):
            row[lab] = {
                "share": float(m.mean()),
                "dense": float(dv[m].mean()) if m.any() else None,
                "ours": float(r[m].mean()) if m.any() else None,
                "points_of_visible": float(100 * (r[m] - dv[m]).sum() / tot),
            }
        # per texel over the whole object (hidden included, black there: Cycles' bake), as the
        # artist room's per-texel measure counts a part no closed solid hides
        ref_all = np.where(h, 0.0, dv)
        row["all_error_pct"] = 100 * (r.sum() / ref_all.sum() - 1)
        # the sides' profile (faces whose normal is horizontal) by height bands, visible points
        side = np.abs(lp.normal[fc][:, 2]) < 0.5
        zb = BANDS[name]
        row["side_bands"] = []
        for lo, hi in zip(zb[:-1], zb[1:]):
            m = side & vis & (p[:, 2] >= lo) & (p[:, 2] < hi)
            if m.any():
                row["side_bands"].append(
                    {
                        "z": [lo, hi],
                        "dense": float(dv[m].mean()),
                        "ours": float(r[m].mean()),
                        "error_pct": float(100 * (r[m].mean() / max(dv[m].mean(), 1e-30) - 1)),
                    }
                )
        res["objects"][nm] = row
        print(
            f"{name:6s} {nm:4s} visible {row['visible_error_pct']:+6.2f}% (all texels, hidden black: "
            f"{row['all_error_pct']:+6.2f}%) | "
            + " | ".join(
                f"{lab} {100 * row[lab]['share']:4.1f}%: dense {row[lab]['dense'] or 0:.4f} ours "
                f"{row[lab]['ours'] or 0:.4f} ({row[lab]['points_of_visible']:+6.2f} pts)"
                for lab in ("hidden", "contact", "beyond")
            ),
            flush=True,
        )
        bands = (
            f"{b['z'][0]:.3f}-{b['z'][1]:.3f} dense {b['dense']:.4f} ours {b['ours']:.4f} "
            f"({b['error_pct']:+.1f}%)"
            for b in row["side_bands"]
        )
        print("        sides by height: " + " | ".join(bands), flush=True)
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="stand,sunk,wall,leg")
    ap.add_argument("--spacing", type=float, default=0.25)
    ap.add_argument("--grid", type=int, default=48)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--json")
    a = ap.parse_args()
    from hr_addon.core.gather import corner_fit, layouts

    for kv in a.set:
        k, v = kv.split("=", 1)
        mod, nm = k.split(".")
        setattr({"layouts": layouts, "corner_fit": corner_fit}[mod], nm, eval(v))
    out = {"spacing": a.spacing, "grid": a.grid, "set": a.set, "scenes": {}}
    for sc in a.scenes.split(","):
        out["scenes"][sc] = run(sc, a.spacing, a.grid)
    if a.json:
        with open(os.path.join(HERE, "out", a.json + ".json"), "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
