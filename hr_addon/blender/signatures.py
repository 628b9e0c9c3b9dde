"""Signatures of what a bake depends on, to tell when the scene changed since the bake.

The bake stores in its manifest, per participating object, a digest of its world-space geometry
as the bake reads it (evaluated mesh: float32 world positions, polygons, loops) and of the
material values used (reflectance and emission per material slot), and, per light shape, its
identity (name, mesh data, vertex and polygon counts, materials: light shapes are animated, so
not their positions). Instances are digested per (instancer, instanced object). Playback,
Preview, Reload and the panel compute the same digests and name the objects that differ.
"""

import hashlib

import bpy
import numpy as np

from .materials import read_material
from .names import TAG
from .scene_in import (
    _hidden_instancer,
    _mesh_arrays,
    _walk_collections,
    evaluated,
    geometry_objects,
    light_shape_objects,
)


def _source_material(m):
    """The material a texture-preview helper copy stands for (the bake reads that one)."""
    if m is None:
        return None
    orig = getattr(m, "original", m)
    if orig.get(TAG) is None:
        return orig
    if orig.get("hr_lightmap_link", "DATA") == "OBJECT":
        return orig.get("hr_lightmap_source")
    return "DATA"


def _materials(ob):
    """Materials of an (evaluated) object's slots as the bake reads them."""
    out = []
    for i, slot in enumerate(ob.material_slots):
        m = _source_material(slot.material)
        if m == "DATA":  # helper on an object-level slot whose original link was the mesh's
            me = ob.original.data
            m = me.materials[i] if i < len(me.materials) else None
        out.append(m)
    return out or [None]


def _material_values(mats, cache):
    h = hashlib.sha1()
    for m in mats:
        key = None if m is None else m.name_full
        if key not in cache:
            s = read_material(m)
            cache[key] = np.concatenate(
                [np.asarray(s.reflectance, np.float64).ravel(), np.asarray(s.emission, np.float64).ravel()]
            ).tobytes()
        h.update(cache[key])
    return h.digest()


def _mesh_digest(arrays):
    co, ls, lt, lv, mi, _ = arrays
    h = hashlib.sha1()
    for a, t in ((ls, np.int64), (lt, np.int64), (lv, np.int64), (mi, np.int64)):
        h.update(np.ascontiguousarray(a, t).tobytes())
    return co, h.digest()


def _placed_digest(co, topo, matrix, matvals):
    M = np.asarray(matrix, np.float64)
    world = (co @ M[:3, :3].T + M[:3, 3]).astype(np.float32)
    h = hashlib.sha1(np.ascontiguousarray(world).tobytes())
    h.update(topo)
    h.update(matvals)
    return h


def geometry_signatures(view_layer, depsgraph):
    """{object name (or 'instancer/source' for instances): hex digest} of everything that takes
    part in the light, as the bake reads it."""
    out, mat_cache, mesh_cache = {}, {}, {}
    for obj in geometry_objects(view_layer):
        if _hidden_instancer(obj):
            continue
        ob, arrays = evaluated(obj, depsgraph)
        if len(arrays[1]) == 0:
            continue
        co, topo = _mesh_digest(arrays)
        out[obj.name] = _placed_digest(
            co, topo, ob.matrix_world, _material_values(_materials(ob), mat_cache)
        ).hexdigest()
    ok = {
        o.name
        for o in _walk_collections(view_layer)
        if not o.hide_render and not o.hr.exclude and not o.hr.is_light_shape
    }
    inst = {}
    for di in depsgraph.object_instances:
        if not di.is_instance or di.object is None or di.object.type != "MESH" or di.parent is None:
            continue
        instancer, source = di.parent.original, di.object.original
        if instancer.name not in ok or source.hr.exclude or source.hr.is_light_shape:
            continue
        me = di.object.data
        key = (me.as_pointer(), me.name)
        if key not in mesh_cache:
            arrays = _mesh_arrays(me)
            mesh_cache[key] = _mesh_digest(arrays) if len(arrays[1]) else None
        if mesh_cache[key] is None:
            continue
        co, topo = mesh_cache[key]
        h = _placed_digest(co, topo, di.matrix_world, _material_values(_materials(di.object), mat_cache))
        inst.setdefault(f"{instancer.name}/{source.name}", []).append(h.digest())
    for k, digests in inst.items():
        out[k] = hashlib.sha1(b"".join(sorted(digests))).hexdigest()
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
