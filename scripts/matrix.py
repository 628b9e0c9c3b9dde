#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender version matrix: the installed-extension tests on bpy 4.2 LTS, 4.5 LTS and 5.0.

    python scripts/matrix.py setup    # create .venvs/bpy-<version>/ for the extra versions
    python scripts/matrix.py test     # run tests/test_matrix.py on every version

The extra versions (the latest 4.2.x and 4.5.x on PyPI when this was written) each get their own
venv under .venvs/ (git-ignored), with bpy and requirements-matrix.txt: no embreex, so the tests
see only the embreex that the extension zip brings. 5.0 is the project's own .venv (README); there
tests/test_matrix.py hides the venv's embreex from the Blender process it starts.

The linux-x64 zip is built once (scripts/build_extension.py, with 5.0's extension builder) and
passed to every run through HR_EXTENSION_ZIP. Exit code: 0 when every version passed.
"""

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VENVS = REPO / ".venvs"
EXTRA = {"4.2": "4.2.23", "4.5": "4.5.15"}  # bpy versions (cp311 wheels, like 5.0.1)
MAIN_PY = REPO / ".venv" / "bin" / "python"


def venv_python(version):
    return VENVS / f"bpy-{version}" / "bin" / "python"


def run(cmd, **kw):
    print("+", " ".join(map(str, cmd)), flush=True)
    return subprocess.run([str(c) for c in cmd], cwd=REPO, stdin=subprocess.DEVNULL, **kw).returncode


def setup(python="python3"):
    for series, version in EXTRA.items():
        py = venv_python(version)
        marker = py.parent.parent / ".installed"
        if marker.is_file() and marker.read_text().strip() == version:
            print(f"matrix: .venvs/bpy-{version} is ready", flush=True)
            continue
        if run([python, "-m", "venv", py.parent.parent]) != 0:
            return 1
        if (
            run([py, "-m", "pip", "install", "-q", f"bpy=={version}", "-r", REPO / "requirements-matrix.txt"])
            != 0
        ):
            return 1
        marker.write_text(version + "\n")
    return 0


def build_zip():
    out = REPO / "build" / "matrix_dist"
    proc = subprocess.run(
        [str(MAIN_PY), str(REPO / "scripts" / "build_extension.py"), "--output-dir", str(out)],
        cwd=REPO,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
    )
    zips = [ln for ln in proc.stdout.splitlines() if ln.endswith("-linux_x64.zip")]
    if proc.returncode != 0 or not zips:
        print(proc.stdout + proc.stderr, file=sys.stderr)
        raise SystemExit("matrix: building the extension failed")
    return zips[-1]


def test(versions):
    zip_path = build_zip()
    print(f"matrix: extension zip {zip_path}", flush=True)
    env = dict(os.environ, HR_EXTENSION_ZIP=zip_path)
    results = {}
    for v in versions:
        py = MAIN_PY if v == "5.0" else venv_python(EXTRA[v])
        t0 = time.perf_counter()
        rc = run([py, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_matrix.py"], env=env)
        results[v] = (rc, time.perf_counter() - t0)
    print("matrix results:", flush=True)
    for v, (rc, dt) in results.items():
        print(f"  bpy {v}: {'passed' if rc == 0 else f'FAILED (exit {rc})'} ({dt:.0f} s)", flush=True)
    return 0 if all(rc == 0 for rc, _ in results.values()) else 1


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("command", choices=["setup", "test", "all"])
    p.add_argument("--versions", default="4.2,4.5,5.0", help="comma-separated (default: 4.2,4.5,5.0)")
    p.add_argument("--python", default="python3", help="Python 3.11 used to create the venvs")
    a = p.parse_args(argv)
    versions = [v.strip() for v in a.versions.split(",") if v.strip()]
    bad = [v for v in versions if v != "5.0" and v not in EXTRA]
    if bad:
        p.error(f"unknown version(s) {bad}; expected among 5.0, {', '.join(EXTRA)}")
    if a.command in ("setup", "all") and setup(a.python) != 0:
        return 1
    if a.command in ("test", "all"):
        return test(versions)
    return 0


if __name__ == "__main__":
    sys.exit(main())
