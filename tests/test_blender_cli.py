"""Command line: `python -m hr_addon bake ...` (subprocesses) and the `blender -c hr_bake` callback."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from test_blender_helpers import REPO_ROOT, SAMPLES, load_bpy, make_samples_module, open_sample

pytestmark = pytest.mark.bpy

pytest.importorskip("bpy")


def start_cli(*args):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME",)}
    env["PYTHONPATH"] = str(REPO_ROOT)
    return subprocess.Popen(
        [sys.executable, "-m", "hr_addon", "bake", *map(str, args)],
        cwd=REPO_ROOT,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish_cli(p, timeout=120):
    out, err = p.communicate(timeout=timeout)
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def run_cli(*args, timeout=120):
    return finish_cli(start_cli(*args), timeout)


def _error_line(proc):
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("hr_bake: error:")]
    assert len(lines) == 1, proc.stdout + proc.stderr
    return lines[0]


@pytest.mark.parametrize(
    "args, code, text",
    [
        (["missing.blend"], 2, "file not found: missing.blend"),
        ([SAMPLES / "cornell.blend", "--frames", "10-5"], 2, "end frame is before the start frame"),
        ([SAMPLES / "cornell.blend", "--frames", "one-two"], 2, "bad frame range"),
        ([SAMPLES / "cornell.blend", "--method", "magic"], 2, "invalid choice: 'magic'"),
        ([SAMPLES / "cornell.blend", "--vertex-spacing", "-1"], 2, "bad vertex spacing -1"),
        ([], 2, "required: blend"),
        (["NOT_A_BLEND"], 2, "cannot open"),
    ],
)
def test_bad_command_lines(args, code, text, tmp_path):
    if args and args[0] == "NOT_A_BLEND":
        args = [tmp_path / "not_a.blend"] + args[1:]
        args[0].write_text("hello")
    proc = run_cli(*args)
    assert proc.returncode == code, proc.stdout + proc.stderr
    assert text in _error_line(proc)
    assert "Traceback" not in proc.stderr


def _save_scene(path, build):
    """Build a scene in this process with `build(bpy, make_samples)` and save it to path."""
    bpy = load_bpy()
    ms = make_samples_module()
    ms.reset()
    build(bpy, ms)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    return path


QUAD = ([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [[0, 1, 2, 3]])


def _box(bpy, ms, wall_material=None):
    mats = {
        "default": wall_material or ms.diffuse("Wall", (0.5, 0.5, 0.5)),
        "ceiling": ms.emission("Lamp", (1, 1, 1), 2.0),
    }
    ms.room((1.0, 1.0, 1.0), mats, subdiv=2)


def test_no_meshes(tmp_path):
    path = _save_scene(tmp_path / "empty.blend", lambda bpy, ms: ms.camera((0, -3, 1), (0, 0, 0)))
    proc = run_cli(path)
    assert proc.returncode == 1
    assert "No mesh objects" in _error_line(proc)


def test_nan_vertices(tmp_path):
    def build(bpy, ms):
        _box(bpy, ms)
        ob = ms.mesh_object("Broken", *QUAD, None, location=(0.2, 0.2, 0.5))
        co = np.zeros(12, np.float32)
        ob.data.vertices.foreach_get("co", co)
        co[4] = np.nan
        ob.data.vertices.foreach_set("co", co)

    path = _save_scene(tmp_path / "nan.blend", build)
    proc = run_cli(path, "--frames", "1-1", "--quality", "draft")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    line = _error_line(proc)
    assert "NaN" in line and "'Broken'" in line


def test_reflectance_at_least_one_is_clamped_with_warning(tmp_path):
    path = _save_scene(
        tmp_path / "white.blend", lambda bpy, ms: _box(bpy, ms, ms.diffuse("Snow", (1.0, 1.0, 1.0)))
    )
    proc = run_cli(path, "--frames", "1-2", "--quality", "draft", "--domain", "point")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "warning: Material 'Snow': reflectance (1.0, 1.0, 1.0) clamped to 0.99" in proc.stdout
    assert "1 solved, 1 unchanged" in proc.stdout
    assert (tmp_path / "hr_cache" / "white" / "manifest.json").is_file()


def _frames(directory):
    from hr_addon.io.cache import CacheReader

    r = CacheReader(directory)
    return {f: r.load(f) for f in sorted(r.frames)}


@pytest.mark.slow
def test_split_bake_in_two_processes_equals_single_bake(tmp_path):
    for sub in ("split", "single"):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "cornell.blend").write_bytes((SAMPLES / "cornell.blend").read_bytes())
    common = ["--quality", "draft", "--method", "auto"]
    single_proc = start_cli(tmp_path / "single" / "cornell.blend", "--frames", "1-24", *common)
    for rng in ("1-12", "13-24"):  # one after the other: the second merges into the first's cache
        proc = run_cli(tmp_path / "split" / "cornell.blend", "--frames", rng, *common)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    proc = finish_cli(single_proc)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "4 solved, 20 unchanged" in proc.stdout
    split, single = (
        _frames(tmp_path / "split" / "hr_cache" / "cornell"),
        _frames(tmp_path / "single" / "hr_cache" / "cornell"),
    )
    assert sorted(split) == sorted(single) == list(range(1, 25))
    for f in single:
        assert sorted(split[f]) == sorted(single[f])
        for name in single[f]:
            np.testing.assert_allclose(
                split[f][name], single[f][name], rtol=1e-4, atol=1e-6, err_msg=f"frame {f} object {name}"
            )


def test_save_option_and_blender_command_callback(tmp_path, capsys):
    bpy = load_bpy()
    import hr_addon.blender as glue
    from hr_addon.blender import cli

    assert glue._cli_handle is not None  # `blender -c hr_bake` is registered
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert cli.cli_command(["--frames", "1-2"]) == 2
    assert "no .blend file loaded" in capsys.readouterr().err
    src = open_sample("cornell", tmp_path / "src")
    for o in bpy.context.scene.objects:  # static scene: quick
        o.hr.exclude = o.hr.is_light_shape
    bpy.ops.wm.save_mainfile()
    assert cli.cli_command(["--frames", "5-1"]) == 2
    out = tmp_path / "elsewhere" / "copy.blend"
    out.parent.mkdir()
    assert cli.cli_command(["--frames", "1-3", "--quality", "draft", "--save", str(out)]) == 0
    assert (tmp_path / "src" / "hr_cache" / "cornell" / "manifest.json").is_file()
    assert bpy.context.scene.hr.bake_dir == "//../src/hr_cache/cornell/"
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(out), load_ui=False)
    assert "HR_Radiance" in bpy.data.objects["floor"].data.color_attributes
    assert (
        Path(bpy.path.abspath(bpy.context.scene.hr.bake_dir)).resolve()
        == (tmp_path / "src" / "hr_cache" / "cornell").resolve()
    )
    assert src.is_file()


def test_bake_never_touches_a_folder_it_did_not_write(tmp_path):
    """`--cache-dir DIR` with a user's files in DIR deleted them all and exited 0 (issue 18); a
    plain file in the way was replaced by a folder."""
    d = tmp_path / "mine"
    (d / "sub").mkdir(parents=True)
    (d / "notes.txt").write_text("notes")
    (d / "sub" / "y.txt").write_text("y")
    proc = run_cli(SAMPLES / "cornell.blend", "--frames", "1", "--cache-dir", d)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    line = _error_line(proc)
    assert f"'{d}' holds files no radiosity bake wrote (notes.txt, sub)" in line
    assert (d / "notes.txt").read_text() == "notes" and (d / "sub" / "y.txt").read_text() == "y"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
    f = tmp_path / "plain"
    f.write_text("file")
    proc = run_cli(SAMPLES / "cornell.blend", "--frames", "1", "--cache-dir", f)
    assert proc.returncode == 1 and f"'{f}' is a file, not a folder" in _error_line(proc)
    assert f.read_text() == "file"
