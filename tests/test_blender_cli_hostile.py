"""The command line under hostile use (issue 10): Ctrl-C / SIGTERM at any phase, warnings shown
once with counts, --help, and the README's sample command."""

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from test_blender_helpers import REPO_ROOT, SAMPLES, load_bpy, make_samples_module, open_sample
from test_blender_cli import run_cli, start_cli

pytestmark = pytest.mark.bpy

pytest.importorskip("bpy")


def _snapshot(d):
    """The bake's files. Not the scene precompute: it is no part of the bake, and a cancel after
    the build keeps the new one the build finished and stored (checked whole below)."""
    return {p.name: p.read_bytes() for p in sorted(Path(d).iterdir()) if p.name != "precompute.hrpc"}


def _wait_for(proc, pattern, lines):
    """Read proc's stdout until a line matches `pattern` (the phase the test wants to interrupt)."""
    for line in proc.stdout:
        lines.append(line)
        if re.search(pattern, line):
            return line
    raise AssertionError(f"never saw {pattern!r}:\n{''.join(lines)}\n{proc.stderr.read()}")


@pytest.mark.slow
def test_ctrl_c_and_sigterm_cancel_at_every_phase_and_keep_the_previous_bake(tmp_path):
    """SIGINT during bpy's start-up killed the process with tracebacks (add-on registration broke,
    then a crash); elsewhere Ctrl-C gave a KeyboardInterrupt. Now, at every phase (start-up,
    hierarchy build, frames) Ctrl-C and SIGTERM print one line, exit 130, keep the previous bake
    and leave no temporary folder."""
    from hr_addon.io import precompute

    blend = tmp_path / "cornell.blend"
    shutil.copy(SAMPLES / "cornell.blend", blend)
    proc = run_cli(blend, "--frames", "1-2", "--quality", "draft")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    cache = tmp_path / "hr_cache" / "cornell"
    before = _snapshot(cache)
    cases = [
        ("start-up", None, signal.SIGINT),
        ("build", r"Building the hierarchy: ", signal.SIGINT),
        ("build", r"Building the hierarchy: ", signal.SIGTERM),
        ("frames", r"HR Radiosity: Frame 1 \(", signal.SIGINT),
        ("frames", r"HR Radiosity: Frame 1 \(", signal.SIGTERM),
    ]
    for phase, pattern, sig in cases:
        p = start_cli(blend, "--quality", "medium", "--method", "auto")
        lines = []
        if pattern is None:
            time.sleep(0.5)  # inside `import bpy` (about a second): nothing is printed before it
        else:
            _wait_for(p, pattern, lines)
        p.send_signal(sig)
        out, err = p.communicate(timeout=120)
        what = f"{phase}, {signal.Signals(sig).name}: {''.join(lines) + out}\n{err}"
        assert p.returncode == 130, what
        assert err.strip().splitlines() == ["hr_bake: cancelled; the previous bake is kept"], what
        assert "Traceback" not in out + err, what
        assert _snapshot(cache) == before, what
        assert sorted(x.name for x in cache.parent.iterdir()) == ["cornell"], what
        precompute.read(cache / "precompute.hrpc")  # whole: the old one or the new one, no lock left
        assert not (cache / "precompute.lock").exists(), what


def _warnings_scene(path):
    """The Cornell sample plus a degenerate triangle and a light shape that slides along the top of
    the back wall, half of it above the wall, on frames 1-8."""
    bpy = load_bpy()
    ms = make_samples_module()
    open_sample("cornell", path.parent)
    scene = bpy.context.scene
    ms.mesh_object("Sliver", [(0.1, 0.1, 0.2), (0.2, 0.1, 0.2), (0.3, 0.1, 0.2)], [[0, 1, 2]])
    top = 0.5488
    ob = ms.light_shape(
        "Edge",
        [
            (0.1, 0.5592, top - 0.05),
            (0.2, 0.5592, top - 0.05),
            (0.2, 0.5592, top + 0.05),
            (0.1, 0.5592, top + 0.05),
        ][::-1],
        [[0, 1, 2, 3]],
        ms.emission("Edge light", (1, 1, 1), 4.0),
    )
    for f in range(1, 9):
        ob.location = (0.03 * f, 0, 0)
        ob.keyframe_insert("location", frame=f)
    scene.frame_start, scene.frame_end = 1, 8
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)


@pytest.mark.slow
def test_every_warning_is_printed_once_with_counts(tmp_path):
    """The CLI ended with 'hr_bake: N warning(s)' but warnings from the build and the cache commit
    were never printed, and one shape reported on 8 frames gave 8 lines."""
    blend = tmp_path / "w" / "warn.blend"
    blend.parent.mkdir()
    _warnings_scene(blend)
    proc = run_cli(blend, "--quality", "draft", "--method", "fe", timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    warn = [ln for ln in lines if ln.startswith("HR Radiosity: warning: ")]
    assert len([w for w in warn if "Dropped 1 degenerate polygon(s)" in w and "'Sliver'" in w]) == 1, (
        proc.stdout
    )
    edge = [w for w in warn if "shape 'Edge': only 50.0% of its area lies on surfaces" in w]
    assert len(edge) == 1 and "[8 times on frames 1-8]" in edge[0], proc.stdout
    assert len(warn) == len(set(warn)) and f"hr_bake: {len(warn)} warning(s) (listed above)" in lines, (
        proc.stdout
    )
    proc = run_cli(blend, "--quality", "medium", "--method", "fe", "--frames", "1-2", timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (
        "HR Radiosity: warning: The previous bake's frames 3-8 were discarded: it used quality draft "
        "(this bake: medium)." in proc.stdout.splitlines()
    ), proc.stdout


def test_help_lists_every_option_and_the_exit_codes():
    """`python -m hr_addon --help` showed an outdated usage line; `bake --help` had no help for several
    options and no exit codes."""
    from hr_addon.blender.cli import make_parser

    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    top = subprocess.run(
        [sys.executable, "-m", "hr_addon", "--help"],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO_ROOT,
        timeout=60,
    )
    bake = subprocess.run(
        [sys.executable, "-m", "hr_addon", "bake", "--help"],
        capture_output=True,
        text=True,
        env=env,
        cwd=REPO_ROOT,
        timeout=60,
    )
    assert top.returncode == 0 and bake.returncode == 0
    parser = make_parser()
    for action in parser._actions:
        if not action.option_strings or action.dest == "help":
            continue
        assert action.help, action.option_strings
        for opt in action.option_strings:
            assert opt in top.stdout, (opt, top.stdout)
            assert opt in bake.stdout, (opt, bake.stdout)
    assert "python -m hr_addon bake --help" in top.stdout
    codes = bake.stdout[bake.stdout.index("exit codes:") :]
    for code in ("0", "1", "2", "130"):
        assert re.search(rf"^\s+{code}\s+\S", codes, re.M), codes


def _readme():
    return (REPO_ROOT / "README.md").read_text()


def test_readme_sample_command_writes_what_the_readme_says(tmp_path):
    """The README's sample command wrote its cache next to the input file, not where the README
    said (`hr_cache/`)."""
    text = _readme()
    m = re.search(r"Set up and bake the bundled sample scene \((.*?)\):\s*```bash\s*(.*?)\s*```", text, re.S)
    assert m, "the README's sample command is missing"
    claim, command = " ".join(m.group(1).split()), m.group(2).strip()
    bake = command.split("&&")[-1].split()
    assert bake[:4] == [".venv/bin/python", "-m", "hr_addon", "bake"], command
    named = re.findall(r"`([^`]+)`", claim)
    assert len(named) == 2 and named[0].endswith(".blend"), claim
    saved, cache = tmp_path / named[0], tmp_path / named[1]
    (tmp_path / "sample_blends").mkdir()
    shutil.copy(SAMPLES / "cornell.blend", tmp_path / "sample_blends" / "cornell.blend")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONHOME"}
    env["PYTHONPATH"] = str(REPO_ROOT)
    proc = subprocess.run(
        [sys.executable, *bake[1:]], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert saved.is_file(), claim
    assert (cache / "manifest.json").is_file(), (
        claim,
        sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("manifest.json")),
    )


def test_readme_caption_names_the_qualities_used():
    """The picture caption said 'the default (medium) quality', but the sample is saved with draft."""
    bpy = load_bpy()
    bpy.ops.wm.open_mainfile(filepath=str(SAMPLES / "cornell.blend"), load_ui=False)
    saved = bpy.context.scene.hr.quality.lower()
    src = (REPO_ROOT / "scripts" / "render_figures.py").read_text()
    figure = re.search(r'add_argument\("--quality", default="(\w+)"\)', src).group(1)
    m = re.search(r"!\[Cornell box sample[^\n]*\n\n\*(.*?)\*\n", _readme(), re.S)
    caption = " ".join(m.group(1).split())
    assert f"saved with {saved} quality" in caption, caption
    assert f"--quality {figure}" in caption and f"baked with {figure} quality" in caption, caption
