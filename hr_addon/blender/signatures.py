"""Signatures of what a bake depends on, to tell when the scene changed since the bake.

The bake stores in its manifest, per participating object, a digest of its world-space geometry
as the bake reads it (evaluated mesh: float32 world positions, polygons, loops) and of the
material values used (reflectance and emission per material slot), and, per light shape, its
identity (name, mesh data, vertex and polygon counts, materials: light shapes are animated, so
not their positions). Instances are digested per (instancer, instanced object). Playback,
Preview, Reload and the panel compute the same digests and name the objects that differ. The bake
takes its digests from the same walk that reads the meshes (scene_in.collect_geometry); the digest
helpers live there.
"""

import hashlib

import bpy
import numpy as np

from .steps import finish
from .scene_in import (
    _hidden_instancer,
    _instance_digest,
    _joined,
    _mesh_digest,
    _object_digest,
    evaluated,
    geometry_objects,
    light_shape_objects,
    mesh_topology,
    participating_instances,
)


def _digest_arrays(me):
    """What the digests read of a mesh: scene_in._mesh_arrays without its loop triangles (which
    no digest uses: the same digests, without calc_loop_triangles per object)."""
    co, ls, lt, lv = mesh_topology(me)
    mi = np.zeros(len(ls), np.int32)
    if len(ls):
        me.polygons.foreach_get("material_index", mi)
    return co.astype(np.float64), ls, lt, lv, mi, None


def geometry_signatures(view_layer, depsgraph):
    """{object name (or 'instancer/source' for instances): hex digest} of everything that takes
    part in the light, as the bake reads it."""
    return finish(geometry_signature_steps(view_layer, depsgraph))


def geometry_signature_steps(view_layer, depsgraph):
    """geometry_signatures a step at a time (a generator: it yields None after each object, so that
    a caller on the UI thread can spread a big scene over several timer ticks; the dict is its
    return value). Objects are read when their step comes: an object removed meanwhile raises
    ReferenceError (the caller starts again)."""
    out, mat_cache = {}, {}
    for obj in geometry_objects(view_layer):
        if _hidden_instancer(obj):
            continue
        ob, arrays = evaluated(obj, depsgraph, _digest_arrays)
        if len(arrays[1]):
            out[obj.name] = _object_digest(ob, arrays, mat_cache).hexdigest()
        yield
    inst, mesh_cache = {}, {}
    for di, label in participating_instances(view_layer, depsgraph):
        me = di.object.data
        key = (me.as_pointer(), me.name)
        if key not in mesh_cache:
            arrays = _digest_arrays(me)
            mesh_cache[key] = _mesh_digest(arrays) if len(arrays[1]) else None
        if mesh_cache[key] is not None:
            inst.setdefault(label, []).append(_instance_digest(di, mesh_cache[key], mat_cache))
    out.update(_joined(inst))
    return out


def light_shape_identity(view_layer):
    """{light-shape object name: digest of its identity} (not its animated geometry)."""
    out = {}
    for obj in light_shape_objects(view_layer, include_hidden=True):
        me = obj.data
        mats = [getattr(s.material, "name_full", "") for s in obj.material_slots]
        key = repr((me.name, len(me.vertices), len(me.polygons), mats)).encode()
        out[obj.name] = hashlib.sha1(key).hexdigest()
    return out


def view_layer_of(scene, name=None):
    if name and name in scene.view_layers:
        return scene.view_layers[name]
    if bpy.context.scene == scene and bpy.context.view_layer is not None:
        return bpy.context.view_layer
    return scene.view_layers[0]
