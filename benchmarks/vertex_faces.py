"""Per face of some objects: what the vertex output's corners show against a dense gather over the
face (vx30, issue 19). Bakes the furnished sample (draft, vertex output at a Vertex Spacing, one
thread, a fresh precompute) in Blender, keeps the bake's LoopGather, then for each output face of
the named objects prints its normal and size, the rendered mean (the corner values interpolated
over the face's visible test points, as a render does) against the mean of a dense gather over the
same points (the bake's gather settings, each point on the transport patch under it), and where
its corners' samples lie and what they read. The difference is the corner layout's alone (the
gathered light is the same machinery's).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/vertex_faces.py \
        [--blend sample_blends/furnished.blend] [--spacing 0.25] [--grid 64] [--set layouts.X=V ...] \
        [--npz NAME] OBJECT [OBJECT ...]

--set: module constants of hr_addon.core.gather (layouts / corner_fit) set before the bake.
--npz: keep every output loop's value and the faces' figures in benchmarks/out/NAME.npz.
Prints how many corner samples layouts._toward_mouths and _toward_openings moved (vx30's rules).
"""

import argparse
import os
import shutil
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("objects", nargs="*")
    ap.add_argument("--blend", default=os.path.join(ROOT, "sample_blends", "furnished.blend"))
    ap.add_argument("--spacing", type=float, default=0.25)
    ap.add_argument("--grid", type=int, default=64, help="dense points per face (extra_points)")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--npz")
    ap.add_argument("--profile", action="store_true", help="print each face's dense values")
    ap.add_argument("--prefix", action="append", default=[], help="every object whose name starts so")
    a = ap.parse_args()

    from hr_addon.core.gather import corner_fit, layouts

    for kv in a.set:
        k, v = kv.split("=", 1)
        mod, name = k.split(".")
        setattr({"layouts": layouts, "corner_fit": corner_fit}[mod], name, eval(v))
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    from hr_addon.blender import bake as B
    from hr_addon.core.gather import FinalGather
    from hr_addon.core.output import corner_weights

    got = {}
    make = B.make_gather

    def capture(dyn, plan=None, settings=None, **kw):
        g = make(dyn, plan, settings, **kw)
        got.update(g=g, dyn=dyn, settings=dict(settings))
        return g

    B.make_gather = capture
    moved = {}
    for rule in ("_toward_mouths", "_toward_openings"):  # how many corner samples each rule moves

        def counted(system, pts, *rest, _f=getattr(layouts, rule), _r=rule):
            before = pts.copy()
            out = _f(system, pts, *rest)
            moved[_r] = (int((pts != before).any(1).sum()), len(pts))
            return out  # (_toward_mouths': the samples it moved)

        setattr(layouts, rule, counted)
    folder = tempfile.mkdtemp(prefix="vx30_faces_")
    try:
        path = os.path.join(folder, "scene.blend")
        shutil.copy(a.blend, path)
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        scene = bpy.context.scene
        c0 = time.process_time()
        B.run_bake(
            scene,
            log=lambda *x, **k: None,
            frames=(1, 1),
            quality="draft",
            output="VERTEX",
            vertex_spacing=a.spacing,
            threads=1,
            cache_dir=os.path.join(folder, "cache"),
            rebuild=True,
        )
        print(f"bake {time.process_time() - c0:.1f} s CPU", flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    for rule, (m, n) in moved.items():
        print(f"{rule}: moved {m} of {n} corner samples", flush=True)
    g, dyn, settings = got["g"], got["dyn"], got["settings"]
    s = g.system
    lay = g.output
    pt = lay.patches
    loops = g.loop_radiance(dyn).astype(np.float64).mean(1)
    vals = g.evaluate(dyn, "radiance").mean(1)
    names = list(pt.object_names)
    want = [n for n in names if n in a.objects or any(n.startswith(p) for p in a.prefix)]
    pc_loop = g.average[4]
    faces = [k for name in want for k in np.flatnonzero(pt.object_id == names.index(name))]
    # every face's dense points in one gather (each FinalGather is built once: its second level,
    # the emitters' tables)
    qs = [corner_fit.extra_points(pt.corners[[k]], pt.nv[[k]], a.grid)[0] for k in faces]
    Q = np.concatenate(qs) if qs else np.zeros((0, 3))
    K = np.repeat(faces, [len(q) for q in qs]).astype(np.int64)
    tr = lay.transport(K, Q)
    d = FinalGather(dyn, Q, s.patches.normal[tr], tr, **settings)
    DV, DARK = d.evaluate(dyn, "radiance").mean(1), d.dark
    at = np.cumsum([0] + [len(q) for q in qs])
    rows = []
    for i, k in enumerate(faces):
        if i == 0 or pt.object_id[k] != pt.object_id[faces[i - 1]]:
            print(f"{names[pt.object_id[k]]}:", flush=True)
        q, dv, ok = qs[i], DV[at[i] : at[i + 1]], ~DARK[at[i] : at[i + 1]]
        if not ok.any():
            continue
        w = corner_weights(
            np.repeat(pt.corners[k][None], len(q), 0),
            np.full(len(q), pt.nv[k]),
            pt.normal[[k] * len(q)],
            q,
        )
        cl = pc_loop[k, : pt.nv[k]]
        rend = (w[:, : pt.nv[k]] @ loops[cl])[ok].mean()
        dense = dv[ok].mean()
        c = pt.corners[k, : pt.nv[k]]
        size = (np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[-1] - c[0]))
        mine = np.flatnonzero(g.out_patch == k)
        sv = ", ".join(
            f"{vals[j]:.4f}@{tuple(np.round(g.points[j], 3))}{'X' if g.dark[j] else ''}" for j in mine
        )
        err = rend / dense - 1 if dense > 0 else np.nan
        print(
            f"  face {k} n {tuple(np.round(pt.normal[k], 2))} size {size[0]:.3f} x {size[1]:.3f} "
            f"visible {ok.mean():.2f}: rendered {rend:.4f} dense {dense:.4f} ({100 * err:+.1f}%) "
            f"corners {np.round(loops[cl], 4).tolist()}",
            flush=True,
        )
        print(f"    samples {sv}", flush=True)
        if a.profile:  # the dense values on extra_points' grid (rows along the first side)
            a_ = 0.5 * (np.linalg.norm(c[1] - c[0]) + np.linalg.norm(c[2] - c[-1]))
            b_ = 0.5 * (np.linalg.norm(c[-1] - c[0]) + np.linalg.norm(c[2] - c[1]))
            ka = int(np.clip(np.round(np.sqrt(a.grid * a_ / max(b_, 1e-300))), 1, a.grid))
            if pt.nv[k] == 4 and len(q) % ka == 0:
                for r in np.where(ok, dv, np.nan).reshape(ka, -1):
                    print("     ", " ".join(f"{x:.4f}" for x in r))
        rows.append((pt.object_id[k], k, rend, dense, ok.mean(), *pt.normal[k]))
    if a.npz:
        np.savez_compressed(
            os.path.join(HERE, "out", a.npz + ".npz"),
            loops=loops,
            faces=np.array(rows),
            names=np.array(names),
        )


if __name__ == "__main__":
    sys.exit(main())
