"""In-Blender bake time with the bundled Embree against the numpy tracer, through the installed
extension (bpy module). Builds the linux-x64 zip (or HR_EXTENSION_ZIP), and for each ray mode
starts a fresh Blender process with a throw-away user folder: installs the zip, makes a sample
scene with this Blender version, bakes it with the installed extension's operator and reports the
hierarchy build time and the whole bake time. Mode "numpy" hides embreex completely (also the
extension's copy), which is what a platform without a wheel gets.

Usage: python benchmarks/bench_installed.py [--sample cornell|office|...|furnished] [--quality medium]
       [--frames 1-24] [--python .venvs/bpy-4.2.23/bin/python]
"furnished" is a room with 20 boxes placed as collection instances (made here, not a sample file).
Prints one line per mode and the ratios; writes benchmarks/out/installed.json. Timings depend on the
machine and its load: compare the ratio, not the seconds.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

SCRIPT = textwrap.dedent(r"""
    import importlib.abc, importlib.machinery, json, os, sys, time
    zip_path, blend, mode, quality, frames = sys.argv[1:6]
    RES = os.path.realpath(os.environ["BLENDER_USER_RESOURCES"])

    class Embreex(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name != "embreex":
                return None
            mine = [] if mode == "numpy" else [
                p for p in sys.path if os.path.realpath(p or ".").startswith(RES)
            ]
            spec = importlib.machinery.PathFinder.find_spec(name, mine)
            if spec is None:
                raise ModuleNotFoundError("No module named 'embreex'", name=name)
            return spec

    sys.meta_path.insert(0, Embreex())
    import bpy
    assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                    enable_on_install=True) == {"FINISHED"}
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    s = bpy.context.scene
    a, b = frames.split("-")
    s.hr.quality, s.hr.use_frame_range, s.hr.frame_start, s.hr.frame_end = (
        quality.upper(), True, int(a), int(b)
    )
    bake = __import__("bl_ext.user_default.hr_radiosity.hr_addon.blender.bake", fromlist=["run_bake"])
    t0 = time.perf_counter()
    res = bake.run_bake(s, log=lambda *a, **k: None)
    out = {"bpy": bpy.app.version_string, "mode": mode, "rays": res.rays, "build_s": res.build_seconds,
           "bake_s": time.perf_counter() - t0, "nodes": res.build_report.nodes,
           "links": res.build_report.links, "summary": res.summary()}
    print("RESULT:" + json.dumps(out), flush=True)
""")


FURNISHED = textwrap.dedent(r"""
    # A 4 x 4 x 2.6 m room (8x8 quads per wall) lit by a ceiling panel, furnished with 20 boxes:
    # collection instances of one "Box" (its collection excluded from the view layer).
    import sys
    from pathlib import Path
    sys.path.insert(0, sys.argv[2])
    import make_samples as ms
    import bpy
    scene = ms.reset()
    ms.room((4.0, 4.0, 2.6), ms.room_materials())
    ms.quads_object("Lamp", [ms.orient(ms.np.array([(1.5, 1.5, 2.59), (2.5, 1.5, 2.59), (2.5, 2.5, 2.59),
                                                    (1.5, 2.5, 2.59)]), (2, 2, 0))],
                    ms.emission("Lamp", (1, 1, 1), 10.0))
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    box = ms.quads_object("Box", list(ms.box_quads((0, 0, 0), (0.4, 0.4, 0.5), inward=False).values()),
                          ms.diffuse("Wood", (0.5, 0.35, 0.2)), 2)
    scene.collection.objects.unlink(box)
    props.objects.link(box)
    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    rng = ms.np.random.default_rng(1)
    for i in range(20):
        e = bpy.data.objects.new(f"Box{i:02d}", None)
        e.instance_type, e.instance_collection = "COLLECTION", props
        e.location = (0.2 + 3.2 * rng.random(), 0.2 + 3.2 * rng.random(), 0.0)
        e.rotation_euler[2] = 6.283 * rng.random()
        scene.collection.objects.link(e)
    ms.finish(scene, Path(sys.argv[1]), (1, 1), quality="MEDIUM")
""")


def build_zip():
    given = os.environ.get("HR_EXTENSION_ZIP")
    if given:
        return given
    out = REPO / "build" / "bench_dist"
    p = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "build_extension.py"), "--output-dir", str(out)],
        capture_output=True,
        text=True,
        check=True,
    )
    return [ln for ln in p.stdout.splitlines() if ln.endswith("-linux_x64.zip")][-1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", default="cornell")
    ap.add_argument("--quality", default="medium")
    ap.add_argument("--frames", default="1-24")
    ap.add_argument("--python", default=sys.executable, help="the Python whose bpy runs the bake")
    args = ap.parse_args(argv)
    zip_path = build_zip()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_USER_") and k != "PYTHONPATH"}
        blend = tmp / "scene" / f"{args.sample}.blend"
        if args.sample == "furnished":
            (tmp / "furnished.py").write_text(FURNISHED)
            cmd = [args.python, str(tmp / "furnished.py"), str(blend), str(REPO / "scripts")]
        else:
            cmd = [
                args.python,
                str(REPO / "scripts" / "make_samples.py"),
                args.sample,
                "--out",
                str(blend.parent),
            ]
        subprocess.run(cmd, env=env, capture_output=True, check=True)
        (tmp / "script.py").write_text(SCRIPT)
        for mode in ("embree", "numpy"):
            res = tmp / f"user_{mode}"
            res.mkdir()
            e = dict(env, BLENDER_USER_RESOURCES=str(res), HOME=str(res))
            p = subprocess.run(
                [args.python, str(tmp / "script.py"), zip_path, str(blend), mode, args.quality, args.frames],
                env=e,
                capture_output=True,
                text=True,
            )
            lines = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT:")]
            if p.returncode != 0 or not lines:
                raise SystemExit(p.stdout + p.stderr)
            r = json.loads(lines[-1][7:])
            results.append(r)
            print(
                f"bpy {r['bpy']} {args.sample} {args.quality} frames {args.frames}: rays {r['rays']}: "
                f"hierarchy {r['build_s']:.1f} s, bake {r['bake_s']:.1f} s "
                f"({r['nodes']} nodes, {r['links']} links)",
                flush=True,
            )
    e, n = results
    print(
        f"numpy / embree: hierarchy {n['build_s'] / e['build_s']:.1f}x, "
        f"whole bake {n['bake_s'] / e['bake_s']:.1f}x"
    )
    out = REPO / "benchmarks" / "out"
    out.mkdir(exist_ok=True)
    (out / f"installed_{args.sample}_{results[0]['bpy'].split()[0]}.json").write_text(
        json.dumps(
            {
                "sample": args.sample,
                "quality": args.quality,
                "frames": args.frames,
                "zip": os.path.basename(zip_path),
                "zip_bytes": os.path.getsize(zip_path),
                "results": results,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
