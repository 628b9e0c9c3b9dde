"""Geometry as Blender renders it: polygons that must be split follow mesh.loop_triangles, and
instances (collection instances, geometry-nodes instances) take part (scene_in.py)."""

import numpy as np
import pytest

from test_blender_helpers import empty_scene

pytestmark = pytest.mark.bpy

# A non-planar quad whose shorter diagonal is 1-3 (the core's own rule would split it there),
# a concave (U-shaped) octagon, and a planar concave quad (arrowhead).
TWISTED = [(0, 0, 0), (2, 0, 0), (2, 1, 0.5), (0, 1, 0)]
U_SHAPE = [(0, 0, 0), (3, 0, 0), (3, 2, 0), (2, 2, 0), (2, 0.5, 0), (1, 0.5, 0), (1, 2, 0), (0, 2, 0)]
ARROW = [(0, 0, 0), (2, 1, 0), (0, 2, 0), (0.7, 1, 0)]


def _collect(bpy):
    from hr_addon.blender.scene_in import collect_geometry

    vl = bpy.context.view_layer
    return collect_geometry(vl, vl.depsgraph)


def _canon(tri):
    """A triangle as a vertex triple starting at its smallest index (keeps the winding)."""
    k = int(np.argmin(tri))
    return tuple(int(v) for v in np.roll(tri, -k))


def _core_triangles(mesh):
    from hr_addon.core.geometry import prepare_patches

    p = prepare_patches(mesh)
    tri = p.nv == 3
    return sorted(_canon(v[:3]) for v in p.vert_index[tri])


def _blender_triangles(obj, reverse=False):
    me = obj.data
    me.calc_loop_triangles()
    return sorted(
        _canon(np.array(t.vertices)[::-1] if reverse else np.array(t.vertices)) for t in me.loop_triangles
    )


@pytest.mark.parametrize(
    "verts", [TWISTED, U_SHAPE, ARROW], ids=["nonplanar_quad", "concave_ngon", "concave_quad"]
)
@pytest.mark.parametrize("mirrored", [False, True], ids=["", "mirrored"])
def test_split_polygons_follow_loop_triangles(verts, mirrored):
    bpy, ms, scene = empty_scene()
    ob = ms.mesh_object("P", verts, [list(range(len(verts)))], None)
    if mirrored:
        ob.scale = (-1, 1, 1)
    si = _collect(bpy)
    assert len(si.mesh.loop_start) == 1
    got = _core_triangles(si.mesh)
    assert got == _blender_triangles(ob, reverse=mirrored)  # a mirrored polygon is wound the other way
    assert len(got) == len(verts) - 2


def test_twisted_quad_is_where_the_core_alone_differs():
    """Without Blender's triangles the core splits the twisted quad along its shorter diagonal
    (the reason scene_in passes loop_triangles in)."""
    bpy, ms, scene = empty_scene()
    ob = ms.mesh_object("P", TWISTED, [[0, 1, 2, 3]], None)
    si = _collect(bpy)
    import dataclasses

    own = _core_triangles(dataclasses.replace(si.mesh, tri_loops=None))
    assert own != _blender_triangles(ob)
    assert own == sorted([_canon(np.array(t)) for t in ((0, 1, 3), (1, 2, 3))])


def _box(ms, name="Box", material=None, size=0.5):
    v = [(x, y, z) for x in (0, size) for y in (0, size) for z in (0, size)]
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return ms.mesh_object(name, v, faces, material)


def _floor_and_lamp(ms):
    grey = ms.diffuse("Grey", (0.5, 0.5, 0.5))
    lamp = ms.emission("Lamp", (1, 1, 1), 5.0)
    n = 8
    verts = [(x * 4 / n, y * 4 / n, 0) for y in range(n + 1) for x in range(n + 1)]
    quads = [
        [y * (n + 1) + x, y * (n + 1) + x + 1, (y + 1) * (n + 1) + x + 1, (y + 1) * (n + 1) + x]
        for y in range(n)
        for x in range(n)
    ]
    floor = ms.mesh_object("Floor", verts, quads, grey)
    ms.mesh_object("Ceiling", [(0, 0, 2), (0, 4, 2), (4, 4, 2), (4, 0, 2)], [[0, 1, 2, 3]], lamp)
    return floor, grey


def _world_verts_ok(si, box_local, matrices):
    """Every placed instance's vertices equal matrix @ the box's vertices (some part of the mesh)."""
    V = si.mesh.verts
    for M in matrices:
        M = np.array(M)
        want = box_local @ M[:3, :3].T + M[:3, 3]
        d = np.min(np.linalg.norm(V[:, None, :] - want[None], axis=2), axis=0)
        if d.max() > 1e-5:
            return False
    return True


def collection_instances(bpy, ms, scene, material, locations=((1, 1, 0), (2.5, 2.5, 0))):
    """(box, empties): a box in an excluded collection "Props" (the usual set-up), instanced by
    the empties Inst0, Inst1, ... at `locations`."""
    props = bpy.data.collections.new("Props")
    scene.collection.children.link(props)
    box = _box(ms, material=material)
    scene.collection.objects.unlink(box)
    props.objects.link(box)
    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    empties = []
    for i, loc in enumerate(locations):
        e = bpy.data.objects.new(f"Inst{i}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = props
        e.location = loc
        scene.collection.objects.link(e)
        empties.append(e)
    bpy.context.view_layer.update()
    return box, empties


def test_collection_instances_take_part(tmp_path):
    bpy, ms, scene = empty_scene()
    floor, grey = _floor_and_lamp(ms)
    box, empties = collection_instances(bpy, ms, scene, grey)
    si = _collect(bpy)
    assert {k: v.count for k, v in si.instances.items()} == {("Inst0", "Box"): 1, ("Inst1", "Box"): 1}
    assert len(si.mesh.loop_start) == 64 + 1 + 2 * 6
    assert [t.name for t in si.targets] == ["Ceiling", "Floor"]  # instances get no output
    box_local = np.array([v.co for v in box.data.vertices], float)
    assert _world_verts_ok(si, box_local, [e.matrix_world for e in empties])
    assert any("2 instance(s) take part" in w and "Make Instances Real" in w for w in si.warnings), (
        si.warnings
    )
    # They cast shadows and reflect: the floor's radiance changes when they are there
    scene.render.filepath = str(tmp_path)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "inst.blend"))
    from hr_addon.blender.bake import run_bake
    from test_blender_helpers import shown  # (the floor through the default spacing's modifier)

    run_bake(scene, log=lambda *a, **k: None, frames=(1, 1), quality="draft")
    with_inst = shown(floor).copy()
    for e in empties:
        e.hide_render = True
    res = run_bake(scene, log=lambda *a, **k: None, frames=(1, 1), quality="draft")
    without = shown(floor)
    assert not any("instance" in w for w in res.warnings)
    assert np.abs(with_inst - without)[:, :3].max() > 0.01
    assert with_inst[:, :3].mean() < without[:, :3].mean()  # boxes shade the floor


def test_geometry_nodes_instances_take_part():
    bpy, ms, scene = empty_scene()
    floor, grey = _floor_and_lamp(ms)
    box = _box(ms, material=grey, size=0.3)
    box.hide_render = True  # only its instances render
    host = ms.mesh_object("Host", [(1, 1, 0), (3, 1, 0), (2, 3, 0)], [], None)  # three points
    tree = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin = tree.nodes.new("NodeGroupInput")
    gout = tree.nodes.new("NodeGroupOutput")
    iop = tree.nodes.new("GeometryNodeInstanceOnPoints")
    info = tree.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = box
    info.inputs["As Instance"].default_value = True
    tree.links.new(gin.outputs[0], iop.inputs["Points"])
    tree.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    tree.links.new(iop.outputs["Instances"], gout.inputs[0])
    mod = host.modifiers.new("Scatter", "NODES")
    mod.node_group = tree
    bpy.context.view_layer.update()
    si = _collect(bpy)
    assert {k: v.count for k, v in si.instances.items()} == {("Host", "Box"): 3}, si.instances
    assert len(si.mesh.loop_start) == 64 + 1 + 3 * 6
    assert not any("'Host' has no faces" in w for w in si.warnings)  # it instances
    box_local = np.array([v.co for v in box.data.vertices], float)
    mats = [
        np.array([[1, 0, 0, x], [0, 1, 0, y], [0, 0, 1, 0], [0, 0, 0, 1.0]])
        for x, y in ((1, 1), (3, 1), (2, 3))
    ]
    assert _world_verts_ok(si, box_local, mats)
    # an excluded source takes no part
    box.hr.exclude = True
    assert _collect(bpy).instances == {}


def test_particle_instances_take_part():
    bpy, ms, scene = empty_scene()
    floor, grey = _floor_and_lamp(ms)
    box = _box(ms, material=grey, size=0.2)
    box.hide_render = True
    emitter = ms.mesh_object(
        "Emitter", [(1, 1, 0.5), (3, 1, 0.5), (3, 3, 0.5), (1, 3, 0.5)], [[0, 1, 2, 3]], None
    )
    emitter.modifiers.new("Particles", "PARTICLE_SYSTEM")
    ps = emitter.particle_systems[0].settings
    ps.type = "HAIR"
    ps.count = 5
    ps.render_type = "OBJECT"
    ps.instance_object = box
    ps.particle_size = 1.0
    emitter.show_instancer_for_render = False  # the emitter plane itself does not render
    bpy.context.view_layer.update()
    si = _collect(bpy)
    assert {k: v.count for k, v in si.instances.items()} == {("Emitter", "Box"): 5}, si.instances
    assert len(si.mesh.loop_start) == 64 + 1 + 5 * 6  # floor, ceiling, 5 boxes (not the emitter plane)
    assert "Emitter" not in [t.name for t in si.targets]
    emitter.show_instancer_for_render = True
    assert len(_collect(bpy).mesh.loop_start) == 64 + 1 + 1 + 5 * 6
    assert any("5 instance(s) take part" in w for w in si.warnings)
