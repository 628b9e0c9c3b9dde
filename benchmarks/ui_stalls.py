"""The UI thread's longest stalls on a large room (the guide: "a UI that never freezes").

How long the MAIN thread is blocked per call of each thing the interactive UI runs on it: the Bake
button (background.BackgroundBake.start: the settings, the checks, own values, the saved copy, the
worker's start), each poll() tick of the operator's timer while the worker bakes, the last tick
(the result loaded: use_bake, the current frame's values into every object, the stale check),
Cancel, Delete Bake and Clear Bake, a frame change of the playback (the frame_change handlers
loading the cached values), the bake's stale check half a second after an edit, and Live Relight
(start: collect_geometry over every object; the timer's ticks while the worker thread builds; a
drag's ticks: reading the shapes, writing HR_Radiance; stop). Background mode has no event loop:
the timer functions and handlers are called directly, as the tests do (tests/
test_blender_background.py's job.poll() loop, tests/test_blender_live.py's live._tick()).

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/ui_stalls.py --scene 20k \
        [--repeat 5] [--json benchmarks/out/ui_stalls_20k.json]
    ... --scene 100k --work /tmp/ui26/100k        # makes furnished_100k.blend there on the first run

20k: a copy of sample_blends/furnished.blend (850 objects, ~20k triangles; frames 1-3 baked, the
Window on at frame 3). 100k: bench_bpy_frames.make_blend (bench_live.make_furnished's room,
furnished_room("100k"): 3,882 objects, 101,322 triangles; the Window keyed over frames 1-8; frames
1-3 baked: 2 and 3 move it). Vertex output at the scene's Vertex Spacing (--spacing to set it).
The first bake of a work folder builds the scene precompute in the worker (minutes at 100k); the
later ones load it.

Per item: wall (time.perf_counter) and the main thread's CPU (time.thread_time; process_time too,
which counts the Live worker thread's CPU as well) of each call, median and max over the repeats;
the load average before and after. One process; the machine is shared: read ratios. Benchmarks
print; no test asserts on time.
"""

import argparse
import inspect
import json
import os
import shutil
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "scripts"))

FRAMES = (1, 3)


class Clock:
    """Per-item lists of (wall s, thread CPU s, process CPU s)."""

    def __init__(self, profile=None, keys=()):
        self.items = {}
        self.order = []
        self.profile, self.keys, self.dumped = profile, keys, 0

    def _profiled(self, key, fn, *a, **k):
        import cProfile

        prof = cProfile.Profile()
        try:
            return prof.runcall(fn, *a, **k)
        finally:
            self.dumped += 1
            safe = "".join(c if c.isalnum() else "_" for c in key)[:60]
            prof.dump_stats(str(Path(self.profile) / f"{self.dumped:03d}_{safe}.prof"))

    def add(self, key, wall, thread, proc):
        if key not in self.items:
            self.items[key] = []
            self.order.append(key)
        self.items[key].append((wall, thread, proc))

    def time(self, key, fn, *a, **k):
        """fn(*a, **k) timed under key (under cProfile too, untimed then, with --profile and a key
        starting with one of --profile-keys)."""
        if self.profile and any(key.startswith(p) for p in self.keys):
            return self._profiled(key, fn, *a, **k)
        w0, t0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
        try:
            return fn(*a, **k)
        finally:
            self.add(key, time.perf_counter() - w0, time.thread_time() - t0, time.process_time() - p0)

    def wrap(self, owner, attr, key):
        """Time every call of owner.attr under key (returns an undo callable)."""
        fn = getattr(owner, attr)

        def timed(*a, **k):
            return self.time(key, fn, *a, **k)

        setattr(owner, attr, timed)
        return lambda: setattr(owner, attr, fn)

    def rows(self):
        out = []
        for k in self.order:
            v = self.items[k]
            col = list(zip(*v))
            out.append(
                dict(
                    item=k,
                    n=len(v),
                    wall_ms_median=1000 * statistics.median(col[0]),
                    wall_ms_max=1000 * max(col[0]),
                    cpu_ms_median=1000 * statistics.median(col[1]),
                    cpu_ms_max=1000 * max(col[1]),
                    process_cpu_ms_median=1000 * statistics.median(col[2]),
                )
            )
        return out


def table(rows):
    head = "| item | n | wall ms median / max | main-thread CPU ms median / max |"
    lines = [head, "|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['item']} | {r['n']} | {r['wall_ms_median']:.1f} / {r['wall_ms_max']:.1f} | "
            f"{r['cpu_ms_median']:.1f} / {r['cpu_ms_max']:.1f} |"
        )
    return "\n".join(lines)


# -- the scene ---------------------------------------------------------------------------------------
def open_scene(args):
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.scene == "20k":
        blend = work / "furnished.blend"
        if not blend.exists():
            shutil.copy(ROOT / "sample_blends" / "furnished.blend", blend)
    else:
        blend = work / f"furnished_{args.scene}.blend"
        if not blend.exists():
            from bench_bpy_frames import make_blend

            make_blend(blend, args.scene)
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    scene = bpy.context.scene
    scene.hr.output = "VERTEX"
    if args.spacing is not None:
        scene.hr.vertex_spacing = args.spacing
    scene.frame_set(FRAMES[0])
    return bpy, scene, blend


def _window(bpy):
    return bpy.data.objects["Window"]


# -- the bake button -----------------------------------------------------------------------------
def start_parts(clock):
    """Time start()'s parts by wrapping what it calls (undo callables)."""
    import subprocess

    from hr_addon.blender import background

    undo = [
        clock.wrap(background, "geometry_objects", "bake start: geometry_objects (x2-3)"),
        clock.wrap(background, "light_check", "bake start: light_check"),
        clock.wrap(background, "materials_emit", "bake start: materials_emit"),
        clock.wrap(background, "ensure_own_values", "bake start: ensure_own_values"),
        clock.wrap(background.STATE, "bake_starts", "bake start: bake_starts (Live ends)"),
        clock.wrap(subprocess, "Popen", "bake start: Popen (the worker)"),
    ]
    return lambda: [u() for u in undo]


def bake_once(bpy, scene, clock, limit, label="first bake"):
    """A real background bake of FRAMES, polled every 0.25 s as the operator's timer does (0.02 s
    while the result loads, as its faster timer); each poll() call timed: the ticks while the
    worker bakes, and the ones that load its result (main: one)."""
    from hr_addon.blender import background

    job = background.BackgroundBake(scene, frames=FRAMES)
    clock.time(f"bake start ({label})", job.start)
    t0 = time.monotonic()
    while True:
        w0, c0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
        more = job.poll()
        dt = (time.perf_counter() - w0, time.thread_time() - c0, time.process_time() - p0)
        loading = not more or getattr(job, "finishing", False)
        clock.add(
            f"poll: a tick loading the result ({label})"
            if loading
            else "poll: a tick while the worker bakes",
            *dt,
        )
        if not more:
            break
        if time.monotonic() - t0 > limit:
            job.cancel()
            raise SystemExit(f"the bake took over {limit} s: {job.status}")
        time.sleep(0.02 if loading else 0.25)
    if job.state != "done":
        raise SystemExit(f"the bake ended {job.state}: {job.error}")
    return job


def measure_start_cancel(bpy, scene, clock, repeat, when):
    """start() then cancel(): when 'start' at once (the worker still loading), 'frame' once the
    worker reports a frame (the precompute is loaded by then)."""
    from hr_addon.blender import background

    for _ in range(repeat):
        job = background.BackgroundBake(scene, frames=FRAMES)
        undo = start_parts(clock)
        try:
            clock.time("bake start (precompute stored)", job.start)
        finally:
            undo()
        if when == "frame":
            t0 = time.monotonic()
            while job.poll() and job.status.get("stage") != "frame":
                if time.monotonic() - t0 > 900:
                    break
                time.sleep(0.1)
            if job.state != "running":
                continue
        # the Cancel button's call: main waits for the worker to stop, this branch does not
        cancel = job.cancel
        if "wait" in inspect.signature(job.cancel).parameters:
            cancel = lambda: job.cancel(wait=False)
        clock.time(f"cancel ({'at once after start' if when == 'start' else 'during the frames'})", cancel)
        # the operator's cancel may return before the worker has gone: wait as its timer would
        t0 = time.monotonic()
        while job.poll():
            clock.time("poll: a tick while cancelling", lambda: None)
            if time.monotonic() - t0 > 60:
                break
            time.sleep(0.05)
        assert job.state == "cancelled", job.state


def measure_save(bpy, clock, repeat, work):
    p = Path(work) / "copy_test.blend"
    for _ in range(repeat):
        clock.time(
            "bake start part: the saved copy (save_as_mainfile copy=True)",
            bpy.ops.wm.save_as_mainfile,
            filepath=str(p),
            copy=True,
            check_existing=False,
            relative_remap=True,
        )
    p.unlink(missing_ok=True)


def measure_result(bpy, scene, clock, repeat, job):
    """The work of the ticks that load a finished bake, again (main: one tick, _use_result; this
    branch: a step per tick, _use_result_steps)."""
    from hr_addon.blender import background, playback

    undo = [
        clock.wrap(background, "use_bake", "result: of it use_bake"),
        clock.wrap(playback, "load_frame", "result: of it load_frame"),
    ]
    try:
        for _ in range(repeat):
            j = background.BackgroundBake(scene, frames=FRAMES)
            j.final_dir, j.output, j.blend = job.final_dir, job.output, bpy.data.filepath
            steps = getattr(j, "_use_result_steps", None)
            if steps is None:
                clock.time("result: a loading tick (all of it)", j._use_result)
                clock.add("result: ticks to load it", 1, 0, 0)
                continue
            it, n = steps(), 0
            while True:
                n += 1
                w0, c0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
                try:
                    next(it)
                    end = False
                except StopIteration:
                    end = True
                clock.add(
                    "result: a loading tick (all of it)",
                    time.perf_counter() - w0,
                    time.thread_time() - c0,
                    time.process_time() - p0,
                )
                if end:
                    break
            clock.add("result: ticks to load it", n, 0, 0)
    finally:
        for u in undo:
            u()


def _timer_ticks(clock, key, fn, limit=10000):
    """Call a timer function as Blender's event loop would until it returns None; each call timed."""
    for _ in range(limit):
        if clock.time(key, fn) is None:
            return


def measure_frames(bpy, scene, clock, repeat):
    """Playback: frame_set between frames whose files differ (the handlers load the values); after
    an edit (the handlers compare the scene with the bake, main at once, this branch over timer
    ticks); the stale check half a second after an edit (the timer _deferred_check)."""
    from hr_addon.blender import playback
    from hr_addon.blender.state import STATE

    if hasattr(playback, "SPREAD"):
        playback.SPREAD = True  # as in the UI (background mode compares at once: no timers)
    undo = [
        clock.wrap(playback, "load_frame", "frame change: of it load_frame (read + write)"),
        clock.wrap(playback, "apply_arrays", "frame change: of it apply_arrays (write)"),
    ]
    try:
        scene.frame_set(FRAMES[0])
        for i in range(repeat):
            f = FRAMES[1] if i % 2 == 0 else FRAMES[0]
            clock.time("frame change (frame_set, the handlers included)", scene.frame_set, f)
        for i in range(repeat):  # after an edit: on_frame_change_post compares the scene too
            STATE.dirty.add(scene.name_full)
            f = FRAMES[1] if i % 2 == 0 else FRAMES[0]
            clock.time("frame change after an edit", scene.frame_set, f)
            _timer_ticks(clock, "frame change after an edit: a timer tick after it", playback._deferred_check)
    finally:
        for u in undo:
            u()
    for _ in range(repeat):
        STATE.dirty.add(scene.name_full)
        _timer_ticks(clock, "stale check after an edit: a timer tick", playback._deferred_check)
    dg = bpy.context.evaluated_depsgraph_get()
    for _ in range(repeat):
        clock.time("stale check at once (check_scene, force)", playback.check_scene, scene, dg, True)
    scene.frame_set(FRAMES[0])


def measure_delete(bpy, scene, clock, repeat, job, work):
    """Delete Bake (keep the precompute) and Clear Bake; the bake put back between (untimed)."""
    from hr_addon.blender import ops, own_values, playback, texture
    from hr_addon.blender.bake import use_bake
    from hr_addon.blender.scene_in import geometry_objects
    from hr_addon.blender.settings import BakeConfig

    d = Path(job.final_dir)
    keep = Path(work) / "bake_copy"
    shutil.rmtree(keep, ignore_errors=True)
    shutil.copytree(d, keep, ignore=shutil.ignore_patterns("precompute.hrpc*"))

    def put_back():
        for p in keep.iterdir():
            if not (d / p.name).exists():
                shutil.copy2(p, d / p.name)
        vl = bpy.context.view_layer
        cfg = BakeConfig.resolve(scene.hr)
        own_values.ensure_own_values(geometry_objects(vl), cfg.domain, vl.depsgraph, cfg.vertex_spacing)
        use_bake(scene, str(d), "VERTEX")
        playback.forget_loaded()
        assert playback.load_frame(scene)

    undo = [
        clock.wrap(ops, "delete_cache_files", "delete: of it delete_cache_files"),
        clock.wrap(ops, "_forget_bake", "delete/clear: of it _forget_bake (the rest: Blender's update)"),
        clock.wrap(texture, "remove_material", "delete/clear: of it texture.remove_material"),
        clock.wrap(ops, "remove_own_values", "delete/clear: of it remove_own_values"),
    ]
    try:
        for _ in range(repeat):
            clock.time("Delete Bake (operator)", bpy.ops.hr.delete_bake, "EXEC_DEFAULT", keep_precompute=True)
            put_back()
        for _ in range(repeat):
            clock.time("Clear Bake (operator)", bpy.ops.hr.clear_bake, "EXEC_DEFAULT")
            put_back()
    finally:
        for u in undo:
            u()
    shutil.rmtree(keep, ignore_errors=True)


def measure_preview(bpy, scene, clock):
    """The Preview Bake button and Remove Preview. main: one call (the button's execute); this
    branch: the button's modal, a slice of materials per timer tick, driven as the event loop
    would (stand-ins for the window manager)."""
    from types import SimpleNamespace

    from hr_addon.blender import ops, playback

    op_cls = ops.HR_OT_add_preview
    if not hasattr(op_cls, "modal"):
        clock.time("Preview button (one call)", bpy.ops.hr.add_preview)
    else:
        playback.SPREAD = True
        timers = []
        wm = SimpleNamespace(
            windows=[],
            event_timer_add=lambda step, window=None: timers.append(object()) or timers[-1],
            event_timer_remove=lambda t: None,
            modal_handler_add=lambda op: None,
        )
        ctx = SimpleNamespace(scene=scene, view_layer=bpy.context.view_layer, window_manager=wm, window=None)
        op = SimpleNamespace(report=lambda kind, msg: print(f"{sorted(kind)[0]}: {msg}", flush=True))
        op.execute = lambda c: op_cls.execute(op, c)
        op._end = lambda c: op_cls._end(op, c)
        clock.time("Preview button: invoke", op_cls.invoke, op, ctx, None)
        ev = SimpleNamespace(type="TIMER", timer=timers[0])
        while clock.time("Preview button: a timer tick", op_cls.modal, op, ctx, ev) == {"PASS_THROUGH"}:
            pass
        from hr_addon.blender.state import STATE

        _timer_ticks(
            clock, "Preview button: the stale check's timer ticks after it", playback._deferred_check
        )
        STATE.dirty.discard(scene.name_full)
    rm = ops.HR_OT_remove_preview
    if not hasattr(rm, "modal"):
        clock.time("Remove Preview (one call)", bpy.ops.hr.remove_preview)
        return
    clock.time("Remove Preview button: invoke", rm.invoke, op, ctx, None)
    ev = SimpleNamespace(type="TIMER", timer=timers[-1])
    while clock.time("Remove Preview button: a timer tick", rm.modal, op, ctx, ev) == {"PASS_THROUGH"}:
        pass


def measure_live(bpy, scene, clock, steps, limit):
    """Live: start (threaded, as in the UI), the ticks while the worker builds, a drag (each step:
    the depsgraph update with the handlers, the tick that hands the state over, the tick that
    writes the result), stop."""
    import numpy as np

    from hr_addon.blender import live, live_session, playback

    spread = "spread" in inspect.signature(live.start).parameters  # (ui27: prepared over ticks)
    worker = " (the worker thread's CPU)" if spread else ""
    undo = [
        clock.wrap(live_session, "collect_geometry", "live start: of it collect_geometry"),
        clock.wrap(live_session.preview, "show_radiance", "live start: of it preview.show_radiance"),
        clock.wrap(live_session, "precompute_key", f"live start: of it precompute_key{worker}"),
        clock.wrap(live_session, "solver_setup", f"live start: of it solver_setup{worker}"),
        clock.wrap(live_session, "FlatExtract", "live start: of it FlatExtract"),
        clock.wrap(live_session, "_depsgraph", "live: of it _depsgraph (Blender evaluates the scene)"),
        clock.wrap(live_session.preview, "undo_show_radiance", "live stop: of it preview.undo_show_radiance"),
        clock.wrap(live_session.playback, "load_frame", "live stop: of it playback.load_frame"),
        clock.wrap(live_session, "_read_shapes", "live: of it _read_shapes"),
        clock.wrap(playback, "apply_arrays", "live: of it apply_arrays (HR_Radiance written)"),
        clock.wrap(live, "on_depsgraph_update", "live drag: of it live's depsgraph handler"),
        clock.wrap(playback, "on_depsgraph_update", "live drag: of it playback's depsgraph handler"),
    ]
    # the handlers are registered as functions: re-register the wrapped ones
    h = bpy.app.handlers.depsgraph_update_post
    old = list(h)
    new = []
    for f in old:
        if getattr(f, "__name__", "") == "on_depsgraph_update" and f.__module__ == live.__name__:
            f = live.on_depsgraph_update
        elif getattr(f, "__name__", "") == "on_depsgraph_update" and f.__module__ == playback.__name__:
            f = playback.on_depsgraph_update
        new.append(f)
    h.clear()
    h.extend(new)
    scene.frame_set(FRAMES[1])  # the Window is on (20k: from frame 3)
    try:

        def redraw(key):
            """What the UI's next event-loop pass costs after our call: Blender evaluates the
            depsgraph (the materials and meshes our call changed; a redraw would)."""
            clock.time(
                f"{key}: Blender's evaluation after it (the redraw's)", bpy.context.evaluated_depsgraph_get
            )

        sess = clock.time(
            "live start (main thread; the build goes to the worker)",
            live.start,
            scene,
            None,
            True,
            **({"spread": True} if spread else {}),
        )
        redraw("live start")
        t0 = time.monotonic()
        while getattr(sess, "preparing", None) is not None:  # ui27: a time slice per tick
            clock.time("live tick while it prepares (materials, the scene read)", live._tick)
            redraw("live tick while it prepares")
            if not live.is_live(scene):
                raise SystemExit(f"Live stopped while it prepared: {live.message(scene)}")
        while sess.last is None:
            building = sess.building
            clock.time(
                "live tick while the worker builds" if building else "live tick (the first result written)",
                live._tick,
            )
            if time.monotonic() - t0 > limit or sess.fatal:
                raise SystemExit(f"Live did not build: {sess.fatal or sess.text()}")
            time.sleep(0.02)
        win = _window(bpy)
        u = np.array([0.0, 1.0, 0.0])  # the Window lies on the west wall (x constant) in both rooms
        for i in range(steps):
            win.location = tuple(np.asarray(win.location) + 0.02 * u * (1 if i % 2 == 0 else -1))
            clock.time(
                "live drag: depsgraph update (Blender's + the handlers)", bpy.context.view_layer.update
            )
            clock.time("live drag: the tick that reads the shapes", live._tick)
            assert sess.worker.flush(timeout=limit)
            clock.time("live drag: the tick that writes the result", live._tick)
            redraw("live drag: the tick that writes the result")
            clock.time("live drag: the tick after the write", live._tick)
        clock.time("live stop (the baked playback back)", live.stop, scene)
        redraw("live stop")
        while getattr(live, "restoring", lambda s: False)(scene):  # ui27: a time slice per tick
            clock.time("live stop: a restore tick (the preview undone, the playback loaded)", live._tick)
            redraw("live stop: a restore tick")
    finally:
        for u_ in undo:
            u_()
        h.clear()
        h.extend(old)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="20k", choices=("20k", "100k"))
    ap.add_argument(
        "--work", default=None, help="folder of the .blend and its cache (default /tmp/ui26/<scene>)"
    )
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=6, help="Live drag steps")
    ap.add_argument(
        "--spacing", type=float, default=None, help="Scene.hr.vertex_spacing (default: the file's)"
    )
    ap.add_argument("--limit", type=float, default=3600.0, help="seconds a bake or a Live build may take")
    ap.add_argument(
        "--skip",
        nargs="*",
        default=[],
        help="parts to skip: bake cancel save result frames delete preview live",
    )
    ap.add_argument("--json", default=None)
    ap.add_argument("--profile", default=None, help="folder: cProfile the calls of --profile-keys there")
    ap.add_argument("--profile-keys", nargs="*", default=[], help="item names' beginnings (not timed then)")
    args = ap.parse_args(argv)
    args.work = args.work or f"/tmp/ui26/{args.scene}"
    load0 = os.getloadavg()
    bpy, scene, blend = open_scene(args)
    if args.profile:
        Path(args.profile).mkdir(parents=True, exist_ok=True)
    clock = Clock(args.profile, tuple(args.profile_keys))
    n_obj = sum(1 for o in scene.objects if o.type == "MESH")
    n_tri = sum(len(o.data.loop_triangles) for o in scene.objects if o.type == "MESH")
    print(f"{blend}: {n_obj} mesh objects, {n_tri} triangles; load {load0}", flush=True)
    job = None
    if "bake" not in args.skip:
        undo = start_parts(clock)
        try:
            job = bake_once(bpy, scene, clock, args.limit)
        finally:
            undo()
        print(f"baked: {job.summary}", flush=True)
    if "cancel" not in args.skip:
        measure_start_cancel(bpy, scene, clock, args.repeat, "start")
        measure_start_cancel(bpy, scene, clock, max(1, args.repeat // 2), "frame")
    if "save" not in args.skip:
        measure_save(bpy, clock, args.repeat, args.work)
    if job is None:
        from hr_addon.blender import background
        from hr_addon.blender.bake import cache_dir_for

        from hr_addon.blender import playback
        from hr_addon.blender.bake import use_bake

        job = background.BackgroundBake(scene, frames=FRAMES)
        job.final_dir, job.output = cache_dir_for(scene), "VERTEX"
        use_bake(scene, job.final_dir, "VERTEX")  # the work folder's bake (of an earlier run)
        assert playback.load_frame(scene), "no bake in the work folder: run without --skip bake first"
    if "result" not in args.skip:
        measure_result(bpy, scene, clock, args.repeat, job)
    if "frames" not in args.skip:
        measure_frames(bpy, scene, clock, args.repeat)
    if "delete" not in args.skip:
        measure_delete(bpy, scene, clock, max(1, args.repeat // 2), job, args.work)
    if "preview" not in args.skip:
        measure_preview(bpy, scene, clock)
    if "live" not in args.skip:
        measure_live(bpy, scene, clock, args.steps, args.limit)
    rows = clock.rows()
    load1 = os.getloadavg()
    print(table(rows))
    print(f"load average before {load0}, after {load1}", flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(
            json.dumps(
                dict(
                    scene=args.scene,
                    blend=str(blend),
                    objects=n_obj,
                    triangles=n_tri,
                    repeat=args.repeat,
                    load_before=load0,
                    load_after=load1,
                    rows=rows,
                    date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                ),
                indent=1,
            )
        )
    return rows


if __name__ == "__main__":
    main()
