"""Where a Live edit's CPU goes outside the core, furnished 100k room in bpy (session 28, wr34).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/profile_live_write.py [--cmd DIR]

Builds the room once (bench_live.make_furnished, Live on, FE draft), then per edit kind
(strength, colour: exact; move: progressive previews) times the ui path's stages in process time
(read = live._reconcile, flush = the worker, write = live._deliver, re-evaluation = the
view_layer.update() after the write: Blender evaluates the written meshes) and prints a cProfile of the
read and write stages over all edits of the kind. With --cmd DIR it then runs every *.py put in
DIR (exec, with this module's globals: sess, scene, vl, w, live, playback, ...) until DIR/stop
exists: A/B timings of write variants on the same built room, without building it again.
"""

import argparse
import cProfile
import io
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def stages(sess, scene, vl, w, live, edits, preview, prof_read, prof_write):
    rows = []
    for _, edit in edits:
        edit()
        import bpy

        bpy.context.view_layer.update()
        c0 = time.process_time()
        prof_read.enable()
        live._reconcile(sess, scene, vl, check_geometry=False, fast=True)
        prof_read.disable()
        c1 = time.process_time()
        w.flush(refine=not preview)
        c2 = time.process_time()
        prof_write.enable()
        live._deliver(sess, scene)
        prof_write.disable()
        c3 = time.process_time()
        vl.update()  # Blender's re-evaluation of the written meshes (the main thread, before the redraw)
        c4 = time.process_time()
        assert not sess.error and not sess.problems, (sess.error, sess.problems)
        rows.append((c1 - c0, c2 - c1, c3 - c2, c4 - c3))
    return np.array(rows) * 1000


def show(prof, n=18):
    s = io.StringIO()
    pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(n)
    print(s.getvalue()[:6000], flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cmd", default="")
    args = ap.parse_args()
    import bpy
    import hr_addon

    import bench_live as bl

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    from hr_addon.blender import live, playback
    from hr_addon.blender.live_worker import PREVIEW

    scene, obj, kind, along, normal, step, vl, sess = bl.furnished_live(
        tempfile.mkdtemp(prefix="hr_prof_live_")
    )
    w = sess.worker
    seq = bl.edit_sequence(obj, kind, along, normal, step)
    for k, preview in (("strength", False), ("colour", False), ("move", True)):
        w.preview = PREVIEW if preview else None
        ed = [e for e in seq if e[0] == k]
        pr, pw = cProfile.Profile(), cProfile.Profile()
        a = stages(sess, scene, vl, w, live, ed, preview, pr, pw)
        b = stages(sess, scene, vl, w, live, ed, preview, cProfile.Profile(), cProfile.Profile())
        med = np.median(b, axis=0)
        print(
            f"== {k}: {len(ed)} edits; CPU ms median (unprofiled) read {med[0]:.1f}, flush {med[1]:.1f}, "
            f"write {med[2]:.1f}, re-evaluation {med[3]:.1f}; "
            f"profiled medians {np.median(a, axis=0).round(1).tolist()}",
            flush=True,
        )
        if preview:
            w.flush()
            live._deliver(sess, scene)
        print(f"-- {k}: read stage profile", flush=True)
        show(pr, 12)
        print(f"-- {k}: write stage profile", flush=True)
        show(pw, 22)
    w.preview = None
    if args.cmd:
        d = Path(args.cmd)
        done = set()
        g = dict(
            globals(),
            sess=sess,
            scene=scene,
            vl=vl,
            w=w,
            live=live,
            playback=playback,
            obj=obj,
            seq=seq,
            bpy=bpy,
            PREVIEW=PREVIEW,
        )
        print(f"serving {d}", flush=True)
        while not (d / "stop").exists():
            for f in sorted(d.glob("*.py")):
                if f.name in done:
                    continue
                done.add(f.name)
                print(f"=== {f.name}", flush=True)
                try:
                    exec(compile(f.read_text(), str(f), "exec"), g)
                except Exception as exc:  # keep serving
                    import traceback

                    traceback.print_exc()
                    print(f"failed: {exc}", flush=True)
                print(f"=== end {f.name}", flush=True)
            time.sleep(1)
    scene.hr.live = False
    bpy.ops.hr.live_update()


if __name__ == "__main__":
    main()
