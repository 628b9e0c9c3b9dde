"""Writing Live's result into HR_Radiance of every object of the furnished room (no HR build):
the per-object values from the loop values (the worker's Target.extract + RGBA copy, or
scene_in.FlatExtract), then the UI thread's write (playback.apply_arrays and the Live session's
marking of its own writes). CPU ms per step (time.process_time), the median of --repeats.

    .venv/bin/python benchmarks/bench_write.py [--size 100k] [--root DIR] [--json out.json]

--root: the checkout whose hr_addon is timed (default: this one), e.g. main's for a "before".
The written values are read back and compared between the paths (bitwise).
"""

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", default="100k")
    ap.add_argument("--root", default=str(HERE.parent))
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--domain", default="CORNER")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    sys.path.insert(0, args.root)
    import bpy
    import hr_addon

    from bench_live import make_furnished

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    from hr_addon.blender import playback, scene_in
    from hr_addon.blender.live_worker import _rgba
    from hr_addon.blender.state import STATE

    cpu = time.process_time
    scene, *_ = make_furnished(tempfile.mkdtemp(prefix="hr_bench_write_"), args.size)
    vl = bpy.context.view_layer
    si = scene_in.collect_geometry(vl, bpy.context.evaluated_depsgraph_get())
    targets, d = si.targets, args.domain
    n = len(si.mesh.verts) if d == "POINT" else len(si.mesh.loop_verts)
    rng = np.random.default_rng(0)
    out = dict(size=args.size, root=os.path.dirname(os.path.dirname(hr_addon.__file__)), domain=d)
    out.update(objects=len(targets), load_average=os.getloadavg()[0])

    def timed(label, fn):
        ts = []
        for _ in range(args.repeats):
            c0 = cpu()
            r = fn()
            ts.append(cpu() - c0)
        out[label] = statistics.median(ts) * 1e3
        print(f"{label:34s} {out[label]:7.1f} ms CPU (min {min(ts) * 1e3:.1f})", flush=True)
        return r

    def read_back():
        parts = []
        for t in targets:
            data = bpy.data.objects[t.name].data.attributes["HR_Radiance"].data
            buf = np.empty(len(data) * 4, np.float32)
            data.foreach_get("color", buf)
            parts.append(buf)
        return np.concatenate(parts)

    loops = rng.random((n, 3), dtype=np.float32)
    old_vals = timed(
        "extract: per target + rgba", lambda: {t.name: _rgba(t.extract(loops, d)) for t in targets}
    )

    def deliver_old(values):  # live_session._deliver as it is
        problems = playback.apply_arrays(scene, values, d)
        for obj in playback.objects_by_name(scene, values).values():
            if obj is not None and obj.type == "MESH":
                STATE.writes.mark(obj.data.name, reader=scene.name)
        return problems

    playback.apply_arrays(scene, old_vals, d)  # the attributes exist from here on
    assert not timed("write: apply_arrays", lambda: playback.apply_arrays(scene, old_vals, d))
    timed("write: apply_arrays + Live's marks", lambda: deliver_old(old_vals))
    ref = read_back()
    if hasattr(scene_in, "FlatExtract"):
        fx = scene_in.FlatExtract(targets, d)
        new_vals = timed("extract: FlatExtract.rgba", lambda: fx.rgba(loops))
        out["values_equal"] = all(np.array_equal(old_vals[k], new_vals[k]) for k in old_vals)
        playback.apply_arrays(scene, {k: v * 0 for k, v in old_vals.items()}, d)

        def deliver_new():  # what live_session._deliver can call instead
            return playback.apply_arrays(scene, new_vals, d, reader=scene.name)

        assert not timed("write: apply_arrays(reader=) flat", deliver_new)
        out["written_equal"] = bool(np.array_equal(read_back(), ref))
        print(f"values equal {out['values_equal']}, written values equal {out['written_equal']}", flush=True)

        def former():  # a copy of the code before edit100k: apply_arrays, write_attribute, Live's marks
            objs = playback.objects_by_name(scene, old_vals)
            for name, values in old_vals.items():
                me = objs[name].data
                if objs[name].type != "MESH" or objs[name].mode == "EDIT":
                    continue
                attr = me.color_attributes.get("HR_Radiance")
                assert attr.domain == d and attr.data_type == "FLOAT_COLOR" and len(attr.data) == len(values)
                attr.data.foreach_set("color", np.ascontiguousarray(values, np.float32).ravel())
                me.update_tag()
                STATE.writes.mark(me.name)
            for obj in playback.objects_by_name(scene, old_vals).values():
                if obj is not None and obj.type == "MESH":
                    STATE.writes.mark(obj.data.name, reader=scene.name)

        # the two in turn in one process (the load of the shared machine changes within a run)
        ts = {"former": [], "new": []}
        for _ in range(args.repeats):
            for k, fn in (("former", former), ("new", deliver_new)):
                c0 = cpu()
                fn()
                ts[k].append(cpu() - c0)
        for k, v in ts.items():
            out[f"write in turn: {k}"] = statistics.median(v) * 1e3
            print(f"write in turn: {k:20s} {statistics.median(v) * 1e3:7.1f} ms CPU (min {min(v) * 1e3:.1f})")
    # what follows every write: Blender re-evaluates each written (tagged) mesh; its CPU time
    # includes the depsgraph's own threads, wall time too at this machine's load
    cs, ws = [], []
    for _ in range(3):
        playback.apply_arrays(scene, old_vals, d)
        c0, w0 = cpu(), time.perf_counter()
        vl.update()
        cs.append(cpu() - c0)
        ws.append(time.perf_counter() - w0)
    out["depsgraph update after the write"] = statistics.median(cs) * 1e3
    out["depsgraph update after the write (wall)"] = statistics.median(ws) * 1e3
    c, w = out["depsgraph update after the write"], out["depsgraph update after the write (wall)"]
    print(f"depsgraph update after the write   {c:7.1f} ms CPU, wall {w:.0f} ms", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
