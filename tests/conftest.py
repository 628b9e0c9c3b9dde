"""Shared pytest setup: the repository root on sys.path (`import hr_addon`), and Blender's state.

Tests marked `bpy` need Blender as a Python module: without it they are skipped (so the rest of
the suite runs with numpy and pytest only), with it each starts from Blender's factory startup
file, emptied. read_homefile(use_factory_startup=True) rather than read_factory_settings: it
leaves the preferences alone, so Blender does not re-register its bundled add-ons on every test
(pose_library adds one more load_post handler each time), and takes ~15 ms instead of ~100 ms.
Tests marked `shared_scene` work on Blender data that a module-scoped fixture made and keep it.
"""

import importlib.util
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

HAVE_BPY = importlib.util.find_spec("bpy") is not None


def pytest_collection_modifyitems(config, items):
    if HAVE_BPY:
        return
    skip = pytest.mark.skip(reason="needs bpy (Blender as a Python module, requirements.txt)")
    for item in items:
        if item.get_closest_marker("bpy"):
            item.add_marker(skip)


@pytest.fixture(autouse=True)
def blender_factory_startup(request):
    marked = request.node.get_closest_marker
    if HAVE_BPY and marked("bpy") and not marked("shared_scene"):
        import bpy

        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
