"""The bpy-free packages must not depend on Blender: hr_addon.core (numpy only; mathutils/embreex
optional, in visibility.py), hr_addon.io (bake files) and hr_addon.lightmap (texel plans).

Two checks, both discovering whatever modules exist under those packages at the time:
- dynamic: every module is imported in a fresh subprocess whose meta-path hook makes `import bpy`
  (and the other Blender-only modules) raise; any *attempt* is recorded, even if the module catches
  the ImportError, so `try: import bpy except ImportError` in core fails too;
- static: no core source file contains an import of those modules (also catches imports hidden
  inside functions, which the dynamic check cannot see).
"""

import ast
import json
import pkgutil
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "io", "lightmap")
BLOCKED = (
    "bpy",
    "bmesh",
    "bpy_extras",
    "_bpy",
    "bpy_types",
    "gpu",
    "gpu_extras",
    "blf",
    "bl_math",
    "bgl",
    "aud",
    "idprop",
    "imbuf",
    "freestyle",
    "addon_utils",
)


def _discover(path: Path, prefix: str) -> list[str]:
    """Module names under `path`, found without importing anything (pkgutil on the file system)."""
    names = []
    for info in pkgutil.iter_modules([str(path)], prefix):
        names.append(info.name)
        if info.ispkg:
            names.extend(_discover(path / info.name.rsplit(".", 1)[-1], info.name + "."))
    return names


CORE_MODULES = [
    m
    for pkg in PACKAGES
    for m in [f"hr_addon.{pkg}"] + _discover(REPO_ROOT / "hr_addon" / pkg, f"hr_addon.{pkg}.")
]
CORE_FILES = sorted(
    p
    for pkg in PACKAGES
    for p in (REPO_ROOT / "hr_addon" / pkg).rglob("*.py")
    if "__pycache__" not in p.parts
)

CHILD = textwrap.dedent(r'''
    import importlib, json, sys, traceback
    blocked, modules = json.loads(sys.argv[1]), json.loads(sys.argv[2])
    attempts = []

    class BlockBlender:
        """Meta-path finder: any import of a Blender-only module is recorded and fails."""
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in blocked:
                attempts.append(name)
                raise ImportError("bpy-free packages must not import " + name + " (blocked by the test)")
            return None

    sys.meta_path.insert(0, BlockBlender())
    for name in blocked:
        sys.modules.pop(name, None)
    result = {}
    for mod in modules:
        before = len(attempts)
        try:
            importlib.import_module(mod)
            err = None
        except BaseException:
            err = traceback.format_exc()
        result[mod] = {"error": err, "attempts": attempts[before:]}
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in blocked)
    print("RESULT:" + json.dumps({"modules": result, "leaked": leaked}))
''')


@pytest.fixture(scope="module")
def isolated_imports():
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(BLOCKED), json.dumps(CORE_MODULES)],
        cwd=REPO_ROOT,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT:")]
    assert proc.returncode == 0 and lines, proc.stdout + proc.stderr
    return json.loads(lines[-1][len("RESULT:") :])


@pytest.mark.parametrize("module", CORE_MODULES)
def test_core_module_imports_without_blender(isolated_imports, module):
    res = isolated_imports["modules"][module]
    assert not res["attempts"], "{} tried to import Blender-only module(s) {}".format(module, res["attempts"])
    assert res["error"] is None, "{} failed to import without Blender:\n{}".format(module, res["error"])


def test_no_blender_module_loaded(isolated_imports):
    assert isolated_imports["leaked"] == []


_IMPORT_RE = re.compile(r"^\s*(?:import|from)\s+(?:" + "|".join(map(re.escape, BLOCKED)) + r")\b", re.M)


@pytest.mark.parametrize("path", CORE_FILES, ids=lambda p: p.relative_to(REPO_ROOT).as_posix())
def test_core_source_has_no_blender_import(path):
    text = path.read_text(encoding="utf-8")
    assert "import bpy" not in text, "{} contains 'import bpy'".format(path)
    hits = _IMPORT_RE.findall(text)
    assert not hits, "{}: {}".format(path, hits)
    # AST: also catches `import numpy, bpy`, `__import__("bpy")`, `importlib.import_module("bpy")`.
    for node in ast.walk(ast.parse(text, filename=str(path))):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif (
            isinstance(node, ast.Call)
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
            and (
                (isinstance(node.func, ast.Name) and node.func.id == "__import__")
                or (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
            )
        ):
            names = [node.args[0].value]
        bad = [n for n in names if n.split(".")[0] in BLOCKED]
        assert not bad, "{}:{} imports {}".format(path, node.lineno, bad)


def test_discovery_found_the_packages():
    for pkg in PACKAGES:
        assert (REPO_ROOT / "hr_addon" / pkg / "__init__.py").is_file()
    assert {"hr_addon.io.cache", "hr_addon.lightmap.plan", "hr_addon.core.texels"} <= set(CORE_MODULES)
