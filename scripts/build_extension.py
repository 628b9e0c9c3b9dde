#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Validate and build the Blender extension zip (``dist/hr_radiosity-<version>.zip``).

Runs Blender's own extension tool, ``blender_ext.py``, which ships inside the ``bpy`` wheel
(``bpy/<ver>/scripts/addons_core/bl_pkg/cli/blender_ext.py``), as a plain script with the current
Python, so no Blender binary is needed. This is exactly what
``blender --command extension validate`` / ``blender --command extension build`` run, including the
check of the manifest's tags against Blender's list of valid tags.

Which files end up in the zip is decided by ``[build] paths_exclude_pattern`` in
``blender_manifest.toml`` (see the comment there).

Usage::

    .venv/bin/python scripts/build_extension.py [--output-dir DIR] [--blender-ext PATH]

The absolute path of the built zip is printed as the last line of stdout.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import subprocess
import sys
import tomllib
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
MANIFEST = REPO_ROOT / "blender_manifest.toml"


def find_blender_ext() -> tuple[Path, Path | None]:
    """Return (blender_ext.py, tags.py or None) from the installed ``bpy`` wheel, without importing bpy."""
    env = os.environ.get("BLENDER_EXT_PY")
    if env:
        return Path(env), None
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit(
            "error: the 'bpy' module is not installed for this Python ({}); "
            "install requirements-dev.txt or pass --blender-ext".format(sys.executable)
        )
    bpy_dir = Path(list(spec.submodule_search_locations)[0])
    hits = sorted(glob.glob(str(bpy_dir / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py")))
    if not hits:
        raise SystemExit("error: blender_ext.py not found under {}".format(bpy_dir))
    ext_py = Path(hits[-1])
    version_dir = ext_py.parents[4]  # bpy/<ver>/
    tags = version_dir / "scripts" / "modules" / "_bpy_internal" / "extensions" / "tags.py"
    return ext_py, (tags if tags.is_file() else None)


def run(cmd: list[str]) -> None:
    print("+", " ".join(cmd), flush=True)
    proc = subprocess.run(cmd, cwd=REPO_ROOT, stdin=subprocess.DEVNULL)
    if proc.returncode != 0:
        raise SystemExit("error: command failed with exit code {}".format(proc.returncode))


def build(output_dir: Path, blender_ext: Path | None = None) -> Path:
    if blender_ext is None:
        blender_ext, tags = find_blender_ext()
    else:
        tags = None
    tags_args = ["--valid-tags", str(tags)] if tags is not None else []

    with open(MANIFEST, "rb") as fh:
        manifest = tomllib.load(fh)
    output_dir = output_dir.resolve()
    output_dir.mkdir(parents=True, exist_ok=True)
    zip_path = output_dir / "{}-{}.zip".format(manifest["id"], manifest["version"])

    run([sys.executable, str(blender_ext), "validate", str(REPO_ROOT), *tags_args])
    run([
        sys.executable, str(blender_ext), "build",
        "--source-dir", str(REPO_ROOT),
        "--output-dir", str(output_dir),
        *tags_args,
    ])
    if not zip_path.is_file():
        raise SystemExit("error: expected {} to have been built".format(zip_path))
    return zip_path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output-dir", type=Path, default=REPO_ROOT / "dist",
                        help="where to write the zip (default: <repo>/dist)")
    parser.add_argument("--blender-ext", type=Path, default=None,
                        help="path to blender_ext.py (default: the one in the installed bpy wheel; "
                             "or set BLENDER_EXT_PY)")
    args = parser.parse_args(argv)
    zip_path = build(args.output_dir, args.blender_ext)
    print(zip_path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
