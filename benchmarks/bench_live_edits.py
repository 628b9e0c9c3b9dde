"""Strength and colour edits in Live written within live_session.EDIT_WRITE_THRESHOLD (session 33,
branch livebake; docs/live.md): how many objects an edit changes above it, and what the main thread
pays per edit (the write and Blender's re-evaluation, view_layer.update()) with the threshold and
without (every object whose bits changed), then the settling write of what the threshold left out.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_live_edits.py \
        [--scene furnished|two_rooms] [--size 100k] [--out benchmarks/out/live_edits.json]

furnished: bench_live's room (FE draft, Live on), the window's strength and colour edits
(bench_live.edit_sequence), then 6 drag steps' previews (counted only: a preview's write is
budgeted, session 29). two_rooms: hr_testing.two_rooms at frame 3 (its light shapes on), strength
edits of its lights one at a time (the bedroom's area light, the living room's ceiling panel, the
floor lamp) and a colour edit of the window. Each edit's result is computed once and written
twice, by both ways in a rotating order, each keeping its own record of what HR_Radiance holds
(as bench_live_budget.py: the re-evaluation depends on which meshes are written, not on their
values). CPU ms (process time)."""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def _two_rooms():
    import bpy

    from hr_testing.two_rooms import two_rooms_scene

    scene, _ = two_rooms_scene()
    scene.frame_set(3)
    scene.hr.method, scene.hr.quality, scene.hr.final_gather = "FE", "DRAFT", True
    for o in scene.objects:  # (Live reads the shapes as they are: no keys to follow)
        o.animation_data_clear()
    scene.hr.live = True
    c0 = time.process_time()
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    print(f"built: {time.process_time() - c0:.1f} s CPU", flush=True)
    lights = bpy.data.lights
    window, panel = (
        next(n for n in bpy.data.materials[f"{s} emission"].node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        for s in ("Window", "Ceiling panel")
    )

    def times(owner, attr, k):
        return lambda: setattr(owner, attr, getattr(owner, attr) * k)

    edits = [
        ("bedroom light x1.2", times(lights["Bedroom panel"], "energy", 1.2)),
        ("bedroom light x0.9", times(lights["Bedroom panel"], "energy", 0.9)),
        ("ceiling panel x1.2", times(panel.inputs["Emission Strength"], "default_value", 1.2)),
        ("ceiling panel x0.9", times(panel.inputs["Emission Strength"], "default_value", 0.9)),
        ("floor lamp x1.2", times(lights["Floor lamp"], "energy", 1.2)),
        (
            "window colour",
            lambda: setattr(window.inputs["Emission Color"], "default_value", (1.0, 0.8, 0.6, 1.0)),
        ),
    ]
    return scene, bpy.context.view_layer, edits, []


def _furnished(tmp, size):
    import bench_live as bl

    scene, obj, kind, along, normal, step, vl, _ = bl.furnished_live(tmp, size)
    seq = bl.edit_sequence(obj, kind, along, normal, step)
    edits = [(k, e) for k, e in seq if k in ("strength", "colour")]
    moves = [e for k, e in seq if k == "move"][:6]
    return scene, vl, edits, moves


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="furnished", choices=("furnished", "two_rooms"))
    ap.add_argument("--size", default="100k")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "live_edits.json"))
    args = ap.parse_args()
    import bpy
    import hr_addon

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    from hr_addon.blender import live, live_session, playback
    from hr_addon.blender.live_worker import PREVIEW

    tmp = tempfile.mkdtemp(prefix="hr_live_edits_")
    scene, vl, edits, moves = _two_rooms() if args.scene == "two_rooms" else _furnished(tmp, args.size)
    sess = live.session(scene)
    w = sess.worker
    keys = sess.written.extract.span_keys
    thr = live_session.EDIT_WRITE_THRESHOLD
    print(f"{len(keys)} objects with rows; threshold {thr:.5f}", flush=True)

    def result_of(edit):
        edit()
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        w.flush(refine=False)
        _, r = w.take()
        assert r is not None and r.values is not None and not r.error, r and r.error
        return r

    def write(values, skip):
        c1 = time.process_time()
        problems = playback.apply_arrays(
            scene, values, sess.domain, reader=sess.scene_name, objects=sess.objects, skip=skip
        )
        assert not problems, problems
        c2 = time.process_time()
        vl.update()
        return 1000 * (c2 - c1), 1000 * (time.process_time() - c2)

    modes = ("exact", "threshold")
    shown = dict.fromkeys(modes, sess.written)
    rows = []
    for j, (name, edit) in enumerate(edits):
        r = result_of(edit)
        rel = r.values.change(shown["exact"])
        same = r.values.unchanged(shown["exact"])
        row = {
            "edit": name,
            "events": sorted({e.kind for e in r.report.events}),
            "objects": len(keys),
            "bits_changed": len(keys) - len(same),
            "above_threshold": int((rel > thr).sum()),
            "above_1e-3": int((rel > 1e-3).sum()),
            "above_1e-2": int((rel > 1e-2).sum()),
            "change_median": float(np.median(rel)),
        }
        for m in modes[j % 2 :] + modes[: j % 2]:
            if m == "exact":
                skip, held = r.values.unchanged(shown[m]), r.values
            else:
                skip, held, _ = live_session._within_threshold(r.values, shown[m], thr)
            row[f"{m}_written"] = len(keys) - len(skip)
            row[f"{m}_write_ms"], row[f"{m}_eval_ms"] = write(r.values, skip)
            shown[m] = held
        rows.append(row)
        print(
            f"{name}: bits changed {row['bits_changed']}, above {thr:.4f} {row['above_threshold']}, "
            f"above 1e-3 {row['above_1e-3']}, 1e-2 {row['above_1e-2']} (median change "
            f"{row['change_median']:.4f}); exact {row['exact_written']} w {row['exact_write_ms']:.0f}"
            f"+{row['exact_eval_ms']:.0f} ms, threshold {row['threshold_written']} w "
            f"{row['threshold_write_ms']:.0f}+{row['threshold_eval_ms']:.0f} ms",
            flush=True,
        )
    skip = r.values.unchanged(shown["threshold"])
    settle = {"written": len(keys) - len(skip)}
    settle["write_ms"], settle["eval_ms"] = write(r.values, skip)
    print(f"settling write after the edits: {settle}", flush=True)
    drag = []
    if moves:
        w.preview = PREVIEW
        w.flush()
        _, ex = w.take()
        shown_now = ex.values if ex is not None else r.values
        write(shown_now, None)
        for edit in moves:
            p = result_of(edit)
            rel = p.values.change(shown_now)
            drag.append({"above_threshold": int((rel > thr).sum()), "above_1e-3": int((rel > 1e-3).sum())})
            shown_now = p.values
        print(f"drag steps (previews, each against the one before): {drag}", flush=True)
    summary = {
        m: {k: float(np.median([x[f"{m}_{k}"] for x in rows])) for k in ("written", "write_ms", "eval_ms")}
        for m in modes
    }
    print(f"median over the {len(rows)} edits: {summary}", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(
        json.dumps(
            {"scene": args.scene, "rows": rows, "settle": settle, "drag": drag, "summary": summary}, indent=1
        )
    )
    scene.hr.live = False
    bpy.ops.hr.live_update()


if __name__ == "__main__":
    main()
