"""Build the extension zips with scripts/build_extension.py (one per platform, with that platform's
embreex wheels) and install the linux-x64 one into Blender (bpy module).

The install runs in a subprocess with a throw-away user-resource directory (BLENDER_USER_RESOURCES)
and HOME, so neither this test process's bpy state nor ~/.config/blender is touched.
"""

import json
import subprocess
import sys
import textwrap
import tomllib
import zipfile
from pathlib import Path

import pytest

from hr_testing.blend import isolated_env

REPO_ROOT = Path(__file__).resolve().parent.parent
BUILD_SCRIPT = REPO_ROOT / "scripts" / "build_extension.py"

with open(REPO_ROOT / "blender_manifest.toml", "rb") as _fh:
    MANIFEST = tomllib.load(_fh)
EXT_ID = MANIFEST["id"]
ADDON_MODULE = "bl_ext.user_default." + EXT_ID

# Top-level entries that must never be shipped.
FORBIDDEN_TOP = {
    "tests",
    "sample_blends",
    "benchmarks",
    "hr_testing",
    "docs",
    "scripts",
    ".ci",
    ".venv",
    ".git",
    "dist",
    "build",
    ".pytest_cache",
    "requirements-dev.txt",
    "pytest.ini",
    ".gitignore",
}


PLATFORMS = ["linux-x64", "windows-x64", "macos-arm64", "macos-x64", "windows-arm64"]


@pytest.fixture(scope="module")
def built_zips(tmp_path_factory):
    """{platform: zip path} of one build (the wheels are downloaded into ./wheels/ once)."""
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run(
        [sys.executable, str(BUILD_SCRIPT), "--output-dir", str(out)],
        cwd=REPO_ROOT,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    paths = [Path(ln) for ln in proc.stdout.strip().splitlines()[-len(PLATFORMS) :]]
    for p in paths:
        assert p.is_file(), proc.stdout
        assert p.parent == out
    assert [p.name for p in paths] == [
        "{}-{}-{}.zip".format(EXT_ID, MANIFEST["version"], pl.replace("-", "_")) for pl in PLATFORMS
    ]
    return dict(zip(PLATFORMS, paths))


@pytest.fixture(scope="module")
def built_zip(built_zips):
    return built_zips["linux-x64"]


def test_manifest_fields():
    assert MANIFEST["schema_version"] == "1.0.0"
    assert MANIFEST["id"] == "hr_radiosity"
    assert MANIFEST["type"] == "add-on"
    assert MANIFEST["license"] == ["SPDX:GPL-3.0-or-later"]
    assert "files" in MANIFEST["permissions"]
    licence = (REPO_ROOT / "LICENSE").read_text()
    assert "GNU GENERAL PUBLIC LICENSE" in licence and "Version 3, 29 June 2007" in licence


@pytest.mark.bpy
@pytest.mark.slow  # the module builds the five zips once
def test_zip_layout(built_zip):
    with zipfile.ZipFile(built_zip) as zf:
        names = zf.namelist()
    tops = {n.split("/", 1)[0] for n in names}
    assert "blender_manifest.toml" in names
    assert "__init__.py" in names, "Blender needs __init__.py next to the manifest"
    assert "LICENSE" in names
    assert "hr_addon/__init__.py" in names
    assert "hr_addon/core/__init__.py" in names
    assert "hr_addon/blender/__init__.py" in names
    assert "hr_addon/io/__init__.py" in names and "hr_addon/lightmap/__init__.py" in names
    assert not [n for n in names if n.endswith(("/scenes.py", "/shapes.py"))]  # test scenes stay out
    assert not (tops & FORBIDDEN_TOP), sorted(tops & FORBIDDEN_TOP)
    assert tops <= {"blender_manifest.toml", "__init__.py", "LICENSE", "hr_addon", "wheels"}, sorted(tops)
    assert not [n for n in names if "__pycache__" in n or n.endswith((".pyc", ".pyo"))]
    assert not [n for n in names if any(p.startswith(".") for p in n.split("/"))]
    # Every .py under hr_addon/ in the source tree is shipped.
    src = {
        p.relative_to(REPO_ROOT).as_posix()
        for p in (REPO_ROOT / "hr_addon").rglob("*.py")
        if "__pycache__" not in p.parts
    }
    assert src <= set(names), sorted(src - set(names))


def _zip_wheels(path):
    with zipfile.ZipFile(path) as zf:
        generated = tomllib.loads(zf.read("blender_manifest.toml").decode())["build"]["generated"]
        return sorted(n for n in zf.namelist() if n.startswith("wheels/")), generated


def test_manifest_wheels_cover_platforms_and_pythons():
    """cp311 (Blender 4.2-5.0) and cp313 (5.1+) embreex for every platform that has a wheel."""
    assert MANIFEST["platforms"] == PLATFORMS
    wheels = [w.rsplit("/", 1)[-1] for w in MANIFEST["wheels"]]
    assert all(w.startswith("embreex-") for w in wheels), wheels
    assert not [w for w in MANIFEST["wheels"] if not w.startswith("./wheels/")]
    for plat_tag in ("manylinux", "win_amd64", "arm64", "x86_64"):
        tags = {
            w.split("-")[2] for w in wheels if plat_tag in w and not (plat_tag == "x86_64" and "linux" in w)
        }
        assert tags == {"cp311", "cp313"}, (plat_tag, wheels)
    assert not [w for w in wheels if "numpy" in w], "numpy ships with Blender"


@pytest.mark.bpy
@pytest.mark.slow  # the module builds the five zips once
def test_each_platform_zip_has_only_its_wheels(built_zips):
    expect = {
        "linux-x64": "manylinux",
        "windows-x64": "win_amd64",
        "macos-arm64": "macosx_13_0_arm64",
        "macos-x64": "x86_64.whl",
    }
    for platform, path in built_zips.items():
        names, generated = _zip_wheels(path)
        assert generated["platforms"] == [platform]
        assert [w.rsplit("/", 1)[-1] for w in generated["wheels"]] == [n.rsplit("/", 1)[-1] for n in names]
        if platform == "windows-arm64":  # no embreex wheel exists: the numpy tracer is used
            assert names == [], names
            continue
        assert len(names) == 2 and all(expect[platform] in n for n in names), (platform, names)
        assert {n.split("-")[2] for n in names} == {"cp311", "cp313"}, names
        print(f"{path.name}: {path.stat().st_size / 1e6:.1f} MB")


INSTALL_SCRIPT = textwrap.dedent(r"""
    import importlib, importlib.util, json, os, pkgutil, sys, traceback
    zip_path, ext_id = sys.argv[1], sys.argv[2]
    # The installed copy must be what gets imported, not the source tree.
    assert importlib.util.find_spec("hr_addon") is None, "hr_addon importable from the source tree"
    import bpy
    out = {"user_extensions": bpy.utils.user_resource("EXTENSIONS")}
    res = bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True)
    out["install_result"] = sorted(res)
    mod_name = "bl_ext.user_default." + ext_id
    out["enabled"] = mod_name in bpy.context.preferences.addons
    out["in_sys_modules"] = mod_name in sys.modules
    out["module_file"] = getattr(sys.modules.get(mod_name), "__file__", None)
    # Import every module of the installed package: catches absolute `import hr_addon...`
    # (only relative imports work under bl_ext.<repo>.<id>) and import-time errors.
    errors = {}
    imported = []
    if out["in_sys_modules"]:
        pkg = importlib.import_module(mod_name + ".hr_addon")
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".",
                                          onerror=lambda name: errors.setdefault(name, traceback.format_exc())):
            if info.name.rsplit(".", 1)[-1] == "__main__":
                continue
            try:
                importlib.import_module(info.name)
                imported.append(info.name)
            except BaseException:
                errors[info.name] = traceback.format_exc()
    out["imported"] = imported
    out["import_errors"] = errors
    out["has_ops_hr"] = hasattr(bpy.ops, "hr")
    res = bpy.ops.preferences.addon_disable(module=mod_name)
    out["disable_result"] = sorted(res)
    out["enabled_after_disable"] = mod_name in bpy.context.preferences.addons
    print("RESULT:" + json.dumps(out))
""")


@pytest.mark.bpy
@pytest.mark.slow  # the module builds the five zips once
def test_install_in_blender(built_zip, tmp_path):
    pytest.importorskip("bpy")  # only checks it is installed; the import happens in the subprocess
    env, resources = isolated_env(tmp_path)
    script = tmp_path / "install_check.py"
    script.write_text(INSTALL_SCRIPT)
    proc = subprocess.run(
        [sys.executable, str(script), str(built_zip), EXT_ID],
        cwd=tmp_path,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=50,
    )
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT:")]
    assert lines, log
    out = json.loads(lines[-1][len("RESULT:") :])

    assert Path(out["user_extensions"]).resolve().is_relative_to(resources.resolve()), out
    assert out["install_result"] == ["FINISHED"], log
    assert out["enabled"], log
    assert out["in_sys_modules"], log
    installed_root = resources / "extensions" / "user_default" / EXT_ID
    assert (installed_root / "blender_manifest.toml").is_file()
    assert (installed_root / "hr_addon" / "__init__.py").is_file()
    assert not (installed_root / "tests").exists()
    assert Path(out["module_file"]).resolve() == (installed_root / "__init__.py").resolve()
    assert out["import_errors"] == {}, "\n".join(out["import_errors"].values())
    assert ADDON_MODULE + ".hr_addon.core" in out["imported"]
    assert ADDON_MODULE + ".hr_addon.blender" in out["imported"]
    assert out["disable_result"] == ["FINISHED"], log
    assert not out["enabled_after_disable"], log
    assert "Traceback" not in log, log
