"""Live Relight benchmark: time per light-shape edit, in bpy, through the extension's own Live code.

    .venv/bin/python benchmarks/bench_live.py [--quality draft,medium] [--methods FE,AUTO]
                                              [--furnished] [--furnished-quality draft] [--out benchmarks/out]
    .venv/bin/python benchmarks/bench_live.py --plot          # chart and table from the JSON only

Scenes: the Cornell sample (sample_blends/cornell.blend: its window stays on, the back-wall patch is
edited) and, with --furnished, the furnished room of hr_testing/furnished.py (furnished_room("100k"):
~100k triangles, 3,882 objects, made into Blender objects here; a window on the west wall is edited).

Each run turns Live on (hr.live_update, which builds the hierarchy), then makes a fixed sequence
of edits of one light shape: drag steps across its wall, scaling, rotation in its plane, a
reshape (a corner moved), strength and colour changes, hide / show. Per edit it measures, with
time.perf_counter():
  - `ui`: what the interactive path does after the depsgraph handler fired: read the light shapes
    and hand them over (main thread), the worker's DynamicRadiosity.apply + per-object values
    (`apply`, `output`), writing HR_Radiance (main thread), and Blender's re-evaluation of the
    written meshes that follows (`eval`: view_layer.update(), main thread, ~65 us per written mesh
    at 100k; counted since session 29, lvbudget). The timer's polling interval (20 ms) and the
    viewport's drawing are not included;
  - `op`: the same edits again through bpy.ops.hr.live_update() (the synchronous entry point),
    which also compares every participating object with the hierarchy's geometry (signatures);
  - `op_fast`: again with hr.live_update(check_geometry=False) (only which objects take part and
    what the depsgraph reported are compared).
With --preview the `ui` path runs as progressive Live (docs/live.md, "Progressive Live"): each
geometry edit is delivered as the worker's preview (live_worker.PREVIEW, flush(refine=False)), and
after the last edit of each kind (the drag pauses) the refine is timed apart (`refine` rows); the
results go to live_preview.json (the `op` paths are synchronous: exact at once, as without it).
Medians and 95th percentiles per edit kind and over all edits go to benchmarks/out/live.json.
Timings are wall seconds on this machine; other jobs sharing the two cores make them noisy, so each
run also keeps the `ui` path's CPU seconds of the process per edit (main thread and worker: the
figure to compare on a shared machine). benchmarks/live_edits.png and the README's table (printed
last) show those CPU ms, each run exact (live.json) beside its progressive one (live_preview.json)
where that exists. Benchmarks print and plot; no test asserts on time.
"""

import argparse
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
OUT = ROOT / "benchmarks" / "out"
TARGETS = {
    ("cornell", "draft"): 0.030,
    ("cornell", "medium"): 0.100,
    ("furnished_100k", "draft"): 0.300,
    ("furnished_100k", "medium"): 0.300,
}


HELPERS = None  # --helpers: the Vertex Spacing whose modifiers and helpers the scene gets before Live


# -- scenes --------------------------------------------------------------------------------------
def open_cornell(tmp):
    import bpy

    path = Path(tmp) / "cornell.blend"
    shutil.copy(ROOT / "sample_blends" / "cornell.blend", path)
    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    scene = bpy.context.scene
    for o in scene.objects:
        if o.hr.is_light_shape:
            o.animation_data_clear()
            o.hide_render = False
    patch = bpy.data.objects["Back Patch"]
    _origin_to_centre(patch)
    # the patch slides along the back wall (plane y = 0.5592, normal -y): x in the wall, z up
    return scene, patch, "EMISSION", np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 0.016


def make_furnished(tmp, size="100k"):
    """The furnished room as Blender objects (one per object of the core builder, materials shared
    per distinct colour), a window light shape on the west wall."""
    import bpy

    sys.path.insert(0, str(ROOT / "scripts"))
    from hr_testing.furnished import furnished_room
    import make_samples as ms

    mesh, info = furnished_room(size)
    ms.reset()
    mats = {}
    order = np.argsort(mesh.object_id, kind="stable")
    bounds = np.searchsorted(mesh.object_id[order], np.arange(len(mesh.object_names) + 1))
    for k, name in enumerate(mesh.object_names):
        polys = order[bounds[k] : bounds[k + 1]]
        if not len(polys):
            continue
        loops = [mesh.loop_verts[mesh.loop_start[p] : mesh.loop_start[p] + mesh.loop_total[p]] for p in polys]
        used = np.unique(np.concatenate(loops))
        remap = np.full(len(mesh.verts), -1, np.int64)
        remap[used] = np.arange(len(used))
        rho, em = tuple(np.round(mesh.reflectance[polys[0]], 6)), tuple(np.round(mesh.emission[polys[0]], 6))
        key = (rho, em)
        if key not in mats:
            if max(em) > 0:
                s = max(em)
                mats[key] = ms.principled(f"m{len(mats)}", rho, tuple(e / s for e in em), s)
            else:
                mats[key] = ms.diffuse(f"m{len(mats)}", rho)
        ms.mesh_object(name, mesh.verts[used], [remap[lp].tolist() for lp in loops], mats[key])
    wall, (o, u, v) = info["light_wall"]
    c = o + 0.6 * u + 0.5 * v
    w, h = 0.9, 0.7
    corners = [
        c - w / 2 * u - h / 2 * v,
        c + w / 2 * u - h / 2 * v,
        c + w / 2 * u + h / 2 * v,
        c - w / 2 * u + h / 2 * v,
    ]
    win = ms.light_shape(
        "Window",
        [tuple(p - c) for p in corners],
        [[0, 1, 2, 3]],
        ms.emission("Window Light", (1.0, 0.95, 0.85), 20.0),
        location=tuple(c),
    )
    scene = bpy.context.scene
    path = Path(tmp) / f"furnished_{size}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    return scene, win, "EMISSION", u, np.cross(u, v), 0.05, info


def furnished_live(tmp, size="100k"):
    """make_furnished's room with Live on (FE draft, the final gather; built by hr.live_update()):
    (scene, the window, its node kind, along, normal, step, view layer, session)."""
    import bpy

    from hr_addon.blender import live

    c0 = time.process_time()
    scene, obj, kind, along, normal, step, _ = make_furnished(tmp, size)
    scene.hr.method, scene.hr.quality, scene.hr.final_gather = "FE", "DRAFT", True
    scene.hr.live = True
    assert bpy.ops.hr.live_update() == {"FINISHED"}
    print(f"built: {time.process_time() - c0:.1f} s CPU", flush=True)
    return scene, obj, kind, along, normal, step, bpy.context.view_layer, live.session(scene)


def _origin_to_centre(obj):
    """Put the object's origin at its mesh's centre (so it rotates and scales about itself)."""
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)
    c = co.mean(0)
    me.vertices.foreach_set("co", (co - c).astype(np.float32).ravel())
    me.update()
    obj.location = tuple(np.asarray(obj.location) + c)


# -- edits ---------------------------------------------------------------------------------------
def edit_sequence(obj, kind, along, normal, step, drag=24):
    """[(kind, callable)] of edits of one light shape: drag steps in its plane (first along
    `along`, then across it: every position a new one, so no response is reused from the cache of
    recently removed shapes), scale, rotate about its normal, reshape, strength, colour, hide / show
    (these last ones do reuse the cached response: a shape switched back on)."""
    from mathutils import Matrix, Vector

    node = next(n for n in obj.data.materials[0].node_tree.nodes if n.type == kind)
    strength = node.inputs["Strength"]
    colour = node.inputs["Color"]
    up = np.cross(normal, along)
    edits = []
    for i in range(drag):
        d = step * along if i < drag // 2 else 0.5 * step * up
        edits.append(("move", lambda d=d: setattr(obj, "location", Vector(obj.location) + Vector(d))))
    for f in (1.1, 1.1, 0.9, 0.9, 1.05, 0.95):
        edits.append(("scale", lambda f=f: setattr(obj, "scale", Vector(obj.scale) * f)))
    for a in (8, 8, -8, -8, 5, -5):
        R = Matrix.Rotation(math.radians(a), 4, Vector(normal))

        def rot(R=R):
            obj.matrix_world = (
                Matrix.Translation(obj.matrix_world.translation)
                @ R
                @ Matrix.Translation(-obj.matrix_world.translation)
                @ obj.matrix_world
            )

        edits.append(("rotate", rot))
    for d in (0.3, -0.3, 0.2, -0.2):

        def reshape(d=d):
            v = obj.data.vertices[2]
            v.co = Vector(v.co) + Vector(
                d * step * np.array([1.0, 1.0, 1.0]) * (along + np.cross(normal, along))
            )
            obj.data.update()

        edits.append(("reshape", reshape))
    for s in (1.5, 0.8, 1.2, 0.9, 1.1, 0.7):
        edits.append(("strength", lambda s=s: setattr(strength, "default_value", strength.default_value * s)))
    for c in ((1.0, 0.6, 0.4), (0.5, 0.7, 1.0), (1.0, 1.0, 0.8), (0.8, 1.0, 0.8)):
        edits.append(("colour", lambda c=c: setattr(colour, "default_value", (*c, 1.0))))
    for _ in range(3):
        edits.append(("hide", lambda: setattr(obj, "hide_render", True)))
        edits.append(("show", lambda: setattr(obj, "hide_render", False)))
    return edits


def _written(names):
    """Every named object's HR_Radiance, one float32 array."""
    import bpy

    parts = []
    for n in names:
        data = bpy.data.objects[n].data.attributes["HR_Radiance"].data
        parts.append(np.empty(len(data) * 4, np.float32))
        data.foreach_get("color", parts[-1])
    return np.concatenate(parts)


def _stats(xs):
    xs = np.asarray(xs, float)
    return {
        "n": int(len(xs)),
        "median": float(np.median(xs)),
        "p95": float(np.percentile(xs, 95)),
        "max": float(xs.max()),
    }


def run(scene_name, quality, method, furnished_size="100k", final_gather=True, preview=False, kinds=None):
    import bpy
    import hr_addon

    if not hasattr(bpy.types.Scene, "hr"):
        hr_addon.register()
    from hr_addon.blender import live

    tmp = tempfile.mkdtemp(prefix="hr_bench_live_")
    try:
        info = {}
        if scene_name == "cornell":
            scene, obj, kind, along, normal, step = open_cornell(tmp)
        else:
            t0 = time.perf_counter()
            scene, obj, kind, along, normal, step, info = make_furnished(tmp, furnished_size)
            info = {"scene_seconds": time.perf_counter() - t0, **info}
            info.pop("light_wall", None)
        scene.hr.method = method
        scene.hr.quality = quality.upper()
        scene.hr.final_gather = final_gather
        vl = bpy.context.view_layer
        if HELPERS is not None:  # what a vertex bake at that Vertex Spacing leaves (own_values)
            from hr_addon.blender.own_values import ensure_own_values
            from hr_addon.blender.scene_in import geometry_objects

            ensure_own_values(geometry_objects(vl), scene.hr.domain, vl.depsgraph, HELPERS)
            info["helpers_spacing"] = HELPERS
        scene.hr.live = True
        t0 = time.perf_counter()
        assert bpy.ops.hr.live_update() == {"FINISHED"}
        first = time.perf_counter() - t0
        sess = live.session(scene)
        w = sess.worker
        if preview:
            from hr_addon.blender.live_worker import PREVIEW

            w.preview = PREVIEW
        out = {
            "scene": scene_name,
            "quality": quality,
            "method": method,
            "final_gather": bool(scene.hr.final_gather),
            "first_update_s": first,
            "build_s": w.build_seconds,
            "nodes": int(w.dyn.h.n),
            "links": int(len(w.dyn.links)),
            "polygons": int(w.spec.polygons),
            "edits": {},
            **info,
        }
        start = (np.array(obj.location), tuple(obj.rotation_euler), tuple(obj.scale))
        for m, mode in enumerate(("ui", "op", "op_fast")):
            # each pass starts a third of a step further across: its positions are new ones
            obj.location, obj.rotation_euler, obj.scale = (
                start[0] - m / 3 * step * np.cross(normal, along),
                *start[1:],
            )
            assert bpy.ops.hr.live_update() == {"FINISHED"}
            rows = []
            seq = [e for e in edit_sequence(obj, kind, along, normal, step) if not kinds or e[0] in kinds]
            for j, (k, edit) in enumerate(seq):
                edit()
                if mode == "ui":
                    bpy.context.view_layer.update()  # the depsgraph handler fires, as in the UI
                    t0, c0 = time.perf_counter(), time.process_time()
                    live._reconcile(sess, scene, vl, check_geometry=False, fast=True)  # as the timer
                    t1, c1 = time.perf_counter(), time.process_time()
                    w.flush(refine=not preview)
                    t2, c2 = time.perf_counter(), time.process_time()
                    live._deliver(sess, scene)
                    t3, c3 = time.perf_counter(), time.process_time()
                    vl.update()  # Blender's re-evaluation of the written meshes (before the redraw)
                    t4, c4 = time.perf_counter(), time.process_time()
                    assert not sess.error and not sess.problems, (sess.error, sess.problems)
                    r = sess.last
                    if preview and (j + 1 == len(seq) or seq[j + 1][0] != k):  # the drag pauses
                        t5, c5 = time.perf_counter(), time.process_time()
                        w.flush()
                        live._deliver(sess, scene)
                        vl.update()
                        t6, c6 = time.perf_counter(), time.process_time()
                        assert not sess.last.preview and sess.text().startswith("Live: up to date, exact")
                        if sess.last is not r:
                            rows.append({"kind": "refine", "total": t6 - t5, "cpu": c6 - c5, "of": k})
                    rows.append(
                        {
                            "kind": k,
                            "total": t4 - t0,
                            "cpu": c4 - c0,  # CPU seconds of the process (main thread + worker)
                            # (the worker computes in this thread in background mode: flush)
                            "cpu_parts": {
                                "read": c1 - c0,
                                "flush": c2 - c1,
                                "write": c3 - c2,
                                "eval": c4 - c3,
                            },
                            "read": t1 - t0,
                            "apply": r.t_apply,
                            "output": r.t_output,
                            "write": t3 - t2,
                            "eval": t4 - t3,
                            "events": [e.kind for e in r.report.events],
                            "iterations": int(r.report.iterations),
                            "preview": bool(r.preview),
                        }
                    )
                    if preview:  # the refine row (if any) after this edit's
                        rows[-2:] = sorted(rows[-2:], key=lambda x: x["kind"] == "refine")
                else:
                    t0 = time.perf_counter()
                    assert bpy.ops.hr.live_update(check_geometry=(mode == "op")) == {"FINISHED"}
                    rows.append({"kind": k, "total": time.perf_counter() - t0})
            done = sorted({r["kind"] for r in rows}, key=[r["kind"] for r in rows].index)
            edits = [r for r in rows if r["kind"] != "refine"]  # (refines: --preview's own rows)
            res = {"all": _stats([r["total"] for r in edits])}
            res.update({k: _stats([r["total"] for r in rows if r["kind"] == k]) for k in done})
            if mode == "ui":
                for part in ("read", "apply", "output", "write", "eval"):
                    res[f"part_{part}"] = _stats([r[part] for r in edits])
                res["all_cpu"] = _stats([r["cpu"] for r in edits])
                for k in done:
                    res[f"{k}_cpu"] = _stats([r["cpu"] for r in rows if r["kind"] == k])
                    parts = [r["cpu_parts"] for r in rows if r["kind"] == k and "cpu_parts" in r]
                    for part in (
                        ("read", "flush", "write", "eval") if parts else ()
                    ):  # (--preview's refines: none)
                        res[f"{k}_cpu_{part}"] = _stats([p[part] for p in parts])
                moves = [r["iterations"] for r in rows if r["kind"] == "move"]
                res["moves_iterations"] = _stats(moves) if moves else None
                if preview:
                    res["previews_cpu"] = _stats([r["cpu"] for r in rows if r.get("preview")])
                    res["refine_cpu"] = _stats([r["cpu"] for r in rows if r["kind"] == "refine"])
                    pv, rf = res["previews_cpu"], res["refine_cpu"]
                    print(
                        f"[ui] previews CPU median {1000 * pv['median']:.1f} / p95 {1000 * pv['p95']:.1f} ms;"
                        f" refines CPU median {1000 * rf['median']:.1f} / p95 {1000 * rf['p95']:.1f} ms"
                    )
                out["rows"] = rows
                if kinds:  # HR_Radiance after the ui pass: another checkout's run compares with it
                    out["written"] = _written(sess.targets)
            out["edits"][mode] = res
            print(
                f"{scene_name} {quality} {method} [{mode}] per edit: "
                f"median {1000 * res['all']['median']:.1f} ms, "
                f"p95 {1000 * res['all']['p95']:.1f} ms; "
                + (
                    "; ".join(
                        f"{k} median {1000 * res[k]['median']:.1f} ms"
                        for k in done
                        if k in ("move", "colour", "strength")
                    )
                ),
                flush=True,
            )
            if mode == "ui" and kinds:
                print(
                    "; ".join(
                        f"{k} CPU median {1000 * res[f'{k}_cpu']['median']:.1f} ms ("
                        + ", ".join(
                            f"{p} {1000 * res[f'{k}_cpu_{p}']['median']:.1f}"
                            for p in ("read", "flush", "write", "eval")
                        )
                        + ")"
                        for k in done
                        if f"{k}_cpu_read" in res  # (--preview's refine rows: no parts)
                    ),
                    flush=True,
                )
        scene.hr.live = False
        bpy.ops.hr.live_update()
        return out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# -- report --------------------------------------------------------------------------------------
def table(results):
    """Markdown: per scene / quality / method, median / p95 ms of each edit kind (the UI path), of
    all edits, and of all edits through hr.live_update() (with and without the geometry check)."""
    kinds = ("move", "scale", "rotate", "reshape", "strength", "colour", "hide", "show")
    lines = [
        "| scene | quality | method | final gather | build | all edits | all edits, CPU | "
        + " | ".join(kinds)
        + " | hr.live_update() | same, check_geometry=False | target (p95) |",
        "|---" * (10 + len(kinds)) + "|",  # 7 + kinds + 3 columns
    ]

    def ms(s):
        return f"{1000 * s:.0f}" if s >= 0.0095 else f"{1000 * s:.1f}"

    def mp(st):
        return f"{ms(st['median'])} / {ms(st['p95'])}"

    for r in results:
        e, o, f = r["edits"]["ui"], r["edits"]["op"], r["edits"]["op_fast"]
        tgt = TARGETS.get((r["scene"], r["quality"]))
        met = "" if tgt is None else f"{ms(tgt)} ({'met' if e['all']['p95'] <= tgt else 'not met'})"
        lines.append(
            f"| {r['scene']} | {r['quality']} | {r['method']} | "
            f"{ {True: 'on', False: 'off'}.get(r.get('final_gather'), 'before it') } | "
            f"{r['build_s']:.1f} s | {mp(e['all'])} | "
            f"{mp(e['all_cpu']) if 'all_cpu' in e else '-'} | "
            + " | ".join(mp(e[k]) for k in kinds)
            + f" | {mp(o['all'])} | {mp(f['all'])} | {met} |"
        )
    return "\n".join(lines)


KINDS = ("move", "scale", "rotate", "reshape", "strength", "colour", "hide", "show")


def readme_table(exact, previews=()):
    """README's Live Relight table: per Cornell quality / method, the `ui` path's CPU ms of the process
    per edit (median / 95th percentile) over all edits and per kind, exact (live.json) and progressive
    (live_preview.json: the geometry edits as previews, as the UI's threaded worker shows a drag)."""
    prev = {(r["scene"], r["quality"], r["method"]): r for r in previews}
    lines = [
        "| Cornell, final gather on | Live path | build (wall) | all edits | "
        + " | ".join(KINDS)
        + " | issue 19 target (median, all edits) |",
        "|---" * (4 + len(KINDS) + 1) + "|",
    ]

    def ms(s):
        return f"{1000 * s:.0f}" if s >= 0.0095 else f"{1000 * s:.1f}"

    def mp(st):
        return f"{ms(st['median'])} / {ms(st['p95'])}"

    for r in exact:
        if r["scene"] != "cornell" or "all_cpu" not in r["edits"]["ui"]:
            continue
        tgt = 0.030 if r["quality"] == "draft" else None
        for path, run in (("exact", r), ("progressive", prev.get((r["scene"], r["quality"], r["method"])))):
            if run is None:
                continue
            e = run["edits"]["ui"]
            med = e["all_cpu"]["median"]
            met = "-" if tgt is None else f"30 ms: {'met' if med <= tgt else '**missed**'}"
            lines.append(
                f"| {r['quality']} {r['method']} | {path} | {run['build_s']:.1f} s | {mp(e['all_cpu'])} ms | "
                + " | ".join(mp(e[f"{k}_cpu"]) for k in KINDS)
                + f" | {met} |"
            )
    return "\n".join(lines)


def plot(results, path, date="", previews=()):
    """The chart: the `ui` path's CPU ms of the process per edit (the figure a shared machine keeps),
    each run exact (live.json) and, where live_preview.json has it, progressive (previews)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, NullFormatter

    prev = {(r["scene"], r["quality"], r["method"]): r for r in previews}
    rows = []  # (label, ui stats, target)
    for r in results:
        if "all_cpu" not in r["edits"]["ui"]:  # runs before the CPU was kept: not comparable
            continue
        key = (r["scene"], r["quality"], r["method"])
        tgt = 1000 * TARGETS.get((r["scene"], r["quality"]), float("nan"))
        rows.append((f"{r['scene']} {r['quality']} {r['method']}, exact", r["edits"]["ui"], tgt))
        if key in prev:
            rows.append(
                (f"{r['scene']} {r['quality']} {r['method']}, progressive", prev[key]["edits"]["ui"], tgt)
            )
    fig, axes = plt.subplots(
        1, 2, figsize=(12, 0.45 * len(rows) + 2.6), gridspec_kw={"width_ratios": [1, 1.4]}
    )
    y = np.arange(len(rows))
    ax = axes[0]
    ax.barh(y, [1000 * e["all_cpu"]["median"] for _, e, _ in rows], color="#4c72b0", label="median")
    ax.scatter(
        [1000 * e["all_cpu"]["p95"] for _, e, _ in rows],
        y,
        color="k",
        marker="|",
        s=200,
        label="95th percentile",
        zorder=3,
    )
    ax.scatter([t for _, _, t in rows], y, color="#c44e52", marker="x", s=60, label="target", zorder=3)
    ax.set_yticks(y, [lb for lb, _, _ in rows])
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlim(left=1)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("CPU ms per edit (read shapes + light events + write HR_Radiance)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, fontsize=8)
    ax.set_title("All edits")
    ax = axes[1]
    width = 0.8 / len(KINDS)
    for j, k in enumerate(KINDS):
        vals = [1000 * e[f"{k}_cpu"]["median"] for _, e, _ in rows]
        ax.barh(y + (j - len(KINDS) / 2 + 0.5) * width, vals, height=width, label=k)
    ax.set_yticks(y, [""] * len(y))
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlim(left=1)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("median CPU ms per edit, by kind")
    ax.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    ax.set_title("By edit kind")
    when = f", measured {date} (CPU ms of the process, 2 shared cores)" if date else ""
    fig.suptitle(f"Live Relight: time per light-shape edit (benchmarks/bench_live.py){when}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quality", default="draft,medium")
    ap.add_argument("--methods", default="FE,AUTO")
    ap.add_argument(
        "--furnished", action="store_true", help="also the furnished 100k-triangle room (slow build)"
    )
    ap.add_argument("--furnished-quality", default="draft")
    ap.add_argument("--furnished-methods", default="FE")
    ap.add_argument("--skip-cornell", action="store_true")
    ap.add_argument("--no-final-gather", action="store_true", help="Live with the final gather off")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--plot", action="store_true", help="only redraw the chart and table from the JSON")
    ap.add_argument("--preview", action="store_true", help="ui path: progressive Live (live_preview.json)")
    ap.add_argument(
        "--kinds",
        default="",
        help="only these edit kinds (e.g. strength,colour): the JSON into --out's live_kinds.json, no chart",
    )
    ap.add_argument(
        "--root", default="", help="the checkout whose hr_addon is timed (e.g. main's for a before)"
    )
    ap.add_argument(
        "--helpers",
        type=float,
        default=None,
        metavar="S",
        help="first give the scene the HR Radiance modifiers and helpers a vertex bake at Vertex Spacing S "
        "makes (own_values.ensure_own_values): Live after such a bake",
    )
    args = ap.parse_args()
    if args.root:
        sys.path.insert(0, args.root)
    global HELPERS
    HELPERS = args.helpers
    kinds = [k for k in args.kinds.split(",") if k]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jpath = out / ("live_kinds.json" if kinds else "live_preview.json" if args.preview else "live.json")
    old = json.loads(jpath.read_text()) if jpath.exists() else {"runs": []}
    if not args.plot:
        runs, fg_off = [], args.no_final_gather
        if not args.skip_cornell:
            for q in args.quality.split(","):
                for m in args.methods.split(","):
                    runs.append(
                        run("cornell", q, m, final_gather=not fg_off, preview=args.preview, kinds=kinds)
                    )
        if args.furnished:
            for q in args.furnished_quality.split(","):
                for m in args.furnished_methods.split(","):
                    runs.append(
                        run(
                            "furnished_100k", q, m, final_gather=not fg_off, preview=args.preview, kinds=kinds
                        )
                    )
        keep = [
            r
            for r in old["runs"]
            if (r["scene"], r["quality"], r["method"])
            not in {(n["scene"], n["quality"], n["method"]) for n in runs}
        ]
        old = {
            "machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.python_version()}",
            "date": time.strftime("%Y-%m-%d %H:%M"),
            "runs": keep + runs,
        }
        if kinds:
            import hr_addon

            old.update(
                kinds=kinds, hr_addon=str(Path(hr_addon.__file__).parent), load_average=os.getloadavg()
            )
            for r in runs:
                np.save(out / f"written_{r['scene']}_{r['quality']}_{r['method']}.npy", r.pop("written"))
        jpath.write_text(json.dumps(old, indent=1))
        print(f"wrote {jpath}")
        if kinds:
            return
    order = {"cornell": 0, "furnished_100k": 1}
    res = sorted(old["runs"], key=lambda r: (order.get(r["scene"], 9), r["quality"] != "draft", r["method"]))
    print(table(res))
    # the chart and README's table: the exact runs (live.json) with their progressive ones beside them
    exact_path, prev_path = out / "live.json", out / "live_preview.json"
    exact = json.loads(exact_path.read_text()) if exact_path.exists() else {"runs": []}
    previews = json.loads(prev_path.read_text())["runs"] if prev_path.exists() else []
    res = sorted(
        exact["runs"], key=lambda r: (order.get(r["scene"], 9), r["quality"] != "draft", r["method"] != "FE")
    )
    print(readme_table(res, previews))
    # the README's chart from the default folder's JSONs; another --out keeps its chart beside them
    chart = (
        ROOT / "benchmarks" / "live_edits.png" if out.resolve() == OUT.resolve() else out / "live_edits.png"
    )
    plot(res, chart, exact.get("date", ""), previews)


if __name__ == "__main__":
    main()
