"""Live Relight's edits on the furnished 100k room, core only (no bpy): the stored build
(bench_gather_events.py --cache) loaded, then Live's engine (DynamicRadiosity with Live's solver
options, the stored LoopGather) runs a window added on the light wall, drag steps along it, colour
and strength edits, as live_worker runs them. CPU seconds (time.process_time) per edit, split into
apply and output, and the parts of live_replay.PARTS summed over the drag steps.

    .venv/bin/python benchmarks/live_100k.py --cache /work/cache/c100k [--method FE] [--steps 6]
        [--preview] [--options live|gather|old] [--json out.json] [--dump previews.npz]

--preview: every drag step is Live's preview (live_worker.PREVIEW), the exact light follows once at
the end (refine, timed apart); else every step is exact (an unthreaded worker, hr.live_update()).
--options: "live" the worker's (live_worker: the bake's solver options with the gather), "old"
Live's before the fixed response steps (responses to 1e-5 in float32, the base to the system's).
Not in here: reading the shapes in bpy and writing HR_Radiance (docs/live.md: 70-90 ms for 3,882
objects). Benchmarks print; no test asserts on time.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import numpy as np  # noqa: E402


def _preview_error(mesh, p, e):
    """A preview p against the exact loop values e (L, 3) of the same state: per object, the
    relative difference of the mean over its corners (the channels summed), over the objects whose
    mean is above 1e-3 of the brightest's; per corner, live_replay._errors."""
    import live_replay

    obj = np.repeat(mesh.object_id, mesh.loop_total)
    cnt = np.maximum(np.bincount(obj), 1)
    mp, me = (np.bincount(obj, x.astype(np.float64).sum(1)) / cnt for x in (p, e))
    lit = me > 1e-3 * me.max()
    rel = np.abs(mp - me)[lit] / me[lit]
    c = live_replay._errors(p, e)
    return dict(
        objects=int(lit.sum()),
        object_median=float(np.median(rel)),
        object_p95=float(np.percentile(rel, 95)),
        object_max=float(rel.max()),
        corner_max=float(c[0]),
        corner_median=float(c[1]),
        corner_rms=float(c[2]),
        corner_bias=float(c[3]),
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", required=True, help="folder of bench_gather_events.py's stored build")
    ap.add_argument("--size", default="100k")
    ap.add_argument("--method", default="FE")
    ap.add_argument("--steps", type=int, default=6, help="drag steps")
    ap.add_argument("--step", type=float, default=0.05, help="metres per drag step")
    ap.add_argument("--preview", action="store_true")
    ap.add_argument("--options", default="live", choices=("live", "old"))
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="the preview's Preview fields instead of Live's (e.g. levels=2 reuse_share=0.5)",
    )
    ap.add_argument("--json", default=None)
    ap.add_argument("--dump", default=None, help="npz of the drag steps' outputs (loop values)")
    args = ap.parse_args(argv)

    from hr_testing import shapes as S
    from hr_testing.furnished import furnished_room
    from hr_addon.blender.live_worker import PREVIEW, RESPONSE_TOL
    from hr_addon.blender.settings import solve_options
    from hr_addon.core.events import DynamicRadiosity, LightShape
    from hr_addon.io import precompute as pc
    import live_replay

    import dataclasses

    fields = {f.name: f.type for f in dataclasses.fields(PREVIEW)}
    kw = dict(a.split("=", 1) for a in args.set)
    conv = {bool: lambda v: v.lower() in ("1", "true")}
    preview = dataclasses.replace(PREVIEW, **{k: conv.get(fields[k], fields[k])(v) for k, v in kw.items()})
    cpu = time.process_time
    _, info = furnished_room(args.size)
    from bench_gather_events import load_store

    s, g, _ = load_store(Path(args.cache) / pc.FILENAME)
    s.links.extended(s.h)  # the solver's far-link terms (a loaded build's first event pays them)
    opts = (
        solve_options("DRAFT", True)
        if args.options == "live"
        else dict(response_tol=RESPONSE_TOL, response_float32=True)
    )
    c0 = cpu()
    dyn = DynamicRadiosity(s, method=args.method, **opts)
    g.loop_radiance(dyn)
    out = dict(
        size=args.size,
        method=args.method,
        options=args.options,
        dyn_options=opts,
        preview=repr(preview) if args.preview else None,
        load_average=os.getloadavg()[0],
        start_cpu_s=cpu() - c0,
    )
    _, frame = info["light_wall"]

    def window(cx, em=(20.0, 20.0, 20.0)):
        rect = S.on_plane(S.rect(0.9, 0.7, centre=(cx, 0.6), angle=0.2), frame)
        return {"w": LightShape(rect, np.asarray(em, float), "window")}

    acc = live_replay._timed_parts()
    rows, last = [], [None]

    def edit(kind, shapes, preview=None):
        c0 = cpu()
        rep = dyn.apply(shapes, preview=preview)
        c1 = cpu()
        last[0] = g.loop_radiance(dyn)
        c2 = cpu()
        rows.append(
            dict(
                kind=kind,
                cpu_ms=1000 * (c2 - c0),
                apply_ms=1000 * (c1 - c0),
                output_ms=1000 * (c2 - c1),
                iterations=int(rep.iterations),
            )
        )
        print(
            f"{kind:9s} {rows[-1]['cpu_ms']:8.1f} ms CPU (apply {rows[-1]['apply_ms']:7.1f}, output "
            f"{rows[-1]['output_ms']:7.1f}), {rep.iterations} it",
            flush=True,
        )

    x = 0.7
    edit("add", window(x))
    for v in acc.values():
        v[:] = [0.0, 0]
    steps = []
    for _ in range(args.steps):
        x += args.step
        edit("drag", window(x), preview if args.preview else None)
        steps.append(last[0].astype(np.float32))
    if args.dump:
        np.savez_compressed(args.dump, *steps)
    drag_parts = {k: v[0] for k, v in acc.items()}
    if args.preview:
        c0 = cpu()
        dyn.refine()
        c1 = cpu()
        exact = g.loop_radiance(dyn)
        rows.append(
            dict(
                kind="refine",
                cpu_ms=1000 * (cpu() - c0),
                apply_ms=1000 * (c1 - c0),
                output_ms=1000 * (cpu() - c1),
            )
        )
        print(f"refine    {rows[-1]['cpu_ms']:8.1f} ms CPU (apply {rows[-1]['apply_ms']:7.1f})", flush=True)
        out["last_preview_error"] = err = _preview_error(s.mesh, last[0], exact)
        print(
            "the last preview against the refine (the same state): per object (mean over its corners) "
            "median {object_median:.2e} p95 {object_p95:.2e} max {object_max:.2e} over {objects} lit "
            "objects; "
            "per corner max {corner_max:.2e} median {corner_median:.2e} RMS {corner_rms:.2e} bias "
            "{corner_bias:+.2e}".format(**err),
            flush=True,
        )
    for i in range(4):
        edit("colour", window(x, (20.0, 20.0 + i, 20.0 + 2 * i)))
    for i in range(4):
        edit("strength", window(x, (20.0 + 5 * i, 20.0 + 5 * i, 20.0 + 5 * i)))
    for kind in ("drag", "colour", "strength"):
        v = [r["cpu_ms"] for r in rows if r["kind"] == kind]
        out[f"{kind}_median_ms"] = float(np.median(v))
        print(f"{kind}: median {np.median(v):.1f} ms CPU over {len(v)}")
    n = args.steps
    print(f"parts over the {n} drag steps, s CPU per step:")
    for k, t in drag_parts.items():
        print(f"  {k:38s} {t / n:7.3f}")
    out["drag_parts_s_per_step"] = {k: t / n for k, t in drag_parts.items()}
    out["rows"] = rows
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
