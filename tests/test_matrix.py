"""The installed extension in Blender (bpy module), in an environment without embreex: the
linux-x64 zip brings its own embreex wheel, Blender installs it, and a bake through the installed
extension's operator traces with Embree; then playback, and a background bake.

This file is the version matrix's test (scripts/matrix.py runs it on bpy 4.2 LTS, 4.5 LTS and
5.0, each in its own venv; .ci/run calls it). In the matrix venvs embreex is not installed at all.
In the project's own .venv (5.0) it is, so the Blender process started here hides it: a meta-path
finder lets `import embreex` find only copies under the throw-away Blender user folder, i.e. the
one the extension installed, and the test first checks that embreex is not importable.

HR_EXTENSION_ZIP: a built linux-x64 zip to install (default: built here).
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hr_testing.blend import isolated_env

REPO_ROOT = Path(__file__).resolve().parent.parent
pytestmark = [
    pytest.mark.bpy,
    pytest.mark.slow,
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="installs the linux-x64 zip"),
]


@pytest.fixture(scope="module")
def linux_zip(tmp_path_factory):
    pytest.importorskip("bpy")
    given = os.environ.get("HR_EXTENSION_ZIP")
    if given:
        return Path(given)
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "scripts" / "build_extension.py"), "--output-dir", str(out)],
        cwd=REPO_ROOT,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return Path([ln for ln in proc.stdout.splitlines() if ln.endswith("-linux_x64.zip")][-1])


PRELUDE = textwrap.dedent(r"""
    import importlib, importlib.abc, importlib.machinery, importlib.util, json, os, sys, time
    zip_path, blend = sys.argv[1], sys.argv[2]
    RES = os.path.realpath(os.environ["BLENDER_USER_RESOURCES"])

    class OnlyTheExtensionsEmbreex(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name != "embreex":
                return None
            mine = [p for p in sys.path if os.path.realpath(p or ".").startswith(RES)]
            spec = importlib.machinery.PathFinder.find_spec(name, mine)
            if spec is None:
                raise ModuleNotFoundError("No module named 'embreex' (outside the extension)", name=name)
            return spec

    sys.meta_path.insert(0, OnlyTheExtensionsEmbreex())
    out = {}
    try:
        import embreex  # noqa: F401
        out["embreex_before"] = embreex.__file__
    except ImportError:
        out["embreex_before"] = None
    assert importlib.util.find_spec("hr_addon") is None, "hr_addon importable from the source tree"
    import bpy
    import numpy as np
    out["bpy"] = bpy.app.version_string
    res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    out["install"] = sorted(res)
    MOD = "bl_ext.user_default.hr_radiosity"
    out["enabled"] = MOD in bpy.context.preferences.addons
    import embreex
    out["embreex_after"] = os.path.realpath(embreex.__file__)
    out["embreex_version"] = getattr(embreex, "__version__", "")
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    scene = bpy.context.scene
    scene.hr.quality = "DRAFT"
    scene.hr.method = "FE"
    scene.hr.use_frame_range = True
    scene.hr.frame_start, scene.hr.frame_end = 1, 13

    def colours(name):
        a = bpy.data.objects[name].data.color_attributes["HR_Radiance"]
        v = np.empty(len(a.data) * 4, np.float32)
        a.data.foreach_get("color", v)
        return v.reshape(-1, 4)

    def cache_values(frame, name):
        d = bpy.path.abspath(scene.hr.bake_dir)
        m = json.load(open(os.path.join(d, "manifest.json")))
        return m, np.load(os.path.join(d, m["frames"][str(frame)]))[name]
""")

BAKE_SCRIPT = PRELUDE + textwrap.dedent(r"""
    out["bake"] = sorted(bpy.ops.hr.bake())          # the installed extension's operator (EXEC)
    m, _ = cache_values(1, "right_green")
    out["manifest_rays"] = m.get("rays")
    # playback: frame 1 (no window), 6 (window on the green wall), back to 1
    scene.frame_set(1)
    c1 = colours("right_green")
    scene.frame_set(6)
    c6 = colours("right_green")
    _, want6 = cache_values(6, "right_green")
    scene.frame_set(9)                                # held: same file as frame 6
    c9 = colours("right_green")
    scene.frame_set(1)
    out["playback"] = {"changes": bool(np.abs(c6 - c1).max() > 1e-3), "equals_cache": bool(np.array_equal(c6, want6)),
                       "held": bool(np.array_equal(c9, c6)), "back": bool(np.array_equal(colours("right_green"), c1)),
                       "brighter": float(c6[:, :3].mean() - c1[:, :3].mean())}
    print("RESULT:" + json.dumps(out))
""")

BACKGROUND_SCRIPT = PRELUDE + textwrap.dedent(r"""
    background = importlib.import_module(MOD + ".hr_addon.blender.background")
    scene.frame_set(6)
    job = background.BackgroundBake(scene).start()
    out["worker"] = job.proc.args[:3]
    t0 = time.monotonic()
    while job.poll():
        assert time.monotonic() - t0 < 600, job.status
        time.sleep(0.02)
    out["state"], out["error"], out["summary"] = job.state, job.error, job.summary
    out["stages"] = sorted({s for _, s, _, _ in job.seen if s})
    out["fractions"] = [f for f, _, _, _ in job.seen]
    out["loaded"] = job.loaded
    if job.state == "done":
        m, want6 = cache_values(6, "right_green")
        out["manifest_rays"] = m.get("rays")
        out["shows_frame_6"] = bool(np.array_equal(colours("right_green"), want6))
    print("RESULT:" + json.dumps(out))
""")


BINARY_SCRIPT = PRELUDE + textwrap.dedent(r"""
    # The worker command used inside Blender (Blender's binary, -b --python-expr ... -- args),
    # with the bpy module standing in for the binary: the same expression (enable the installed
    # extension in a fresh process, run its hr_bake) and the same arguments.
    background = importlib.import_module(MOD + ".hr_addon.blender.background")
    job = background.BackgroundBake(scene)
    real_command = job.command

    def as_blender(args):
        argv, env = real_command(args, binary="blender", module=MOD)
        assert argv[:5] == ["blender", "-b", "--python-exit-code", "1", "--python-expr"], argv
        expr_file = os.path.join(os.path.dirname(args[0]), "expr.py")
        with open(expr_file, "w") as fh:
            fh.write(argv[5])
        boot = "import sys, bpy; e = open(sys.argv[1]).read(); sys.argv = ['blender', '--'] + sys.argv[2:]; exec(e)"
        return [sys.executable, "-c", boot, expr_file, *argv[argv.index("--") + 1:]], env

    job.command = as_blender
    job.start()
    t0 = time.monotonic()
    while job.poll():
        assert time.monotonic() - t0 < 600, job.status
        time.sleep(0.02)
    out["state"], out["error"], out["summary"], out["loaded"] = job.state, job.error, job.summary, job.loaded
    print("RESULT:" + json.dumps(out))
""")


SAMPLES_SCRIPT = PRELUDE + textwrap.dedent(r"""
    # every bundled sample opens in this Blender and bakes its first frame with the extension
    out["samples"] = {}
    for path in sys.argv[2:]:
        bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        scene = bpy.context.scene
        scene.hr.quality = "DRAFT"
        scene.hr.use_frame_range = True
        scene.hr.frame_start = scene.hr.frame_end = scene.frame_start
        res = sorted(bpy.ops.hr.bake())
        vals = [a.data.color_attributes["HR_Radiance"] for a in bpy.data.objects
                if a.type == "MESH" and "HR_Radiance" in a.data.color_attributes]
        top = 0.0
        for attr in vals:
            v = np.empty(len(attr.data) * 4, np.float32)
            attr.data.foreach_get("color", v)
            top = max(top, float(v.reshape(-1, 4)[:, :3].max()))
        out["samples"][os.path.basename(path)] = {"bake": res, "objects": len(vals), "max": top}
    print("RESULT:" + json.dumps(out))
""")


def _run(script, zip_path, tmp_path, blends=None):
    env, resources = isolated_env(tmp_path)
    if blends is None:  # the sample is made by this Blender version
        blends = [_make_cornell(tmp_path, env)]
    path = tmp_path / "check.py"
    path.write_text(script)
    proc = subprocess.run(
        [sys.executable, str(path), str(zip_path), *map(str, blends)],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=900,
    )
    log = proc.stdout + proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT:")]
    assert proc.returncode == 0 and lines, log
    out = json.loads(lines[-1][len("RESULT:") :])
    assert out["embreex_before"] is None, "embreex must not be importable before the install"
    assert out["install"] == ["FINISHED"] and out["enabled"], log
    assert out["embreex_after"].startswith(os.path.realpath(resources)), out  # the extension's wheel
    print(f"bpy {out['bpy']}, embreex {out['embreex_version']} from the extension")
    return out, log


def _make_cornell(tmp_path, env):
    blend = tmp_path / "scene" / "cornell.blend"
    proc = subprocess.run(
        [
            sys.executable,
            str(REPO_ROOT / "scripts" / "make_samples.py"),
            "cornell",
            "--out",
            str(blend.parent),
        ],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0 and blend.is_file(), proc.stdout + proc.stderr
    return blend


def test_installed_extension_bakes_with_bundled_embree(linux_zip, tmp_path):
    out, log = _run(BAKE_SCRIPT, linux_zip, tmp_path)
    assert out["bake"] == ["FINISHED"], log
    assert out["manifest_rays"] == "embree", out
    summary = [ln for ln in log.splitlines() if "HR Radiosity: baked frames 1-13" in ln]
    assert summary and summary[-1].endswith("rays: embree)"), summary
    p = out["playback"]
    assert p["changes"] and p["brighter"] > 0 and p["equals_cache"] and p["held"] and p["back"], p


def test_installed_extension_background_bake(linux_zip, tmp_path):
    out, log = _run(BACKGROUND_SCRIPT, linux_zip, tmp_path)
    assert out["state"] == "done", (out, log)
    assert out["worker"][1:3] == ["-m", "hr_addon"], out["worker"]  # the bpy module has no Blender binary
    assert "rays: embree" in out["summary"] and out["manifest_rays"] == "embree", out
    assert {"build", "frame"} <= set(out["stages"]), out
    assert any(0 < f < 1 for f in out["fractions"]), out["fractions"]
    assert out["loaded"] and out["shows_frame_6"], out


def test_installed_extension_worker_command_for_blender_binary(linux_zip, tmp_path):
    out, log = _run(BINARY_SCRIPT, linux_zip, tmp_path)
    assert out["state"] == "done", (out, log)
    assert "rays: embree" in out["summary"] and out["loaded"], out


def test_every_bundled_sample_opens_and_bakes(linux_zip, tmp_path):
    """The samples were saved by 5.0, whose files 4.2 and 4.5 cannot open (issue 18): they are
    made by the oldest supported Blender, and every supported version opens and bakes each."""
    samples = tmp_path / "samples"
    shutil.copytree(REPO_ROOT / "sample_blends", samples)
    blends = sorted(samples.glob("*.blend"))
    assert len(blends) >= 8
    out, log = _run(SAMPLES_SCRIPT, linux_zip, tmp_path, blends)
    for b in blends:
        got = out["samples"].get(b.name)
        assert got and got["bake"] == ["FINISHED"] and got["objects"] > 0 and got["max"] > 0, (
            b.name,
            got,
            log,
        )
