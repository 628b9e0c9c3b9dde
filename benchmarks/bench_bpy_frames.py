"""A Blender bake of the furnished 100k room, frame by frame (issues 19, 23): where a frame goes
outside the core. bpy module, one process per run.

    nice -n 5 env OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_bpy_frames.py \
        --blend /tmp/bpy100k/furnished_100k.blend --make       # the .blend (once)
    ... --blend B --path bake  --output vertex  --json benchmarks/out/bpy100k_vertex.json
    ... --blend B --path op    --output vertex                  # bpy.ops.hr.bake() (as a user's script)
    ... --blend B --path cli   --output vertex                  # python -m hr_addon bake (a subprocess)
    ... --blend B --path cancel --output vertex                 # close the bake after 3 frames (Esc)
    ... --blend B --path cli --term-after 3                     # SIGTERM the command line's bake
    ... --blend B --path play --json benchmarks/out/play100k_main.json  # play a vertex bake back
    ... --blend B --path background [--cancel-after 3]          # the Bake button's worker (and Cancel)
    (--output texture --resolution R for the lightmaps: objects of over 200 faces get 8 R, the
    spheres of 5,120 faces (a chart per face) 16 R)

--make: bench_live.make_furnished's room (furnished_room("100k"): 3,882 objects) and its Window
light shape on the west wall, keyed over frames 1-8 (constant interpolation): frames 2, 3 move it
2.5 cm along the wall, 4 is frame 3 again (nothing changes), 5 only its strength (20 -> 30), 6-8
move it on. Draft quality, the final gather on, threads 1 (the core's figures are single-threaded).
--path bake: steps bake.bake_frames (what run_bake, the operator and the CLI run) and times every
frame between two yields, CPU (time.process_time) and wall, and its parts, by wrapping the functions
the frame loop calls: scene read (_Bake.lights_at: frame_set + collect_light_shapes + the
signature), apply (DynamicRadiosity.apply: the events), gathered output (the final gather's
loop_radiance or the texture plan's radiance), extract (Target.extract per object), write
(CacheWriter.write: the .npz; TexturePlan.write: the images), reuse (unchanged frames); "rest" is
what the frame costs beyond them (progress, warnings, the yield). --profile DIR: cProfile per frame.
Also: peak RSS (ru_maxrss), the cache on disk per frame file.
--path play (issue 19; the .blend's bake played back, vertex output): scene.frame_set over frames
2-8, 1 twice (16 changes; the first pass reads the files, the second finds them in the reader's
cache), CPU per change and its parts: read (CacheReader.load), apply (playback.apply_arrays: our
3,882 HR_Radiance writes, of which write_attribute), and "blender" = the change less read and
apply (the frame's own evaluation and that of the written meshes); then, untimed, every object's
evaluated mesh read back against the frame's values (what the viewport draws).
Benchmarks print; no test asserts on time. One run each; the machine is shared (quote ratios).
"""

import argparse
import cProfile
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "scripts"))

FRAMES = (1, 8)
STEP = 0.025  # metres a moving frame
# frame: (offset along the wall in steps, strength)
KEYS = {
    1: (0, 20.0),
    2: (1, 20.0),
    3: (2, 20.0),
    4: (2, 20.0),
    5: (2, 30.0),
    6: (3, 30.0),
    7: (4, 30.0),
    8: (5, 30.0),
}


def make_blend(path, size="100k"):
    import numpy as np

    from bench_live import make_furnished

    import make_samples as ms

    scene, win, _, u, _, _, info = make_furnished(str(Path(path).parent), size)
    base = np.asarray(win.location, float)
    strength = win.active_material.node_tree.nodes["Emission"].inputs["Strength"]
    for f, (k, s) in KEYS.items():
        win.location = tuple(base + k * STEP * np.asarray(u, float))
        win.keyframe_insert("location", frame=f)
        strength.default_value = s
        strength.keyframe_insert("default_value", frame=f)
    ms.interpolation(win, "CONSTANT")
    ms.interpolation(win.active_material.node_tree, "CONSTANT")
    scene.hr.threads = 1
    ms.finish(scene, Path(path), FRAMES)
    return info


class Parts:
    """CPU and wall seconds of wrapped functions, accumulated until take()."""

    def __init__(self):
        self.acc = {}
        self.mark = None  # (CPU, wall, parts so far) when the bake's set-up ended (frames_todo returned)

    def wrap(self, owner, attr, key):
        fn = getattr(owner, attr)

        def timed(*a, **k):
            c0, w0 = time.process_time(), time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                t = self.acc.setdefault(key, [0.0, 0.0, 0])
                t[0] += time.process_time() - c0
                t[1] += time.perf_counter() - w0
                t[2] += 1

        setattr(owner, attr, timed)

    def mark_after(self, owner, attr):
        fn = getattr(owner, attr)

        def marked(*a, **k):
            r = fn(*a, **k)
            self.mark = (time.process_time(), time.perf_counter(), self.take())
            return r

        setattr(owner, attr, marked)

    def take(self):
        out, self.acc = self.acc, {}
        return {k: dict(cpu_s=v[0], wall_s=v[1], calls=v[2]) for k, v in out.items()}


def instrument():
    from hr_addon.blender import bake, lights_in, scene_in
    from hr_addon.core.events import DynamicRadiosity
    from hr_addon.core.gather.layouts import LoopGather
    from hr_addon.io.cache import CacheWriter
    from hr_addon.lightmap.plan import TexturePlan

    p = Parts()
    for step in ("build", "open_writer", "frames_todo"):  # before frame 1, in its step: set apart
        p.wrap(bake._Bake, step, "setup." + step)
    p.mark_after(bake._Bake, "frames_todo")
    p.wrap(bake._Bake, "lights_at", "scene_read")
    p.wrap(bake, "collect_light_shapes", "scene_read.collect_light_shapes")
    p.wrap(lights_in, "light_shape_objects", "scene_read.light_shape_objects")
    p.wrap(bake, "shapes_signature", "scene_read.signature")
    p.wrap(DynamicRadiosity, "apply", "apply")
    p.wrap(LoopGather, "loop_radiance", "output")
    p.wrap(TexturePlan, "radiance", "output")
    p.wrap(scene_in.Target, "extract", "extract")
    p.wrap(CacheWriter, "write", "write")
    p.wrap(TexturePlan, "write", "write.images")
    p.wrap(CacheWriter, "reuse", "reuse")
    p.wrap(TexturePlan, "reuse", "reuse.images")
    return p


def _rss_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


def cache_files(d):
    """{relative path: bytes} of a cache folder (frames, images, manifest, precompute)."""
    d = Path(d)
    if not d.exists():
        return {}
    return {str(p.relative_to(d)): p.stat().st_size for p in sorted(d.rglob("*")) if p.is_file()}


def cache_summary(d):
    files = cache_files(d)
    frames = {k: v for k, v in files.items() if k.startswith("frame_") or k.startswith("textures/")}
    inodes = {}
    for k in frames:
        st = (Path(d) / k).stat()
        inodes[(st.st_dev, st.st_ino)] = st.st_size
    return dict(
        files=len(files),
        total_mb=sum(files.values()) / 1e6,
        frame_files=len(frames),
        frame_mb_linked=sum(frames.values()) / 1e6,
        frame_mb_on_disk=sum(inodes.values()) / 1e6,
        precompute_mb=files.get("precompute.hrpc", 0) / 1e6,
    )


def open_blend(blend, output, resolution):
    from hr_testing.blend import load_bpy

    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
    s = bpy.context.scene
    s.hr.output = output.upper()
    s.hr.texture_resolution = resolution
    for o in s.objects:  # the room's big surfaces and the spheres (a chart per face) need more texels
        if o.type == "MESH" and len(o.data.polygons) > 200:
            o.hr.lightmap_resolution = resolution * (16 if len(o.data.polygons) > 4000 else 8)
    return bpy, s


def run_bake(args):
    from hr_addon.blender.bake import bake_frames

    bpy, scene = open_blend(args.blend, args.output, args.resolution)
    if args.vertex_spacing is not None:
        scene.hr.vertex_spacing = args.vertex_spacing
    parts = instrument()
    c0, w0 = time.process_time(), time.perf_counter()
    gen = bake_frames(scene, progress=lambda p: None)
    rows, setup = [], None
    prof_dir = Path(args.profile) if args.profile else None
    if prof_dir:
        prof_dir.mkdir(parents=True, exist_ok=True)
    res = None
    while True:
        prof = cProfile.Profile() if prof_dir and setup is not None else None
        c1, w1 = time.process_time(), time.perf_counter()
        if prof:
            prof.enable()
        try:
            p = next(gen)
        except StopIteration as stop:
            res = stop.value
            p = None
        if prof:
            prof.disable()
        c2, w2 = time.process_time(), time.perf_counter()
        got = parts.take()
        if p is None:  # the commit: the cache folder swapped in, the scene pointed at it, its frame shown
            commit = dict(cpu_s=c2 - c1, wall_s=w2 - w1, parts=got)
            if prof:
                prof.dump_stats(str(prof_dir / f"{args.output}_commit.prof"))
            break
        if p.stage != "frame":
            if setup is None:
                setup = dict(cpu_s=0.0, wall_s=0.0)
            setup["cpu_s"] += c2 - c1
            setup["wall_s"] += w2 - w1
            continue
        if parts.mark is not None:  # frame 1's step began with the build, the writer, the frames to do
            c1, w1, setup["steps"] = parts.mark
            parts.mark = None
        row = dict(
            frame=p.frame,
            reused=p.reused,
            cpu_s=c2 - c1,
            wall_s=w2 - w1,
            parts=got,
            rest_cpu_s=(c2 - c1) - sum(v["cpu_s"] for k, v in got.items() if "." not in k),
        )
        if prof:
            path = prof_dir / f"{args.output}_frame{p.frame}.prof"
            prof.dump_stats(str(path))
        rows.append(row)
        print(
            f"frame {p.frame}: {row['cpu_s']:.3f} s CPU, {row['wall_s']:.3f} s wall"
            + (" (unchanged)" if p.reused else "")
            + "; "
            + ", ".join(f"{k} {v['cpu_s'] * 1000:.1f} ms" for k, v in got.items()),
            flush=True,
        )
    # the first frame report carries the build, the open_writer, the first frame: set apart
    total_cpu, total_wall = time.process_time() - c0, time.perf_counter() - w0
    d = res.cache_dir
    res_tex = args.resolution if args.output == "texture" else None
    out = dict(
        path="bake",
        output=args.output,
        resolution=res_tex,
        blend=str(args.blend),
        load_average=os.getloadavg()[0],
        total_cpu_s=total_cpu,
        total_wall_s=total_wall,
        setup=setup,
        frames=rows,
        commit=commit,
        precompute_loaded=res.precompute_loaded,
        build_s=res.build_seconds,
        summary=res.summary(),
        peak_rss_gb=_rss_gb(),
        cache=cache_summary(d),
        per_frame_files=_per_frame(d),
    )
    print(res.summary())
    print(
        f"total {total_cpu:.1f} s CPU, {total_wall:.1f} s wall; peak RSS {out['peak_rss_gb']:.2f} GB; "
        f"cache {out['cache']}",
        flush=True,
    )
    return out


PLAY = [2, 3, 4, 5, 6, 7, 8, 1] * 2


def run_play(args):
    import numpy as np

    from hr_addon.blender import playback
    from hr_addon.blender.paths import bake_dir_abs
    from hr_addon.io.cache import CacheReader

    bpy, scene = open_blend(args.blend, "vertex", args.resolution)
    assert scene.hr.playback and bake_dir_abs(scene), "the .blend has no bake to play back"
    if args.regroup:
        regroup(bpy, scene, playback.get_reader(bake_dir_abs(scene)).domain)
    parts = Parts()
    parts.wrap(CacheReader, "load", "read")
    parts.wrap(playback, "apply_arrays", "apply")
    parts.wrap(playback, "write_attribute", "apply.write_attribute")
    prof_dir = Path(args.profile) if args.profile else None
    if prof_dir:
        prof_dir.mkdir(parents=True, exist_ok=True)
    scene.frame_set(1)
    parts.take()
    rows = []
    for i, f in enumerate(PLAY):
        prof = cProfile.Profile() if prof_dir else None
        c1, w1 = time.process_time(), time.perf_counter()
        if prof:
            prof.enable()
        scene.frame_set(f)
        if prof:
            prof.disable()
            prof.dump_stats(str(prof_dir / f"play{i}_frame{f}.prof"))
        c2, w2 = time.process_time(), time.perf_counter()
        got = parts.take()
        ms = {k: 1000 * v["cpu_s"] for k, v in got.items()}
        rows.append(
            dict(
                frame=f,
                cpu_ms=1000 * (c2 - c1),
                wall_ms=1000 * (w2 - w1),
                parts_ms=ms,
                blender_ms=1000 * (c2 - c1) - ms.get("read", 0) - ms.get("apply", 0),
                shown=_shown(bpy, scene, playback, np),
            )
        )
        print(
            f"frame {f}: {rows[-1]['cpu_ms']:.1f} ms CPU; "
            + ", ".join(f"{k} {v:.1f}" for k, v in ms.items())
            + f", blender {rows[-1]['blender_ms']:.1f}; shown: {rows[-1]['shown']}",
            flush=True,
        )
    moved = [r for r in rows if r["frame"] != 4]  # frame 4 holds frame 3's file: nothing written

    def med(key, rs=moved):
        return float(np.median([r[key] if key in r else r["parts_ms"].get(key, 0.0) for r in rs]))

    out = dict(
        path="play",
        blend=str(args.blend),
        load_average=os.getloadavg()[0],
        frames=rows,
        median_cpu_ms=med("cpu_ms"),
        median_read_ms_first_pass=med("read", moved[:7]),
        median_apply_ms=med("apply"),
        median_write_attribute_ms=med("apply.write_attribute"),
        median_blender_ms=med("blender_ms"),
        unchanged_frame_cpu_ms=[r["cpu_ms"] for r in rows if r["frame"] == 4],
        all_shown=all(r["shown"] == "all" for r in rows),
        peak_rss_gb=_rss_gb(),
    )
    print({k: v for k, v in out.items() if k != "frames"}, flush=True)
    return out


def cpu_ms(f, n=5):
    """(median, [each]) of n calls of f, CPU ms (process time), rounded."""
    out = []
    for _ in range(n):
        c = time.process_time()
        f()
        out.append(1000 * (time.process_time() - c))
    return round(sorted(out)[n // 2]), [round(x) for x in out]


def regroup(bpy, scene, domain):
    """--regroup: the subdividing modifiers of a bake made before FINER_VERSION 4 (session 32,
    branch playfix) brought to this version's group in memory, each at its own spacing, with its
    helper made anew from the subdivided mesh: what a bake with this version makes of them (never
    saved: the file on disk keeps its group)."""
    from hr_addon.blender import own_values as ov
    from hr_addon.blender.playback import forget_loaded

    c = time.process_time()
    objs = [o for o in scene.objects if ov.subdividing(o) > 0]
    for o in objs:
        ov._ensure(o, domain, ov.subdividing(o))
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    bpy.data.batch_remove([me for o in objs if (me := ov._helper(o, dg)) is not None])
    forget_loaded()  # (the helpers are new: frame 1 written again)
    bare = sum(ov.GUARD not in o.modifiers[-1][ov._socket(o.modifiers[-1])].data.attributes for o in objs)
    print(
        f"regroup: {len(objs)} modifiers to group version {ov.FINER_VERSION} ({bare} helpers without "
        f"the guard), {time.process_time() - c:.1f} s CPU",
        flush=True,
    )


def _shown(bpy, scene, playback, np):
    """'all' when every object's evaluated mesh holds the frame's values in HR_Radiance, else the
    first object that does not."""
    reader = playback.get_reader(playback.bake_dir_abs(scene))
    arrays = reader.load(scene.frame_current)
    dg = bpy.context.evaluated_depsgraph_get()
    objs = playback.objects_by_name(scene, arrays)
    for name, values in arrays.items():
        attr = objs[name].evaluated_get(dg).data.attributes.get(playback.ATTRIBUTE)
        buf = np.empty(values.size, np.float32)
        if attr is not None:
            attr.data.foreach_get("color", buf)
        if attr is None or not np.array_equal(buf, values.reshape(-1)):
            return name
    return "all"


def _per_frame(d):
    """{frame: bytes on disk} of each frame's own files (.npz, or its images)."""
    import re

    out = {}
    for k, v in cache_files(d).items():
        m = re.search(r"(\d{6})\.(npz|exr|png)$", k)
        if m:
            out[int(m.group(1))] = out.get(int(m.group(1)), 0) + v
    return out


def run_op(args):
    bpy, scene = open_blend(args.blend, args.output, args.resolution)
    c0, w0 = time.process_time(), time.perf_counter()
    r = bpy.ops.hr.bake()
    out = dict(
        path="op",
        output=args.output,
        result=sorted(r),
        total_cpu_s=time.process_time() - c0,
        total_wall_s=time.perf_counter() - w0,
        peak_rss_gb=_rss_gb(),
        load_average=os.getloadavg()[0],
    )
    print(out, flush=True)
    return out


def run_cli(args):
    """python -m hr_addon bake in a subprocess; --term-after N: SIGTERM after its Nth frame line (a
    user's Ctrl-C / a farm's kill): exit 130 and the cache folder as before."""
    import signal

    cmd = [
        sys.executable,
        "-m",
        "hr_addon",
        "bake",
        str(args.blend),
        "--output",
        args.output,
        "--quality",
        "draft",
    ]
    if args.output == "texture":
        cmd += ["--resolution", str(args.resolution)]
    d = Path(args.blend).parent / "hr_cache" / Path(args.blend).stem
    before = _stat(d)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    lines, frames = [], 0
    with subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as pr:
        for line in pr.stdout:
            lines.append((time.perf_counter() - w0, line.rstrip()))
            print(f"{lines[-1][0]:8.2f} {line.rstrip()}", flush=True)
            frames += "HR Radiosity: Frame " in line
            if args.term_after and frames == args.term_after:
                pr.send_signal(signal.SIGTERM)
                frames += 1  # once
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = dict(
        path="cli",
        output=args.output,
        cmd=cmd[1:],
        exit=pr.returncode,
        total_cpu_s=(r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime),
        total_wall_s=time.perf_counter() - w0,
        peak_rss_gb=r1.ru_maxrss / 1e6,
        load_average=os.getloadavg()[0],
        lines=lines,
    )
    if args.term_after:
        out.update(
            term_after=args.term_after,
            cache_unchanged=_stat(d) == before,
            files_before=len(before),
            leftovers=_leftovers(d),
        )
        print({k: out[k] for k in ("exit", "cache_unchanged", "files_before", "leftovers")}, flush=True)
    return out


def _stat(d):
    """{relative path: (bytes, mtime ns)} of a cache folder: what a cancelled bake must leave alone."""
    d = Path(d)
    files = [p for p in d.rglob("*") if p.is_file()]
    return {str(p.relative_to(d)): (p.stat().st_size, p.stat().st_mtime_ns) for p in files}


def _leftovers(d):
    """Folders beside the cache a bake left (its temporary folder)."""
    return sorted(p.name for p in Path(d).parent.iterdir() if p.name != Path(d).name)


def run_background(args):
    """The Bake button's path: background.BackgroundBake (a saved copy baked by a worker process,
    python -m hr_addon bake with a status file), polled every 0.25 s as the operator's timer does;
    --cancel-after N: Cancel (the operator's, SIGTERM) once the worker reports frame N."""
    from hr_addon.blender import background

    bpy, scene = open_blend(args.blend, args.output, args.resolution)
    d = Path(args.blend).parent / "hr_cache" / Path(args.blend).stem
    before = _stat(d)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    c0, w0 = time.process_time(), time.perf_counter()
    job = background.BackgroundBake(scene, bpy.context.view_layer)
    job.start()
    frames, last, finish_cpu = [], None, 0.0
    while True:
        c1 = time.process_time()
        running = job.poll()
        if not running:
            finish_cpu = time.process_time() - c1  # the result loaded into the scene (use_bake, the frame)
            break
        f = job.frame if job.status.get("stage") == "frame" else None
        if f is not None and f != last:
            frames.append((f, time.perf_counter() - w0))
            last = f
            if args.cancel_after and len(frames) == args.cancel_after:
                job.cancel()
                break
        time.sleep(0.25)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = dict(
        path="background",
        output=args.output,
        state=job.state,
        summary=job.summary,
        worker_cpu_s=(r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime),
        this_process_cpu_s=time.process_time() - c0,
        result_load_cpu_s=finish_cpu,
        total_wall_s=time.perf_counter() - w0,
        frames_seen=frames,
        worker_peak_rss_gb=r1.ru_maxrss / 1e6,
        load_average=os.getloadavg()[0],
    )
    if args.cancel_after:
        out.update(cache_unchanged=_stat(d) == before, files_before=len(before), leftovers=_leftovers(d))
    print({k: v for k, v in out.items() if k != "frames_seen"}, flush=True)
    return out


def run_cancel(args):
    """Close the bake generator after --cancel-after frames (what Esc / Cancel does to a bake in this
    process; the interactive one kills its worker): the cache folder must be as before."""
    from hr_addon.blender.bake import BakeJob, bake_frames, cache_dir_for

    bpy, scene = open_blend(args.blend, args.output, args.resolution)
    d = cache_dir_for(scene)
    before = _stat(d)
    job = BakeJob(bake_frames(scene))
    n = 0
    while job.step():
        if job.progress.stage == "frame":
            n += 1
            if n == (args.cancel_after or 3):
                job.cancel()
                break
    out = dict(
        path="cancel",
        output=args.output,
        frames_done=n,
        files_before=len(before),
        cache_unchanged=_stat(d) == before,
        leftovers=_leftovers(d),
        peak_rss_gb=_rss_gb(),
    )
    print(out, flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--blend", required=True)
    ap.add_argument("--make", action="store_true", help="make the .blend first")
    ap.add_argument("--path", choices=("bake", "op", "cli", "background", "cancel", "play"), default=None)
    ap.add_argument("--output", choices=("vertex", "texture"), default="vertex")
    ap.add_argument("--resolution", type=int, default=16, help="texture output's lightmap size")
    ap.add_argument("--cancel-after", type=int, default=0, help="cancel / background: after N frames (3)")
    ap.add_argument("--term-after", type=int, default=0, help="--path cli: SIGTERM after N frame lines")
    ap.add_argument("--profile", default=None, help="folder for a cProfile file per frame")
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--regroup",
        action="store_true",
        help="--path play: the bake's subdividing "
        "modifiers brought to this version's group in memory first (regroup)",
    )
    ap.add_argument("--size", default="100k", help="--make: furnished_room's size (20k, 100k)")
    ap.add_argument("--vertex-spacing", type=float, default=None, help="the bake's Vertex Spacing")
    args = ap.parse_args(argv)
    if args.make:
        c0 = time.process_time()
        info = make_blend(args.blend, args.size)
        print(
            f"made {args.blend}: {info['objects']} objects, {info['triangles']} triangles, "
            f"{time.process_time() - c0:.1f} s CPU",
            flush=True,
        )
    if args.path is None:
        return
    paths = dict(
        bake=run_bake, op=run_op, cli=run_cli, background=run_background, cancel=run_cancel, play=run_play
    )
    out = paths[args.path](args)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
