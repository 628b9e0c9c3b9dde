"""Live's per-update write budget for a drag's previews, furnished 100k room in bpy (session 29, lvbudget).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_live_budget.py \
        [--budgets none,1000,500,250] [--steps 24] [--out benchmarks/out/live_budget.json]

Builds the room once (bench_live.make_furnished, Live on, FE draft, progressive previews), then
drags the Window (bench_live.edit_sequence's moves). Each step's preview is computed once and
written once per budget, in a rotating order, each budget keeping its own record of what
HR_Radiance would hold (live_session._within_budget; no budget: the exact skip of bit-identical
objects, Rows.unchanged). Per step and budget, in process time: the write (the choice included)
and Blender's re-evaluation that follows it (view_layer.update(): what the main thread pays before
the redraw), the objects written, and how far what is shown lags the full preview (Rows.change:
per object, the largest RGB change relative to its level; max and 95th percentile over objects).
The re-evaluation depends on which meshes were written, not on their values, so the budgets share
one drag (the same previews). At the end the drag's refine (exact) is compared with its last
preview (the preview's own error, for scale). Then a real drag through live._deliver with the
default budget, its refine, and HR_Radiance read back: bit-identical to the refine's values.
"""

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


def _lag(values, shown):
    """max and p95 over objects of Rows.change(shown) (0 when nothing lags)."""
    rel = values.change(shown)
    return float(rel.max()), float(np.percentile(rel, 95))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--budgets", default="none,1000,500,250")
    ap.add_argument("--steps", type=int, default=24)
    ap.add_argument("--size", default="100k")  # (a smaller furnished room: a quick check of this script)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out" / "live_budget.json"))
    args = ap.parse_args()
    budgets = [None if b == "none" else int(b) for b in args.budgets.split(",")]
    import bpy
    import hr_addon

    import bench_live as bl

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    from hr_addon.blender import live, live_session, playback
    from hr_addon.blender.live_worker import PREVIEW

    scene, obj, kind, along, normal, step, vl, sess = bl.furnished_live(
        tempfile.mkdtemp(prefix="hr_live_budget_"), args.size
    )
    w = sess.worker
    w.preview = PREVIEW
    n_obj = len(sess.written.extract.span_keys)
    print(f"{n_obj} objects with rows, {sess.written.buffer.size} floats", flush=True)
    moves = [e for _, e in bl.edit_sequence(obj, kind, along, normal, step) if _ == "move"]
    drag = (moves * (1 + args.steps // len(moves)))[: args.steps]

    def preview_of(edit):
        edit()
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        c = time.process_time()
        w.flush(refine=False)
        flush = time.process_time() - c
        _, r = w.take()
        assert r is not None and r.values is not None and not r.error, r and r.error
        return r, flush

    def write(values, skip):
        problems = playback.apply_arrays(
            scene, values, sess.domain, reader=sess.scene_name, objects=sess.objects, skip=skip
        )
        assert not problems, problems

    shown = {b: sess.written for b in budgets}
    rows = []
    for j, edit in enumerate(drag):
        r, flush = preview_of(edit)
        assert live_session._budgeted(sess, r), [e.kind for e in r.report.events]
        order = budgets[j % len(budgets) :] + budgets[: j % len(budgets)]
        for b in order:
            c1 = time.process_time()
            if b is None:
                skip, held = r.values.unchanged(shown[b]), r.values
            else:
                skip, held, _ = live_session._within_budget(r.values, shown[b], b)
            write(r.values, skip)
            c2 = time.process_time()
            vl.update()  # Blender's re-evaluation of the written meshes
            c3 = time.process_time()
            shown[b] = held
            lag = _lag(r.values, held)
            rows.append(
                {
                    "step": j,
                    "budget": b,
                    "written": n_obj - len(skip),
                    "write_ms": 1000 * (c2 - c1),
                    "eval_ms": 1000 * (c3 - c2),
                    "main_ms": 1000 * (c3 - c1),  # what the main thread pays for this preview
                    "lag_max": lag[0],
                    "lag_p95": lag[1],
                    "flush_ms": 1000 * flush,
                }
            )
        line = "; ".join(
            f"{x['budget']}: {x['written']} w {x['write_ms']:.0f}+{x['eval_ms']:.0f} ms "
            f"lag {x['lag_max']:.3f}/{x['lag_p95']:.4f}"
            for x in sorted(rows[-len(budgets) :], key=lambda x: budgets.index(x["budget"]))
        )
        print(f"step {j:2d} (preview {1000 * flush:.0f} ms): {line}", flush=True)
    last = r.values
    w.flush()
    _, ex = w.take()
    assert ex is not None and not ex.preview
    pe = _lag(ex.values, last)
    print(
        f"refine against the last preview (the preview's own error): max {pe[0]:.4f}, p95 {pe[1]:.4f}",
        flush=True,
    )
    # the exact write after the drag, for each budget's record: everything differing is written
    exact = {}
    for b in budgets:
        skip = ex.values.unchanged(shown[b])
        c1 = time.process_time()
        write(ex.values, skip)
        c2 = time.process_time()
        vl.update()
        exact[str(b)] = {
            "written": n_obj - len(skip),
            "write_ms": 1000 * (c2 - c1),
            "eval_ms": 1000 * (time.process_time() - c2),
        }
    print(f"exact writes after the drag: {exact}", flush=True)
    # the real path: live._deliver with the default budget over a drag, then the refine
    sess.written, sess.write_budget = None, live_session.PREVIEW_WRITE_BUDGET
    sess.last, sess.force_write = ex, True  # the refine written whole (as after an undo): a known start
    live._deliver(sess, scene)
    vl.update()
    real = []
    for edit in drag[:8]:
        edit()
        vl.update()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        w.flush(refine=False)
        c1 = time.process_time()
        live._deliver(sess, scene)
        c2 = time.process_time()
        vl.update()
        c3 = time.process_time()
        held = bl._written(sess.written.extract.span_keys)
        mirror = np.concatenate([sess.written[k].ravel() for k in sess.written.extract.span_keys])
        assert np.array_equal(held.view(np.uint32), mirror.view(np.uint32)), (
            "sess.written is not what HR_Radiance holds"
        )
        real.append({"write_ms": 1000 * (c2 - c1), "eval_ms": 1000 * (c3 - c2), "behind": bool(sess.behind)})
    print(f"real drag (budget {sess.write_budget}): {real}", flush=True)
    # the drag pauses: the timer writes the rest of the last preview, a budget per tick (no waiting here)
    catch = []
    while sess.behind and len(catch) < 20:
        sess.wrote_at -= live_session.CATCH_UP_AFTER
        c1 = time.process_time()
        assert live._deliver(sess, scene)
        c2 = time.process_time()
        vl.update()
        catch.append({"write_ms": 1000 * (c2 - c1), "eval_ms": 1000 * (time.process_time() - c2)})
    lag = _lag(sess.last.values, sess.written)
    print(
        f"catch-up writes after the pause: {catch}; then lag max {lag[0]:.4f}, p95 {lag[1]:.5f}", flush=True
    )
    w.flush()
    live._deliver(sess, scene)
    assert not sess.last.preview and not sess.behind
    keys = sess.last.values.extract.span_keys
    held = bl._written(keys)
    want = np.concatenate([sess.last.values[k].ravel() for k in keys])
    same = bool(np.array_equal(held.view(np.uint32), want.view(np.uint32)))
    print(f"HR_Radiance after the refine bit-identical to its values: {same}", flush=True)
    assert same
    summary = {}
    for b in budgets:
        x = [r for r in rows if r["budget"] == b]
        summary[str(b)] = {
            k: {
                "median": float(np.median([r[k] for r in x])),
                "p95": float(np.percentile([r[k] for r in x], 95)),
                "max": float(np.max([r[k] for r in x])),
            }
            for k in ("written", "write_ms", "eval_ms", "main_ms", "lag_max", "lag_p95")
        }
        s = summary[str(b)]
        print(
            f"budget {b}: written {s['written']['median']:.0f}, write {s['write_ms']['median']:.1f} + "
            f"re-evaluation {s['eval_ms']['median']:.1f} ms (both: p95 {s['main_ms']['p95']:.0f}); "
            f"lag max over objects: median {s['lag_max']['median']:.4f}, worst {s['lag_max']['max']:.4f}; "
            f"p95 over objects: median {s['lag_p95']['median']:.5f}, worst {s['lag_p95']['max']:.5f}",
            flush=True,
        )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(
        json.dumps(
            {
                "rows": rows,
                "summary": summary,
                "preview_error": pe,
                "exact": exact,
                "real": real,
                "refine_bit_identical": same,
            },
            indent=1,
        )
    )
    scene.hr.live = False
    bpy.ops.hr.live_update()


if __name__ == "__main__":
    main()
