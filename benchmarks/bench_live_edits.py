"""Strength and colour edits in Live written within live_session.EDIT_WRITE_THRESHOLD (session 33,
branch livebake; docs/live.md): how many objects an edit changes above it, and what the main thread
pays per edit (the write and Blender's re-evaluation, view_layer.update()) with the threshold and
without (every object whose bits changed), then the settling write of what the threshold left out.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_live_edits.py \
        [--scene furnished|two_rooms|baked --blend BAKED.blend] [--size 100k] [--out OUT.json]

furnished: bench_live's room (FE draft, Live on), the window's strength and colour edits
(bench_live.edit_sequence), then 6 drag steps' previews (each written within Live's budget, timed,
its objects above the threshold counted). two_rooms: hr_testing.two_rooms at frame 3 (its light
shapes on), strength edits of its lights one at a time (the bedroom's area light, the living room's
ceiling panel, the floor lamp) and a colour edit of the window. baked: a baked file's first light
shape, as furnished (its drag steps along the shape's local x), the file opened in place and never
saved. Each edit's result is computed once and written twice, by both ways in a rotating order,
each keeping its own record of what HR_Radiance holds (as bench_live_budget.py: the re-evaluation
depends on which meshes are written, not on their values). CPU ms (process time)."""

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


def _baked(path):
    """A baked file (opened in place, never saved; its modifiers brought to this version's group in
    memory, bench_bpy_frames.regroup) with Live on: its first light shape's strength and colour
    edits as bench_live's, 6 drag steps along the shape's local x."""
    import bpy
    from mathutils import Vector

    import bench_bpy_frames as bf

    bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
    scene = bpy.context.scene
    bf.regroup(bpy, scene, "CORNER")
    scene.hr.method, scene.hr.quality, scene.hr.final_gather = "FE", "DRAFT", True
    for o in scene.objects:
        o.animation_data_clear()
    scene.hr.live = True
    c0 = time.process_time()
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    print(f"built: {time.process_time() - c0:.1f} s CPU", flush=True)
    obj = next(o for o in scene.objects if o.hr.is_light_shape and not o.hide_render)
    node = next(n for n in obj.data.materials[0].node_tree.nodes if n.type in ("EMISSION", "BSDF_PRINCIPLED"))
    strength, colour = (
        node.inputs[k]
        for k in (
            ("Strength", "Color") if node.type == "EMISSION" else ("Emission Strength", "Emission Color")
        )
    )
    edits = [
        ("strength", lambda f=f: setattr(strength, "default_value", strength.default_value * f))
        for f in (1.5, 0.8, 1.2, 0.9, 1.1, 0.7)
    ]
    edits += [
        ("colour", lambda c=c: setattr(colour, "default_value", (*c, 1.0)))
        for c in ((1.0, 0.6, 0.4), (0.5, 0.7, 1.0), (1.0, 1.0, 0.8), (0.8, 1.0, 0.8))
    ]
    d = 0.05 * Vector(obj.matrix_world.col[0][:3]).normalized()
    moves = [lambda: setattr(obj, "location", obj.location + d)] * 6
    print(f"edits of {obj.name!r} ({node.type})", flush=True)
    return scene, bpy.context.view_layer, edits, moves


def _furnished(tmp, size):
    import bench_live as bl

    scene, obj, kind, along, normal, step, vl, _ = bl.furnished_live(tmp, size)
    seq = bl.edit_sequence(obj, kind, along, normal, step)
    edits = [(k, e) for k, e in seq if k in ("strength", "colour")]
    moves = [e for k, e in seq if k == "move"][:6]
    return scene, vl, edits, moves


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="furnished", choices=("furnished", "two_rooms", "baked"))
    ap.add_argument("--blend", help="--scene baked: the baked file (opened in place, never saved)")
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
    if args.scene == "baked":
        scene, vl, edits, moves = _baked(args.blend)
    else:
        scene, vl, edits, moves = _two_rooms() if args.scene == "two_rooms" else _furnished(tmp, args.size)
    sess = live.session(scene)
    w = sess.worker
    keys = sess.written.extract.span_keys
    thr = getattr(live_session, "EDIT_WRITE_THRESHOLD", 1 / 512)
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

    modes = ("exact", "threshold") if hasattr(live_session, "_within_threshold") else ("exact",)
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
        for m in modes[j % len(modes) :] + modes[: j % len(modes)]:
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
            f"{row['change_median']:.4f}); "
            + ", ".join(
                f"{m} {row[f'{m}_written']} w {row[f'{m}_write_ms']:.0f}+{row[f'{m}_eval_ms']:.0f} ms"
                for m in modes
            ),
            flush=True,
        )
    skip = r.values.unchanged(shown[modes[-1]])
    settle = {"written": len(keys) - len(skip)}
    settle["write_ms"], settle["eval_ms"] = write(r.values, skip)
    print(f"settling write after the edits: {settle}", flush=True)
    drag = []
    if moves:  # (each preview's write budgeted as Live's, timed; its objects above the threshold)
        w.preview = PREVIEW
        w.flush()
        _, ex = w.take()
        shown_now = ex.values if ex is not None else r.values
        write(shown_now, None)
        held = shown_now
        for edit in moves:
            p = result_of(edit)
            rel = p.values.change(shown_now)
            step = {"above_threshold": int((rel > thr).sum()), "above_1e-3": int((rel > 1e-3).sum())}
            # the preview's write as Live makes it (budget PREVIEW_WRITE_BUDGET, against what is shown)
            skip, held, _ = live_session._within_budget(p.values, held, live_session.PREVIEW_WRITE_BUDGET)
            step["written"] = len(keys) - len(skip)
            step["write_ms"], step["eval_ms"] = write(p.values, skip)
            drag.append(step)
            shown_now = p.values
        print(f"drag steps (previews, each against the one before): {drag}", flush=True)
    if drag:
        summary_drag = {k: float(np.median([x[k] for x in drag])) for k in ("written", "write_ms", "eval_ms")}
        print(f"drag previews, median: {summary_drag}", flush=True)
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
