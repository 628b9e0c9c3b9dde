"""Live's edits without bpy: record the light-shape states bench_live.py's edit sequence hands to
the worker on the Cornell sample, then replay them through DynamicRadiosity + LoopGather as
blender/live_worker.py runs them (CPU seconds per edit, the outputs kept for comparing code
states; docs/live.md, *Fixed costs cut*).

    .venv/bin/python benchmarks/live_replay.py record --quality draft --out states_draft.pkl   # needs bpy
    .venv/bin/python benchmarks/live_replay.py replay states_draft.pkl --method FE --dump a.npz [--profile]
    .venv/bin/python benchmarks/live_replay.py compare a.npz b.npz

`replay --parts` sums the process time of a few functions over edits 1.. (the direct light, its
sampling, rays, form factors and clear-shaft test, the GMRES solves and their operator
applications, the levels' matvecs, AUTO's first bounce, the coverage): cheaper than cProfile,
whose per-call overhead inflates numpy-heavy code.

Run `replay` from two checkouts (the script imports hr_addon from its own tree) on one recording
to compare code states; `compare` prints, per edit, "bitwise" or the differences at the corners
lit above 1e-3 of the brightest. Benchmarks print; no test asserts on time.
"""

import argparse
import dataclasses
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def record(quality, out):
    import bpy

    import bench_live as bl
    import hr_addon

    hr_addon.register()
    from hr_addon.blender import live

    scene, obj, kind, along, normal, step = bl.open_cornell(tempfile.mkdtemp(prefix="hr_live_replay_"))
    scene.hr.method, scene.hr.quality, scene.hr.final_gather = "FE", quality.upper(), True
    vl = bpy.context.view_layer
    scene.hr.live = True
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    sess = live.session(scene)
    w = sess.worker
    states = []
    for k, edit in bl.edit_sequence(obj, kind, along, normal, step):
        edit()
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        states.append((k, w._last_shapes[2]))  # the full light state the worker was handed
        w.flush()
        live._deliver(sess, scene)
    s = w.spec
    keep = dict(mesh=s.mesh, params=s.params, gather=s.gather, min_area_rel=s.min_area_rel, domain=s.domain)
    Path(out).write_bytes(pickle.dumps(dict(keep, states=states)))
    print(f"{len(states)} states -> {out}")


PARTS = [  # (module, attribute, label) timed by --parts
    ("hr_addon.core.gather.direct", "DirectLight.direct_light", "direct light"),
    ("hr_addon.core.gather.sampling", "Emitter.sample_at", "  its sampling"),
    ("hr_addon.core.gather.direct", "shape_form_factors", "  form factors (and AUTO's)"),  # two names
    ("hr_addon.core.events.direct", "shape_form_factors", "  form factors (and AUTO's)"),  # of one function
    ("hr_addon.core.planes", "ClearShafts.clear", "  clear-shaft test (and AUTO's)"),
    ("hr_addon.core.solver", "_gmres", "response solves"),
    ("hr_addon.core.solver", "_gmres_steps", "response solves"),  # fixed steps (the gather's)
    ("hr_addon.core.solver", "Operator.gather", "  operator gathers"),
    ("hr_addon.core.gather.final", "_csr_matvec", "levels' matvecs"),
    ("hr_addon.core.events.direct", "FirstBounce.direct", "AUTO's first bounce"),
    ("hr_addon.core.events.coverage", "Coverage.cover", "coverage"),
    ("hr_addon.core.gather.final", "FinalGather._preview_part", "preview's D + I (both in the output)"),
    ("hr_addon.core.gather.final", "FinalGather._preview_shape", "  preview's direct light"),
    ("hr_addon.core.events.dynamic", "DynamicRadiosity.apply", "apply"),
    ("hr_addon.core.events.dynamic", "DynamicRadiosity.refine", "refine"),
    ("hr_addon.core.gather.final", "FinalGather.evaluate_kinds", "output (gather)"),
]


def _timed_parts():
    """Wrap PARTS with process-time accumulators: {label: [seconds, calls]}."""
    import importlib

    acc = {}
    for mod, attr, label in PARTS:
        owner = importlib.import_module(mod)
        *path, name = attr.split(".")
        for p in path:
            owner = getattr(owner, p)
        f = getattr(owner, name)
        acc.setdefault(label, [0.0, 0])

        def timed(*a, _f=f, _k=label, **kw):
            c0 = time.process_time()
            try:
                return _f(*a, **kw)
            finally:
                acc[_k][0] += time.process_time() - c0
                acc[_k][1] += 1

        setattr(owner, name, timed)
    return acc


def replay(path, method, dump=None, profile=False, parts=False):
    from hr_addon.blender.live_worker import RESPONSE_TOL
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.gather import LoopGather
    from hr_addon.core.lights import Light
    from hr_addon.core.radiosity import RadiositySystem

    d = pickle.loads(Path(path).read_bytes())
    c0 = time.process_time()
    s = RadiositySystem(d["mesh"], d["params"])
    dyn = DynamicRadiosity(
        s, method=method, min_area_rel=d["min_area_rel"], response_tol=RESPONSE_TOL, response_float32=True
    )
    g = LoopGather(dyn, **d["gather"])
    print(f"build {time.process_time() - c0:.1f} s CPU", flush=True)
    acc = _timed_parts() if parts else None
    prof = None
    if profile:
        import cProfile

        prof = cProfile.Profile(time.process_time)
    out, rows = {}, []
    for i, (kind, shapes) in enumerate(d["states"]):
        if acc is not None and i == 1:  # the first edit adds every shape: not a typical one
            for v in acc.values():
                v[:] = [0.0, 0]
        c0 = time.process_time()
        if prof:
            prof.enable()
        lights = {k: v for k, v in shapes.items() if isinstance(v, Light)}
        rep = dyn.apply({k: v for k, v in shapes.items() if k not in lights}, lights)
        c1 = time.process_time()
        out[str(i)] = g.loop_radiance(dyn, d["domain"])
        if prof:
            prof.disable()
        c2 = time.process_time()
        rows.append((kind, c2 - c0, c1 - c0, c2 - c1, rep.iterations))
        print(
            f"{i:2d} {kind:8s} CPU {1000 * (c2 - c0):7.1f} ms (apply {1000 * (c1 - c0):6.1f}, output "
            f"{1000 * (c2 - c1):6.1f}), {rep.iterations} iterations",
            flush=True,
        )
    cpu = np.array([r[1] for r in rows])
    geo = np.array([r[1] for r in rows if r[0] in ("move", "scale", "rotate", "reshape")])
    print(
        f"{method}: all edits median {1000 * np.median(cpu):.1f} / p95 {1000 * np.percentile(cpu, 95):.1f} "
        f"ms CPU; geometry edits median {1000 * np.median(geo):.1f}; total {cpu.sum():.2f} s"
    )
    if acc is not None:
        print(f"edits 1..{len(cpu) - 1}: {cpu[1:].sum():.2f} s CPU; parts (s CPU, calls):")
        for label, (t, n) in acc.items():
            print(f"  {label:32s} {t:6.2f} {n:5d}")
    if dump:
        np.savez(dump, **out)
    if prof:
        import pstats

        pstats.Stats(prof).sort_stats("cumulative").print_stats(50)


GEOMETRY = ("move", "scale", "rotate", "reshape")


def _errors(x, y):
    """Preview x against exact y (corners, 3), at the corners lit above 1e-3 of the brightest:
    (max, median, RMS of the per-corner relative error (largest channel), mean signed relative
    difference (bias))."""
    m = np.abs(y).max(1)
    lit = m > 1e-3 * m.max()
    rel = (np.abs(x - y).max(1) / np.maximum(m, 1e-30))[lit]
    signed = ((x - y).sum(1) / np.maximum(y.sum(1), 1e-30))[lit]
    return rel.max(), np.median(rel), np.sqrt(np.mean(rel**2)), signed.mean()


def replay_preview(path, method, exact, preview, check=False, parts=False):
    """Progressive Live over the recorded edits, as live_worker runs it: every geometry edit a
    preview (events.Preview), a refine after the last of each run of edits of one kind (the drag
    pauses) and on every other edit. CPU ms of the previews and refines; each preview against
    `exact` (an npz of `replay --dump`: every state solved exactly, today's Live); check: a second
    system replays only the states Live computed exactly, with today's apply, and the refined
    outputs are compared with its bitwise."""
    from hr_addon.blender.live_worker import RESPONSE_TOL
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.gather import LoopGather
    from hr_addon.core.lights import Light
    from hr_addon.core.radiosity import RadiositySystem

    d = pickle.loads(Path(path).read_bytes())
    ref = np.load(exact)

    def make():
        s = RadiositySystem(d["mesh"], d["params"])
        dyn = DynamicRadiosity(
            s, method=method, min_area_rel=d["min_area_rel"], response_tol=RESPONSE_TOL, response_float32=True
        )
        return dyn, LoopGather(dyn, **d["gather"])

    def split(shapes):
        lights = {k: v for k, v in shapes.items() if isinstance(v, Light)}
        return {k: v for k, v in shapes.items() if k not in lights}, lights

    dyn, g = make()
    twin = make() if check else None
    acc = _timed_parts() if parts else None
    states = d["states"]
    pv, rf, errs, bitwise = [], [], [], []
    for i, (kind, shapes) in enumerate(states):
        drag = i > 0 and kind in GEOMETRY
        pause = not drag or i + 1 == len(states) or states[i + 1][0] != kind
        c0 = time.process_time()
        rep = dyn.apply(*split(shapes), preview=preview if drag else None)
        ca = time.process_time()
        out = g.loop_radiance(dyn, d["domain"])
        c1 = time.process_time()
        line = f"{i:2d} {kind:8s}"
        if drag:
            pv.append(c1 - c0)
            e = _errors(out, ref[str(i)])
            errs.append(e)
            line += (
                f" preview {1000 * (c1 - c0):6.1f} ms (apply {1000 * (ca - c0):5.1f}, {rep.iterations} it.), "
                f"max {e[0]:.2e} median {e[1]:.2e} RMS {e[2]:.2e} bias {e[3]:+.1e}"
            )
        if pause:
            c1 = time.process_time()
            rep = dyn.refine()
            if rep.events or not drag:
                out = g.loop_radiance(dyn, d["domain"])
            c2 = time.process_time()
            if drag:
                rf.append(c2 - c1)
                line += f"; refine {1000 * (c2 - c1):6.1f} ms"
            if twin is not None:
                twin[0].apply(*split(shapes))
                same = np.array_equal(out, twin[1].loop_radiance(twin[0], d["domain"]))
                bitwise.append(same)
                line += "; refined = exact-only replay: " + ("bitwise" if same else "DIFFERS")
        print(line, flush=True)
    pv, rf, errs = np.array(pv), np.array(rf), np.array(errs)
    print(f"{preview}")

    def ms(x):
        return f"median {1000 * np.median(x):.1f} / p95 {1000 * np.percentile(x, 95):.1f} ms CPU"

    print(f"previews ({len(pv)}): {ms(pv)}; refines ({len(rf)}): {ms(rf)}")
    print(
        "preview errors, median (max) over the previews: max corner {:.2e} ({:.2e}), median {:.2e} ({:.2e}), "
        "RMS {:.2e} ({:.2e}), bias {:+.2e} (mean {:+.2e})".format(
            np.median(errs[:, 0]),
            errs[:, 0].max(),
            np.median(errs[:, 1]),
            errs[:, 1].max(),
            np.median(errs[:, 2]),
            errs[:, 2].max(),
            np.median(errs[:, 3]),
            errs[:, 3].mean(),
        )
    )
    if acc is not None:
        print("parts over all edits, the first included (s CPU, calls):")
        for label, (t, n) in acc.items():
            print(f"  {label:38s} {t:6.2f} {n:5d}")
    if check:
        print(f"refined outputs bitwise equal to the exact-only replay: {sum(bitwise)} of {len(bitwise)}")


def compare(a, b):
    a, b = np.load(a), np.load(b)
    for k in sorted(a.files, key=int):
        x, y = a[k], b[k]
        if np.array_equal(x, y):
            print(k, "bitwise")
            continue
        m = np.abs(x).max(1)
        lit = m > 1e-3 * m.max()
        rel = (np.abs(x - y).max(1) / np.maximum(m, 1e-30))[lit]
        signed = ((y - x).sum(1) / np.maximum(x.sum(1), 1e-30))[lit].mean()
        print(
            f"{k} max {rel.max():.2e} median {np.median(rel):.2e} mean signed {signed:+.2e} "
            f"largest / brightest {np.abs(x - y).max() / np.abs(x).max():.2e}"
        )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--quality", default="draft")
    r.add_argument("--out", required=True)
    p = sub.add_parser("replay")
    p.add_argument("states")
    p.add_argument("--method", default="FE")
    p.add_argument("--dump")
    p.add_argument("--profile", action="store_true")
    p.add_argument("--parts", action="store_true", help="process time of a few functions (see PARTS)")
    v = sub.add_parser("preview", help="progressive Live: previews during drags, refines at pauses")
    v.add_argument("states")
    v.add_argument("--exact", required=True, help="npz of `replay --dump` on the same recording")
    v.add_argument("--method", default="FE")
    v.add_argument("--tol", type=float, default=None)
    v.add_argument("--shadow-rays", type=int, default=None)
    v.add_argument("--levels", type=int, default=None)
    v.add_argument("--second-shadow-rays", type=int, default=None)
    v.add_argument("--preview-method", default=None)
    v.add_argument("--reuse-visibility", type=int, default=None, help="1/0: Preview.reuse_visibility")
    v.add_argument("--reuse-share", type=float, default=None)
    v.add_argument("--guess-share", type=float, default=None)
    v.add_argument("--check", action="store_true", help="refined outputs against an exact-only replay")
    v.add_argument("--parts", action="store_true", help="process time of a few functions (see PARTS)")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "record":
        sys.path.insert(0, str(ROOT / "benchmarks"))
        record(args.quality, args.out)
    elif args.cmd == "replay":
        replay(args.states, args.method, args.dump, args.profile, args.parts)
    elif args.cmd == "preview":
        from hr_addon.blender.live_worker import PREVIEW

        kw = {
            k: getattr(args, a)
            for k, a in (
                ("tol", "tol"),
                ("shadow_rays", "shadow_rays"),
                ("levels", "levels"),
                ("second_shadow_rays", "second_shadow_rays"),
                ("method", "preview_method"),
                ("reuse_visibility", "reuse_visibility"),
                ("reuse_share", "reuse_share"),
                ("guess_share", "guess_share"),
            )
            if getattr(args, a) is not None
        }
        replay_preview(
            args.states, args.method, args.exact, dataclasses.replace(PREVIEW, **kw), args.check, args.parts
        )
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
