#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Validate and build the Blender extension zips, one per platform
(``dist/hr_radiosity-<version>-<platform>.zip``, e.g. ``..._linux_x64.zip``).

Runs Blender's own extension tool, ``blender_ext.py``, which ships inside the ``bpy`` wheel
(``bpy/<ver>/scripts/addons_core/bl_pkg/cli/blender_ext.py``), as a plain script with the current
Python, so no Blender binary is needed. This is exactly what
``blender --command extension validate`` / ``blender --command extension build`` run, including the
check of the manifest's tags against Blender's list of valid tags.

Which files end up in the zip is decided by ``[build] paths_exclude_pattern`` in
``blender_manifest.toml`` (see the comment there), plus the manifest's ``wheels``: the embreex
wheels, which are not in git. Before building, every wheel the manifest lists that is missing from
``./wheels/`` is downloaded with ``pip download <name>==<version> --no-deps --only-binary=:all:
--platform <tag> --python-version <ver>``, the tags taken from the wheel's file name, and must
arrive under exactly that name. The builder's ``--split-platforms`` then writes one zip per
platform of the manifest, each with only that platform's wheels.

Usage::

    .venv/bin/python scripts/build_extension.py [--output-dir DIR] [--blender-ext PATH]

Prints each zip with its size; the last lines of stdout are the absolute paths of the zips, one
per line, in the manifest's platform order.
"""

from __future__ import annotations

import argparse
import glob
import shutil
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
    hits = sorted(
        glob.glob(str(bpy_dir / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"))
    )
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


def wheel_download_args(filename: str) -> list[str]:
    """pip download arguments that fetch exactly the wheel `filename` (name-version-py-abi-plat)."""
    parts = filename[: -len(".whl")].split("-")
    if not filename.endswith(".whl") or len(parts) not in (5, 6):
        raise SystemExit("error: not a wheel file name: {}".format(filename))
    name, version, py, abi, plat = parts[0], parts[1], parts[-3], parts[-2], parts[-1]
    if not (py.startswith("cp") and py[2:].isdigit()):
        raise SystemExit("error: {}: expected a CPython wheel (cpXY), got {}".format(filename, py))
    args = [
        "{}=={}".format(name, version),
        "--no-deps",
        "--only-binary=:all:",
        "--python-version",
        py[2:],
        "--implementation",
        "cp",
        "--abi",
        abi,
    ]
    for tag in plat.split("."):  # compressed tag sets, e.g. manylinux_2_27_x86_64.manylinux_2_28_x86_64
        args += ["--platform", tag]
    return args


def fetch_wheels(manifest: dict) -> list[Path]:
    """Download the manifest's wheels that are missing; returns their paths."""
    paths = []
    for rel in manifest.get("wheels", []):
        path = (REPO_ROOT / rel).resolve()
        paths.append(path)
        if path.is_file():
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.parent / ".download"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        try:
            run(
                [
                    sys.executable,
                    "-m",
                    "pip",
                    "download",
                    "-q",
                    "--disable-pip-version-check",
                    "--dest",
                    str(tmp),
                    *wheel_download_args(path.name),
                ]
            )
            got = tmp / path.name
            if not got.is_file():
                raise SystemExit(
                    "error: pip did not download {} (got: {})".format(
                        path.name, ", ".join(sorted(p.name for p in tmp.iterdir())) or "nothing"
                    )
                )
            os.replace(got, path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return paths


def zip_paths(manifest: dict, output_dir: Path) -> list[Path]:
    platforms = manifest.get("platforms") or []
    stem = "{}-{}".format(manifest["id"], manifest["version"])
    if not platforms:
        return [output_dir / (stem + ".zip")]
    return [output_dir / "{}-{}.zip".format(stem, p.replace("-", "_")) for p in platforms]


def build(output_dir: Path, blender_ext: Path | None = None) -> list[Path]:
    if blender_ext is None:
        blender_ext, tags = find_blender_ext()
    else:
        tags = None
    tags_args = ["--valid-tags", str(tags)] if tags is not None else []

    with open(MANIFEST, "rb") as fh:
        manifest = tomllib.load(fh)
    output_dir = output_dir.resolve()
    output_dir.mkdir(parents=True, exist_ok=True)
    fetch_wheels(manifest)
    zips = zip_paths(manifest, output_dir)
    for z in zips:
        if z.exists():
            z.unlink()

    run([sys.executable, str(blender_ext), "validate", str(REPO_ROOT), *tags_args])
    run(
        [
            sys.executable,
            str(blender_ext),
            "build",
            "--source-dir",
            str(REPO_ROOT),
            "--output-dir",
            str(output_dir),
            *(["--split-platforms"] if manifest.get("platforms") else []),
            *tags_args,
        ]
    )
    missing = [str(z) for z in zips if not z.is_file()]
    if missing:
        raise SystemExit("error: expected {} to have been built".format(", ".join(missing)))
    return zips


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--output-dir",
        type=Path,
        default=REPO_ROOT / "dist",
        help="where to write the zip (default: <repo>/dist)",
    )
    parser.add_argument(
        "--blender-ext",
        type=Path,
        default=None,
        help="path to blender_ext.py (default: the one in the installed bpy wheel; or set BLENDER_EXT_PY)",
    )
    args = parser.parse_args(argv)
    zips = build(args.output_dir, args.blender_ext)
    for z in zips:
        print("{}: {:.1f} MB".format(z.name, z.stat().st_size / 1e6))
    for z in zips:
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
