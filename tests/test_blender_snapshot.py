"""One read of the scene: collect_geometry takes each object's signature in the walk that reads its
mesh, and those are the digests signatures.geometry_signatures computes on its own (what playback
compares with the bake's manifest to say "the scene changed since the bake")."""

import pytest

from test_blender_helpers import empty_scene
from test_blender_instances_triangles import _box, _floor_and_lamp, collection_instances

pytestmark = pytest.mark.bpy


def _both(bpy):
    from hr_addon.blender.scene_in import collect_geometry
    from hr_addon.blender.signatures import geometry_signatures

    vl = bpy.context.view_layer
    vl.update()
    return collect_geometry(vl, vl.depsgraph).signatures, geometry_signatures(vl, vl.depsgraph)


def test_the_scene_read_signs_objects_and_instances_as_the_stale_check_does():
    bpy, ms, scene = empty_scene()
    floor, grey = _floor_and_lamp(ms)
    mirrored = _box(ms, "Mirrored", ms.diffuse("Red", (0.8, 0.1, 0.1)))
    mirrored.scale = (-1, 1, 1)
    ms.mesh_object("Edges", [(0, 0, 1), (1, 0, 1)], [], None)  # no faces: skipped by both
    _, empties = collection_instances(bpy, ms, scene, grey)
    read, own = _both(bpy)
    assert set(read) == {"Floor", "Ceiling", "Mirrored", "Inst0/Box", "Inst1/Box"}
    assert read == own
    empties[1].location = (3, 2.5, 0)  # an instance moves: its digest changes, in both
    moved, moved_own = _both(bpy)
    assert moved == moved_own
    assert moved["Inst1/Box"] != read["Inst1/Box"] and moved["Ceiling"] == read["Ceiling"]
